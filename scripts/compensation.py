"""Snakemake adapter: one call to huefringe.stages.compensation."""
from huefringe.stages import compensation, run_from_snakemake

run_from_snakemake(snakemake, compensation)  # noqa: F821 (snakemake is injected by Snakemake)
