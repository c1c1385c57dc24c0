"""Snakemake adapter: one call to huefringe.stages.cloud_frames."""
from huefringe.stages import cloud_frames, run_from_snakemake

run_from_snakemake(snakemake, cloud_frames)  # noqa: F821 (snakemake is injected by Snakemake)
