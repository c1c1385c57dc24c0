# The virtual bench writes the sessions listed under bench_sessions (and the Table 1 sweep) when
# they are absent; {bench_dir} is one of their folders (constrained in common.smk).
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/bench.smk).


rule bench_session:
    output:
        "{bench_dir}/session.yaml",
    log:
        "logs/bench/{bench_dir}.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        config=lambda w: BENCH_PLANS[w.bench_dir].bench,
        out=lambda w: w.bench_dir,
        period_px=lambda w: BENCH_PLANS[w.bench_dir].period_px,
    script:
        "../../scripts/bench_session.py"
