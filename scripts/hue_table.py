"""Snakemake adapter: one call to huefringe.stages.hue_table."""
from huefringe.stages import hue_table, run_from_snakemake

run_from_snakemake(snakemake, hue_table)  # noqa: F821 (snakemake is injected by Snakemake)
