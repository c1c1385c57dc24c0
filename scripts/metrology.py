"""Snakemake adapter: one call to huefringe.stages.metrology_report."""
from huefringe.stages import metrology_report, run_from_snakemake

run_from_snakemake(snakemake, metrology_report)  # noqa: F821 (snakemake is injected by Snakemake)
