# Shared planning: sessions, ids, frame batches and the paths of every output.
import re
import sys
from pathlib import Path

from huefringe.plan import PlanError, plan_sessions, plan_table1

# The plan reads the configuration and the session folders only, never workflow.cores: the SLURM
# executor's job-side Snakemake (--cores all on the node) must plan the same batches as the
# submitting one (no --cores), or a batch job writes only part of its declared outputs.
try:
    PLANS = plan_sessions(config, base=Path.cwd())
    TABLE1_IDS = plan_table1(config, PLANS, base=Path.cwd())
except PlanError as exc:
    sys.stderr.write(f"\nhuefringe: cannot start.\n{exc}\n\n")
    sys.exit(1)

RESULTS = config["results_dir"]
#: session folders the virtual bench writes (rule bench_session), by folder
BENCH_PLANS = {str(p.path): p for p in PLANS.values() if p.bench is not None}
#: capture sessions (the one-shot hue route) and structured-light sessions (the rig route, rig.smk)
CAPTURE_IDS = [sid for sid, p in PLANS.items() if p.kind == "capture"]
RIG_IDS = [sid for sid, p in PLANS.items() if p.kind == "structured-light"]
ANY_SID = "|".join(re.escape(s) for s in PLANS) or "^$"
RIG_SID = "|".join(re.escape(s) for s in RIG_IDS) or "^$"
#: structured-light sessions of coded blocks only (rule rig_measure) and with one-shot frames (rig_oneshot_<sid>)
ONESHOT_IDS = [
    sid for sid in RIG_IDS if PLANS[sid].oneshot_frames and PLANS[sid].measure
]
CODED_SID = "|".join(re.escape(s) for s in RIG_IDS if s not in ONESHOT_IDS) or "^$"


wildcard_constraints:
    sid="|".join(re.escape(s) for s in CAPTURE_IDS) or "^$",
    bench_dir="|".join(re.escape(d) for d in BENCH_PLANS) or "^$",
    frame=r"\d{4}",
    which="reference|object",


def rule_resources(rule, **defaults):
    """Resources of a generated rule: ``defaults`` updated by config ``resources: {rule: {...}}``."""
    return {**defaults, **config.get("resources", {}).get(rule, {})}


def R(sid, *parts):
    """Path of a result of session ``sid``."""
    return "/".join([RESULTS, sid, *parts])


def fname(n):
    return f"frame_{n:04d}"


def session_dir(wildcards_or_sid):
    sid = (
        wildcards_or_sid if isinstance(wildcards_or_sid, str) else wildcards_or_sid.sid
    )
    return str(PLANS[sid].path)


def session_yaml(wildcards):
    return str(Path(session_dir(wildcards)) / "session.yaml")


def frame_outputs(sid, frames):
    return {
        "heights": [R(sid, "height", f"{fname(n)}.tiff") for n in frames],
        "clouds": [R(sid, "cloud", f"{fname(n)}.ply") for n in frames],
        "phases": [R(sid, "phase", f"{fname(n)}.tiff") for n in frames],
        "hues": [R(sid, "hue", f"{fname(n)}.tiff") for n in frames],
        "qa": [R(sid, "qa", "frames", f"{fname(n)}.json") for n in frames],
        "uncertainties": [R(sid, "uncertainty", f"{fname(n)}.tiff") for n in frames],
        "supports": [R(sid, "support", f"{fname(n)}.tiff") for n in frames],
        "x3p": [R(sid, "x3p", f"{fname(n)}.x3p") for n in frames],
    }


def x3p_selection(sid):
    """Frames of session ``sid`` written as X3P (``x3p.frames``: first, all, a list or none)."""
    sel = config.get("x3p", {}).get("frames", "all")
    return [] if sel == "none" else PLANS[sid].frame_selection(sel)


