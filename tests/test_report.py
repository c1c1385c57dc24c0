"""Tests of huefringe.report: report.json contract, schema, figure and self-contained HTML."""

from __future__ import annotations

import copy
import html as html_lib
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from huefringe.io import write_json
from huefringe.metrology import evaluate_session
from huefringe.report import (
    CONTRACT_STEP_KEYS,
    ReportError,
    build_report_json,
    collect_provenance,
    run_summary,
    load_schema,
    per_frame_figure,
    render_report_html,
    validate_report,
    write_report_html,
)

CHROMIUM = Path("/usr/bin/chromium")
PITCH = 0.2
H, W = 120, 160
SPECIMEN = {
    "kind": "step_heights",
    "base_roi": [[4, 4, 156, 20], [4, 100, 156, 116]],
    "steps": [
        {"name": "green", "nominal_mm": 3.0, "roi": [20, 40, 50, 85]},
        {"name": "blue", "nominal_mm": 1.0, "roi": [65, 40, 95, 85]},
        {"name": "red", "nominal_mm": 4.0, "roi": [110, 40, 140, 85]},
    ],
    "tolerance_mm": 0.05,
}


def frames(n: int, noise: float, seed: int, bias: dict[str, float] | None = None) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    out = []
    for _ in range(n):
        z = 0.4 + 0.001 * u * PITCH + 0.002 * v * PITCH + rng.uniform(-0.2, 0.2)
        for s in SPECIMEN["steps"]:
            u0, v0, u1, v1 = s["roi"]
            z[v0 - 3 : v1 + 3, u0 - 3 : u1 + 3] += s["nominal_mm"] + (bias or {}).get(s["name"], 0.0)
        out.append((z + rng.normal(0, noise, z.shape)).astype(np.float32))
    return out


@pytest.fixture(scope="module")
def method_result():
    return evaluate_session(frames(8, 0.01, 1), SPECIMEN, PITCH, range_mm=4.0)


@pytest.fixture(scope="module")
def baseline_result():
    return evaluate_session(
        frames(8, 0.03, 2, bias={"red": 0.08}), SPECIMEN, PITCH, range_mm=4.0, method="three-step-phase-shift"
    )


@pytest.fixture(scope="module")
def report(method_result, baseline_result):
    return build_report_json("gauge-blocks-p60", SPECIMEN, method_result, baseline_result, {"hue_model": "hsi"})


def with_uncertainty(result: dict, expanded: dict[str, float]) -> dict:
    """``result`` with u_mm, U_mm and the ISO 14253-1 conformance per step (U given per step)."""
    from huefringe.uncertainty import conformance

    out = copy.deepcopy(result)
    tol = SPECIMEN["tolerance_mm"]
    for st in out["steps"]:
        big_u = expanded[st["name"]]
        st.update(u_mm=big_u / 2, U_mm=big_u, conformance=conformance(st["error_mm"], tol, big_u))
    zones = {st["conformance"] for st in out["steps"]}
    out["verdict_with_uncertainty"] = "FAIL" if "fail" in zones else "UNDECIDED" if "undecided" in zones else "PASS"
    return out


@pytest.fixture(scope="module")
def u_report(baseline_result):
    # blue 0.03 mm off, U 0.03 mm: within the tolerance (contract pass) but not by U -> undecided
    res = evaluate_session(frames(8, 0.01, 1, bias={"blue": 0.03}), SPECIMEN, PITCH, range_mm=4.0)
    res = with_uncertainty(res, {"green": 0.01, "red": 0.012, "blue": 0.03})
    return build_report_json("gauge-blocks-p60", SPECIMEN, res, baseline_result, {"hue_model": "hexcone"})


def tiny_png(path: Path, colour=(200, 30, 30)) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3, 2), dpi=50)
    FigureCanvasAgg(fig)
    fig.add_subplot().imshow(np.tile(np.array(colour, np.uint8), (8, 8, 1)))
    fig.savefig(path, format="png")
    return path


# ------------------------------------------------------------------------------------------ json


def test_schema_is_valid_and_shipped():
    schema = load_schema()
    assert schema["required"] == ["session", "method", "frames", "steps"]
    assert schema["$defs"]["step"]["required"] == list(CONTRACT_STEP_KEYS)


