"""Snakemake adapter: one call to huefringe.stages.check_session."""
from huefringe.stages import check_session, run_from_snakemake

run_from_snakemake(snakemake, check_session)  # noqa: F821 (snakemake is injected by Snakemake)
