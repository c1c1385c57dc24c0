"""Snakemake adapter: one call to huefringe.stages.archive."""
from huefringe.stages import archive, run_from_snakemake

run_from_snakemake(snakemake, archive)  # noqa: F821 (snakemake is injected by Snakemake)
