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
