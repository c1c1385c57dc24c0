"""Archives: a session and its results in one deterministic ZIP with RO-Crate metadata, verified."""

from __future__ import annotations

import json
import os
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import tifffile
from session_factory import make_session

from huefringe.archive import ArchiveError, read_crate, verify_archive, write_archive
from huefringe.cli import main
from huefringe.settings import software_identity

CONFIG = {"sessions": ["resources/s"], "results_dir": "results", "hue_model": "hexcone", "measurement": {"unwrap": "reference"}}


def _results(root: Path) -> Path:
    """A small stand-in for results/<id>/ (the archive does not interpret the files)."""
    out = root / "test-session"
    (out / "height").mkdir(parents=True)
    tifffile.imwrite(out / "height" / "frame_0000.tiff", np.linspace(0, 1, 24 * 32, dtype=np.float32).reshape(24, 32))
    (out / "metrology").mkdir()
    (out / "metrology" / "report.json").write_text(json.dumps({"session": "test-session", "frames": 1}) + "\n")
    return out


@pytest.fixture
def packed(tmp_path: Path) -> tuple[Path, Path, Path]:
    session = make_session(tmp_path / "s", bands=6, repeats=1, frames=1, phase_shift=False)
    results = _results(tmp_path / "results")
    out = write_archive(session, results, tmp_path / "results" / "test-session.archive.zip", config=CONFIG)
    return session, results, out


