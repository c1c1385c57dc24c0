"""The workflow on a real single-node SLURM through ``workflow/profiles/slurm``, byte for byte a local run.

The cluster (Debian's ``slurm-wlm`` and ``munge``, no accounting, loopback) is started by a
session fixture (``slurm_cluster.LocalSlurm``) and stopped by process id afterwards. A dry run
cannot show what this checks: the job-side Snakemake plans the same batches as the submitting
one, every job writes all its declared outputs, the status queries end (``squeue``, there being
no accounting for ``sacct``), and each SLURM job is given the cores, memory and time its rule
declares.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from bench_helpers import CONFIG, REPO, bench_config
from slurm_cluster import LocalSlurm, missing_reason

PROFILE = REPO / "workflow" / "profiles" / "slurm"

_why_not = missing_reason() or (
    None if importlib.util.find_spec("snakemake_executor_plugin_slurm")
    else "snakemake-executor-plugin-slurm not installed (the 'slurm' extra; tools/bootstrap.sh installs it)"
)
# slow: two dozen dependent SLURM jobs, mostly Snakemake starting in each and the plugin's status polls. It shares
# nothing with tests running beside it (pytest -n 2): its own ports, temp folder and daemons.
pytestmark = [pytest.mark.slow, pytest.mark.skipif(_why_not is not None, reason=_why_not or "")]

FRAMES = 4


@pytest.fixture(scope="session")
def slurm(tmp_path_factory: pytest.TempPathFactory):
    cluster = LocalSlurm(tmp_path_factory.mktemp("slurm"))
    try:
        cluster.start()
        yield cluster
    finally:
        cluster.stop()


def _workdir(path: Path) -> Path:
    """A small gauge-block bench session with phase-shift captures, in two batches of two frames,
    and the bench rig's gauge (a structured-light session) with the session that calibrates it."""
    path.mkdir(parents=True)
    bench = bench_config("demo", width=200, height=150, hue_bands=24, repeats=2, frames=FRAMES, id="slurm-demo")
    bench["scene"]["blocks"] = [
        {"name": "green", "nominal_mm": 3.0, "reflectance": [0.12, 0.65, 0.18], "rect_mm": [6.0, 10.0, 12.0, 20.0]},
        {"name": "blue", "nominal_mm": 1.0, "reflectance": [0.15, 0.25, 0.7], "rect_mm": [17.0, 10.0, 23.0, 20.0]},
        {"name": "red", "nominal_mm": 4.0, "reflectance": [0.7, 0.15, 0.12], "rect_mm": [28.0, 10.0, 34.0, 20.0]},
    ]
    (path / "bench.yaml").write_text(yaml.safe_dump(bench))
    cfg = json.loads(json.dumps(CONFIG))
    cfg["sessions"] = ["sessions/slurm-demo", "sessions/rig-gauge"]
    cfg["bench_sessions"] = {"sessions/slurm-demo": "bench.yaml", "sessions/rig-gauge": "rig-gauge",
                             "sessions/rig-poses": "rig-poses"}
    cfg["render"].update(width=320, height=240)
    cfg["measurement"]["parallel_jobs"] = 2
    cfg.pop("table1", None)
    (path / "config.yaml").write_text(yaml.safe_dump(cfg))
    return path


def _snakemake_start(workdir: Path, *args: str, env: dict[str, str]) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir), *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**env, "PYTHONHASHSEED": "0"})


