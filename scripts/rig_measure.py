"""Snakemake adapter: one call to huefringe.stages.rig_measure."""
from huefringe.stages import rig_measure, run_from_snakemake

run_from_snakemake(snakemake, rig_measure)  # noqa: F821 (snakemake is injected by Snakemake)
