"""Snakemake adapter: one call to huefringe.stages.rig_surfaces."""
from huefringe.stages import rig_surfaces, run_from_snakemake

run_from_snakemake(snakemake, rig_surfaces)  # noqa: F821 (snakemake is injected by Snakemake)
