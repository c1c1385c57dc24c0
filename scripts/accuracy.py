"""Snakemake adapter: one call to huefringe.pipeline.accuracy_report."""
from huefringe.pipeline import accuracy_report, run_from_snakemake

run_from_snakemake(snakemake, accuracy_report)  # noqa: F821 (snakemake is injected by Snakemake)
