"""Snakemake adapter: one call to huefringe.stages.measure_frames."""
from huefringe.stages import measure_frames, run_from_snakemake

run_from_snakemake(snakemake, measure_frames)  # noqa: F821 (snakemake is injected by Snakemake)
