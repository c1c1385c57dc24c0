"""Snakemake adapter: one call to huefringe.stages.rig_oneshot."""
from huefringe.stages import rig_oneshot, run_from_snakemake

run_from_snakemake(snakemake, rig_oneshot)  # noqa: F821 (snakemake is injected by Snakemake)
