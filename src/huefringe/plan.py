"""Plan the workflow at parse time: which sessions, their ids, frames, batches and selections.

Snakemake needs every output path before it runs anything, so the plan is made from the session
folders (validated here, before any work starts) or, for a session the virtual bench will write,
from its bench configuration.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from huefringe import bench
from huefringe.codecs.sequence import HueBandsBlock
from huefringe.patterns import single_repeat_problem
from huefringe.rig.decoded import relative_axes_problems
from huefringe.session import SL_FORMAT, SessionError, load_session, load_sl_session, session_format


class PlanError(ValueError):
    """The configuration cannot be planned (bad session, clashing ids, unknown frames)."""


def config_problems(config: dict[str, Any], schema: str | Path) -> list[str]:
    """The ways ``config`` breaks the workflow's JSON schema, one line each (``key.path: what``).

    For a short message before Snakemake's own validation (which fills in defaults but reports
    a problem with the whole schema attached).
    """
    import jsonschema
    import yaml

    doc = yaml.safe_load(Path(schema).read_text(encoding="utf-8"))
    validator = jsonschema.validators.validator_for(doc)(doc)
    out = []
    for err in sorted(validator.iter_errors(config), key=lambda e: [str(p) for p in e.absolute_path]):
        where = ".".join(str(p) for p in err.absolute_path) or "(top level)"
        out.append(f"{where}: {err.message}")
    return out


@dataclass
class SessionPlan:
    path: Path
    id: str
    frames: list[int]
    phase_shift: list[int]
    ground_truth: bool
    specimen: bool
    bench: str | None = None
    """Bench preset or YAML that writes this session when it is absent."""
    period_px: float | None = None
    """Fringe period overriding the bench YAML's (a period sweep, paper Table 1)."""
    batches: list[list[int]] = field(default_factory=list)
    """The measurement jobs' frames (:func:`batch_frames`)."""
    phase_shift_batches: list[list[int]] = field(default_factory=list)
    """The three-step baseline jobs' frames (:func:`batch_frames` of ``phase_shift``)."""
    kind: str = "capture"
    """``capture`` (capture-session/1: planes and the one-shot hue) or ``structured-light``
    (structured-light-session/1: coded light triangulated with a rig calibration)."""
    calibrate: bool = False
    """Structured light: the workflow calibrates the rig from this session's poses and board (rule rig_calibrate)."""
    calibration_file: str | None = None
    """Structured light: the session's own calibration file (relative to the session folder)."""
    calibration_session: Path | None = None
    """Structured light: the folder of the session whose poses calibrate this one, as named."""
    calibrated_by: str | None = None
    """Structured light: id of the session whose ``calib/rig.yml`` this one is measured with."""
    measure: bool = True
    """False for a calibration session that only the sessions naming it brought into the run."""
    sequence: Any = field(default=None, repr=False)
    """Structured light, read from the folder: its ``huefringe.codecs.SequenceSpec``."""
    oneshot_frames: int = 0
    """Structured light: the sequence's one-shot (``trapezoid``) frames, measured by rule
    ``rig_oneshot_<sid>`` into ``frame_0000 ..``; 0 for a coded session (rule ``rig_measure``)."""
    oneshot_axis: str | None = None
    """Structured light: the trapezoid blocks' axis (None without one-shot frames)."""
    oneshot_reference: Path | None = None
    """Structured light: the folder of the session whose coded captures are the one-shot frames'
    order reference (``oneshot: {reference: {session: PATH}}``), as named; None: its own coded blocks."""
    reference_id: str | None = None
    """Structured light: id of the session ``oneshot_reference`` names (in the run, measured or not)."""
    reference_absolute: dict[str, bool] | None = None
    """Structured light, read from the folder or the bench YAML: whether the sequence decodes absolutely
    along each axis (``{"x": bool, "y": bool}``), for a session that is another's order reference."""

    def frame_selection(self, sel: Any) -> list[int]:
        if sel == "first":
            return self.frames[:1]
        if sel == "all":
            return list(self.frames)
        missing = [f for f in sel if f not in self.frames]
        if missing:
            raise PlanError(f"session '{self.id}': frames {missing} selected in the config do not exist")
        return list(sel)


