"""Snakemake adapter: one call to huefringe.pipeline.check_session."""
from huefringe.pipeline import check_session, run_from_snakemake

run_from_snakemake(snakemake, check_session)  # noqa: F821 (snakemake is injected by Snakemake)