def test_report_has_exactly_the_contract_keys(report, method_result):
    validate_report(report)
    assert list(report)[:4] == ["session", "method", "frames", "steps"]
    assert report["session"] == "gauge-blocks-p60"
    assert report["method"] == "trapezoidal-hsi"
    assert report["frames"] == 8 and isinstance(report["frames"], int)
    assert [s["name"] for s in report["steps"]] == ["green", "blue", "red"]
    for s, m in zip(report["steps"], method_result["steps"], strict=True):
        assert list(s)[: len(CONTRACT_STEP_KEYS)] == list(CONTRACT_STEP_KEYS)
        assert isinstance(s["pass"], bool)
        assert len(s["per_frame_mm"]) == 8
        assert s["error_pct"] == 100 * (s["mean_mm"] - s["nominal_mm"]) / s["nominal_mm"]
        assert s["pass"] == (abs(s["error_mm"]) <= report["tolerance_mm"])
        assert s["mean_mm"] == m["mean_mm"]
    b = report["baseline"]
    assert b["method"] == "three-step-phase-shift"
    assert set(CONTRACT_STEP_KEYS) <= set(b["steps"][0])
    assert report["hue_model"] == "hsi"
    assert report["verdict"] == "PASS"
    assert b["verdict"] == "FAIL" and not b["steps"][2]["pass"]  # the biased red baseline


def test_report_round_trips_through_json(report, tmp_path):
    path = tmp_path / "metrology" / "report.json"
    write_json(path, report)  # refuses NaN
    loaded = json.loads(path.read_text())
    validate_report(loaded)
    assert loaded == json.loads(json.dumps(report))


def test_baseline_only_when_given(method_result):
    r = build_report_json("s1", SPECIMEN, method_result)
    assert "baseline" not in r
    validate_report(r)


def test_wrong_baseline_method_refused(method_result):
    other = dict(method_result, method="four-step")
    with pytest.raises(ReportError, match="three-step-phase-shift"):
        build_report_json("s1", SPECIMEN, method_result, other)


def test_extras_may_not_replace_contract_keys(method_result):
    with pytest.raises(ReportError, match="'frames'"):
        build_report_json("s1", SPECIMEN, method_result, extras={"frames": 3})


def test_specimen_mismatch_refused(method_result):
    spec = copy.deepcopy(SPECIMEN)
    spec["steps"][1]["nominal_mm"] = 1.5
    with pytest.raises(ReportError, match="blue"):
        build_report_json("s1", spec, method_result)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda r: r["steps"][0].pop("pass"), "'pass' is a required property"),
        (lambda r: r.update(frames="8"), "'8' is not of type 'integer'"),
        (lambda r: r.update(session="Gauge Blocks"), "does not match"),
        (lambda r: r["steps"][1].update(per_frame_mm=[]), "should be non-empty"),
        (lambda r: r["baseline"].update(method="three-step"), "three-step-phase-shift"),
        (lambda r: r["steps"][0].update(error_pct=r["steps"][0]["error_pct"] + 1e-3), "error_pct"),
        (lambda r: r["steps"][0].update(error_pct=100 * r["steps"][0]["error_mm"]), "error_pct"),
        (lambda r: r["steps"][2].update({"pass": not r["steps"][2]["pass"]}), "pass"),
        (lambda r: r["steps"][1].update(std_mm=r["steps"][1]["std_mm"] * 1.01), "std_mm"),
        (lambda r: r["steps"][1]["per_frame_mm"].pop(), "per_frame_mm has 7 values"),
        (lambda r: r.update(verdict="FAIL"), "verdict"),
    ],
)
def test_validate_report_rejects(report, mutate, message):
    bad = copy.deepcopy(report)
    mutate(bad)
    with pytest.raises(ReportError, match=re.escape(message)):
        validate_report(bad)


# ------------------------------------------------------------------------------------------ html


def test_per_frame_figure(report, tmp_path):
    out = per_frame_figure(report, tmp_path / "per_frame.png")
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 10_000