def _unmeasurable_bands(n_bands: int, repeats: int, where: str) -> str | None:
    """Why the hue bands of a session cannot be measured (:func:`huefringe.patterns.single_repeat_problem`),
    prefixed with where they are declared; None where they can."""
    too_few = single_repeat_problem(n_bands, repeats)
    return None if too_few is None else f"at {where}: cannot be measured: {too_few}"


def _from_sl_session(path: Path) -> SessionPlan:
    s = load_sl_session(path)
    hue = next((b for b in s.spec.blocks if isinstance(b, HueBandsBlock)), None)
    bad = (None if hue is None or not s.spec.oneshot_frames
           else _unmeasurable_bands(hue.n, hue.repeats, "the sequence's hue_bands"))
    if bad:
        raise SessionError.at(path / "session.yaml", bad)
    cal = s.meta.get("calibration", {})
    return SessionPlan(
        path=path,
        id=s.id,
        frames=[0],
        phase_shift=[],
        ground_truth="xyz" in s.ground_truth,
        specimen=s.features is not None,
        kind="structured-light",
        calibrate=bool(s.poses) and s.board is not None,
        calibration_file=cal.get("file"),
        calibration_session=s.calibration_session,
        sequence=s.spec,
        oneshot_frames=s.spec.oneshot_frames,
        oneshot_axis=_trapezoid_axis(s.spec),
        oneshot_reference=s.oneshot_reference,
        reference_absolute=_absolute_axes(s.spec),
    )


def _trapezoid_axis(spec: Any) -> str | None:
    from huefringe.codecs.sequence import TrapezoidBlock

    return next((b.axis for b in spec.blocks if isinstance(b, TrapezoidBlock)), None)


def _absolute_axes(spec: Any) -> dict[str, bool]:
    from huefringe.codecs.sequence import axis_is_absolute

    return {a: bool(axis_is_absolute(spec, a)) for a in ("x", "y")}


def _from_session(path: Path) -> SessionPlan:
    if session_format(path) == SL_FORMAT:
        return _from_sl_session(path)
    s = load_session(path)
    bad = _unmeasurable_bands(s.hue_bands, s.repeats, "pattern")
    if bad:
        raise SessionError.at(path / "session.yaml", bad)
    return SessionPlan(
        path=path,
        id=s.id,
        frames=s.frame_ids,
        phase_shift=sorted(s.phase_shift),
        ground_truth=bool(s.ground_truth) and sorted(s.ground_truth) == s.frame_ids,
        specimen=s.specimen is not None,
    )


def bench_yaml(bench_ref: str, base: str | Path = ".") -> Path:
    """The bench YAML a config names: a path (``.yaml``/``.yml``, relative to ``base``) or a preset."""
    ref = Path(base) / bench_ref
    return ref if ref.suffix in (".yaml", ".yml") else bench.preset_path(bench_ref)


def bench_config_for(bench_ref: str, base: str | Path = ".", period_px: float | None = None) -> dict[str, Any]:
    """The bench configuration of a preset name or YAML path, optionally at another period
    (:func:`huefringe.bench.sweep_config`: the session id gets the suffix ``-p<period>``)."""
    cfg = bench.load_bench_config(bench_yaml(bench_ref, base))
    return cfg if period_px is None else bench.sweep_config(cfg, period_px)


def _from_bench(path: Path, cfg: dict[str, Any], cfg_path: Path, period_px: float | None = None) -> SessionPlan:
    bad = _unmeasurable_bands(int(cfg["session"]["hue_bands"]), int(cfg["session"]["repeats"]), "session")
    if bad:
        raise bench.BenchConfigError(cfg_path, bad)
    frames = list(range(int(cfg["session"]["frames"])))
    return SessionPlan(
        path=path,
        id=str(cfg["session"]["id"]),
        frames=frames,
        phase_shift=frames if cfg["phase_shift"]["enabled"] else [],
        ground_truth=bool(cfg["session"]["ground_truth"]),
        specimen=cfg["scene"]["kind"] == "gauge_blocks",
        bench=str(cfg_path),
        period_px=period_px,
    )


