"""Snakemake adapter: one call to huefringe.stages.mesh_frame."""
from huefringe.stages import mesh_frame, run_from_snakemake

run_from_snakemake(snakemake, mesh_frame)  # noqa: F821 (snakemake is injected by Snakemake)