def test_per_frame_figure_shows_u_and_keeps_the_legend_off_the_data(u_report, tmp_path, monkeypatch):
    import huefringe.report._html as rep
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    seen = []
    write = rep.write_figure_png
    monkeypatch.setattr(rep, "write_figure_png", lambda fig, out, *a, **k: (seen.append(fig), write(fig, out, *a, **k))[1])
    per_frame_figure(u_report, tmp_path / "pf.png")
    (fig,) = seen
    axes = [a for a in fig.axes if a.get_visible()]
    assert [a.get_title() for a in axes] == [
        "green: nominal 3 mm (pass, ISO 14253-1 pass)", "blue: nominal 1 mm (pass, ISO 14253-1 undecided)",
        "red: nominal 4 mm (pass, ISO 14253-1 pass)"]  # fmt: skip
    for ax, st in zip(axes, u_report["steps"], strict=True):
        spans = [p for p in ax.patches if p.get_label() == "mean ± U (k = 2)"]
        assert len(spans) == 1
        y0, y1 = spans[0].get_path().transformed(spans[0].get_patch_transform()).get_extents().intervaly
        assert (y0, y1) == pytest.approx((st["mean_mm"] - st["U_mm"], st["mean_mm"] + st["U_mm"]))
        assert ax.get_legend() is None
    (leg,) = fig.legends
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    box = leg.get_window_extent(canvas.get_renderer())
    assert not any(box.overlaps(a.get_window_extent(canvas.get_renderer())) for a in axes)


@pytest.fixture(scope="module")
def html_file(u_report, tmp_path_factory):
    report = u_report
    d = tmp_path_factory.mktemp("html")
    figs = {
        "per_frame": per_frame_figure(report, d / "per_frame.png"),
        "height": tiny_png(d / "height.png", (30, 60, 200)),
        "calibration_qa": tiny_png(d / "qa.png"),
    }
    inputs = [figs["height"], figs["calibration_qa"]]
    prov = collect_provenance("gauge-blocks-p60", {"period_px": 60, "note": "<script>alert(1)</script>"}, inputs, root=d)
    prov["capture"] = {"captured_at": "2026-11-30T14:05:00Z", "instrument": "bench-2 <DLP>", "simulated": True}
    path = write_report_html(d / "metrology" / "report.html", report, figs, prov, pixel_pitch_mm=PITCH)
    return path, figs, prov


def test_html_is_self_contained(html_file):
    path, figs, prov = html_file
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    low = text.lower()
    assert "http://" not in low and "https://" not in low
    assert 'src="http' not in low and 'src="//' not in low and "url(" not in low and "@import" not in low
    assert "<script" not in low and "<link" not in low and "<iframe" not in low
    imgs = re.findall(r"<img\b[^>]*>", text)
    assert len(imgs) == len(figs)
    for tag in imgs:
        assert re.search(r'src="data:image/png;base64,[A-Za-z0-9+/=]+"', tag), tag[:80]
    assert all(re.search(r'src="([^"]*)"', t).group(1).startswith("data:") for t in re.findall(r"<\w+[^>]*\bsrc=[^>]*>", text))
    # order: verdict, table, figures (known order), provenance
    pos = [text.index(k) for k in ('id="verdict"', 'id="steps"', 'id="fig-height"', 'id="fig-per_frame"', 'id="fig-calibration_qa"', "<details")]
    assert pos == sorted(pos)
    # escaped text, provenance content
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert prov["inputs_sha256"]["height.png"] in text
    assert 'class="verdict-word">UNDECIDED<' in text and "three-step-phase-shift" in text
    for s in ("±3σ", "Error / nominal (%)", "Error / range (%)", "green", "blue", "red"):
        assert s in text
    # capture provenance in the header, before the verdict; operator absent -> said so
    header = text[text.index("<header>"):text.index("</header>")]
    assert "<dt>Captured</dt><dd>2026-11-30T14:05:00Z</dd>" in header and "bench-2 &lt;DLP&gt;" in header
    assert "<dt>Operator</dt><dd><span class=\"note\">not recorded in session.yaml</span>" in header
    assert "<strong>Simulated data.</strong>" in header


