"""The manual (docs/, Sphinx + MyST + numpydoc) builds offline with warnings as errors, and what it
generates is right: an API page per module with its docstrings, every configuration key with
its default, every page of docs/ in the contents, the contracts equal to the shared ones."""

from __future__ import annotations

import html
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import huefringe_docs  # noqa: E402


def _text(page: Path) -> str:
    """The visible text of an HTML page, whitespace collapsed."""
    raw = re.sub(r"(?s)<(script|style)\b.*?</\1>", " ", page.read_text(encoding="utf-8"))
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", raw)).split())


def _squeezed(text: str) -> str:
    """Text compared across docstring and page: no whitespace, plain quotes, no ``()`` after names."""
    return re.sub(r"\s+", "", text.replace("\u2019", "'").replace("\u201c", '"').replace("\u201d", '"')).replace("()", "")


@pytest.fixture(scope="module")
def manual(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One build of the manual, as the README says, into a temporary folder; no network."""
    out = tmp_path_factory.mktemp("manual")
    env = {**os.environ, "HUEFRINGE_DOCS_OFFLINE": "1"}
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
           "-d", str(out / "doctrees"), str(DOCS), str(out / "html")]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    problems = [ln for ln in proc.stderr.splitlines() if "WARNING" in ln or "ERROR" in ln]
    assert proc.returncode == 0 and not problems, proc.stderr[-6000:]
    return out / "html"


def _modules() -> list[str]:
    import huefringe

    names = ["huefringe"]
    for info in pkgutil.walk_packages(huefringe.__path__, "huefringe."):
        if not info.name.rpartition(".")[2].startswith("_"):
            names.append(info.name)
    return names


def _first_line(obj: object) -> str:
    doc = getattr(obj, "__doc__", None) or ""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    return re.sub(r":\w+:`~?([^`]*)`", r"\1", first).replace("``", "")


def test_api_page_per_module_with_its_docstring(manual: Path) -> None:
    names = _modules()
    assert {"huefringe.api", "huefringe.kernel", "huefringe.bench.simulator"} <= set(names)
    for name in names:
        page = manual / "api" / f"{name}.html"
        assert page.is_file(), f"no API page for {name}"
    api = _text(manual / "api" / "huefringe.api.html")
    from huefringe.api import measure

    first = _first_line(measure)
    assert first and _squeezed(first) in _squeezed(api), first
    # a numba-compiled function is documented from its Python source, with its docstring
    from huefringe import phase

    assert type(phase.denoise_weight).__module__.startswith("numba")
    text = _text(manual / "api" / "huefringe.phase.html")
    assert "denoise_weight" in text and _squeezed(_first_line(phase.denoise_weight)) in _squeezed(text)
    # the bench and the kernel are there too
    sim = _text(manual / "api" / "huefringe.bench.simulator.html")
    assert "simulate_capture" in sim
    assert "frame_to_height" in _text(manual / "api" / "huefringe.kernel.html")


def _leaves(tree: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update(_leaves(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def test_configuration_page_lists_every_key_with_its_default(manual: Path) -> None:
    schema = yaml.safe_load((REPO / "workflow" / "schemas" / "config.schema.yaml").read_text())
    defaults = yaml.safe_load((REPO / "src" / "huefringe" / "defaults.yaml").read_text())
    page = (manual / "configuration.html").read_text(encoding="utf-8")
    rows = {
        html.unescape(re.sub(r"<[^>]+>", "", m[1])).strip(): " ".join(html.unescape(re.sub(r"<[^>]+>", " ", m[2])).split())
        for m in re.finditer(r'<tr[^>]*id="config-[^"]*"[^>]*>\s*<td[^>]*>(.*?)</td>(.*?)</tr>', page, re.S)
    }
    keys = {k.removesuffix(" (required)") for k in rows}
    assert set(schema["properties"]) <= keys, set(schema["properties"]) - keys
    for key, value in _leaves(defaults).items():
        if key.startswith("archive."):
            continue  # mappings in flow style: their sub-keys are rows, their values documented above
        row = next(v for k, v in rows.items() if k.removesuffix(" (required)") == key)
        shown = huefringe_docs._yaml_inline(value)
        assert shown in row, (key, shown, row)
    assert "hexcone" in rows["hue_model (required)"]


def test_every_configuration_key_is_documented() -> None:
    rows = huefringe_docs.config_rows()
    assert len(rows) > 60
    assert [r[0] for r in rows if not r[3]] == []
    by_key = {r[0]: r for r in rows}
    # the text of a key comes from the comment of defaults.yaml, continued over its lines
    assert by_key["measurement.own_noise"][3].endswith("along the bands of each sextant (stats noise_rad.source; docs/noise.md)")
    assert by_key["measurement.denoise_adaptive.max_radius"][2] == "6"
    assert by_key["calibration.plane_smooth_degree"][1] == "integer or null, >= 1, <= 6"


def test_yaml_comments(tmp_path: Path) -> None:
    f = tmp_path / "c.yaml"
    f.write_text(
        "# file header\n\n"
        "# above a\n# second line\n"
        "a: 1\n"
        "b:                # section b\n"
        "  c: \"x # y\"      # trailing c\n"
        "                  # continued\n"
        "  d: 2\n"
        "e: 3  # e\n"
    )
    assert huefringe_docs.yaml_comments(f) == {
        "a": "above a second line", "b": "section b", "b.c": "trailing c continued", "e": "e",
    }


def test_contents_place_every_page_once() -> None:
    found = {"index", "guide", "capture", "accuracy", "accuracy-texture", "accuracy-cameras",
             "uncertainty", "zzz-new", "api", "api/huefringe", "spec/results"}
    sections = [("User guide", ["guide", "capture*"]), ("Measured", ["accuracy*", "uncertainty*"]),
                ("Formats", ["spec/results"]), ("API reference", ["api"])]
    md = huefringe_docs.contents_markdown(found, sections)
    blocks = {m[1]: m[2].split() for m in re.finditer(r":caption: ([^\n]*)\n:maxdepth: 1\n\n(.*?)\n```", md, re.S)}
    assert blocks == {
        "User guide": ["guide", "capture"],
        "Measured": ["accuracy", "accuracy-cameras", "accuracy-texture", "uncertainty"],
        "Formats": ["spec/results"], "API reference": ["api"], "More": ["zzz-new"],
    }


def test_every_page_is_built_and_in_the_contents(manual: Path) -> None:
    index = (manual / "index.html").read_text(encoding="utf-8")
    pages = sorted(p.relative_to(DOCS).with_suffix("") for p in DOCS.rglob("*.md")
                   if p.name != "index.md" and (not p.relative_to(DOCS).parts[0].startswith(("_", "api")) or p.name == "api.md"))
    assert len(pages) >= 15
    for page in pages:
        assert (manual / page.with_suffix(".html")).is_file(), page
        assert f'href="{page.as_posix()}.html"' in index, page
    # the capture guide of other work: linked when present, named (not a broken link) when not
    guide = _text(manual / "guide.html")
    if (DOCS / "capture.md").is_file():
        assert 'href="capture.html"' in (manual / "guide.html").read_text(encoding="utf-8")
    else:
        assert "docs/capture.md, not in this checkout yet" in guide
    # measured pages start with the command that regenerates them
    for name in ("accuracy", "table1", "uncertainty", "throughput", "hue-models", "real-captures"):
        first = (DOCS / f"{name}.md").read_text(encoding="utf-8").split("```", 2)
        assert first[1].startswith("bash\n./run "), name


def _shared_spec() -> Path | None:
    for d in (os.environ.get("HUEFRINGE_SHARED_SPEC"), REPO.parent / "shared" / "spec"):
        if d and Path(d, "results.md").is_file():
            return Path(d)
    return None


@pytest.mark.skipif(_shared_spec() is None, reason="no shared/spec beside the clone")
def test_contract_copies_equal_the_shared_spec() -> None:
    spec = _shared_spec()
    assert spec is not None
    for name in ("capture-session.md", "results.md"):
        assert (DOCS / "spec" / name).read_bytes() == (spec / name).read_bytes(), name


def test_readme_front_page() -> None:
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    lines = readme.splitlines()
    assert lines[2:6] == ["```bash", lines[3], lines[4], "```"]
    assert lines[3].startswith("./run snakemake --cores 2 ") and lines[4].startswith("./run pytest -n 2 ")
    ci = (REPO / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci == "./run pytest -n 2"
    # the manual's build command is the one the test above runs
    assert "./run python -m sphinx -W --keep-going docs build/manual" in readme
    # relative links point at files of the repository (the capture guide is written by other work)
    for target in re.findall(r"\]\((?!https?://|#)([^)#\s]+)", readme):
        if target != "docs/capture.md":
            assert (REPO / target).exists(), target


def test_the_manual_states_what_is_true_now() -> None:
    """No work-session history in the manual or the README: no "Session 9" headings, no dated
    runs, no "before = main at <hash>"; how the figures moved is CHANGELOG.md's (and git's)."""
    history = re.compile(r"\b[Ss]ession [0-9]+\b|\b[0-9]{1,2} (?:Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]* 20[0-9]{2}\b"
                         r"|\bmain at [0-9a-f]{7,40}\b|\bHEAD [0-9a-f]{7,40}\b"
                         r"|\bas before\b|, (?:before|now) \||\b(?:before|now): ")
    pages = [p for p in DOCS.rglob("*.md") if p.relative_to(DOCS).parts[0] not in ("spec", "api", "_build")]
    found = [f"{p.relative_to(REPO)}:{i}: {m[0]}" for p in [*pages, REPO / "README.md"]
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) for m in [history.search(line)] if m]
    assert found == [], "\n".join(found)
    # and the test sees what it looks for
    assert history.search("## Session 9, after every merge (3 Dec 2026, 17:25 UTC)")
    assert history.search("before = main at f821a46") and not history.search("a capture session with 3 planes, 10 frames")
    assert history.search("| whole, before | 0.0333 |") and history.search("measures as before (its own")
    assert not history.search("refused before any work starts") and not history.search("| whole, fixed noise |")
