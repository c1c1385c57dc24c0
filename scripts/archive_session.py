"""Snakemake adapter: one call to huefringe.stages.archive_session."""
from huefringe.stages import archive_session, run_from_snakemake

run_from_snakemake(snakemake, archive_session)  # noqa: F821 (snakemake is injected by Snakemake)