def _rewrite(src: Path, dst: Path, *, drop: str | None = None, change: str | None = None, add: str | None = None) -> None:
    """Copy a ZIP member by member, dropping, altering or adding one (a consistent ZIP)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            if info.filename == drop:
                continue
            data = zin.read(info)
            if info.filename == change:
                data = bytes([data[0] ^ 0x01]) + data[1:]
            zout.writestr(info, data)
        if add:
            zout.writestr(add, b"not part of the run\n")


def test_archive_holds_crate_and_verifies(packed: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    session, results, out = packed
    with zipfile.ZipFile(out) as zf:
        names = zf.namelist()
    assert names[0] == "ro-crate-metadata.json"
    assert names[1:] == sorted(names[1:])
    assert "config.yaml" in names and "session/session.yaml" in names
    assert "results/height/frame_0000.tiff" in names and "results/metrology/report.json" in names

    crate = read_crate(out)
    assert crate["@context"][0] == "https://w3id.org/ro/crate/1.1/context"
    by_id = {e["@id"]: e for e in crate["@graph"]}
    assert by_id["ro-crate-metadata.json"]["conformsTo"] == [{"@id": "https://w3id.org/ro/crate/1.1"},
                                                            {"@id": "https://w3id.org/ro/wfrun/process/0.5"}]
    root = by_id["./"]
    assert root["@type"] == "Dataset" and root["identifier"] == "test-session"
    assert {"name", "description", "datePublished", "license"} <= set(root)
    files = [e for e in crate["@graph"] if e["@type"] == "File"]
    assert sorted(e["@id"] for e in files) == sorted(names[1:])
    for e in files:
        assert len(e["sha256"]) == 64 and int(e["contentSize"]) > 0 and "/" in e["encodingFormat"]
    assert by_id["results/height/frame_0000.tiff"]["encodingFormat"] == "image/tiff"
    # inputs vs outputs: the run's object and result
    (action,) = [e for e in crate["@graph"] if e["@type"] == "CreateAction"]
    assert {"@id": "session/"} in action["object"] and {"@id": "config.yaml"} in action["object"]
    assert action["result"] == {"@id": "results/"}  # a single value (RO-Crate RECOMMENDED)
    inputs = {p["@id"] for p in by_id["session/"]["hasPart"]}
    outputs = {p["@id"] for p in by_id["results/"]["hasPart"]}
    assert "session/object/white.png" in inputs and "results/metrology/report.json" in outputs
    assert not inputs & outputs
    software = {e["name"]: e["version"] for e in crate["@graph"] if e["@type"] == "SoftwareApplication"}
    assert {"huefringe", "Python", "numpy"} <= set(software)
    assert action["instrument"] == {"@id": software_identity().url}  # [project.urls] Homepage of pyproject.toml
    assert any(e["@id"].startswith("https://pypi.org/project/numpy/") for e in crate["@graph"])

    with zipfile.ZipFile(out) as zf:
        assert "results_dir: results" in zf.read("config.yaml").decode()
        assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in zf.infolist())

    v = verify_archive(out)
    assert v.ok, v.problems
    assert (v.files, v.inputs, v.outputs) == (len(files), len(inputs), len(outputs))
    assert main(["verify", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"OK: {out}")


def test_flipped_byte_is_reported_with_the_file_name(packed: tuple[Path, Path, Path], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    _, _, out = packed
    target = "session/object/white.png"  # stored uncompressed: the flip lands in the file's bytes
    # 1. one byte flipped in place in the ZIP file (the member's CRC no longer matches)
    raw = bytearray(out.read_bytes())
    with zipfile.ZipFile(out) as zf:
        info = zf.getinfo(target)
    name_len = int.from_bytes(raw[info.header_offset + 26 : info.header_offset + 28], "little")
    extra_len = int.from_bytes(raw[info.header_offset + 28 : info.header_offset + 30], "little")
    raw[info.header_offset + 30 + name_len + extra_len + 40] ^= 0xFF
    flipped = tmp_path / "flipped.zip"
    flipped.write_bytes(bytes(raw))
    v = verify_archive(flipped)
    assert [p.split(":")[0] for p in v.problems] == [target], v.problems
    assert "altered" in v.problems[0]
    # 2. the member replaced by content with one byte changed, in a well-formed ZIP (only sha256 tells)
    changed = tmp_path / "changed.zip"
    _rewrite(out, changed, change="results/height/frame_0000.tiff")
    v = verify_archive(changed)
    assert len(v.problems) == 1 and v.problems[0].startswith("results/height/frame_0000.tiff: altered (sha256")
    assert main(["verify", str(changed)]) == 1
    printed = capsys.readouterr().out
    assert printed.startswith(f"FAILED: {changed}: 1 problem(s):") and "results/height/frame_0000.tiff: altered" in printed


def test_missing_and_unlisted_members_are_reported(packed: tuple[Path, Path, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    _, _, out = packed
    broken = tmp_path / "broken.zip"
    _rewrite(out, broken, drop="results/metrology/report.json", add="results/notes.txt")
    v = verify_archive(broken)
    assert v.problems == [
        "results/metrology/report.json: missing (listed in ro-crate-metadata.json, not in the archive)",
        "results/notes.txt: unlisted (in the archive, not in ro-crate-metadata.json)",
    ]
    assert main(["verify", str(broken)]) == 1
    assert "results/metrology/report.json: missing" in capsys.readouterr().out
    # no crate at all, and not a ZIP at all
    bare = tmp_path / "bare.zip"
    _rewrite(out, bare, drop="ro-crate-metadata.json")
    with pytest.raises(ArchiveError, match="no ro-crate-metadata.json"):
        verify_archive(bare)
    junk = tmp_path / "junk.zip"
    junk.write_bytes(out.read_bytes()[:1000])
    assert main(["verify", str(junk)]) == 1
    assert f"FAILED: {junk}: not a readable ZIP archive" in capsys.readouterr().out


def test_same_inputs_give_byte_identical_archives(packed: tuple[Path, Path, Path], tmp_path: Path) -> None:
    session, results, out = packed
    # copies of the same files, written later (other modification times), elsewhere
    session2 = shutil.copytree(session, tmp_path / "elsewhere" / "s2", copy_function=shutil.copyfile)
    results2 = shutil.copytree(results, tmp_path / "elsewhere" / "results" / "test-session", copy_function=shutil.copyfile)
    os.utime(session2 / "session.yaml", (1e9, 1e9))
    again = write_archive(session2, results2, tmp_path / "again.zip", config=dict(reversed(list(CONFIG.items()))))
    assert again.read_bytes() == out.read_bytes()
    # and anything else changes them
    other = write_archive(session, results, tmp_path / "other.zip", config={**CONFIG, "hue_model": "hsi"})
    assert other.read_bytes() != out.read_bytes()


def test_archiving_leaves_inputs_alone_and_skips_partial_files(tmp_path: Path) -> None:
    session = make_session(tmp_path / "s", bands=6, repeats=1, frames=1, phase_shift=False)
    results = _results(tmp_path / "results")
    (results / "height" / ".frame_0001.x1y2z3.part.tiff").write_bytes(b"half a TIFF")  # killed atomic write
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in [*session.rglob("*"), *results.rglob("*")] if p.is_file()}
    out = write_archive(session, results, tmp_path / "a.zip")
    after = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in [*session.rglob("*"), *results.rglob("*")] if p.is_file()}
    assert after == before
    with zipfile.ZipFile(out) as zf:
        assert not any(".part" in n for n in zf.namelist()) and "config.yaml" not in zf.namelist()
    assert verify_archive(out).ok
    # an extracted crate verifies too, and an edit in it is named
    folder = tmp_path / "extracted"
    with zipfile.ZipFile(out) as zf:
        zf.extractall(folder)
    assert verify_archive(folder).ok
    (folder / "session" / "session.yaml").write_text("edited\n")
    assert [p.split(":")[0] for p in verify_archive(folder).problems] == ["session/session.yaml"]


def test_archive_refuses_mismatched_folders(tmp_path: Path) -> None:
    session = make_session(tmp_path / "s", bands=6, repeats=1, frames=1, phase_shift=False)
    results = _results(tmp_path / "results")
    wrong = results.rename(tmp_path / "results" / "other-id")
    with pytest.raises(ArchiveError, match="must be named 'test-session'"):
        write_archive(session, wrong, tmp_path / "a.zip")
    with pytest.raises(ArchiveError, match="inside"):
        write_archive(session, wrong.rename(results), session / "a.zip")
    assert main(["archive", str(tmp_path / "nowhere"), str(results), str(tmp_path / "a.zip")]) == 1
    assert not (tmp_path / "a.zip").exists()


def test_archive_stage_indexes_the_runs_archives(packed: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """Rule ``archive`` -> ``stages.archive``: each ZIP's size and sha256 (as ``sha256sum`` gives
    them) and its crate's counts, in ``results/archives.json``."""
    import hashlib

    from huefringe import stages

    _, _, out = packed
    stages.archive([str(out)], index=str(tmp_path / "archives.json"))
    (row,) = json.loads((tmp_path / "archives.json").read_text())["archives"]
    crate = read_crate(out)
    files = [e for e in crate["@graph"] if e["@type"] == "File"]
    assert row == {
        "file": "test-session.archive.zip", "session": "test-session", "bytes": out.stat().st_size,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "date_published": {e["@id"]: e for e in crate["@graph"]}["./"]["datePublished"],
        "files": len(files), "inputs": verify_archive(out).inputs, "outputs": 2,
    }
    with pytest.raises(ArchiveError, match="nothing.zip: no such file"):
        stages.archive([str(tmp_path / "nothing.zip")], index=str(tmp_path / "x.json"))
