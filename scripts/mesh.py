"""Snakemake adapter: one call to huefringe.stages.mesh."""
from huefringe.stages import mesh, run_from_snakemake

run_from_snakemake(snakemake, mesh)  # noqa: F821 (snakemake is injected by Snakemake)
