"""Snakemake adapter: one call to huefringe.pipeline.measure_frames."""
from huefringe.pipeline import measure_frames, run_from_snakemake

run_from_snakemake(snakemake, measure_frames)  # noqa: F821 (snakemake is injected by Snakemake)