def _row(text: str, table_id: str, name: str) -> str:
    table = text[text.index(f'id="{table_id}"'):]
    table = table[: table.index("</table>")]
    return re.search(rf"<tr><td>{name}</td>.*?</tr>", table, re.S).group(0)


def test_html_iso_zone_beside_the_contract_pass(html_file, u_report):
    path, _, _ = html_file
    text = path.read_text(encoding="utf-8")
    tol = u_report["tolerance_mm"]
    zones = {st["name"]: st["conformance"] for st in u_report["steps"]}
    assert zones == {"green": "pass", "blue": "undecided", "red": "pass"}
    assert u_report["verdict"] == "PASS" and u_report["verdict_with_uncertainty"] == "UNDECIDED"
    verdict = text[text.index('id="verdict"'):text.index("</section>")]
    # the headline is the ISO 14253-1 decision with its reason, never a bare PASS beside an UNDECIDED
    assert 'class="verdict verdict-undecided" id="verdict"' in text and 'class="verdict-word">UNDECIDED<' in verdict
    assert ">PASS<" not in verdict
    blue = next(st for st in u_report["steps"] if st["name"] == "blue")
    e, big_u = abs(blue["error_mm"]), blue["U_mm"]
    assert (f"ISO 14253-1 decision with the measurement uncertainty: blue: |error| {e:.4f} mm lies between "
            f"T - U = {tol - big_u:.4f} mm and T + U = {tol + big_u:.4f} mm: the uncertainty U does not allow a "
            "decision (2 of 3 steps conform).") in verdict
    assert u_report["conformity"]["decision"] == "undecided" and u_report["conformity"]["undecided"] == ["blue"]
    assert "Tolerance test without U (the results contract's <code>pass</code>, not a conformance decision): " \
           "3 of 3 step heights within ±0.05 mm" in verdict
    assert '<span class="zone undecided">UNDECIDED</span>' in verdict and "2 pass, 1 undecided" in verdict
    assert "<title>UNDECIDED: metrology report" in text
    # steps table: the contract's pass and the zone, side by side
    assert "ISO 14253‑1 zone (with U)" in text
    blue = _row(text, "steps", "blue")
    assert '<td class="ok">pass</td><td class="undecided">undecided</td>' in blue
    assert '<td class="ok">pass</td><td class="ok">pass</td>' in _row(text, "steps", "green")
    # decision table: the zone limits T - U and T + U per step
    for st in u_report["steps"]:
        row = _row(text, "conformance", st["name"])
        big_u = st["U_mm"]
        assert f"<td>{abs(st['error_mm']):.4f}</td><td>{big_u:.4f}</td>" in row
        assert f"<td>≤ {tol - big_u:.4f}</td><td>&gt; {tol + big_u:.4f}</td>" in row
        assert f'<td class="{ {"pass": "ok", "undecided": "undecided"}[st["conformance"]] }">{st["conformance"]}</td>' in row


def test_html_fail_zone(method_result):
    res = evaluate_session(frames(4, 0.01, 5, bias={"red": 0.08}), SPECIMEN, PITCH, range_mm=4.0)
    res = with_uncertainty(res, {"green": 0.06, "blue": 0.01, "red": 0.01})
    r = build_report_json("s3", SPECIMEN, res)
    green, red = r["steps"][0], r["steps"][2]
    assert red["error_mm"] > SPECIMEN["tolerance_mm"] + 0.01 and red["conformance"] == "fail" and not red["pass"]
    text = render_report_html(r, {}, {})
    assert 'class="verdict-word">DOES NOT CONFORM<' in text and '<span class="zone fail">FAIL</span>' in text
    assert r["conformity"]["decision"] == "does not conform" and r["conformity"]["nonconforming"] == ["red"]
    assert f"red: |error| {abs(red['error_mm']):.4f} mm &gt; T + U = {0.05 + red['U_mm']:.4f} mm: non-conformance proven" in text
    assert "1 pass, 1 undecided, 1 fail" in text
    assert '<td class="bad">FAIL</td><td class="bad">fail</td>' in _row(text, "steps", "red")
    # U larger than the tolerance: no pass zone at all, whatever the error
    assert green["conformance"] == "undecided" and green["pass"]
    assert "<td>none (U ≥ T)</td><td>&gt; 0.1100</td>" in _row(text, "conformance", "green")


