"""Snakemake adapter: one call to huefringe.stages.rig_accuracy."""
from huefringe.stages import rig_accuracy, run_from_snakemake

run_from_snakemake(snakemake, rig_accuracy)  # noqa: F821 (snakemake is injected by Snakemake)
