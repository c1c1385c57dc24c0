"""Snakemake adapter: one call to huefringe.stages.metrology."""
from huefringe.stages import metrology, run_from_snakemake

run_from_snakemake(snakemake, metrology)  # noqa: F821 (snakemake is injected by Snakemake)