def test_html_method_and_hue_model_in_words(html_file, method_result):
    path, _, _ = html_file
    text = path.read_text(encoding="utf-8")
    verdict = text[text.index('id="verdict"'):text.index("</section>")]
    assert "method trapezoidal-hsi (trapezoidal HSI phase shifting, hue model hexcone)" in verdict
    cond = text[text.index("<h2>Measurement conditions</h2>"):]
    cond = cond[: cond.index("</dl>")]
    assert "<dt>Method</dt><dd>trapezoidal-hsi: the paper&#39;s trapezoidal HSI phase shifting" in cond
    assert "the hue model below is the RGB → hue formula it uses" in cond
    assert "<dt>Hue model</dt><dd>hexcone: HSV hexcone hue (Smith), exactly linear in the code phase" in cond
    hsi = render_report_html(build_report_json("s4", SPECIMEN, method_result, extras={"hue_model": "hsi"}), {}, {})
    assert "<dt>Hue model</dt><dd>hsi: the paper&#39;s HSI hue, eqs. 1-2" in hsi


def test_html_boxes_in_pixels_and_mm(html_file, u_report):
    path, _, _ = html_file
    text = path.read_text(encoding="utf-8")
    assert "pixels <span class=\"nw\">[u0, v0, u1, v1)</span></th><th>Evaluated box, mm <span class=\"nw\">[x0, y0, x1, y1)</span>" in text
    for st in u_report["steps"]:
        px = st["evaluated_roi"]
        row = _row(text, "flatness", st["name"])
        assert f'<td class="mono">[{", ".join(str(int(x)) for x in px)})</td>' in row
        assert f'<td class="mono">[{", ".join(f"{x * PITCH:.2f}" for x in px)})</td>' in row
    assert f"pixel pitch {PITCH:g} mm" in text
    base = u_report["base"]["rois"][0]
    assert f"[{', '.join(str(x) for x in base)}) = [{', '.join(f'{x * PITCH:.2f}' for x in base)}) mm" in text
    # without the pitch: pixels only, and said so
    bare = render_report_html(u_report, {}, {})
    assert "the pixel pitch was not given, so no mm" in bare and "<td class=\"mono\">—</td>" in bare


