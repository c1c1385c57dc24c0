# The virtual bench writes the sessions listed under bench_sessions when they are absent.

for _sid, _plan in PLANS.items():
    if _plan.bench is None:
        continue

    rule:
        name:
            f"bench_{_sid.replace('-', '_')}"
        output:
            f"{_plan.path}/session.yaml",
        params:
            config=_plan.bench,
            out=lambda wildcards, output: str(Path(output[0]).parent),
            period_px=_plan.period_px,
        log:
            f"logs/bench/{_sid}.log",
        threads: 1
        resources:
            mem_mb=2000,
            runtime=30,
        conda:
            "../envs/huefringe.yaml"
        script:
            "../../scripts/bench_session.py"
