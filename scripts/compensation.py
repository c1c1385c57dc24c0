"""Snakemake adapter: one call to huefringe.pipeline.compensation."""
from huefringe.pipeline import compensation, run_from_snakemake

run_from_snakemake(snakemake, compensation)  # noqa: F821 (snakemake is injected by Snakemake)
