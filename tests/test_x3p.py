"""X3P files (ISO 25178-72) of a bench session, read back by a second, independent reader.

The writer is ``x3pio`` (huefringe.x3p); the reader here is ``surfalize`` (its own ZIP and XML
parsing, GPL-3.0, so a test-only extra), which also computes the ISO 25178-2 height parameters
that the report's flatness figures are compared with.
"""

from __future__ import annotations

import datetime as dt
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bench_helpers import bench_config, process, write

from huefringe import metrology, stages
from huefringe.io import read_tiff
from huefringe.session import load_session
from huefringe.settings import software_identity
from huefringe.x3p import PLACEHOLDER_DATE, X3PError, write_height_x3p

surfalize = pytest.importorskip("surfalize")
x3pio = pytest.importorskip("x3pio")

CAPTURE = {"captured_at": "2026-11-30T14:05:00Z", "operator": "J. Doe"}
#: Sa, Sq, Sz of surfalize against the report's (huefringe.metrology.flatness), mm. Both take the
#: same pixels of the same evaluated box, remove the least-squares plane and apply the ISO 25178-2
#: definitions; they differ only in float64 arithmetic (surfalize works in um on coordinates
#: normalised to [-1, 1], metrology in mm on X, Y in mm; the heights pass mm -> m -> um): a few
#: ulp of heights of ~5 mm summed over ~500-2000 pixels, ~1e-13 mm at most (9e-16 measured).
#: 1e-12 mm is 10 times that bound and 1e-8 of the smallest Sa here, so any difference of region,
#: plane, holes or definition fails it.
FLATNESS_TOL_MM = 1e-12


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The demo scene (gauge blocks) at 320 x 240, 2 frames, measured, with X3P files."""
    root = tmp_path_factory.mktemp("x3p")
    cfg = bench_config("demo", width=320, height=240, hue_bands=32, repeats=2, frames=2, id="x3p-demo", **CAPTURE)
    session = write(cfg, root)
    out = process(session, root / "out")
    s = load_session(session)
    x3p = [str(root / "out" / "x3p" / Path(h).with_suffix(".x3p").name) for h in out["heights"]]
    stages.x3p_frames(str(session), s.frame_ids, out["heights"], x3p)
    out.update(x3p=x3p, session=s, root=root)
    return out


def test_an_independent_reader_gets_the_values_increments_and_metadata(measured: dict[str, Any]) -> None:
    s = measured["session"]
    for n, height, path in zip(s.frame_ids, measured["heights"], measured["x3p"], strict=True):
        h = read_tiff(height)
        surface = surfalize.Surface.load(path)  # um
        assert surface.data.shape == h.shape
        assert np.array_equal(np.isnan(surface.data), np.isnan(h))  # the holes, point for point
        assert 0.05 < np.isnan(h).mean() < 0.5  # there are holes to compare (and mostly heights)
        valid = ~np.isnan(h)
        # value for value: every float32 mm height comes back exactly
        assert np.array_equal((surface.data[valid] * 1e-3).astype(np.float32), h[valid])
        assert np.max(np.abs(surface.data[valid] * 1e-3 - h[valid])) < 1e-12
        assert surface.step_x == surface.step_y == pytest.approx(s.pixel_pitch_mm * 1e3, rel=1e-15)  # um
        m = surface.metadata
        assert m["Date"] == dt.datetime(2026, 11, 30, 14, 5, tzinfo=dt.UTC)
        assert m["Creator"] == "J. Doe"
        assert m["InstrumentModel"] == s.provenance["instrument"]
        assert m["InstrumentVersion"] == f"huefringe {software_identity().version}"
        assert m["ProbingSystemType"] == "NonContacting"
        assert "huefringe" in m["ProbingSystemIdentification"]
        assert f"frame {n:04d} of capture session 'x3p-demo'" in m["Comment"]
        assert "SIMULATED" in m["Comment"] and software_identity().url in m["Comment"]
        assert "CalibrationDate" not in m  # the rig's calibration date is not in the session


def test_the_writer_checks_its_own_file(measured: dict[str, Any]) -> None:
    """x3pio reads it back with the MD5s checked, in metres, and refuses a changed byte."""
    path = Path(measured["x3p"][0])
    f = x3pio.read(path, verify=True)
    h = read_tiff(measured["heights"][0])
    assert np.array_equal(f.layers[0].z, h.astype(np.float64) * 1e-3, equal_nan=True)
    assert f.header.x.increment == f.header.y.increment == measured["session"].pixel_pitch_mm * 1e-3
    assert f.metadata.probing_system.type is x3pio.ProbingType.NON_CONTACTING
    with zipfile.ZipFile(path) as zf:
        members = {i.filename: zf.read(i) for i in zf.infolist()}
        assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in zf.infolist())  # no clock
    assert set(members) == {"main.xml", "md5checksum.hex", "bindata/data.bin"}
    data = bytearray(members["bindata/data.bin"])
    data[8] ^= 1
    bad = path.with_name("tampered.x3p")
    with zipfile.ZipFile(bad, "w") as zf:
        for name, content in {**members, "bindata/data.bin": bytes(data)}.items():
            zf.writestr(name, content)
    with pytest.raises(x3pio.X3pChecksumError):
        x3pio.read(bad, verify=True)


def _areal(path: str, box: list[int]) -> dict[str, float]:
    """Sa, Sq, Sz (mm) by surfalize over the half-open pixel box [u0, v0, u1, v1), levelled."""
    u0, v0, u1, v1 = box
    cropped = surfalize.Surface.load(path).crop((u0, u1 - 1, v0, v1 - 1), in_units=False)
    holes = np.isnan(cropped.data)
    # surfalize refuses NaN in its parameters; a masked point is left out of the plane and of them
    surface = surfalize.Surface(np.where(holes, 0.0, cropped.data), cropped.step_x, cropped.step_y, mask=holes)
    surface.level(inplace=True)
    return {"Sa_mm": surface.Sa() * 1e-3, "Sq_mm": surface.Sq() * 1e-3, "Sz_mm": surface.Sz() * 1e-3}


@pytest.mark.parametrize("holes", [False, True])
def test_areal_parameters_agree_with_the_reports_flatness(measured: dict[str, Any], tmp_path: Path,
                                                          holes: bool) -> None:
    """On the measured maps (their evaluated boxes are whole), and on the same maps with 15 % of
    each evaluated box's pixels made holes (so that both leave the same points out)."""
    s = measured["session"]
    maps = [read_tiff(p) for p in measured["heights"]]
    paths = measured["x3p"]
    if holes:
        rng = np.random.default_rng(25)
        for st in s.specimen["steps"]:
            u0, v0, u1, v1 = metrology.central_box(st["roi"], metrology.DEFAULT_EDGE_EXCLUSION)
            for z in maps:
                z[v0:v1, u0:u1][rng.random((v1 - v0, u1 - u0)) < 0.15] = np.nan
        paths = [str(write_height_x3p(tmp_path / f"frame_{i:04d}.x3p", z, s.pixel_pitch_mm)) for i, z in enumerate(maps)]
    # what report.json's steps[].flatness holds (stages.metrology calls this, same arguments)
    method = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=max(s.planes_mm) - min(s.planes_mm))
    cover = [st["coverage"]["evaluated"] for st in method["steps"]]
    assert (max(cover) < 0.9) if holes else (min(cover) > 0.99)
    worst = 0.0
    for step in method["steps"]:
        per_frame = [_areal(p, step["evaluated_roi"]) for p in paths]
        for key in ("Sa_mm", "Sq_mm", "Sz_mm"):
            theirs = float(np.mean([f[key] for f in per_frame]))
            ours = step["flatness"][key]
            assert ours > 1e-4  # a real texture to compare (noise of the measurement)
            assert abs(theirs - ours) <= FLATNESS_TOL_MM, (step["name"], key, theirs, ours)
            worst = max(worst, abs(theirs - ours))
    print(f"evaluated coverage {min(cover):.3f}-{max(cover):.3f}; worst |surfalize - report| over {len(method['steps'])} steps x Sa/Sq/Sz: {worst:.2e} mm")


