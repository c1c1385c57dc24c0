"""Snakemake adapter: one call to huefringe.pipeline.baseline_frames."""
from huefringe.pipeline import baseline_frames, run_from_snakemake

run_from_snakemake(snakemake, baseline_frames)  # noqa: F821 (snakemake is injected by Snakemake)
