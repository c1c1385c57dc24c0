"""Command-line entry point: ``huefringe check|bench|patterns|session|sl-session|decode|archive|verify ...`` and ``--version``."""

from __future__ import annotations

import argparse
import sys
from typing import Any
from collections.abc import Sequence
from pathlib import Path


def _cmd_check_sl(args: argparse.Namespace) -> int:
    from huefringe.codecs import FlatBlock, HueBandsBlock, SkipBlock
    from huefringe.session import SessionError
    from huefringe.session import load_sl_session

    try:
        s = load_sl_session(args.session, deep=args.deep)
    except SessionError as exc:
        print(f"REFUSED: {args.session} is not a valid structured-light session ({len(exc.problems)} problem(s)):")
        for p in exc.problems:
            print(f"  - {p}")
        return 1
    blocks = ", ".join(b.level if isinstance(b, FlatBlock) else f"skip {b.frames}" if isinstance(b, SkipBlock)
                       else f"hue_bands {b.n} x {b.repeats}" if isinstance(b, HueBandsBlock)
                       else f"{type(b).__name__.removesuffix('Block').lower()} {b.axis}" for b in s.spec.blocks)
    extras = []
    if s.calibration is not None:
        extras.append(f"calibration {s.calibration.relative_to(s.root)}")
    if s.poses:
        extras.append(f"{len(s.poses)} calibration poses")
    if s.ground_truth:
        extras.append(f"ground truth for {', '.join(s.ground_truth)}")
    print(f"OK: structured-light session '{s.id}' at {s.root}: {s.width} x {s.height} px, {s.bit_depth}-bit, "
          f"projector {s.spec.projector_width} x {s.spec.projector_height}, {len(s.captures)} captures ({blocks})"
          + ("; " + ", ".join(extras) if extras else ""))
    hue = next((b for b in s.spec.blocks if isinstance(b, HueBandsBlock)), None)
    if hue is not None and s.spec.oneshot_frames:
        _warn_unmeasurable_bands(hue.n, hue.repeats)
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from huefringe.session import SessionError, load_session
    from huefringe.session import SL_FORMAT
    from huefringe.session import session_format

    if session_format(args.session) == SL_FORMAT:
        return _cmd_check_sl(args)
    try:
        s = load_session(args.session, deep=args.deep)
        if args.deep:  # the content: hue bands in their order
            from huefringe.assemble import session_band_problems

            if problems := session_band_problems(s):
                raise SessionError(problems)
    except SessionError as exc:
        print(f"REFUSED: {args.session} is not a valid capture session ({len(exc.problems)} problem(s)):")
        for p in exc.problems:
            print(f"  - {p}")
        return 1
    extras = []
    if s.phase_shift:
        extras.append(f"{len(s.phase_shift)} phase-shift triples")
    if s.ground_truth:
        extras.append(f"ground truth for {len(s.ground_truth)} frames")
    if s.specimen:
        extras.append(f"specimen with {len(s.specimen['steps'])} steps")
    cam = s.meta["camera"]
    if cam.get("model") == "pinhole":
        extras.append(f"pinhole camera (fx {cam['matrix'][0][0]:g} px, plate at {cam['plate_pose']['tvec'][2]:g} mm)")
    if cam.get("distortion") and any(cam["distortion"]):
        extras.append(f"lens distortion ({len(cam['distortion'])} coefficients)")
    if s.ground_truth_xy:
        extras.append(f"X/Y ground truth for {len(s.ground_truth_xy)} frames")
    print(
        f"OK: session '{s.id}' at {s.root}: {s.width} x {s.height} px, {s.bit_depth}-bit, "
        f"pitch {s.pixel_pitch_mm} mm, period {s.period_px:g} px, {s.hue_bands} bands x {s.repeats} repeats, "
        f"{len(s.planes)} planes, {len(s.frames)} frames" + ("; " + ", ".join(extras) if extras else "")
    )
    _warn_unmeasurable_bands(s.hue_bands, s.repeats)
    return 0


