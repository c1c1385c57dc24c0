"""Snakemake adapter: one call to huefringe.stages.bench_session."""
from huefringe.stages import bench_session, run_from_snakemake

run_from_snakemake(snakemake, bench_session)  # noqa: F821 (snakemake is injected by Snakemake)