def map_frames(sid):
    """Frames of session ``sid`` whose phase and hue maps are written (``measurement.maps``)."""
    plan = PLANS[sid]
    if config["measurement"].get("maps", "rendered") == "all":
        return list(plan.frames)
    return sorted(set(plan.frame_selection(config["render"]["frames"])))


def measure_outputs(sid, frames):
    """Outputs of the measurement job of a batch: height and QA of every frame, maps of some."""
    out = {
        k: v
        for k, v in frame_outputs(sid, frames).items()
        if k in ("heights", "qa", "uncertainties", "supports")
    }
    maps = [n for n in frames if n in set(map_frames(sid))]
    if maps:
        out.update({k: frame_outputs(sid, maps)[k] for k in ("phases", "hues")})
    return out


def baseline_outputs(sid, frames):
    return {
        "heights": [R(sid, "baseline", "height", f"{fname(n)}.tiff") for n in frames],
        "qa": [R(sid, "baseline", "qa", f"{fname(n)}.json") for n in frames],
    }


RENDER_VIEWS = ["top", "oblique1", "oblique2"]


def render_outputs(sid, n):
    views = [R(sid, "renders", f"{fname(n)}_{v}.png") for v in RENDER_VIEWS]
    return views + [
        R(sid, "renders", f"{fname(n)}_height.png"),
        R(sid, "renders", f"{fname(n)}_phase.png"),
        R(sid, "renders", f"{fname(n)}_uncertainty.png"),
    ]


def rig_calibration(w):
    """The calibration a structured-light session is measured with: its own file, or
    results/<sid>/calib/rig.yml (calibrated from its poses, or copied from the session that
    calibrates it)."""
    sid = w if isinstance(w, str) else w.sid
    plan = PLANS[sid]
    if plan.calibration_file:
        return str(Path(session_dir(sid)) / plan.calibration_file)
    return R(sid, "calib", "rig.yml")


def rig_jackknife(w):
    sid = w if isinstance(w, str) else w.sid
    return (
        [] if PLANS[sid].calibration_file else [R(sid, "calib", "rig.jackknife.json")]
    )


def rig_calibration_report(w):
    return (
        [] if PLANS[w.sid].calibration_file else [R(w.sid, "calib", "rig.report.json")]
    )


def rig_calibration_source(w):
    """The calibration files of the session that calibrates session ``w.sid``."""
    src = PLANS[w.sid].calibrated_by
    return {
        "source_calibration": R(src, "calib", "rig.yml"),
        "source_report": R(src, "calib", "rig.report.json"),
        "source_jackknife": R(src, "calib", "rig.jackknife.json"),
    }


#: structured-light sessions calibrated from their own poses, and those measured with another's calibration
CALIBRATE_SID = "|".join(re.escape(s) for s in RIG_IDS if PLANS[s].calibrate) or "^$"
BORROW_SID = (
    "|".join(
        re.escape(s)
        for s in RIG_IDS
        if PLANS[s].calibrated_by not in (None, s) and not PLANS[s].calibrate
    )
    or "^$"
)


RIG_FRAME_FILES = {
    "xyz": ("xyz", "{}.tiff"),
    "xyz_sigma": ("xyz", "{}_sigma.tiff"),
    "xyz_u": ("xyz", "{}_u.tiff"),
    "decoded": ("decode", "{}.tiff"),
    "cloud": ("cloud", "{}.ply"),
    "height": ("height", "{}.tiff"),
    "uncertainty": ("uncertainty", "{}.tiff"),
    "x3p": ("x3p", "{}.x3p"),
    "qa": ("qa/frames", "{}.json"),
    "quality": ("qa", "{}_decode.png"),
}


def oneshot_outputs(sid):
    """The files rig_oneshot_<sid> writes: those of rig_measure for each one-shot frame."""
    n = PLANS[sid].oneshot_frames
    return {
        k: [R(sid, d, f.format(fname(i))) for i in range(n)]
        for k, (d, f) in RIG_FRAME_FILES.items()
    }


