"""Snakemake adapter: one call to huefringe.stages.camera_calibration."""
from huefringe.stages import camera_calibration, run_from_snakemake

run_from_snakemake(snakemake, camera_calibration)  # noqa: F821 (snakemake is injected by Snakemake)
