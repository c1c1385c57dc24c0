"""Snakemake adapter: one call to huefringe.stages.accuracy_report."""
from huefringe.stages import accuracy_report, run_from_snakemake

run_from_snakemake(snakemake, accuracy_report)  # noqa: F821 (snakemake is injected by Snakemake)
