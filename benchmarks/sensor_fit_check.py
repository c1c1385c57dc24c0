"""Study: which shot + read model predicts a frame's hue noise: fitted on the channels or on the hue.

Usage: ./run python benchmarks/sensor_fit_check.py [--cases NAME ...] [--keep DIR]

For each bench case with two or more hue-band repeats (default: the ``--noise`` cases of
``accuracy_matrix.py`` with two repeats, tuning and hold-out) three shot + read models are fitted on
the object's hue bands as the chain reads them (the session's camera corrections, the colour
demixing among them): the library's (``huetable.fit_hue_noise``) from every repeat (the hue's
spread between repeats) and from the first repeat of each band alone (the hue's third differences
along the bands), and, for comparison, a fit on the channels' own spread between the repeats
(:func:`channel_fit`: each channel's temporal variance against its signal, 64 bins, weighted least
squares). Each model predicts the per-pixel hue
noise of the session's first two frames from their own signal (``perframe.frame_hue_noise``); the
truth is the frames' hue difference over sqrt 2 (the frames of these cases differ only by noise).
Printed per model: the fitted gains and read terms, and the rms of the difference over the
prediction over the table's valid pixels, overall and per quintile of the prediction (1 = the
prediction holds). About 20 s a case with its session kept.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import colour, perframe  # noqa: E402
from huefringe.camera import corrections  # noqa: E402
from huefringe.huetable import build_table  # noqa: E402
from huefringe.pipeline import _calibration_opts, session_camera_record  # noqa: E402
from huefringe.session import load_session  # noqa: E402
from huefringe.settings import load_config  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CASES = [n for n in am.NOISE_CASES if n.endswith("x2") or "x2 " in n]


def channel_fit(bands: list, read, stride: int = 3, bins: int = 64) -> dict:
    """Per channel ``var = gain * signal + read`` from the repeats' temporal variance against their
    mean signal (pixels on a grid of ``stride``, repeats clipped at 0 or full scale left out,
    ``bins`` signal bins, least squares weighted by ``count / var^2``, both terms kept >= 0)."""
    var_sum, sig_sum, count = (np.zeros((3, bins)) for _ in range(3))
    for paths in bands:
        x = np.array([np.asarray(read(p))[::stride, ::stride] for p in paths], np.float64)
        mean, var = x.mean(axis=0), x.var(axis=0, ddof=1)
        ok = (x.min(axis=0) > 0.0) & (x.max(axis=0) < 1.0)
        idx = np.minimum((mean * bins).astype(np.int64), bins - 1)
        for c in range(3):
            m = ok[..., c]
            var_sum[c] += np.bincount(idx[..., c][m], var[..., c][m], bins)
            sig_sum[c] += np.bincount(idx[..., c][m], mean[..., c][m], bins)
            count[c] += np.bincount(idx[..., c][m], minlength=bins)
    gain, rd = [], []
    for c in range(3):
        m = count[c] >= 50
        sg, v = sig_sum[c][m] / count[c][m], var_sum[c][m] / count[c][m]
        sw = np.sqrt(count[c][m] / np.maximum(v, 1e-30) ** 2)
        g, r = np.linalg.lstsq(np.stack([sg, np.ones_like(sg)], axis=1) * sw[:, None], v * sw, rcond=None)[0]
        if r < 0:
            g, r = float(np.sum(sw**2 * sg * v) / np.sum(sw**2 * sg * sg)), 0.0
        if g < 0:
            g, r = 0.0, float(np.sum(sw**2 * v) / np.sum(sw**2))
        gain.append(float(g))
        rd.append(max(float(r), 1e-12))
    return {"gain": gain, "read": rd}


def _z(d: np.ndarray, pred: np.ndarray, ok: np.ndarray) -> tuple[float, list[float]]:
    z = d[ok] / pred[ok]
    p = pred[ok]
    qs = np.quantile(p, np.linspace(0.0, 1.0, 6))
    per = [float(np.sqrt(np.mean(z[(p >= a) & (p <= b)] ** 2))) for a, b in zip(qs[:-1], qs[1:], strict=True)]
    return float(np.sqrt(np.mean(z**2))), per


def rows(case: str, root: Path) -> list[str]:
    cfg = {**am.CASES, **am.NOISE_CASES}[case]
    session, _ = am._case_dirs(root, cfg["cfg"])
    s = load_session(session)
    if min(len(b) for b in s.object_bands) < 2:
        raise SystemExit(f"{case}: the check needs two or more repeats")
    config = load_config(REPO / "config.yaml")
    reader = corrections(session_camera_record(s, config["camera"], config["calibration"]), s.meta)[1]
    white = reader.rgb(s.object_white)
    opts = _calibration_opts(config["calibration"])
    every = build_table(s.object_bands, white, read=reader.rgb, progress=False, **opts)
    one = build_table([b[:1] for b in s.object_bands], white, read=reader.rgb, progress=False, **opts)
    chan = copy.copy(every)
    chan.stats = {**every.stats, "sensor_noise": channel_fit(s.object_bands, reader.rgb)}
    tables = {"the channels' spread between repeats": chan, "the hue's spread between repeats": every,
              "one repeat's hue differences": one}
    gains = colour.white_gains(white)
    rgbs = [reader.rgb(s.frames[n]) for n in s.frame_ids[:2]]
    hues = [colour.hue(colour.white_balance(x, white), "hexcone").astype(np.float64) for x in rgbs]
    d = np.angle(np.exp(1j * (hues[0] - hues[1]))) / np.sqrt(2.0)
    set_name = "hold-out" if cfg["holdout"] else "tuning"
    out = []
    for name, t in tables.items():
        m = t.stats["sensor_noise"]
        pred = np.sqrt(0.5 * sum(perframe.frame_hue_noise(t, x, gains, "hexcone") ** 2 for x in rgbs))
        ok = every.valid & np.isfinite(d) & np.isfinite(pred) & (pred > 0)
        zall, per = _z(d, pred, ok)
        out.append(f"| {case} | {set_name} | {name} | {' / '.join(f'{g * 1e5:.2f}' for g in m['gain'])} | "
                   f"{' / '.join(f'{r * 1e6:.2f}' for r in m['read'])} | {zall:.3f} | "
                   f"{' / '.join(f'{x:.2f}' for x in per)} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT_CASES)
    ap.add_argument("--keep", type=Path, default=None, help="write sessions here, reuse sessions found there")
    a = ap.parse_args()
    print("| case | set | model fitted on | gain R / G / B (1e-5) | read R / G / B (1e-6) | rms z | rms z by quintile "
          "of the prediction |")
    print("| --- | --- | --- | --- | --- | ---: | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases:
            slug = ("noise-" if case in am.NOISE_CASES else "") + am._slug(case)  # accuracy_matrix.py's folders
            for line in rows(case, (a.keep or Path(tmp)) / slug):
                print(line, flush=True)


if __name__ == "__main__":
    main()
