"""Snakemake adapter: one call to huefringe.stages.rig_calibration_from."""
from huefringe.stages import rig_calibration_from, run_from_snakemake

run_from_snakemake(snakemake, rig_calibration_from)  # noqa: F821 (snakemake is injected by Snakemake)
