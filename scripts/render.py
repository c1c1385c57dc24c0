"""Snakemake adapter: one call to huefringe.stages.render_frame."""
from huefringe.stages import render_frame, run_from_snakemake

run_from_snakemake(snakemake, render_frame)  # noqa: F821 (snakemake is injected by Snakemake)
