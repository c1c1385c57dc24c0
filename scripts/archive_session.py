"""Snakemake adapter: one call to huefringe.pipeline.archive_session."""
from huefringe.pipeline import archive_session, run_from_snakemake

run_from_snakemake(snakemake, archive_session)  # noqa: F821 (snakemake is injected by Snakemake)