def _warn_unmeasurable_bands(n_bands: int, repeats: int) -> None:
    """A session the format accepts but the workflow refuses to measure: say so beside its OK."""
    from huefringe.patterns import single_repeat_problem

    too_few = single_repeat_problem(n_bands, repeats)
    if too_few:
        print(f"WARNING: {too_few}; the workflow refuses to measure this session")


def _cmd_bench(args: argparse.Namespace) -> int:
    from huefringe import bench

    try:
        ref = bench.preset_path(args.config) if args.preset else args.config
        if bench.bench_kind(ref) == "structured-light-session/1":
            if args.patterns or args.periods:
                print("REFUSED: --patterns and --periods are for capture-session benches", file=sys.stderr)
                return 2
            try:
                print(bench.write_sl_session(bench.load_sl_bench_config(ref), Path(args.out)))
            except FileExistsError as exc:
                print(f"REFUSED: {exc}", file=sys.stderr)
                return 2
            return 0
        cfg = bench.load_bench_config(ref)
    except FileNotFoundError as exc:  # no such preset: the message lists the available ones
        print(f"REFUSED: --preset: {exc}", file=sys.stderr)
        return 1
    except bench.BenchConfigError as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 1
    if args.patterns:
        if args.periods:
            print("REFUSED: --patterns and --periods exclude each other", file=sys.stderr)
            return 2
        try:
            out = bench.capture_patterns(cfg, Path(args.patterns), Path(args.out), progress=not args.quiet)
        except (bench.ProjectionError, FileExistsError) as exc:
            print(f"REFUSED: {exc}", file=sys.stderr)
            return 2
        n = len(list(out.glob("IMG_*.png")))
        print(f"wrote {n} camera files to {out} (assemble with: huefringe session {out} {args.patterns} SPEC.yaml SESSION)")
        return 0
    if args.periods:
        for out in bench.period_sweep(cfg, periods=args.periods, out_root=Path(args.out)):
            print(out)
    else:
        print(bench.write_session(cfg, Path(args.out), progress=not args.quiet))
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from huefringe.archive import ArchiveError, verify_archive

    try:
        result = verify_archive(args.archive)
    except ArchiveError as exc:
        print(f"FAILED: {exc}")
        return 1
    print(result.summary())
    return 0 if result.ok else 1


