"""Snakemake adapter: one call to huefringe.pipeline.render_frame."""
from huefringe.pipeline import render_frame, run_from_snakemake

run_from_snakemake(snakemake, render_frame)  # noqa: F821 (snakemake is injected by Snakemake)
