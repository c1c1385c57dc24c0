"""Snakemake adapter: one call to huefringe.stages.render."""
from huefringe.stages import render, run_from_snakemake

run_from_snakemake(snakemake, render)  # noqa: F821 (snakemake is injected by Snakemake)