def batch_frames(frames: list[int], parallel: int, cap: int) -> list[list[int]]:
    """Split a session's frames into measurement batches that keep ``parallel`` jobs busy.

    The number of batches is the smallest multiple of ``parallel`` that holds every frame with
    at most ``cap`` frames per batch (a multiple, so the last round of jobs leaves no core
    idle), but never more than one batch per frame; the frames are dealt out in order in
    batches whose sizes differ by at most one. A session with at least two frames per job so
    runs on every core, and ``cap`` (``measurement.frames_per_job``) only bounds a job's length.

    The result depends on its arguments only: the workflow takes them from the configuration
    (``measurement.parallel_jobs``, ``measurement.frames_per_job``), never from the cores of
    the Snakemake process that plans, so the submitting Snakemake and the job-side ones of a
    cluster executor plan the same batches.

    Parameters
    ----------
    frames : list of int
        The session's frame numbers, in order.
    parallel : int
        Jobs meant to run at once (``measurement.parallel_jobs``); values below 1 count as 1.
    cap : int
        Most frames per batch (>= 1).

    Returns
    -------
    list of list of int
        Consecutive runs of ``frames``; empty when ``frames`` is.

    Examples
    --------
    >>> [len(b) for b in batch_frames(list(range(200)), parallel=2, cap=250)]
    [100, 100]
    >>> [len(b) for b in batch_frames(list(range(600)), parallel=2, cap=250)]
    [150, 150, 150, 150]
    >>> batch_frames([0, 1, 2], parallel=4, cap=250)
    [[0], [1], [2]]
    """
    if cap < 1:
        raise ValueError(f"frames per job must be at least 1, got {cap}")
    n = len(frames)
    if n == 0:
        return []
    parallel = max(1, int(parallel))
    jobs = -(-n // cap)
    jobs = min(n, -(-jobs // parallel) * parallel)
    size, extra = divmod(n, jobs)
    out, start = [], 0
    for j in range(jobs):
        stop = start + size + (1 if j < extra else 0)
        out.append(list(frames[start:stop]))
        start = stop
    return out


def plan_sessions(config: dict[str, Any], base: str | Path = ".") -> dict[str, SessionPlan]:
    """Plan every session of the configuration, keyed by session id.

    The frames are measured in batches of :func:`batch_frames` (a multiple of
    ``measurement.parallel_jobs`` jobs, at most ``measurement.frames_per_job`` frames each): the
    plan depends on the configuration and the session folders only, so every Snakemake process
    of a run, wherever it evaluates the workflow, makes the same one.

    Raises
    ------
    PlanError
        With a message naming every refused session folder or file and its problems (all of
        them at once, so a long list of sessions is fixed in one pass).
    """
    base = Path(base)
    bench_sessions = {str(Path(k)): v for k, v in (config.get("bench_sessions") or {}).items()}
    plans: dict[str, SessionPlan] = {}
    refused: list[str] = []
    for entry in config["sessions"]:
        path = Path(entry)
        full = path if path.is_absolute() else base / path
        try:
            plan = _plan_folder(path, base, bench_sessions)
        except SessionError as exc:
            refused.append(f"session {entry} is refused:\n{exc}")
            continue
        except bench.BenchConfigError as exc:
            refused.append(f"session {entry} cannot be written by the bench:\n{exc}")
            continue
        _add(plans, plan, config)
    refused += _link_references(plans, base, config, bench_sessions)
    refused += _link_calibrations(plans, base, config, bench_sessions)
    if refused:
        head = f"{len(refused)} of {len(config['sessions'])} sessions refused:\n" if len(refused) > 1 else ""
        raise PlanError(head + "\n".join(refused))
    return plans


def _plan_folder(path: Path, base: Path, bench_sessions: dict[str, str]) -> SessionPlan:
    """The plan of the session folder ``path``: read from it, or from the bench YAML that writes it."""
    full = path if path.is_absolute() else base / path
    if (full / "session.yaml").exists() or str(path) not in bench_sessions:
        plan = _from_session(full)
        plan.path = path
        return plan
    ref = bench_sessions[str(path)]
    cfg_path = bench_yaml(ref, base)
    if bench.bench_kind(cfg_path) == SL_FORMAT:
        return _from_sl_bench(path, cfg_path)
    return _from_bench(path, bench_config_for(ref, base), cfg_path)


def _from_sl_bench(path: Path, cfg_path: Path) -> SessionPlan:
    info = bench.sl_session_plan(bench.load_sl_bench_config(cfg_path))
    bad = None if info["hue_bands"] is None or not info["oneshot_frames"] else _unmeasurable_bands(
        *info["hue_bands"], "sequence.blocks' hue_bands")
    if bad:
        raise bench.BenchConfigError(cfg_path, bad)
    cal, ref = info["calibration_session"], info["oneshot_reference"]
    return SessionPlan(path=path, id=str(info["id"]), frames=[0], phase_shift=[], ground_truth=bool(info["ground_truth"]),
                       specimen=bool(info["features"]), bench=str(cfg_path), kind="structured-light",
                       calibrate=bool(info["poses"]), calibration_session=None if cal is None else path / cal,
                       oneshot_frames=int(info["oneshot_frames"]), oneshot_axis=info["oneshot_axis"],
                       oneshot_reference=None if ref is None else path / ref, reference_absolute=info["absolute_axes"])


def _link_references(plans: dict[str, SessionPlan], base: Path, config: dict[str, Any],
                     bench_sessions: dict[str, str]) -> list[str]:
    """Give each one-shot session that names a reference session (``oneshot: {reference: {session:
    PATH}}``) that session: one of the run, else added to it (not measured) from its folder or the
    bench YAML that writes it; refused when it cannot be read or does not decode absolutely along the
    trapezoid's axis."""
    full, by_path, bench_by_path = _run_folders(plans, base, bench_sessions)
    refused = []
    for plan in list(plans.values()):
        if plan.oneshot_reference is None or not plan.measure:
            continue
        target = full(plan.oneshot_reference)
        other = _session_of_run(target, plans, by_path, bench_by_path, base, config, bench_sessions, refused,
                                f"session {plan.path}: its one-shot reference session {target}")
        if other is None:
            continue
        axis = plan.oneshot_axis or "x"
        if other.kind != "structured-light":
            refused.append(f"session {plan.path}: its one-shot reference session {target} is not a structured-light "
                           "session")
        elif not (other.reference_absolute or {}).get(axis, False):
            seq = full(other.path) / "sequence.yaml"
            refused.append(f"session {plan.path}: its one-shot reference session {target}: {seq} does not decode "
                           f"absolutely along {axis}, the trapezoid's axis (Gray code + phase, or two periods): no order "
                           "reference")
        else:
            plan.reference_id = other.id
    return refused


def _run_folders(plans: dict[str, SessionPlan], base: Path, bench_sessions: dict[str, str]
                 ) -> tuple[Callable[[Path], Path], dict[Path, SessionPlan], dict[Path, Path]]:
    """Resolving a session folder against ``base``, the run's plans by resolved folder, and the bench
    sessions' folders by resolved folder."""
    def full(p: Path) -> Path:
        return (p if p.is_absolute() else base / p).resolve()

    return full, {full(p.path): p for p in plans.values()}, {full(Path(k)): Path(k) for k in bench_sessions}


def _session_of_run(target: Path, plans: dict[str, SessionPlan], by_path: dict[Path, SessionPlan],
                    bench_by_path: dict[Path, Path], base: Path, config: dict[str, Any],
                    bench_sessions: dict[str, str], refused: list[str], what: str) -> SessionPlan | None:
    """The run's plan of the session folder ``target`` (resolved), else that session added to the run,
    not measured, from its folder or the bench YAML that writes it; None, with ``what`` and the cause
    in ``refused``, when it cannot be read."""
    other = by_path.get(target)
    if other is None:
        try:
            other = _plan_folder(bench_by_path.get(target, target), base, bench_sessions)
        except (SessionError, bench.BenchConfigError) as exc:
            refused.append(f"{what} is refused:\n{exc}")
            return None
        other.measure = False
        _add(plans, other, config)
        by_path[target] = other
    return other


def _link_calibrations(plans: dict[str, SessionPlan], base: Path, config: dict[str, Any],
                       bench_sessions: dict[str, str]) -> list[str]:
    """Give each structured-light session its calibration: its own file, the session it names (added to
    the run, calibration only, when the configuration does not list it) or its own poses."""
    full, by_path, bench_by_path = _run_folders(plans, base, bench_sessions)
    refused = []
    for plan in list(plans.values()):
        if plan.measure and plan.sequence is not None and plan.oneshot_reference is None:
            refused += [f"session {plan.path} is refused:\n{full(plan.path) / 'sequence.yaml'}: {p}"
                        for p in relative_axes_problems(plan.sequence, config["rig"]["triangulation"])]
        if plan.kind != "structured-light" or plan.calibration_file:
            continue
        if plan.calibration_session is not None:
            target = full(plan.calibration_session)
            other = _session_of_run(target, plans, by_path, bench_by_path, base, config, bench_sessions, refused,
                                    f"session {plan.path}: its calibration session {target}")
            if other is None:
                continue
            if not other.calibrate:
                refused.append(f"session {plan.path}: its calibration session {target} has no poses and board to calibrate from")
                continue
            plan.calibrated_by = other.id
            plan.calibrate = False  # measured with the named session's calibration, not with poses of its own
        elif plan.calibrate:
            plan.calibrated_by = plan.id
        elif plan.measure:
            refused.append(f"session {plan.path} is refused:\n{full(plan.path) / 'session.yaml'}: no calibration: give the "
                           "rig's calibration file (calibration: {file, sha256}), the session whose poses calibrate it "
                           "(calibration: {session: PATH}), or poses and a board of its own")
    return refused


def _add(plans: dict[str, SessionPlan], plan: SessionPlan, config: dict[str, Any]) -> None:
    if plan.id in plans:
        raise PlanError(f"sessions {plans[plan.id].path} and {plan.path} share the id '{plan.id}'")
    m = config["measurement"]
    parallel, per_job = int(m["parallel_jobs"]), int(m["frames_per_job"])
    # structured-light sessions are measured by the rig rules (rig.smk), not in frame batches
    plan.batches = batch_frames(plan.frames, parallel, per_job) if plan.kind == "capture" else []
    plan.phase_shift_batches = batch_frames(plan.phase_shift, parallel, per_job)
    plans[plan.id] = plan


def plan_table1(config: dict[str, Any], plans: dict[str, SessionPlan], base: str | Path = ".") -> list[str]:
    """Add the sessions of the paper's Table 1 experiment (a period sweep) to ``plans``.

    Returns their ids, in the configured period order. The sessions are written by the bench
    under ``table1.root`` when absent, like any bench session.
    """
    t1 = config.get("table1")
    if not t1:
        return []
    base = Path(base)
    ids = []
    for period in t1["periods"]:
        cfg = bench_config_for(t1["bench"], base, float(period))
        sid = str(cfg["session"]["id"])
        path = Path(t1["root"]) / sid
        full = base / path
        if (full / "session.yaml").exists():
            try:
                plan = _from_session(full)
            except SessionError as exc:
                raise PlanError(f"Table 1 session {path} is refused:\n{exc}") from exc
            plan.path = path
        else:
            plan = _from_bench(path, cfg, bench_yaml(t1["bench"], base), float(period))
        _add(plans, plan, config)
        ids.append(plan.id)
    return ids