def _snakemake_wait(proc: subprocess.Popen) -> subprocess.CompletedProcess:
    try:
        out, err = proc.communicate(timeout=1800)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    if proc.returncode != 0:
        raise AssertionError(f"{' '.join(proc.args)} failed ({proc.returncode}):\n{out[-4000:]}\n{err[-8000:]}")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _snakemake(workdir: Path, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return _snakemake_wait(_snakemake_start(workdir, *args, env=env))


def _outputs(workdir: Path) -> dict[str, str]:
    """sha256 of every file the workflow wrote: the bench session and results/ (not logs/, .snakemake/)."""
    out = {}
    for top in ("sessions", "results"):
        for f in sorted((workdir / top).rglob("*")):
            if f.is_file():
                out[str(f.relative_to(workdir))] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def _minutes(limit: str) -> int:
    """SLURM's time limit (``[D-]HH:MM:SS`` or ``MM:SS``) in minutes."""
    days, _, hms = limit.rpartition("-")
    parts = [int(p) for p in hms.split(":")]
    while len(parts) < 3:
        parts.insert(0, 0)
    h, m, s = parts
    return (int(days or 0) * 24 + h) * 60 + m + (s > 0)


def _declared(log: str) -> dict[str, dict[str, int | str]]:
    """SLURM job id -> the rule, threads, mem_mb and runtime Snakemake declared for it (from its log).

    Snakemake prints each job (``rule NAME:`` ... ``jobid: N`` ... ``resources: ...``) before
    the plugin reports ``Job N has been submitted with SLURM jobid M``, several jobs at a time.
    """
    jobs: dict[str, dict[str, int | str]] = {}
    for block in re.split(r"\n(?=(?:local)?rule \S+:)", log):
        head = re.match(r"(?:local)?rule (\S+):", block)
        jobid = re.search(r"\n\s+jobid: (\d+)", block)
        res = re.search(r"\n\s+resources: (.*)", block)
        if not (head and jobid and res):
            continue
        kv = dict(p.split("=", 1) for p in res.group(1).split(", "))
        threads = re.search(r"\n\s+threads: (\d+)", block)
        jobs[jobid.group(1)] = {"rule": head.group(1), "threads": int(threads.group(1)) if threads else 1,
                                "mem_mb": int(kv["mem_mb"]), "runtime": int(kv["runtime"])}
    return {slurm_id: jobs[job] for job, slurm_id in re.findall(r"Job (\d+) has been submitted with SLURM jobid (\d+)", log)}


def _bench_sessions(tmp_path: Path, *workdirs: Path) -> None:
    """The bench's sessions written once, by a local run of their rule, and copied into each
    workdir: the runs compared measure the same bytes, and the cluster runs the measuring jobs."""
    prep = _workdir(tmp_path / "prep")
    targets = [f"sessions/{s}/session.yaml" for s in ("slurm-demo", "rig-gauge", "rig-poses")]
    _snakemake(prep, "--cores", "2", *targets, env=dict(os.environ))
    for wd in workdirs:
        shutil.copytree(prep / "sessions", wd / "sessions")


def test_profile_run_matches_a_local_run_byte_for_byte(slurm: LocalSlurm, tmp_path: Path) -> None:
    local, cluster = _workdir(tmp_path / "local"), _workdir(tmp_path / "cluster")
    _bench_sessions(tmp_path, local, cluster)
    # the local reference runs while the cluster run waits for its jobs
    reference = _snakemake_start(local, "--cores", "2", env=dict(os.environ))
    # the profile as documented; only the first status check comes sooner than a real cluster needs
    proc = _snakemake(cluster, "--profile", str(PROFILE), "--slurm-init-seconds-before-status-checks", "2",
                      env=slurm.env)
    local_log = _snakemake_wait(reference).stderr
    log = proc.stdout + proc.stderr

    want, got = _outputs(local), _outputs(cluster)
    assert len(want) > 60, sorted(want)
    assert sorted(got) == sorted(want)
    differ = [f for f in want if got[f] != want[f]]
    assert differ == [], f"{len(differ)} of {len(want)} files differ from the local run: {differ}"

    # one SLURM job per rule instance, each given what its rule declares
    declared = _declared(log)
    ran_locally = sorted(r for r in re.findall(r"Finished jobid: \d+ \(Rule: (\S+)\)", local_log) if r != "all")
    assert sorted(str(d["rule"]) for d in declared.values()) == ran_locally
    assert len(ran_locally) >= 19 and ran_locally.count("hue_table") == 2
    assert {"rig_calibrate", "rig_calibration_from", "rig_measure", "rig_surfaces", "rig_metrology",
            "rig_accuracy"} <= set(ran_locally)
    rows = slurm.run("squeue", "--states=all", "--noheader", "--format=%i|%T|%C|%m|%l|%k", check=True).stdout
    seen = {}
    for row in rows.split():
        jobid, state, cpus, mem, limit, comment = row.split("|")
        seen[jobid] = (state, int(cpus), mem, _minutes(limit), comment)
    for jobid, want_res in declared.items():
        state, cpus, mem, minutes, comment = seen[jobid]
        assert state == "COMPLETED", (jobid, comment, state)
        assert comment.startswith(f"rule_{want_res['rule']}"), (comment, want_res)
        assert cpus == want_res["threads"], (comment, cpus, want_res)
        assert mem == f"{want_res['mem_mb']}M", (comment, mem, want_res)
        assert minutes == want_res["runtime"], (comment, minutes, want_res)
    # the batches the submitting Snakemake planned are the ones the jobs ran
    batch_jobs = sorted(c for _, _, _, _, c in seen.values() if c.startswith("rule_measure_frames"))
    assert batch_jobs == ["rule_measure_frames_slurm_demo_000", "rule_measure_frames_slurm_demo_001"]
    # the profile keeps every job's SLURM log (a job that 'succeeds' short of its outputs is then
    # still explained); the rule logs are where a local run writes them
    slurm_logs = list((cluster / "logs" / "slurm").rglob("*.log"))
    assert len(slurm_logs) == len(declared)
    assert (cluster / "logs" / "slurm-demo" / "measure_001.log").is_file()