def _cmd_archive(args: argparse.Namespace) -> int:
    import yaml

    from huefringe.archive import ArchiveError, write_archive

    config = None
    if args.config:
        try:
            config = yaml.safe_load(Path(args.config).read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
            print(f"REFUSED: {args.config}: cannot read the configuration ({exc})", file=sys.stderr)
            return 1
    try:
        out = write_archive(args.session, args.results, args.out, config=config)
    except ArchiveError as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 1
    print(out)
    return 0


def _cmd_patterns(args: argparse.Namespace) -> int:
    from huefringe.patterns import single_repeat_problem
    from huefringe.projection import PatternsError, write_patterns

    try:
        planes = [float(z) for z in args.planes.split(",") if z.strip()]
    except ValueError:
        print(f"REFUSED: --planes: {args.planes!r} is not a comma-separated list of mm (e.g. 0,2,4)", file=sys.stderr)
        return 2
    try:
        out = write_patterns(
            args.out, width=args.width, height=args.height, period_px=args.period_px, hue_bands=args.bands,
            repeats=args.repeats, planes_mm=planes, frames=args.frames, phase_shift=not args.no_phase_shift,
            bit_depth=args.bit_depth, camera_period_px=args.camera_period_px, magnification=args.magnification,
            compensated=args.compensated,
        )
    except PatternsError as exc:
        flag = {"out_dir": "OUT", "hue_bands": "--bands", "planes_mm": "--planes"}.get(
            exc.argument, "--" + exc.argument.replace("_", "-"))
        print(f"REFUSED: {flag}: {exc.problem}", file=sys.stderr)
        return 2
    n_img = len(list(out.glob("[0-9][0-9][0-9][0-9]_*.png")))
    with open(out / "manifest.csv", encoding="utf-8") as fh:
        n_cap = sum(1 for _ in fh) - 1
    extra = " and predistortion.csv (compensated trapezoid, paper Fig. 6)" if args.compensated else ""
    if args.compensated and not args.no_phase_shift:
        extra += " and phase_shift_levels.csv (phase shifts pre-compensated for the projector gamma)"
    print(f"wrote {n_img} projector images ({args.width} x {args.height}, {args.bit_depth}-bit), a manifest "
          f"of {n_cap} captures{extra} to {out}")
    too_few = single_repeat_problem(args.bands, args.repeats)
    if too_few:  # a plan the format allows but the workflow will refuse: say so before anything is captured
        print(f"WARNING: --bands {args.bands} --repeats {args.repeats}: {too_few}; the workflow refuses such a "
              "session", file=sys.stderr)
    return 0


def _cmd_session(args: argparse.Namespace) -> int:
    from huefringe.assemble import assemble_session
    from huefringe.session import SessionError

    try:
        out = assemble_session(args.captures, args.patterns_dir, args.spec, args.out, bayer=args.bayer)
    except SessionError as exc:
        print(f"REFUSED: no session written ({len(exc.problems)} problem(s)):", file=sys.stderr)
        for p in exc.problems:
            print(f"  - {p}", file=sys.stderr)
        return 2
    print(f"OK: {out}")
    return 0


def _cmd_sl_session(args: argparse.Namespace) -> int:
    from huefringe.session import SessionError
    from huefringe.session import assemble_sl_session

    try:
        b = _board(args)
    except ValueError as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 2
    board = None if b is None else {"cols": b.cols, "rows": b.rows, "pitch_mm": b.pitch_mm, "kind": b.kind}
    try:
        out = assemble_sl_session(args.captures, args.sequence, args.out, calibration=args.calibration,
                                  poses=args.poses, session_id=args.id, board=board, features=args.features,
                                  calibration_session=args.calibration_session)
    except SessionError as exc:
        print(f"REFUSED: no session written ({len(exc.problems)} problem(s)):", file=sys.stderr)
        for p in exc.problems:
            print(f"  - {p}", file=sys.stderr)
        return 2
    print(f"OK: {out}")
    return 0


DESCRIPTION = """\
huefringe: one-shot trapezoidal HSI fringe-projection profilometry.

Measuring runs through Snakemake, not through this command:
  snakemake --cores 2                                  the sessions listed in config.yaml
  snakemake --cores 2 --configfile my-sessions.yaml    your own sessions
  snakemake --cores 2 archive                          results/<id>.archive.zip per session

This command checks sessions, writes bench sessions, decodes N-step / Gray-code / multi-period
captures into projector coordinates and packs or verifies archives (subcommands below;
huefringe SUBCOMMAND --help for each).
"""


def _cmd_decode(args: argparse.Namespace) -> int:
    from huefringe.codecs import DecodeOptions, SequenceError
    from huefringe.codecs.output import decode_folder
    from huefringe.settings import load_config

    try:
        opts = DecodeOptions.from_config(load_config(*(args.configfile or [])))
    except (OSError, KeyError, TypeError, ValueError) as exc:
        print(f"REFUSED: --configfile {' '.join(args.configfile or [])}: cannot read the codecs block ({exc})", file=sys.stderr)
        return 2
    try:
        summary = decode_folder(args.captures, args.sequence, args.out, projector_gamma=args.projector_gamma,
                                estimate_gamma=args.estimate_gamma, options=opts)
    except SequenceError as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 2
    axes = ", ".join(f"{a}: {v['valid_fraction']:.1%} valid{'' if v['absolute'] else ' (relative: within a period)'}, "
                     f"median u {v['median_sigma_px'] or float('nan'):.3f} px"
                     for a, v in summary["axes"].items())
    text = (f"{args.out}: {summary['frames']} frames decoded in {summary['decode_seconds']:.1f} s "
            f"(projector gamma {summary['projector']['gamma']:.3f}, {summary['projector']['gamma_source']}); {axes}")
    few = [a for a, v in summary["axes"].items() if v["valid_fraction"] < opts.min_valid_fraction]
    if few:
        print(f"FAILED: {text}; axis {', '.join(few)} below codecs.min_valid_fraction {opts.min_valid_fraction:.1%} "
              f"(reasons_<axis>.png and decode.json say which test dropped the pixels)", file=sys.stderr)
        return 1
    print(f"OK: {text}")
    return 0


def _board(args: argparse.Namespace) -> Any:
    """``--board COLSxROWS --pitch-mm MM [--kind]`` as a :class:`huefringe.rig.Board`, None without
    ``--board``; ValueError saying what to give."""
    from huefringe.rig import Board

    if not args.board:
        return None
    try:
        cols, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError:
        raise ValueError(f"--board {args.board!r}: COLSxROWS of inner corners expected (e.g. 9x7)") from None
    if args.pitch_mm is None or not args.pitch_mm > 0:
        raise ValueError(f"--board {args.board} needs --pitch-mm MM, the side of one square in mm")
    return Board(cols, rows, args.pitch_mm, args.kind)


def _is_sl_session(path: str) -> bool:
    from huefringe.session import SL_FORMAT as FORMAT, session_format

    return session_format(path) == FORMAT


def _config(files: list[str] | None) -> dict[str, Any]:
    """The packaged defaults with each ``--configfile`` over them, as the workflow reads them."""
    from huefringe.settings import load_config

    try:
        return load_config(*(files or []))
    except (OSError, ValueError, TypeError) as exc:
        raise SystemExit(f"REFUSED: --configfile {' '.join(files or [])}: cannot be read ({exc})") from None


def _print_calibration(out: str, report: dict[str, Any], baseline_mm: float) -> None:
    print("  per pose, RMS reprojection error against the final joint model (board pose from the camera):")
    for p in report["poses"]:
        flag = "" if p["used"] else "  DOES NOT FIT: left out"
        print(f"    {p['name']}: camera {p['camera_rms_px']:.3f} px, projector {p['projector_rms_px']:.3f} px{flag}")
    r = report["rms_px"]
    print(f"OK: {out}: RMS of the fit over all used corners: camera alone {r['camera']:.3f} px, projector alone "
          f"{r['projector']:.3f} px, stereo (joint model) {r['stereo']:.3f} px; baseline {baseline_mm:.1f} mm; "
          f"{len(report['jackknife_poses'])} leave-one-pose-out calibrations for the calibration's uncertainty"
          + (f"; poses left out: {', '.join(report['rejected'])}" if report["rejected"] else ""))


def _cmd_rig_calibrate(args: argparse.Namespace) -> int:
    import json

    from huefringe.rig.measure import RigError, calibrate_folders, write_rig_calibration
    from huefringe.session import SessionError
    from huefringe.stages import calibrate_rig_session

    sl = bool(args.inputs) and _is_sl_session(args.inputs[0])
    if len(args.inputs) != (2 if sl else 3):
        print("REFUSED: give SESSION OUT (a structured-light session with poses/) or POSES SEQUENCE OUT; got "
              f"{len(args.inputs)} argument(s): {' '.join(args.inputs)}", file=sys.stderr)
        return 2
    out = args.inputs[-1]
    try:
        board = _board(args)
    except ValueError as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 2
    if board is None and not sl:
        print("REFUSED: --board COLSxROWS and --pitch-mm MM name the board (a session may carry them as board:)",
              file=sys.stderr)
        return 2
    cfg = _config(args.configfile)
    try:
        if sl:
            files = calibrate_rig_session(args.inputs[0], out, cfg, board)
        else:
            files = write_rig_calibration(calibrate_folders(args.inputs[0], args.inputs[1], board, cfg), out)
    except (RigError, SessionError) as exc:
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 2
    from huefringe.rig import read_calibration

    _print_calibration(out, json.loads(Path(files["report"]).read_text()), read_calibration(out).baseline_mm)
    return 0


def _cmd_rig_measure(args: argparse.Namespace) -> int:
    import json

    from huefringe.rig.measure import RigError
    from huefringe.session import SessionError, assemble_sl_session
    from huefringe.stages import measure_rig_session

    sl = bool(args.inputs) and _is_sl_session(args.inputs[0])
    if (sl and len(args.inputs) != 2) or (not sl and (len(args.inputs) != 4 or args.calibration)):
        print("REFUSED: give SESSION OUTDIR [--calibration FILE] (a structured-light session) or "
              f"CAPTURES SEQUENCE CALIBRATION OUTDIR; got {' '.join(args.inputs)}", file=sys.stderr)
        return 2
    outdir = Path(args.inputs[-1])
    if outdir.exists() and any(outdir.iterdir()):
        print(f"REFUSED: {outdir}: already exists and is not empty; give a new folder", file=sys.stderr)
        return 2
    cfg = _config(args.configfile)
    made = not outdir.exists()
    try:
        if sl:
            session, calibration = args.inputs[0], args.calibration
        else:  # captures in a folder: assembled into OUTDIR/session first, then measured as a session
            session = assemble_sl_session(args.inputs[0], args.inputs[1], outdir / "session", calibration=args.inputs[2])
            calibration = None
        files = measure_rig_session(session, outdir, cfg, calibration=calibration)
    except (RigError, SessionError) as exc:
        if made and outdir.exists():
            import shutil

            shutil.rmtree(outdir)
        print(f"REFUSED: {exc}", file=sys.stderr)
        return 2
    qa = json.loads(files["qa"].read_text())
    head = (f"OK: {outdir}: {qa['points']} points ({qa['valid_fraction']:.1%} of the camera), triangulation "
            f"{qa['triangulation']}")
    if "json" in files:
        c = json.loads(files["json"].read_text())["conformity"]
        print(f"{c['decision'].upper()} (ISO 14253-1) - {c['reason']}\n  report: {files['html']}\n{head}")
    else:
        print(f"{head}; no features.yaml in the session, so no metrology report (what to measure: docs/rig.md)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from huefringe import __version__

    parser = argparse.ArgumentParser(prog="huefringe", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"huefringe {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="{check,bench,patterns,session,sl-session,decode,rig-calibrate,rig-measure,archive,verify}")

    p = sub.add_parser("rig-calibrate", help="calibrate a projector-camera rig from board poses of coded captures",
                       usage="huefringe rig-calibrate (SESSION | POSES SEQUENCE) OUT [--board COLSxROWS --pitch-mm MM] "
                             "[--configfile FILE ...]")
    p.add_argument("inputs", nargs="+", metavar="SESSION | POSES SEQUENCE, OUT",
                   help="a structured-light session with poses/ (corners in each pose's mean frame), or a folder of "
                        "pose folders (each with the sequence's captures and optionally board.png) and the sequence "
                        "YAML (both projector axes); then the calibration to write (OpenCV FileStorage: .yml, .xml "
                        "or .json), its report (.report.json) and leave-one-pose-out calibrations (.jackknife.json) "
                        "beside it")
    p.add_argument("--board", help="inner corners (circles) COLSxROWS, e.g. 9x7 (default: the session's board:)")
    p.add_argument("--pitch-mm", type=float, help="square size (circle spacing), mm")
    p.add_argument("--kind", choices=["chessboard", "circles", "acircles"], default="chessboard")
    p.add_argument("--configfile", nargs="+", metavar="FILE", help="YAML files overriding the packaged defaults "
                   "(codecs, rig), as snakemake --configfile")
    p.set_defaults(func=_cmd_rig_calibrate)

    p = sub.add_parser("rig-measure", help="measure a structured-light session as the workflow does: X, Y, Z per camera "
                                           "pixel, cloud, mesh, height map, X3P, renders, report with U and the decision",
                       usage="huefringe rig-measure (SESSION | CAPTURES SEQUENCE CALIBRATION) OUTDIR "
                             "[--calibration FILE] [--configfile FILE ...]")
    p.add_argument("inputs", nargs="+", metavar="SESSION | CAPTURES SEQUENCE CALIBRATION, OUTDIR",
                   help="a structured-light session (its captures/, calibration/ and features.yaml), or a folder of "
                        "the sequence's captures, the sequence YAML and the calibration file (assembled into "
                        "OUTDIR/session first); then a new output folder, written in the layout of results/<id>/")
    p.add_argument("--calibration", help="with a SESSION: the calibration file to use instead of its calibration/ "
                                         "(a file rig-calibrate wrote brings its leave-one-pose-out calibrations)")
    p.add_argument("--configfile", nargs="+", metavar="FILE", help="YAML files overriding the packaged defaults "
                   "(codecs, rig, mesh, render), as snakemake --configfile")
    p.set_defaults(func=_cmd_rig_measure)

    p = sub.add_parser("check", help="validate a capture session (capture-session/1 or structured-light-session/1); exit 1 if it is refused")
    p.add_argument("session", help="the session folder (holding session.yaml)")
    p.add_argument("--deep", action="store_true", help="also decode every image and check the hue bands' order")
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser("bench", help="write a capture session (or, with --patterns, camera files; or a structured-light "
                                     "session for a huefringe-sl-bench/1 YAML) with the virtual bench")
    p.add_argument("config", help="bench YAML, or a preset name with --preset (demo, flat, dental, table1, rehearsal, "
                                  "rig-poses, rig-gauge, rig-board, ...)")
    p.add_argument("out", help="output session folder (with --periods: a folder for the sweep; with --patterns: "
                               "the folder of camera files)")
    p.add_argument("--preset", action="store_true", help="CONFIG names a packaged preset")
    p.add_argument("--periods", type=int, nargs="+", help="write a period sweep (e.g. 20 40 60 80 100)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--patterns", metavar="PATTERNS_DIR",
                   help="instead of a session: show this huefringe patterns folder's images in manifest order and "
                        "write one camera file per row (OUT/IMG_0001.png ...) for huefringe session")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("verify", help="check every file of an archive against its RO-Crate sha256; exit 1 on any problem")
    p.add_argument("archive", help="an archive (results/<id>.archive.zip) or the folder it was extracted into")
    p.set_defaults(func=_cmd_verify)

    p = sub.add_parser("archive", help="pack a session and its results into one ZIP with RO-Crate metadata")
    p.add_argument("session", help="the session folder (holding session.yaml)")
    p.add_argument("results", help="its results folder, results/<id>")
    p.add_argument("out", help="the archive to write, e.g. results/<id>.archive.zip")
    p.add_argument("--config", help="the workflow configuration YAML used (stored as config.yaml)")
    p.set_defaults(func=_cmd_archive)

    p = sub.add_parser("patterns", help="write the projector images of a session and the manifest of capture order")
    p.add_argument("out", help="new folder to write (refused if it exists and is not empty)")
    p.add_argument("--width", type=int, required=True, help="projector width in pixels")
    p.add_argument("--height", type=int, required=True, help="projector height in pixels")
    p.add_argument("--period-px", type=float, help="fringe period in projector pixels (at least 6)")
    p.add_argument("--camera-period-px", type=float,
                   help="wanted fringe period in camera pixels on the reference plane (with --magnification)")
    p.add_argument("--magnification", type=float,
                   help="measured camera pixels per projector pixel; projector period = camera period / magnification")
    p.add_argument("--bands", type=int, default=256, help="hue bands N (6..999; default 256)")
    p.add_argument("--repeats", type=int, default=3, help="captures per hue band R (default 3)")
    p.add_argument("--planes", default="0,2,4", help="calibration planes in mm, comma list with 0 (default 0,2,4)")
    p.add_argument("--frames", type=int, default=1, help="object frames (default 1)")
    p.add_argument("--no-phase-shift", action="store_true", help="no three-step phase-shift images")
    p.add_argument("--bit-depth", type=int, choices=(8, 16), default=8, help="PNG bit depth (default 8)")
    p.add_argument("--compensated", metavar="CALIB",
                   help="pre-distort the trapezoid (paper Fig. 6) from the plate's hue table CALIB/table_reference.json "
                        "(a run's results/<id>/calib) and write predistortion.csv for huefringe session; the "
                        "phase-shift images are pre-compensated for the projector gamma fitted to the same table "
                        "(phase_shift_levels.csv)")
    p.set_defaults(func=_cmd_patterns)

    p = sub.add_parser("session", help="assemble a checked capture session from a folder of camera files; exit 2 if refused")
    p.add_argument("captures", help="folder of camera files (PNG/TIFF), one per manifest row, in natural order of name")
    p.add_argument("patterns_dir", help="the patterns folder (manifest.csv + patterns.yaml)")
    p.add_argument("spec", help="spec YAML: id, pixel_pitch_mm, period_px, optional specimen, provenance, camera, bayer, bit_depth_in")
    p.add_argument("out", help="the session folder to write (new or empty)")
    p.add_argument("--bayer", choices=["RGGB", "BGGR", "GRBG", "GBRG"], help="raw Bayer mosaics: demosaic with this pattern")
    p.set_defaults(func=_cmd_session)

    p = sub.add_parser("sl-session", help="assemble a checked structured-light session (N-step, Gray code, multi-period "
                                          "captures) from a folder of captures and a sequence YAML; exit 2 if refused")
    p.add_argument("captures", help="folder of the captures (the sequence's frames: a glob, sorted by the number in "
                                      "their names, or a list of file names in capture order)")
    p.add_argument("sequence", help="sequence YAML: projector, frames, blocks (phase, gray, white, black) or kamino410; "
                                    "optional id, calibration, poses, provenance")
    p.add_argument("out", help="the session folder to write (new or empty)")
    p.add_argument("--calibration", help="OpenCV FileStorage calibration of the rig (.yml/.yaml/.xml/.json), stored "
                                         "in the session as calibration/rig.<ext> with its sha256")
    p.add_argument("--poses", help="folder of calibration pose folders, each holding one full sequence of captures")
    p.add_argument("--board", help="with --poses: the board they show, inner corners COLSxROWS (e.g. 9x7)")
    p.add_argument("--pitch-mm", type=float, help="with --board: the square size, mm")
    p.add_argument("--kind", choices=["chessboard", "circles", "acircles"], default="chessboard",
                   help="with --board: the target (default chessboard)")
    p.add_argument("--features", help="what to measure: a features YAML (base, steps, planes, distances, spheres in "
                                      "camera pixels), stored as features.yaml")
    p.add_argument("--calibration-session", help="the session whose poses calibrate this one (instead of --calibration)")
    p.add_argument("--id", help="session id ([a-z0-9-]+; default the YAML's id, else OUT's name)")
    p.set_defaults(func=_cmd_sl_session)

    p = sub.add_parser("decode", help="decode N-step / Gray-code / multi-period captures into projector coordinates; "
                                      "exit 2 if refused, 1 if an axis has fewer valid pixels than codecs.min_valid_fraction")
    p.add_argument("captures", help="folder of the captures (the sequence's frames: a glob, sorted by the number in "
                                      "their names, or a list of file names in capture order)")
    p.add_argument("sequence", help="sequence YAML: projector, frames, blocks (phase, gray, skip, white, black, hue_bands, "
                                      "trapezoid) or kamino410")
    p.add_argument("out", help="new (or empty) folder for coord/sigma/modulation TIFFs, valid and reasons PNGs, quality.png, decode.json")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--projector-gamma", type=float, help="the projector's gamma (overrides the sequence's)")
    g.add_argument("--estimate-gamma", action="store_true", help="estimate the projector's gamma from the captures")
    p.add_argument("--configfile", nargs="+", metavar="FILE", help="YAML files overriding the packaged defaults "
                   "(the codecs block: validity thresholds, noise model), as snakemake --configfile")
    p.set_defaults(func=_cmd_decode)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
