"""Snakemake adapter: one call to huefringe.stages.baseline_frames."""
from huefringe.stages import baseline_frames, run_from_snakemake

run_from_snakemake(snakemake, baseline_frames)  # noqa: F821 (snakemake is injected by Snakemake)
