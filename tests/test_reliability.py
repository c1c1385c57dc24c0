"""Reliability: bad inputs are refused with a message naming the file (and never modified),
interrupted runs resume to the same outputs, and repeated runs are deterministic.

Library-level cases call the stage functions of :mod:`huefringe.stages` (what each Snakemake
job runs) on a small virtual-bench session (160 x 120 px, 24 bands x 2 repeats, 4 frames).
Workflow-level cases run Snakemake as a subprocess on a temporary copy of the workflow, never
on the repository's own ``results/``.

Cases checked with ``known_defect`` guard a refusal that is easy to lose (no refusal, or a message
not naming the file); they are asserted after the hard part of each case (that the input is refused at all,
with the right error type).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
import yaml
from session_factory import make_session, write_image

from huefringe import perframe, stages
from huefringe.archive import is_partial_file, verify_archive
from huefringe.height import PlaneCalibrationError
from huefringe.huetable import HueTableError
from huefringe.io import read_tiff, write_tiff
from huefringe.metrology import MetrologyError
from huefringe.session import SessionError
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
SID = "tiny-bench"
BENCH = {"id": SID, "width": 160, "height": 120, "hue_bands": 24, "repeats": 2, "frames": 4,
         "pixel_pitch_mm": 0.5, "period_px": 24}  # the demo scene at a quarter of the pixels, 4 frames
# the library defaults and the repository's config.yaml, scaled down for the tiny session (new keys reach these tests too)
_BASE: dict[str, Any] = load_config(REPO / "config.yaml")
CALIBRATION: dict[str, Any] = {
    **_BASE["calibration"],
    "compensation": {"projector_width": 64, "projector_height": 48, "period_px": 16,
                     "threshold_rad": 0.005, "max_iter": 5, "gain": 0.8},
}  # fmt: skip
MEASUREMENT: dict[str, Any] = {**_BASE["measurement"], "frames_per_job": 50}
CONFIG: dict[str, Any] = {
    **{k: v for k, v in _BASE.items() if k != "table1"},
    "sessions": ["resources/tiny"],
    "bench_sessions": {"resources/tiny": "tiny.yaml"},
    "results_dir": "results",
    "calibration": CALIBRATION,
    "measurement": MEASUREMENT,
    "mesh": {**_BASE["mesh"], "frames": "first"},
    "render": {"frames": "first", "width": 64, "height": 64},
}


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def snapshot(*roots: Path) -> dict[Path, str]:
    """sha256 of every file under the given folders (to prove nothing was modified)."""
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for r in roots for p in sorted(r.rglob("*")) if p.is_file()}


def write_bench_yaml(path: Path) -> Path:
    from huefringe import bench

    cfg = bench.load_bench_config(bench.preset_path("demo"))
    cfg["session"].update(BENCH)
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def known_defect(condition: bool, what: str) -> None:
    """Assert ``condition`` (these cases were defects once; the message says which)."""
    assert condition, what


def stage_paths(out: Path, frames: list[int]) -> dict[str, list[str]]:
    return {
        "heights": [str(out / "height" / f"frame_{n:04d}.tiff") for n in frames],
        "phases": [str(out / "phase" / f"frame_{n:04d}.tiff") for n in frames],
        "hues": [str(out / "hue" / f"frame_{n:04d}.tiff") for n in frames],
        "qa": [str(out / "qa" / f"frame_{n:04d}.json") for n in frames],
    }


def build_tables(session: Path, out: Path, which: tuple[str, ...] = ("reference", "object")) -> None:
    for w in which:
        stages.hue_table(str(session), w, "hexcone", CALIBRATION, str(out / f"table_{w}.json"),
                           str(out / f"table_{w}.stats.json"))


def calibrate(session: Path, out: Path) -> None:
    stages.plane_calibration(str(session), str(out / "table_reference.json"), "hexcone", CALIBRATION,
                               str(out / "phase_to_height.npz"), str(out / "planes.json"))


def measure(session: Path, calib: Path, out: Path, frames: list[int]) -> None:
    stages.measure_frames(str(session), frames, str(calib / "table_object.json"), str(calib / "phase_to_height.npz"),
                            "hexcone", MEASUREMENT, CALIBRATION, **stage_paths(out, frames))


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small bench session (read only: tests copy it before breaking anything)."""
    from huefringe import bench

    root = tmp_path_factory.mktemp("tiny")
    cfg = bench.load_bench_config(write_bench_yaml(root / "tiny.yaml"))
    return bench.write_session(cfg, root / "session")


