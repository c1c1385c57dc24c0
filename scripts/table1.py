"""Snakemake adapter: one call to huefringe.stages.table1."""
from huefringe.stages import run_from_snakemake, table1

run_from_snakemake(snakemake, table1)  # noqa: F821 (snakemake is injected by Snakemake)
