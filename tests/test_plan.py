"""Measurement batches sized from the configuration and the session's length (plan.batch_frames),
the same in every Snakemake process of a run whatever its cores."""

import pytest

from huefringe.plan import batch_frames


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 19, 20, 21, 199, 200, 251, 600, 1000, 1001])
@pytest.mark.parametrize("parallel", [1, 2, 3, 4, 8])
@pytest.mark.parametrize("cap", [1, 7, 100, 250])
def test_batches_cover_the_session_in_order_within_the_cap(n, parallel, cap):
    frames = list(range(10, 10 + n))
    batches = batch_frames(frames, parallel, cap)
    assert [f for b in batches for f in b] == frames  # every frame once, in order
    assert all(1 <= len(b) <= cap for b in batches)
    if batches:
        sizes = [len(b) for b in batches]
        assert max(sizes) - min(sizes) <= 1  # balanced
        assert len(batches) == min(n, len(batches))
        # as few jobs as the cap allows, rounded up to a multiple of ``parallel`` (no idle core
        # in the last round), but never more jobs than frames
        need = -(-n // cap)
        assert len(batches) == min(n, -(-need // parallel) * parallel)


@pytest.mark.parametrize("parallel", [1, 2, 4, 8])
@pytest.mark.parametrize("per_job", [2, 3, 10, 125])
def test_two_frames_per_job_keep_every_job_busy(parallel, per_job):
    batches = batch_frames(list(range(parallel * per_job)), parallel, cap=250)
    assert len(batches) >= parallel
    assert len(batches) % parallel == 0


def test_known_sizes():
    # 200 frames for 2 parallel jobs: two of 100 (not one of 200 and an idle core); 1000: 4 of 250
    assert [len(b) for b in batch_frames(list(range(200)), 2, 250)] == [100, 100]
    assert [len(b) for b in batch_frames(list(range(1000)), 2, 250)] == [250] * 4
    assert [len(b) for b in batch_frames(list(range(20)), 2, 250)] == [10, 10]
    assert [len(b) for b in batch_frames(list(range(600)), 2, 250)] == [150] * 4
    assert batch_frames([5], 4, 250) == [[5]]
    assert batch_frames([], 2, 250) == []
    assert [len(b) for b in batch_frames(list(range(10)), 0, 250)] == [10]  # below 1 counts as 1


def test_bad_cap_is_refused():
    with pytest.raises(ValueError, match="at least 1"):
        batch_frames([0, 1], 2, 0)


def _plan_config(parallel_jobs: int) -> dict:
    import json

    from bench_helpers import CONFIG

    cfg = json.loads(json.dumps(CONFIG))
    cfg["measurement"]["parallel_jobs"] = parallel_jobs
    cfg["measurement"]["frames_per_job"] = 4
    cfg["sessions"] = ["sessions/plan-demo"]
    cfg["bench_sessions"] = {"sessions/plan-demo": "demo"}
    cfg.pop("table1", None)
    return cfg


def test_plan_follows_the_configuration(tmp_path):
    from huefringe.plan import plan_sessions

    cfg = _plan_config(3)
    (plan,) = plan_sessions(cfg, base=tmp_path).values()  # the demo preset: 10 frames, phase-shift captures
    assert [len(b) for b in plan.batches] == [4, 3, 3]  # 3 jobs hold 10 frames within 4 per job
    assert plan.phase_shift_batches == plan.batches
    cfg["measurement"]["parallel_jobs"] = 2
    (plan,) = plan_sessions(cfg, base=tmp_path).values()
    assert [len(b) for b in plan.batches] == [3, 3, 2, 2]  # 3 jobs needed, rounded up to 4


def test_workflow_plan_is_the_same_whatever_the_cores(tmp_path):
    """The submitting Snakemake of a cluster run has no --cores, the job-side one --cores all: one plan."""
    import os
    import subprocess
    import sys

    import yaml
    from bench_helpers import REPO

    cfg = _plan_config(2)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    jobs = {}
    for cores in (["--cores", "1"], ["--cores", "2"], ["--cores", "all"], ["--jobs", "100"]):
        proc = subprocess.run(
            [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(tmp_path),
             "-n", "--quiet", "rules", *cores],
            capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"})
        assert proc.returncode == 0, proc.stderr[-3000:]
        rows = [line.split() for line in (proc.stdout + proc.stderr).splitlines()]
        jobs[" ".join(cores)] = sorted({r[0] for r in rows if len(r) == 2 and r[0].startswith(("measure_frames", "baseline_frames"))})
    first = next(iter(jobs.values()))
    assert first == [f"{k}_frames_gauge_blocks_demo_{b:03d}" for k in ("baseline", "measure") for b in range(4)], jobs
    assert all(v == first for v in jobs.values()), jobs