@pytest.fixture(scope="module")
def tiny_run(tiny_session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Tables, plane calibration and height maps of every frame of the tiny session (library stages)."""
    out = tmp_path_factory.mktemp("tiny-run")
    build_tables(tiny_session, out)
    calibrate(tiny_session, out)
    measure(tiny_session, out, out, [0, 1, 2, 3])
    return out


@pytest.fixture
def session_copy(tiny_session: Path, tmp_path: Path) -> Path:
    return shutil.copytree(tiny_session, tmp_path / "session")


def edit_image(path: Path, edit: Callable[[np.ndarray], np.ndarray]) -> None:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]
    write_image(path, np.ascontiguousarray(edit(img)))


# --------------------------------------------------------------------------------------------
# corrupt and truncated images (beyond tests/test_session.py)
# --------------------------------------------------------------------------------------------


def _truncate_tiff(root: Path) -> None:
    p = root / "object/frames/frame_0001.tiff"
    p.write_bytes(p.read_bytes()[:-500])


def _corrupt_compressed_tiff(root: Path) -> None:
    p = root / "reference/hue/band_002_r1.tiff"
    rng = np.random.default_rng(3)
    tifffile.imwrite(p, rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), photometric="rgb", compression="zlib")
    data = bytearray(p.read_bytes())
    offset = tifffile.TiffFile(p).pages[0].dataoffsets[0]
    data[offset + 10 : offset + 40] = b"\x00" * 30  # inside the zlib stream, header intact
    p.write_bytes(bytes(data))


def _float_tiff(root: Path) -> None:
    tifffile.imwrite(root / "object/white.tiff", np.ones((24, 32, 3), np.float32), photometric="rgb")


def _bad_ground_truth(root: Path) -> None:
    (root / "ground_truth/frames/frame_0000.tiff").write_bytes(b"II*\x00garbage")


CORRUPT: dict[str, tuple[str, Callable[[Path], None], str, str]] = {
    # name: (image suffix of the session, breakage, file the message must name, words)
    "zero-byte png": (".png", lambda r: (r / "object/frames/frame_0001.png").write_bytes(b""),
                      "object/frames/frame_0001.png", "not a PNG file"),
    "text named .png": (".png", lambda r: (r / "reference/white.png").write_text("white\n"),
                        "reference/white.png", "not a PNG file"),
    "truncated tiff": (".tiff", _truncate_tiff, "object/frames/frame_0001.tiff", "truncated TIFF"),
    "corrupt zlib tiff": (".tiff", _corrupt_compressed_tiff, "reference/hue/band_002_r1.tiff", "cannot decode"),
    "float tiff": (".tiff", _float_tiff, "object/white.tiff", "float"),
    "corrupt ground truth": (".png", _bad_ground_truth, "ground_truth/frames/frame_0000.tiff", "ground truth"),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(CORRUPT))
def test_corrupt_images_are_refused_by_the_check_stage(tmp_path: Path, name: str) -> None:
    ext, breakage, file_part, words = CORRUPT[name]
    root = make_session(tmp_path / "s", ext=ext, bands=6, repeats=2, frames=2)
    breakage(root)
    before = snapshot(root)
    summary = tmp_path / "out" / "session_check.json"
    with pytest.raises(SessionError) as info:
        stages.check_session(str(root), str(summary))  # the workflow's first stage (deep check)
    line = next((ln for ln in str(info.value).splitlines() if file_part in ln), None)
    assert line is not None, f"message does not name {file_part}: {info.value}"
    assert words in line, line
    assert not summary.exists()
    assert snapshot(root) == before


# --------------------------------------------------------------------------------------------
# frames: saturated, lens cap
# --------------------------------------------------------------------------------------------


def test_saturated_frame_is_refused_with_its_clipped_fraction(session_copy: Path, tiny_run: Path, tmp_path: Path) -> None:
    frame = session_copy / "object/frames/frame_0002.png"
    edit_image(frame, lambda im: np.clip(im.astype(np.int32) * 4, 0, 255).astype(np.uint8))  # 4x over-exposed
    before = snapshot(session_copy)
    out = tmp_path / "out"
    with pytest.raises(perframe.FrameError) as info:
        measure(session_copy, tiny_run, out, [2])
    msg = str(info.value)
    assert msg.startswith(str(frame)), msg
    assert "% of the pixels are clipped (sensor saturated), above the limit of 5.0 %" in msg
    clipped = float(msg.split(": ", 1)[1].split(" %")[0])
    assert 20 < clipped <= 100
    assert not (out / "height" / "frame_0002.tiff").exists()
    assert snapshot(session_copy) == before


def test_slightly_clipped_frame_is_measured_and_its_clipped_fraction_reported(session_copy: Path, tiny_run: Path,
                                                                                tmp_path: Path) -> None:
    frame = session_copy / "object/frames/frame_0001.png"

    def spot(im: np.ndarray) -> np.ndarray:
        im = im.copy()
        im[50:60, 70:80] = 255  # a 10 x 10 specular highlight: 100 / 19200 = 0.52 %
        return im

    edit_image(frame, spot)
    out = tmp_path / "out"
    measure(session_copy, tiny_run, out, [1])
    qa = json.loads((out / "qa" / "frame_0001.json").read_text())
    assert qa["clipped_fraction"] == pytest.approx(100 / (160 * 120), abs=2e-4)
    h = read_tiff(out / "height" / "frame_0001.tiff")
    assert np.isnan(h[50:60, 70:80]).all() and np.isfinite(h).mean() > 0.5


def test_maps_of_chosen_frames_only_and_the_same_heights(tiny_session: Path, tiny_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    p = stage_paths(out, [0, 1, 2])
    kw = {"heights": p["heights"], "qa": p["qa"]}
    stages.measure_frames(str(tiny_session), [0, 1, 2], str(tiny_run / "table_object.json"),
                            str(tiny_run / "phase_to_height.npz"), "hexcone", MEASUREMENT, CALIBRATION,
                            phases=[p["phases"][1]], hues=[p["hues"][1]], map_frames=[1], **kw)
    assert sorted(x.name for x in (out / "phase").iterdir()) == ["frame_0001.tiff"]
    assert sorted(x.name for x in (out / "hue").iterdir()) == ["frame_0001.tiff"]
    for n in (0, 1, 2):  # the maps change nothing else
        for kind, ext in (("height", "tiff"), ("qa", "json")):
            assert (out / kind / f"frame_{n:04d}.{ext}").read_bytes() == (tiny_run / kind / f"frame_{n:04d}.{ext}").read_bytes()
    assert (out / "phase" / "frame_0001.tiff").read_bytes() == (tiny_run / "phase" / "frame_0001.tiff").read_bytes()
    with pytest.raises(ValueError, match="not in the batch"):
        stages.measure_frames(str(tiny_session), [0], str(tiny_run / "table_object.json"),
                                str(tiny_run / "phase_to_height.npz"), "hexcone", MEASUREMENT, CALIBRATION,
                                phases=[p["phases"][1]], hues=[p["hues"][1]], map_frames=[1],
                                heights=p["heights"][:1], qa=p["qa"][:1])


def test_lens_cap_black_frame_is_refused(session_copy: Path, tiny_run: Path, tmp_path: Path) -> None:
    frame = session_copy / "object/frames/frame_0003.png"
    edit_image(frame, np.zeros_like)
    before = snapshot(session_copy)
    with pytest.raises(perframe.FrameError) as info:
        measure(session_copy, tiny_run, tmp_path / "out", [3])
    msg = str(info.value)
    assert msg.startswith(str(frame)) and "only 0.0 % of the pixels carry a usable fringe" in msg and "lens cap" in msg
    assert not (tmp_path / "out" / "height" / "frame_0003.tiff").exists()
    assert snapshot(session_copy) == before


# --------------------------------------------------------------------------------------------
# hue tables that are not monotonic for most pixels
# --------------------------------------------------------------------------------------------


def _shuffle_bands(folder: Path, n: int, seed: int = 1) -> None:
    """Relabel the hue bands in a random order (mislabelled or mis-captured bands)."""
    perm = np.random.default_rng(seed).permutation(n)
    files = sorted(folder.glob("band_*_r*.png"))
    data = {f.name: f.read_bytes() for f in files}
    for f in files:
        i, r = int(f.name[5:8]), f.name[10:-4]
        f.write_bytes(data[f"band_{perm[i]:03d}_r{r}.png"])


def test_unordered_object_bands_never_reach_a_height_map(session_copy: Path, tiny_run: Path, tmp_path: Path) -> None:
    """Refused at the table stage (proposed) or, today, at the frame stage: never a height map."""
    _shuffle_bands(session_copy / "object/hue", BENCH["hue_bands"])
    out = tmp_path / "out"
    try:
        build_tables(session_copy, out, ("object",))
    except HueTableError as exc:
        assert str(session_copy / "object/hue") in str(exc)
        return
    stats = json.loads((out / "table_object.stats.json").read_text())
    assert stats["valid_fraction"] < 0.05
    assert stats["masked_by_reason"]["order"] + stats["masked_by_reason"]["coverage"] > 0.9 * stats["n_pixels"]
    shutil.copy(tiny_run / "phase_to_height.npz", out / "phase_to_height.npz")
    with pytest.raises(perframe.FrameError, match="usable fringe"):
        measure(session_copy, out, out / "m", [0])
    assert not (out / "m" / "height" / "frame_0000.tiff").exists()


@pytest.mark.parametrize("which", ["object", "reference"])
def test_unordered_hue_bands_are_refused_naming_the_band_folder(session_copy: Path, tmp_path: Path, which: str) -> None:
    folder = session_copy / which / "hue"
    _shuffle_bands(folder, BENCH["hue_bands"])
    before = snapshot(session_copy)
    out = tmp_path / "out"
    try:
        build_tables(session_copy, out, (which,))
    except (HueTableError, SessionError) as exc:
        assert str(folder) in str(exc) and ("order" in str(exc) or "monoton" in str(exc)), str(exc)
        assert not (out / f"table_{which}.json").exists()
    else:
        stats = json.loads((out / f"table_{which}.stats.json").read_text())
        known_defect(False, f"a {which} hue table valid for {100 * stats['valid_fraction']:.1f} % of the pixels "
                            f"(masked: {stats['masked_by_reason']}) is accepted by stages.hue_table; the error comes "
                            "later, naming a frame ('lens cap?') or no file at all ('plane z = 0.000 mm has only 0.0 % "
                            "valid pixels')")  # fmt: skip
    assert snapshot(session_copy) == before


# --------------------------------------------------------------------------------------------
# calibration planes: wrong order, too close
# --------------------------------------------------------------------------------------------


def _swap_planes(root: Path) -> None:
    a, b = root / "reference/planes/z_3.000.png", root / "reference/planes/z_6.000.png"
    da, db = a.read_bytes(), b.read_bytes()
    a.write_bytes(db)
    b.write_bytes(da)


def _close_planes(root: Path) -> None:
    meta = yaml.safe_load((root / "session.yaml").read_text())
    meta["planes_mm"] = [0.0, 3.0, 3.001]
    (root / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    (root / "reference/planes/z_6.000.png").unlink()
    shutil.copy(root / "reference/planes/z_3.000.png", root / "reference/planes/z_3.001.png")


def _flat_plane(root: Path) -> None:
    shutil.copy(root / "reference/planes/z_0.000.png", root / "reference/planes/z_3.000.png")


PLANES: dict[str, tuple[Callable[[Path], None], str]] = {
    "wrong order (files swapped)": (_swap_planes, "order"),
    "too close to fit": (_close_planes, "too close"),
    "no phase shift (plane = reference)": (_flat_plane, "phase"),
}


@pytest.mark.parametrize("name", list(PLANES))
def test_bad_calibration_planes_are_refused(session_copy: Path, tiny_run: Path, tmp_path: Path, name: str) -> None:
    breakage, words = PLANES[name]
    breakage(session_copy)
    before = snapshot(session_copy)
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(tiny_run / "table_reference.json", out)
    for suffix in (".npy", ".maps.npz"):
        shutil.copy(tiny_run / f"table_reference{suffix}", out)
    try:
        calibrate(session_copy, out)
    except PlaneCalibrationError as exc:
        msg = str(exc)
        assert words in msg, msg
        assert not (out / "phase_to_height.npz").exists()
        assert snapshot(session_copy) == before
        known_defect("reference/planes" in msg or "session.yaml" in msg,
                     f"PlaneCalibrationError does not name the plane files or session.yaml: {msg!r}")
    else:
        stats = json.loads((out / "planes.json").read_text())
        assert snapshot(session_copy) == before
        known_defect(False, f"planes '{name}' accepted: fit residual {stats['fit_residual_rms_mm']:.3g} mm, "
                            f"projector height {stats['projector_height_mm_estimate']} mm, "
                            f"unambiguous range {stats['unambiguous_range_mm']}")  # fmt: skip


# --------------------------------------------------------------------------------------------
# metrology: ROIs on invalid pixels, NaN-only height maps
# --------------------------------------------------------------------------------------------


def _metrology(session: Path, tiny_run: Path, heights: list[Path], out: Path) -> None:
    png = out / "figure.png"
    write_image(png, np.zeros((8, 8, 3), np.uint8))
    stages.metrology(
        session=str(session), heights=[str(h) for h in heights],
        qa=[str(tiny_run / "qa" / f"frame_{n:04d}.json") for n in range(len(heights))], baseline=[],
        planes=str(tiny_run / "planes.json"), tables=str(tiny_run / "table_object.stats.json"),
        cross_section=str(png), render=str(png), height_map=str(png), accuracy=[], config=CONFIG,
        json=str(out / "report.json"), html=str(out / "report.html"), profile=str(out / "profile.png"),
        per_frame=str(out / "per_frame.png"),
    )  # fmt: skip


def _heights(tiny_run: Path, dst: Path) -> list[Path]:
    dst.mkdir(parents=True, exist_ok=True)
    return [Path(shutil.copy(tiny_run / "height" / f"frame_{n:04d}.tiff", dst)) for n in range(4)]


def test_metrology_of_the_tiny_run_passes(tiny_session: Path, tiny_run: Path, tmp_path: Path) -> None:
    _metrology(tiny_session, tiny_run, _heights(tiny_run, tmp_path / "h"), tmp_path)
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["session"] == SID and report["frames"] == 4 and len(report["steps"]) == 3


def test_roi_on_invalid_pixels_is_refused_naming_roi_and_file(tiny_session: Path, tiny_run: Path, tmp_path: Path) -> None:
    heights = _heights(tiny_run, tmp_path / "h")
    meta = yaml.safe_load((tiny_session / "session.yaml").read_text())
    step = meta["specimen"]["steps"][0]
    u0, v0, u1, v1 = step["roi"]
    h = read_tiff(heights[2])
    h[v0:v1, u0:u1] = np.nan  # e.g. the ROI drawn over a shadow or an unlit region
    write_tiff(heights[2], h)
    before = snapshot(tiny_session, tmp_path / "h")
    with pytest.raises(MetrologyError) as info:
        _metrology(tiny_session, tiny_run, heights, tmp_path)
    msg = str(info.value)
    assert f"ROI '{step['name']}'" in msg and "no valid pixel" in msg, msg
    assert not (tmp_path / "report.json").exists() and not (tmp_path / "report.html").exists()
    assert snapshot(tiny_session, tmp_path / "h") == before
    known_defect(str(heights[2]) in msg, f"MetrologyError names the list index, not the height file: {msg!r}")


def test_nan_only_height_map_is_refused_by_metrology(tiny_session: Path, tiny_run: Path, tmp_path: Path) -> None:
    heights = _heights(tiny_run, tmp_path / "h")
    write_tiff(heights[1], np.full((BENCH["height"], BENCH["width"]), np.nan, np.float32))
    with pytest.raises(MetrologyError) as info:
        _metrology(tiny_session, tiny_run, heights, tmp_path)
    msg = str(info.value)
    assert "no valid pixel (all NaN)" in msg, msg
    assert not (tmp_path / "report.json").exists()
    known_defect(str(heights[1]) in msg, f"MetrologyError names the list index, not the height file: {msg!r}")


def test_nan_only_height_map_gives_an_empty_mesh(tiny_session: Path, tmp_path: Path) -> None:
    """Documented behaviour of the surface stages: nothing valid -> an empty mesh, not a crash."""
    height = tmp_path / "frame_0000.tiff"
    write_tiff(height, np.full((BENCH["height"], BENCH["width"]), np.nan, np.float32))
    out = tmp_path / "mesh"
    stages.mesh(str(tiny_session), str(height), CONFIG["mesh"], str(out / "frame_0000.ply"),
                        str(out / "frame_0000.stl"), str(out / "frame_0000.stats.json"))
    stats = json.loads((out / "frame_0000.stats.json").read_text())
    assert stats["faces"] == 0 and stats["vertices"] == 0


# --------------------------------------------------------------------------------------------
# workflow level: empty sessions, unknown configuration keys
# --------------------------------------------------------------------------------------------


def workflow_copy(dst: Path, config: dict[str, Any] | None = None) -> Path:
    """A runnable copy of the workflow (Snakefile, rules, schemas, scripts) with its own config.yaml."""
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPO / "Snakefile", dst / "Snakefile")
    for folder in ("workflow", "scripts"):
        shutil.copytree(REPO / folder, dst / folder, ignore=shutil.ignore_patterns("__pycache__"))
    (dst / "config.yaml").write_text(yaml.safe_dump(config or CONFIG, sort_keys=False))
    write_bench_yaml(dst / "tiny.yaml")
    return dst


def snakemake(workdir: Path, *args: str, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=workdir, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def dry_workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return workflow_copy(tmp_path_factory.mktemp("dry"))


def test_empty_session_folder_is_refused_before_any_work(dry_workdir: Path, tmp_path: Path) -> None:
    empty = tmp_path / "empty-session"
    empty.mkdir()
    only_yaml = tmp_path / "only-yaml"
    only_yaml.mkdir()
    make_session(tmp_path / "donor", bands=6, repeats=1, frames=1)
    shutil.copy(tmp_path / "donor" / "session.yaml", only_yaml / "session.yaml")
    for folder, expect in ((empty, f"{empty}/session.yaml: missing file"), (only_yaml, f"{only_yaml}/reference: missing folder")):
        cfg = tmp_path / f"{folder.name}.yaml"
        cfg.write_text(yaml.safe_dump({"sessions": [str(folder)]}))
        before = snapshot(folder)
        res = snakemake(dry_workdir, "-n", "--configfile", str(cfg))
        assert res.returncode != 0
        assert "huefringe: cannot start" in res.stderr and expect in res.stderr, res.stderr[-2000:]
        assert snapshot(folder) == before
    cfg = tmp_path / "no-sessions.yaml"
    cfg.write_text("sessions: []\n")
    res = snakemake(dry_workdir, "-n", "--configfile", str(cfg))
    assert res.returncode != 0 and "[] should be non-empty" in res.stdout + res.stderr


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (lambda c: c.update(hue_modle="hsi"), "hue_modle"),
        (lambda c: c["measurement"].update(max_clip=0.1), "max_clip"),
        (lambda c: c["calibration"]["compensation"].update(period=16), "period"),
    ],
    ids=["top-level typo", "unknown measurement key", "nested compensation key"],
)
def test_unknown_config_key_is_named(dry_workdir: Path, tmp_path: Path, edit: Callable[[dict], None], key: str) -> None:
    cfg = json.loads(json.dumps(CONFIG))
    edit(cfg)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(cfg, sort_keys=False))
    before = bad.read_bytes()
    res = snakemake(dry_workdir, "-n", "--configfile", str(bad))
    out = res.stdout + res.stderr
    assert res.returncode != 0
    assert "is not valid" in out and f"('{key}' was unexpected)" in out, out[-3000:]
    assert str(bad) in out  # the message names the config file the user gave
    assert bad.read_bytes() == before
    assert not (dry_workdir / "results").exists()


# --------------------------------------------------------------------------------------------
# workflow level: interrupted runs and determinism (slow: whole runs of the tiny session)
# --------------------------------------------------------------------------------------------

ARCHIVE = f"results/{SID}.archive.zip"


@contextlib.contextmanager
def _exclusive(lock: Path) -> Iterator[None]:
    with open(lock, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


#: Documented volatile fields: values that legitimately differ between runs (none left: timings
#: go to the job logs, not to result files).
VOLATILE: dict[str, tuple[str, ...]] = {}


def outputs(results: Path) -> dict[str, str]:
    """sha256 of every file under a results folder (relative paths), leftover partial files excluded;
    for the files of :data:`VOLATILE`, the sha256 of the JSON without the volatile fields."""
    out = {}
    for p in sorted(results.rglob("*")):
        if not p.is_file() or is_partial_file(p.name):
            continue
        key = p.relative_to(results).as_posix()
        data = p.read_bytes()
        if key in VOLATILE:
            doc = json.loads(data)
            for field in VOLATILE[key]:
                doc.pop(field, None)
            data = json.dumps(doc, sort_keys=True).encode()
        out[key] = hashlib.sha256(data).hexdigest()
    return out


def crate_sums(archive: Path) -> dict[str, str]:
    """sha256 listed in an archive's crate for every file, volatile ones and the crate itself excluded."""
    from huefringe.archive import read_crate

    return {e["@id"]: e["sha256"] for e in read_crate(archive)["@graph"]
            if e["@type"] == "File" and e["@id"].removeprefix("results/") not in VOLATILE}  # fmt: skip


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One uninterrupted run (all + archive) of the tiny bench session, shared by the xdist workers."""
    shared = tmp_path_factory.getbasetemp().parent if os.environ.get("PYTEST_XDIST_WORKER") else tmp_path_factory.getbasetemp()
    wd = shared / "reliability-reference-run"
    with _exclusive(shared / "reliability-reference-run.lock"):
        if not (wd / "DONE").exists():
            shutil.rmtree(wd, ignore_errors=True)
            workflow_copy(wd)
            res = snakemake(wd, "--cores", "2", "all", "archive")
            assert res.returncode == 0, res.stderr[-4000:]
            (wd / "DONE").write_text("ok\n")
    return wd


def _run_until(workdir: Path, trigger: Path, sig: signal.Signals, *args: str) -> bool:
    """Start Snakemake in its own process group; send ``sig`` to the group once ``trigger`` exists.

    Returns True if the run was interrupted, False if it finished first.
    """
    err = open(workdir / f"interrupted-{sig.name}.log", "w")  # noqa: SIM115 - closed below
    p = subprocess.Popen([sys.executable, "-m", "snakemake", "--cores", "2", *args], cwd=workdir,
                         stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    try:
        deadline = time.monotonic() + 600
        while not trigger.exists():
            if p.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.005)
        interrupted = p.poll() is None
        if interrupted:
            os.killpg(p.pid, sig)
        p.wait(timeout=120)
        return interrupted
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)  # nothing of the run may outlive the test
        err.close()


@pytest.mark.slow
def test_interrupted_run_resumes_to_the_same_outputs(reference_run: Path, tmp_path: Path) -> None:
    wd = workflow_copy(tmp_path / "wd")
    shutil.copytree(reference_run / "resources", wd / "resources")  # the same session (the bench is not re-run)
    session = wd / "resources" / "tiny"
    before = snapshot(session)
    res_dir = wd / "results" / SID
    # 1. SIGTERM while the hue tables are being written
    assert _run_until(wd, res_dir / "calib" / "table_reference.json", signal.SIGTERM, "all", "archive")
    # 2. SIGKILL (no clean-up at all) in the middle of the batch of frames
    assert _run_until(wd, res_dir / "height" / "frame_0000.tiff", signal.SIGKILL, "all", "archive", "--rerun-incomplete")
    # The kill lands within a few ms of the first height map on an idle machine (mid-batch); on a
    # loaded one the poll may wake later, but the run must still have been cut before its end.
    assert not (res_dir / "cloud" / "frame_0003.ply").exists() or not (wd / ARCHIVE).exists()
    # 3. resume: remove the stale lock of the killed run, re-run the incomplete jobs
    assert snakemake(wd, "--unlock").returncode == 0
    res = snakemake(wd, "--cores", "2", "--rerun-incomplete", "all", "archive")
    assert res.returncode == 0, res.stderr[-4000:]

    want, got = outputs(reference_run / "results" / SID), outputs(res_dir)
    assert sorted(got) == sorted(want)
    differ = sorted(k for k in want if got[k] != want[k])
    assert not differ, f"outputs differ from the uninterrupted run: {differ}"
    assert verify_archive(wd / ARCHIVE).ok
    assert crate_sums(wd / ARCHIVE) == crate_sums(reference_run / ARCHIVE)
    assert snapshot(session) == before
    # the only debris a SIGKILL can leave: temporary files of atomic writes, never a target name
    leftovers = [p for p in res_dir.rglob("*") if p.is_file() and is_partial_file(p.name)]
    assert all(p.name.startswith(".") for p in leftovers)


@pytest.mark.slow
def test_same_session_and_config_give_identical_results(reference_run: Path) -> None:
    """A second run into another results folder: identical height maps, report.json and every other
    output, once the documented volatile fields (:data:`VOLATILE`) are removed, except report.html,
    whose provenance shows the configuration (results_dir differs)."""
    cfg = json.loads(json.dumps(CONFIG))
    cfg["results_dir"] = "results-again"
    again = reference_run / "again.yaml"
    again.write_text(yaml.safe_dump(cfg, sort_keys=False))
    res = snakemake(reference_run, "--cores", "2", "--configfile", str(again))
    assert res.returncode == 0, res.stderr[-4000:]
    first, second = outputs(reference_run / "results" / SID), outputs(reference_run / "results-again" / SID)
    assert sorted(second) == sorted(first)
    heights = [k for k in first if k.startswith(("height/", "baseline/height/"))]
    assert len(heights) == 8
    for key in [*heights, "metrology/report.json", "accuracy.json"]:
        assert second[key] == first[key], key
    assert sorted(k for k in first if second[k] != first[k]) == ["metrology/report.html"]
    html = [(reference_run / d / SID / "metrology" / "report.html").read_bytes() for d in ("results", "results-again")]
    assert html[1].replace(b"results-again", b"results") == html[0]  # only the configuration shown differs


def test_outputs_get_umask_permissions_and_stale_parts_are_removed(tmp_path: Path) -> None:
    from huefringe.io import atomic_path, remove_stale_parts, write_json

    target = tmp_path / "out" / "x.json"
    write_json(target, {"a": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~mask)
    stale = target.parent / ".x.abc123.part.json"  # what a SIGKILLed atomic_path leaves
    stale.write_text("{")
    assert remove_stale_parts(target) == [stale] and not stale.exists() and target.exists()
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("partial")
        raise RuntimeError("killed")
    assert json.loads(target.read_text()) == {"a": 1}
    assert not list(target.parent.glob(".x.*"))


def test_saturated_white_image_is_refused(session_copy: Path, tmp_path: Path) -> None:
    white = session_copy / "object" / "white.png"
    img = cv2.imread(str(white), cv2.IMREAD_UNCHANGED)
    img[: img.shape[0] // 4] = 255  # a quarter of the sensor saturated
    cv2.imwrite(str(white), img)
    before = snapshot(session_copy)
    with pytest.raises(HueTableError, match=r"white\.png: 25\.0 % .*clipped.*limit 1 %"):
        build_tables(session_copy, tmp_path, which=("object",))
    assert snapshot(session_copy) == before
    assert not (tmp_path / "table_object.json").exists()
    # the limit is the config's calibration.max_white_clipped_fraction
    stages.hue_table(str(session_copy), "object", "hexcone", {**CALIBRATION, "max_white_clipped_fraction": 0.3},
                       str(tmp_path / "table_object.json"), str(tmp_path / "table_object.stats.json"))
    assert (tmp_path / "table_object.json").exists()
