"""Emulate a pinhole camera with lens distortion from a telecentric bench session (for tests of
the method only: the bench's own pinhole camera is the real case).

Each pinhole pixel's surface point is found on the telecentric ground truth (fixed point of
``h = truth(X(h), Y(h))`` along the pixel's ray), and every capture is sampled there. The scene
is Lambertian and seen from nearly straight above, so the radiance a pinhole camera records at a
surface point is the telecentric capture's at the same point; occlusion at step walls is ignored
(those are mixed pixels either way)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import tifffile
import yaml

from huefringe.camera import CameraModel
from huefringe.session import load_session, read_rgb_codes
from session_factory import write_image


def _sample(img: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    return cv2.remap(img, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _surface(model: CameraModel, truth: np.ndarray, pitch: float, iters: int = 40):
    """(X, Y, h) of every pinhole pixel's ray on the telecentric height map ``truth``."""
    filled = np.where(np.isfinite(truth), truth, 0.0).astype(np.float32)
    h = np.zeros((model.height, model.width))
    for _ in range(iters):
        x, y = model.xy(h)
        h = 0.5 * h + 0.5 * _sample(filled, x / pitch, y / pitch).astype(np.float64)  # damped: converges at walls too
    x, y = model.xy(h)
    seen = _sample(np.isfinite(truth).astype(np.float32), x / pitch, y / pitch) > 0.999
    return x, y, np.where(seen, h, np.nan)


def pinhole_copy(session: Path, target: Path, *, distance_mm: float = 300.0, fx_scale: float = 1.04,
                 distortion=(-0.5, 0.1, 0.0, 0.0, 0.0)) -> dict:
    """Write ``target``: ``session`` as seen by a pinhole camera ``distance_mm`` above the plate's
    centre (focal length ``fx_scale * distance / pitch`` px, ``distortion`` in OpenCV order), with
    the camera block, true heights and ``ground_truth/xy``. Returns the camera block."""
    s = load_session(session)
    p, w, h = s.pixel_pitch_mm, s.width, s.height
    fx = fx_scale * distance_mm / p
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    cam = {"width": w, "height": h, "bit_depth": s.bit_depth, "pixel_pitch_mm": distance_mm / fx,
           "model": "pinhole", "matrix": [[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]],
           "distortion": list(map(float, distortion)),
           "plate_pose": {"rvec": [0.0, 0.0, 0.0], "tvec": [-cx * p, -cy * p, distance_mm]}}
    model = CameraModel.from_meta({"camera": cam})
    shutil.copytree(session, target)
    meta = yaml.safe_load((session / "session.yaml").read_text())
    meta["camera"] = cam

    def warp(paths, height_map):
        x, y, _ = _surface(model, height_map, p)
        for src in paths:
            write_image(target / src.relative_to(session), _sample(read_rgb_codes(src), x / p, y / p))

    flat = np.zeros((h, w), np.float32)
    warp([s.reference_white, *[q for reps in s.reference_bands for q in reps]], flat)
    for z, q in s.planes.items():
        warp([q], flat + np.float32(z))
    truth0 = tifffile.imread(s.ground_truth[s.frame_ids[0]])
    warp([s.object_white, *[q for reps in s.object_bands for q in reps]], truth0)
    (target / "ground_truth" / "xy").mkdir(parents=True, exist_ok=True)
    for n, q in s.frames.items():
        truth = tifffile.imread(s.ground_truth[n])
        x, y, hh = _surface(model, truth, p)
        write_image(target / q.relative_to(session), _sample(read_rgb_codes(q), x / p, y / p))
        for ps in s.phase_shift.get(n, ()):
            write_image(target / ps.relative_to(session), _sample(read_rgb_codes(ps), x / p, y / p))
        tifffile.imwrite(target / "ground_truth" / "frames" / f"frame_{n:04d}.tiff", hh.astype(np.float32))
        xy = np.stack([x, y], -1)
        xy[~np.isfinite(hh)] = np.nan
        tifffile.imwrite(target / "ground_truth" / "xy" / f"frame_{n:04d}.tiff", xy.astype(np.float32))
    if meta.get("specimen"):  # boxes: the telecentric boxes' plate rectangles seen by the pinhole camera
        spec = meta["specimen"]
        lvl = {tuple(st["roi"]): float(st["nominal_mm"]) for st in spec["steps"]}

        def box(b, hgt):
            xs = np.array([b[0], b[2] - 1]) * p
            ys = np.array([b[1], b[3] - 1]) * p
            pts = np.array([[xx, yy, -hgt] for xx in xs for yy in ys])
            uv, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.array(cam["plate_pose"]["tvec"]),
                                      np.array(cam["matrix"]), np.array(cam["distortion"]))
            uv = uv.reshape(-1, 2)  # the inner rectangle of the four corners' images
            u0, u1 = np.sort(uv[:, 0])[1], np.sort(uv[:, 0])[2]
            v0, v1 = np.sort(uv[:, 1])[1], np.sort(uv[:, 1])[2]
            return [int(np.ceil(u0)), int(np.ceil(v0)), int(np.floor(u1)) + 1, int(np.floor(v1)) + 1]

        spec["base_roi"] = [box(b, 0.0) for b in spec["base_roi"]]
        for st in spec["steps"]:
            st["roi"] = box(st["roi"], lvl[tuple(st["roi"])])
    (target / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return cam