def oneshot_reference_inputs(sid):
    """The files of the session whose coded captures are one-shot session ``sid``'s order reference
    (``oneshot: {reference: {session: PATH}}``): its session.yaml (which rule bench_session writes
    for a bench session) and, when the folder is there as planned, every file of it."""
    ref = PLANS[sid].reference_id
    if ref is None:
        return []
    folder = Path(session_dir(ref))
    files = [str(folder / "session.yaml")]
    if (folder / "session.yaml").is_file():
        from huefringe.session import load_sl_session

        files += [str(p) for p in load_sl_session(folder).input_files()]
    return sorted(set(files))


def rig_report_frames(kind):
    """The rig_metrology input ``kind`` (a RIG_FRAME_FILES key): frame_0000's file, or every one-shot
    frame's for a one-shot session (its report carries each figure's per-frame series).
    """

    def files(w):
        if w.sid in ONESHOT_IDS:
            return oneshot_outputs(w.sid)[kind]
        d, f = RIG_FRAME_FILES[kind]
        return R(w.sid, d, f.format(fname(0)))

    return files


def rig_targets(sid):
    """Every result of structured-light session ``sid`` (rig.smk)."""
    plan = PLANS[sid]
    out = [R(sid, "calib", "rig.yml")] if plan.calibrate else []
    if not plan.measure:
        return out
    out += [
        R(sid, "xyz", "frame_0000.tiff"),
        R(sid, "cloud", "frame_0000.ply"),
        R(sid, "x3p", "frame_0000.x3p"),
        R(sid, "mesh", "frame_0000.ply"),
        R(sid, "renders", "frame_0000_top.png"),
    ]
    if (
        sid in ONESHOT_IDS
    ):  # every one-shot frame's X, Y, Z, cloud and X3P (rig_oneshot_<sid>)
        out += [
            p
            for k, ps in oneshot_outputs(sid).items()
            if k in ("xyz", "cloud", "x3p")
            for p in ps[1:]
        ]
    if plan.ground_truth:
        out.append(R(sid, "accuracy.json"))
    if plan.specimen:
        out += [R(sid, "metrology", "report.json"), R(sid, "metrology", "report.html")]
    return out


def all_targets():
    out = []
    for sid, plan in PLANS.items():
        if plan.kind == "structured-light":
            out += rig_targets(sid)
            continue
        if sid in TABLE1_IDS:
            continue
        out += frame_outputs(sid, plan.frames)["heights"]
        out += frame_outputs(sid, plan.frames)["clouds"]
        out += frame_outputs(sid, x3p_selection(sid))["x3p"]
        out += [R(sid, "calib", "compensated_pattern.png")]
        if plan.phase_shift:
            out += baseline_outputs(sid, plan.phase_shift)["heights"]
        if plan.ground_truth:
            out.append(R(sid, "accuracy.json"))
        for n in plan.frame_selection(config["mesh"]["frames"]):
            out.append(R(sid, "mesh", f"{fname(n)}.ply"))
        for n in plan.frame_selection(config["render"]["frames"]):
            out += render_outputs(sid, n)
        if plan.specimen:
            out += [
                R(sid, "metrology", "report.json"),
                R(sid, "metrology", "report.html"),
            ]
    return out


def session_results(sid):
    """Every declared result of session ``sid`` (the part of all_targets() under results/<sid>/)."""
    prefix = R(sid, "")
    return [p for p in all_targets() if p.startswith(prefix)]


onsuccess:
    # the end of a run: each session's ISO 14253-1 decision and where its report is
    from huefringe.report import run_summary

    _reports = {
        sid: (R(sid, "metrology", "report.json") if plan.specimen else None)
        for sid, plan in PLANS.items()
        if sid not in TABLE1_IDS and plan.measure
    }
    if _reports:
        print(f"\nhuefringe: results\n{run_summary(_reports)}\n", file=sys.stderr)
