"""Snakemake adapter: one call to huefringe.stages.plane_calibration."""
from huefringe.stages import plane_calibration, run_from_snakemake

run_from_snakemake(snakemake, plane_calibration)  # noqa: F821 (snakemake is injected by Snakemake)