def test_html_from_packaged_templates():
    import fnmatch
    import importlib.resources
    import tomllib

    import huefringe.report

    root = importlib.resources.files("huefringe") / "templates"
    files = sorted(p.relative_to(Path(str(root))).as_posix() for p in Path(str(root)).rglob("*") if p.is_file())
    assert "report.html.j2" in files and any(f.startswith("partials/") for f in files)
    pyproject = tomllib.loads((Path(__file__).resolve().parent.parent / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["huefringe"]
    assert all(any(fnmatch.fnmatch(f"templates/{f}", pat) for pat in patterns) for f in files), (files, patterns)
    assert any(d.startswith("jinja2>=") for d in pyproject["project"]["dependencies"])
    # the HTML lives in the templates, not in f-strings of the report package
    code = "".join(p.read_text() for p in Path(huefringe.report.__file__).parent.glob("*.py"))
    assert "<td" not in code and "<table" not in code and "<section" not in code
    env = huefringe.report._environment()
    assert env.autoescape is True


def test_no_simulated_notice_for_a_real_capture(report):
    text = render_report_html(report, {}, {"capture": {"simulated": False, "operator": "J. Doe"}})
    assert "Simulated data" not in text and "<dt>Operator</dt><dd>J. Doe</dd>" in text


def test_html_fail_verdict_and_escaping(method_result, tmp_path):
    spec = copy.deepcopy(SPECIMEN)
    spec["tolerance_mm"] = 1e-9
    res = copy.deepcopy(method_result)
    res["steps"][0]["name"] = spec["steps"][0]["name"] = "<b>green & co</b>"
    for s in res["steps"]:
        s["pass"] = abs(s["error_mm"]) <= spec["tolerance_mm"]
    r = build_report_json("s2", spec, res)
    assert r["verdict"] == "FAIL"
    text = render_report_html(r, {}, {})
    # no uncertainty in this report: ISO 14253-1 cannot decide, and the headline says why
    assert 'class="verdict-word">UNDECIDED<' in text and "verdict-undecided" in text
    assert "no expanded uncertainty U for the step heights" in text and "holds for 0 of 3 steps" in text
    assert "&lt;b&gt;green &amp; co&lt;/b&gt;" in text and "<b>green" not in text
    assert "<img" not in text and "<h2>Figures</h2>" not in text  # figures only if given


def test_html_refuses_non_png_figure(report, tmp_path):
    fake = tmp_path / "fig.png"
    fake.write_bytes(b"GIF89a not a png")
    with pytest.raises(ValueError, match="not a PNG"):
        render_report_html(report, {"profile": fake}, {})
    with pytest.raises(FileNotFoundError):
        render_report_html(report, {"profile": tmp_path / "missing.png"}, {})
    target = tmp_path / "out" / "report.html"
    with pytest.raises(ValueError, match="not a PNG"):
        write_report_html(target, report, {"profile": fake}, None)
    assert not target.exists() and not any(target.parent.glob("*"))  # nothing half-written
    write_report_html(target, report, None, None)
    assert target.exists() and [p.name for p in target.parent.iterdir()] == ["report.html"]


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian chromium at /usr/bin/chromium for the headless render check")
def test_html_renders_in_headless_chromium(html_file, tmp_path):
    import matplotlib.image

    path, _, _ = html_file
    flags = [
        "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--hide-scrollbars",
    ]  # fmt: skip
    url = path.resolve().as_uri()
    shot = tmp_path / "screenshot.png"
    run = subprocess.run(
        [str(CHROMIUM), *flags, f"--user-data-dir={tmp_path / 'profile-a'}", f"--screenshot={shot}", "--window-size=1280,1400", url],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert shot.exists(), run.stderr[-2000:]
    keep = Path(__file__).resolve().parent.parent / ".pytest_cache" / "report-screenshot.png"
    keep.parent.mkdir(exist_ok=True)
    shutil.copyfile(shot, keep)  # for a human look
    img = matplotlib.image.imread(shot)[..., :3]
    assert img.shape[0] >= 1000 and img.shape[1] >= 1200
    assert img.std() > 0.05
    non_white = (img < 0.9).any(axis=-1).mean()
    assert non_white > 0.05
    amber = np.all(np.abs(img - np.array([0x8A, 0x5A, 0x00]) / 255) < 0.03, axis=-1).mean()
    assert amber > 0.005  # the UNDECIDED banner is drawn
    dom = subprocess.run(
        [str(CHROMIUM), *flags, f"--user-data-dir={tmp_path / 'profile-b'}", "--dump-dom", url],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert 'class="verdict-word">UNDECIDED</div>' in dom.stdout, dom.stderr[-2000:]
    assert dom.stdout.count("data:image/png;base64,") == 3
    assert "<strong>Simulated data.</strong>" in dom.stdout
    # the new items are laid out visibly at 1280 px: a copy of the page with a probe script that
    # reports each element's rendered text, size and whether its table scrolls it out of view
    probe = tmp_path / "probed.html"
    probe.write_text(path.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    dom = subprocess.run(
        [str(CHROMIUM), *flags, f"--user-data-dir={tmp_path / 'profile-c'}", "--window-size=1280,1400", "--dump-dom",
         probe.resolve().as_uri()],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    found = re.search(r'<pre id="probe">(.*?)</pre>', dom.stdout, re.S)
    assert found, dom.stderr[-2000:]
    seen = json.loads(html_lib.unescape(found.group(1)))
    for key, els in seen.items():
        assert els, f"{key}: not on the page"
        for el in els:
            assert el["w"] > 0 and el["h"] > 0 and el["vis"] == "visible" and el["inside"], (key, el)
    assert "UNDECIDED" in seen["verdict_u"][0]["text"] and "2 pass, 1 undecided" in seen["verdict_u"][0]["text"]
    assert "trapezoidal HSI phase shifting, hue model hexcone" in seen["banner"][0]["text"]
    assert [e["text"] for e in seen["zone_cells"]] == ["pass", "undecided", "pass"]
    assert [e["text"] for e in seen["contract_cells"]] == ["pass", "pass", "pass"]
    assert seen["zone_head"][0]["text"].replace("\n", " ") == "ISO 14253‑1 zone (with U)"
    assert [e["text"] for e in seen["conformance_zone"]] == ["pass", "undecided", "pass"]
    assert seen["box_mm"][0]["text"].startswith("[") and seen["box_mm"][0]["text"].endswith(")")
    assert "HSV hexcone hue" in seen["conditions"][0]["text"] and "RGB → hue formula" in seen["conditions"][0]["text"]


_PROBE = """<script>
const sel = {
  banner: "#verdict .verdict-detail", verdict_u: "#verdict-u",
  zone_head: "#steps thead tr:nth-child(2) th:nth-child(8)",
  zone_cells: "#steps tbody td:nth-child(10)", contract_cells: "#steps tbody td:nth-child(9)",
  conformance_zone: "#conformance tbody td:nth-child(6)", box_px: "#flatness tbody td:nth-child(8)",
  box_mm: "#flatness tbody td:nth-child(9)", conditions: "dl.cond",
};
const out = {};
for (const [key, css] of Object.entries(sel)) {
  out[key] = [...document.querySelectorAll(css)].map((e) => {
    const r = e.getBoundingClientRect();
    const wrap = e.closest(".table-wrap");
    const w = wrap ? wrap.getBoundingClientRect() : { left: 0, right: document.documentElement.clientWidth };
    return { text: e.innerText, w: r.width, h: r.height, vis: getComputedStyle(e).visibility,
             inside: r.left >= w.left - 0.5 && r.right <= w.right + 0.5 };
  });
}
const pre = document.createElement("pre");
pre.id = "probe";
pre.textContent = JSON.stringify(out);
document.body.appendChild(pre);
</script>"""


def test_run_summary_says_each_sessions_decision_and_where_the_report_is(u_report, tmp_path):
    d = tmp_path / "results" / "gauge-blocks-p60" / "metrology"
    d.mkdir(parents=True)
    (d / "report.json").write_text(json.dumps(u_report))
    text = run_summary({"gauge-blocks-p60": d / "report.json", "flat-board": None})
    lines = text.splitlines()
    assert lines[0].startswith("  gauge-blocks-p60: UNDECIDED (ISO 14253-1) - blue: |error| ")
    assert lines[1] == f"      report: {d / 'report.html'}"
    assert lines[2] == "  flat-board: no step-height report (the session has no specimen)"


def test_errors_the_u_does_not_hold_stop_a_conforming_decision(method_result):
    res = evaluate_session(frames(4, 0.002, 5), SPECIMEN, PITCH, range_mm=4.0)
    res = with_uncertainty(res, {"green": 0.004, "blue": 0.004, "red": 0.004})
    assert build_report_json("s5", SPECIMEN, res)["conformity"]["decision"] == "conforms"
    banded = {"calibration": {"row_banding": {"suspected": True, "amplitude_rad": 0.144},
                              "colour_flicker": {"suspected": False, "amplitude_rad": 0.0}}}
    r = build_report_json("s5", SPECIMEN, res, extras=banded)
    assert r["conformity"]["decision"] == "undecided" and "row banding" in r["conformity"]["reason"]
    assert "0.144 rad" in r["conformity"]["reason"] and "colour flicker" not in r["conformity"]["reason"]
    assert list(r).index("conformity") == list(r).index("verdict") + 1   # its place in the file
    validate_report(r)                                                    # the contract check agrees
    forged = copy.deepcopy(r)
    forged["conformity"]["decision"] = "conforms"
    with pytest.raises(ReportError, match="conformity decision"):
        validate_report(forged)
    # a proven non-conformance stands
    bad = with_uncertainty(evaluate_session(frames(4, 0.002, 5, bias={"red": 0.2}), SPECIMEN, PITCH, range_mm=4.0),
                           {"green": 0.004, "blue": 0.004, "red": 0.004})
    assert build_report_json("s5", SPECIMEN, bad, extras=banded)["conformity"]["decision"] == "does not conform"
