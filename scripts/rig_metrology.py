"""Snakemake adapter: one call to huefringe.stages.rig_metrology."""
from huefringe.stages import rig_metrology, run_from_snakemake

run_from_snakemake(snakemake, rig_metrology)  # noqa: F821 (snakemake is injected by Snakemake)
