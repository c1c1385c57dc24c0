"""Snakemake adapter: one call to huefringe.stages.rig_calibrate."""
from huefringe.stages import rig_calibrate, run_from_snakemake

run_from_snakemake(snakemake, rig_calibrate)  # noqa: F821 (snakemake is injected by Snakemake)