def test_same_inputs_same_bytes_and_the_date_comes_from_the_session(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    h = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    h[1, 2] = np.nan
    a = write_height_x3p(tmp_path / "a.x3p", h, 0.1, provenance=CAPTURE).read_bytes()
    assert write_height_x3p(tmp_path / "b.x3p", h, 0.1, provenance=CAPTURE).read_bytes() == a
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    f = x3pio.read(write_height_x3p(tmp_path / "c.x3p", h, 0.1))
    assert f.metadata.date == PLACEHOLDER_DATE and "a placeholder" in f.metadata.comment
    assert f.metadata.creator is None
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764511500")
    f = x3pio.read(write_height_x3p(tmp_path / "d.x3p", h, 0.1))
    assert f.metadata.date == dt.datetime(2025, 11, 30, 14, 5, tzinfo=dt.UTC)
    f = x3pio.read(write_height_x3p(tmp_path / "e.x3p", h, 0.1, provenance={"captured_at": "2026-11-30T15:05:00"}))
    assert f.metadata.date == dt.datetime(2026, 11, 30, 15, 5, tzinfo=dt.UTC) and "taken as UTC" in f.metadata.comment
    assert not list(tmp_path.glob(".*part*"))


@pytest.mark.parametrize(("pitch", "match"), [
    (None, "pixel pitch None is not a number"),
    ("0.2mm", "pixel pitch '0.2mm' is not a number"),
    (float("nan"), "positive finite number of mm, got nan"),
    (float("inf"), "positive finite number of mm, got inf"),
    (0.0, "positive finite number of mm, got 0.0"),
    (-0.1, "positive finite number of mm, got -0.1"),
])
def test_a_map_without_a_usable_pitch_is_refused(tmp_path: Path, pitch: Any, match: str) -> None:
    with pytest.raises(X3PError, match=rf"frame_0000.x3p: the {match}" if "number of mm" not in match
                       else rf"frame_0000.x3p: the pixel pitch must be a {match}"):
        write_height_x3p(tmp_path / "frame_0000.x3p", np.zeros((3, 4), np.float32), pitch)
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize(("height", "match"), [
    (np.zeros((2, 3, 4), np.float32), "non-empty 2-D array, got shape"),
    (np.zeros((0, 4), np.float32), "non-empty 2-D array, got shape"),
    (np.zeros((3, 4), np.int16), "floating point"),
    (np.array([[0.0, np.inf], [1.0, np.nan]]), "1 infinite values"),
])
def test_a_map_that_is_not_a_height_map_is_refused(tmp_path: Path, height: np.ndarray, match: str) -> None:
    with pytest.raises(X3PError, match=match):
        write_height_x3p(tmp_path / "f.x3p", height, 0.2)


def test_a_bad_capture_date_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(X3PError, match=r"f.x3p: provenance.captured_at 'yesterday' is not an ISO 8601"):
        write_height_x3p(tmp_path / "f.x3p", np.zeros((3, 4), np.float32), 0.2, provenance={"captured_at": "yesterday"})


def test_the_stage_refuses_lists_of_different_lengths(measured: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="x3p_frames: 2 frames, 1 height maps, 2 X3P files"):
        stages.x3p_frames(str(measured["session"].root), [0, 1], measured["heights"][:1],
                          [str(tmp_path / "a.x3p"), str(tmp_path / "b.x3p")])
