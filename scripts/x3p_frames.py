"""Snakemake adapter: one call to huefringe.stages.x3p_frames."""
from huefringe.stages import run_from_snakemake, x3p_frames

run_from_snakemake(snakemake, x3p_frames)  # noqa: F821 (snakemake is injected by Snakemake)
