"""Synthetic lateral chromatic aberration for tests: a copy of a session whose R and B channels
are magnified about a centre (what a lens with lateral colour does), written with OpenCV."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from huefringe.session import load_session, read_rgb_codes
from session_factory import write_image


def magnify_channels(img: np.ndarray, scale_r: float, scale_b: float, centre: tuple[float, float]) -> np.ndarray:
    """``observed_c(x) = true_c(centre + (x - centre) / (1 + s_c))``: R and B magnified by
    ``1 + s`` (Lanczos, replicated border), G untouched, same dtype."""
    h, w = img.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    out = img.copy()
    for c, s in ((0, scale_r), (2, scale_b)):
        mx = (centre[0] + (u - centre[0]) / (1 + s)).astype(np.float32)
        my = (centre[1] + (v - centre[1]) / (1 + s)).astype(np.float32)
        out[..., c] = cv2.remap(np.ascontiguousarray(img[..., c]), mx, my, cv2.INTER_LANCZOS4,
                                borderMode=cv2.BORDER_REPLICATE)
    return out


def aberrated_copy(session: Path, target: Path, corner_px_r: float, corner_px_b: float) -> tuple[float, float]:
    """Copy ``session`` to ``target`` with every capture's R and B magnified about the image
    centre so that they move by ``corner_px_*`` at the farthest corner; returns the scales."""
    s = load_session(session)
    centre = ((s.width - 1) / 2.0, (s.height - 1) / 2.0)
    r = float(np.hypot(*centre))
    sr, sb = corner_px_r / r, corner_px_b / r
    shutil.copytree(session, target)
    for p in s.all_images():
        q = target / p.relative_to(session)
        write_image(q, magnify_channels(read_rgb_codes(p), sr, sb, centre))
    return sr, sb
