"""The Snakemake adapter (:func:`huefringe.stages.run_from_snakemake`) and the one name from rule to
script to stage function."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from huefringe import stages

REPO = Path(__file__).resolve().parents[1]


class _Named(list):
    """A Snakemake Namedlist in miniature: positional items plus named ones."""

    def __init__(self, *pos, **named):
        super().__init__([*pos, *named.values()])
        self._named = named

    def items(self):
        return self._named.items()


def _job(**kw):
    parts = {k: kw.get(k, _Named()) for k in ("wildcards", "input", "params", "output", "log")}
    return SimpleNamespace(**parts)


def _stage(session: str, summary: str, strict: bool = False) -> None:
    calls.append((session, summary, strict))


calls: list = []


def test_stage_kwargs_pass_known_keys_and_accepted_wildcards() -> None:
    job = _job(wildcards=_Named(sid="x", frame="0001"), params=_Named(session="s"), output=_Named(summary="o.json"))
    assert stages.stage_kwargs(_stage, job) == {"session": "s", "summary": "o.json"}


@pytest.mark.parametrize("source", ["input", "params", "output"])
def test_unknown_key_is_refused_naming_it(source: str) -> None:
    job = _job(params=_Named(session="s"), output=_Named(summary="o.json"))
    getattr(job, source)._named["stirct"] = True  # misspelt: the stage has a default for "strict"
    with pytest.raises(TypeError, match=r"_stage does not accept 'stirct'.*session, summary, strict"):
        stages.stage_kwargs(_stage, job)


def test_run_from_snakemake_refuses_before_calling(tmp_path: Path) -> None:
    calls.clear()
    job = _job(params=_Named(session="s", sesion="t"), output=_Named(summary=str(tmp_path / "o.json")),
               log=_Named(str(tmp_path / "x.log")))
    with pytest.raises(TypeError, match="'sesion'"):
        stages.run_from_snakemake(job, _stage)
    assert calls == []
    stages.run_from_snakemake(_job(params=_Named(session="s"), output=_Named(summary="o.json")), _stage)
    assert calls == [("s", "o.json", False)]


def _rules() -> dict[str, list[tuple[Path, str | None]]]:
    """rule name -> [(rule file, script path or None)], from every workflow file."""
    out: dict[str, list[tuple[Path, str | None]]] = {}
    for f in [REPO / "Snakefile", *sorted((REPO / "workflow" / "rules").glob("*.smk"))]:
        text = f.read_text()
        blocks = re.split(r"^(?=[ \t]*rule\b)", text, flags=re.M)
        for b in blocks:
            m = re.match(r"\s*rule\s*(\w*)\s*:", b)
            if not m:
                continue
            name = m.group(1)
            if not name:  # a generated rule (a loop remains): its name is the stage's, then _{session}_{batch}
                name = re.search(r"name:\s*\n\s*f\"(\w+?)_\{", b).group(1)
            s = re.search(r"script:\s*\n\s*\"([^\"]+)\"", b)
            out.setdefault(name, []).append((f, s.group(1) if s else None))
    return out


def test_every_scripted_rule_has_one_script_and_one_stage_of_its_name() -> None:
    rules = _rules()
    scripted = {n: v for n, v in rules.items() if any(s for _, s in v)}
    assert {"hue_table", "measure_frames", "mesh", "render", "metrology", "bench_session"} <= set(scripted)
    stage_src = "".join(p.read_text() for p in sorted((REPO / "src" / "huefringe" / "stages").glob("*.py")))
    for name, where in scripted.items():
        assert len(where) == 1, f"rule {name} is defined {len(where)} times: {[str(f) for f, _ in where]}"
        script = Path(where[0][1]).name
        assert script == f"{name}.py", f"rule {name} runs {script}"
        text = (REPO / "scripts" / script).read_text()
        assert re.search(rf"run_from_snakemake\(snakemake, {name}\)", text), f"scripts/{script} does not call stages.{name}"
        assert len(re.findall(rf"^def {name}\(", stage_src, flags=re.M)) == 1, f"stages.{name} is not defined once"
    assert sorted(p.stem for p in (REPO / "scripts").glob("*.py")) == sorted(scripted)


def test_a_measurement_job_loads_no_mesh_render_or_figure_library() -> None:
    """The measurement script's imports (scripts/measure_frames.py) in a fresh process: its stage's
    libraries only, not Open3D, trimesh, PyVista or Matplotlib, which other stages use."""
    import subprocess
    import sys

    code = ("import sys; from huefringe.stages import measure_frames, run_from_snakemake; "
            "print(' '.join(m for m in ('open3d', 'trimesh', 'pyvista', 'vtk', 'matplotlib', 'dash') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []
    from huefringe.stages import _measurement

    assert stages.measure_frames is _measurement.measure_frames
    with pytest.raises(AttributeError, match="no attribute 'not_a_stage'"):
        stages.not_a_stage  # noqa: B018


@pytest.mark.parametrize(("names", "unused"), [
    ("check_session, camera_calibration, hue_table, plane_calibration", ("scipy.optimize", "open3d", "trimesh")),
    ("render, metrology, rig_measure, rig_metrology", ("open3d",)),
])
def test_calibration_and_report_jobs_load_no_library_they_do_not_call(names: str, unused: tuple[str, ...]) -> None:
    """SciPy's optimisers load where a projector gamma is fitted, Open3D where a mesh is cleaned
    (its stage, ``mesh``), not in every job of the same stage module (0.4 and 0.7-0.9 s of a job's
    start-up)."""
    import subprocess
    import sys

    code = (f"import sys; from huefringe.stages import {names}, run_from_snakemake; "
            f"print(' '.join(m for m in {unused!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []


def _refused(session: str, summary: str) -> None:
    from huefringe.session import SessionError

    raise SessionError.at(Path(session) / "session.yaml", "missing")


def _broken(session: str, summary: str) -> None:
    raise ValueError("a bug, not an input problem")


def test_run_from_snakemake_ends_an_input_problem_with_its_message_and_the_job_threads(tmp_path: Path, capsys) -> None:
    import cv2
    import numba

    job = _job(params=_Named(session="/data/s1"), output=_Named(summary=str(tmp_path / "o.json")),
               log=_Named(str(tmp_path / "job.log")))
    job.threads = 1
    with pytest.raises(SystemExit) as exc:
        stages.run_from_snakemake(job, _refused)
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert "huefringe: " in err and "/data/s1/session.yaml" in err and "missing" in err and "Traceback" not in err
    assert cv2.getNumThreads() == 1 and numba.get_num_threads() == 1  # the rule's threads, OpenCV's too
    text = (tmp_path / "job.log").read_text()
    age = float(re.search(r"_refused: job started ([0-9.]+) s ago", text).group(1))
    assert 0.0 < age < 3600.0
    with pytest.raises(ValueError, match="a bug"):  # anything else keeps its traceback
        stages.run_from_snakemake(job, _broken)
