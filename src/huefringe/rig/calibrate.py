"""Projector-camera calibration from checkerboard (or circle-grid) poses captured with fringe codes.

For each pose of the board the camera sees the board's corners (:func:`detect_corners`:
``cv2.findChessboardCornersSB`` or ``cv2.findCirclesGrid``) and, under the coded sequence, the
decoded projector coordinates ``u, v`` at every camera pixel. The projector's pixel at a corner
is the local homography from camera to projector pixels, fitted by least squares to the decoded
pixels in a window around the corner (each weighted by its inverse variance) and applied to the corner (:func:`projector_corners`,
Moreno & Taubin 2012). The camera and the projector are then calibrated each with
``cv2.calibrateCameraExtended`` and jointly refined with ``cv2.stereoCalibrateExtended``
(:func:`calibrate_rig`); poses whose reprojection RMS exceeds a multiple of the median are
named and left out of a second fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.rig.model import RigCalibration

__all__ = ["Board", "CalibrationReport", "PoseObservation", "calibrate_rig", "calibrated_field", "detect_corners",
           "field_mask", "projector_corners", "refine_corners_fronto_parallel"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    Parameters
    ----------
    cols, rows : int
        Inner corners (chessboard) or circles per row and per column.
    pitch_mm : float
        Square size (chessboard) or circle spacing.
    kind : {'chessboard', 'circles', 'acircles'}
        Chessboard, symmetric or asymmetric circle grid (OpenCV's layouts).
    """

    cols: int
    rows: int
    pitch_mm: float
    kind: Literal["chessboard", "circles", "acircles"] = "chessboard"

    def object_points(self) -> NDArray[np.float32]:
        """Corner (circle) positions on the board, mm, ``z = 0``, in OpenCV's detection order."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        x = i.astype(np.float64)
        if self.kind == "acircles":
            x = 2 * i + (j % 2)
        pts = np.column_stack([x.ravel(), j.ravel(), np.zeros(j.size)]) * self.pitch_mm
        return pts.astype(np.float32)


@dataclass
class PoseObservation:
    """One board pose: its name (a file or folder), camera corners and projector corners, pixels."""

    name: str
    camera: F64
    projector: F64


@dataclass
class CalibrationReport:
    """Per-pose reprojection errors and the poses that did not fit.

    Attributes
    ----------
    poses : list of dict
        ``name``, ``camera_rms_px``, ``projector_rms_px`` (against the final calibration) and
        ``used``.
    rejected : list of str
        Poses left out: reprojection RMS above ``outlier_factor`` x the median.
    rms_px : dict
        ``camera``, ``projector`` (each device alone) and ``stereo`` (joint) RMS of the final fit.
    """

    poses: list[dict[str, Any]] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    rms_px: dict[str, float] = field(default_factory=dict)
    form_floor: dict[str, Any] | None = None
    """The calibration boards' flatness with the final calibration (:mod:`huefringe.rig.measure`), when measured."""
    corner_refinement: dict[str, Any] | None = None
    """How the camera corners were refined in fronto-parallel views (:func:`refine_corners_fronto_parallel`), when they were."""
    calibrated_field: dict[str, Any] | None = None
    """The camera image the used poses' corners cover (:func:`calibrated_field`)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        out: dict[str, Any] = {"rms_px": self.rms_px, "rejected": self.rejected, "poses": self.poses}
        if self.corner_refinement is not None:
            out["corner_refinement"] = self.corner_refinement
        if self.calibrated_field is not None:
            out["calibrated_field"] = self.calibrated_field
        return out if self.form_floor is None else {**out, "form_floor": self.form_floor}


def calibrated_field(poses: list[PoseObservation], camera_size: tuple[int, int]) -> dict[str, Any]:
    """The part of the camera image the calibration's poses cover: the union of each pose's corner hull.

    The lens distortion is fitted to the corners; outside every pose's board it is extrapolated,
    and a polynomial model (``k1, k2``) extrapolated away from the centre bends a flat surface
    there by far more than the calibration's residuals or its pose-to-pose spread show (on the
    bench's holdout-wide rig, boards near the middle of the image covering 33-38 % of it: a flat
    board's form 1.6-2.6 um inside the covered part, 4.5-54 um over the whole view). A lab reads
    here how much of the image its poses covered and whether what it measures lies inside
    (:func:`field_mask`); spreading the poses over the field, into its corners, widens it.

    Returns
    -------
    dict
        ``image_fraction`` (covered share of the image), ``hulls_px`` (each pose's corner hull,
        camera pixels rounded to 0.1 px, for :func:`field_mask`), ``what``.
    """
    w, h = (int(v) for v in camera_size)
    hulls = [np.round(cv2.convexHull(np.asarray(p.camera, np.float32).reshape(-1, 1, 2)).reshape(-1, 2), 1).tolist()
             for p in poses]
    doc = {"hulls_px": hulls, "camera_size": [w, h]}
    return {"image_fraction": round(float(field_mask(doc, (h, w)).mean()), 4), "hulls_px": hulls,
            "what": "share of the camera image inside at least one used pose's corner hull: where the lens model is "
                    "fitted; outside, its distortion is extrapolated (a flat surface there may bend by more than u says)"}


def field_mask(field: dict[str, Any], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Camera pixels inside the calibrated field (:func:`calibrated_field`'s ``hulls_px``), shape ``(H, W)``."""
    mask = np.zeros(shape, np.uint8)
    for hull in field.get("hulls_px", []):
        pts = np.round(np.asarray(hull, np.float64) * 16.0).astype(np.int32).reshape(-1, 1, 2)   # 1/16 px vertices
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def detect_corners(image: ArrayLike, board: Board) -> F64 | None:
    """The board's corners (circle centres) in ``image``, (N, 2) pixels, or ``None`` if not found."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if img.dtype != np.uint8:
        lo, hi = float(np.nanmin(img)), float(np.nanmax(img))
        img = np.clip((img - lo) / max(hi - lo, 1e-12) * 255 + 0.5, 0, 255).astype(np.uint8)
    size = (board.cols, board.rows)
    if board.kind == "chessboard":
        ok, c = cv2.findChessboardCornersSB(img, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    else:
        flag = cv2.CALIB_CB_SYMMETRIC_GRID if board.kind == "circles" else cv2.CALIB_CB_ASYMMETRIC_GRID
        ok, c = cv2.findCirclesGrid(img, size, flags=flag)
    return c.reshape(-1, 2).astype(np.float64) if ok else None


def refine_corners_fronto_parallel(image: ArrayLike, corners: ArrayLike, board: Board, camera_matrix: ArrayLike,
                                   camera_distortion: ArrayLike, *, max_shift_px: float = 1.0) -> F64 | None:
    """Camera corners found again in a fronto-parallel view of the board (Datta, Kim & Kanade 2009).

    A corner detector's sub-pixel estimate is biased on a tilted board: perspective makes the
    squares around a corner unequal and the edges meet at other angles than 90 degrees. The board's
    pose is estimated from ``corners`` with the camera's model (``cv2.solvePnP``), the image is
    resampled on the board's own plane (as many samples per mm as the camera has pixels per mm
    there, 1.5 squares of margin, wider when the detector misses the board), the corners are detected there (:func:`detect_corners`: the
    squares are square again) and carried back into the camera image through the same model. The
    model's own errors enter the resampling and the way back alike, so they cancel to first order.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The image ``corners`` were found in.
    corners : array_like, shape (N, 2)
        The board's corners in OpenCV's order (:func:`detect_corners`), camera pixels.
    board : Board
    camera_matrix, camera_distortion : array_like
        The camera's model (a first calibration from ``corners``).
    max_shift_px : float
        A refined corner farther than this from its first estimate is not the same corner.

    Returns
    -------
    ndarray, shape (N, 2), or None
        The refined corners in the order of ``corners``; ``None`` when the board is not found in
        the fronto-parallel view or a corner moves more than ``max_shift_px``.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    K, dist = np.asarray(camera_matrix, dtype=np.float64), np.asarray(camera_distortion, dtype=np.float64)
    obj = board.object_points().astype(np.float64)
    ok, rv, tv = cv2.solvePnP(obj, c, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    # camera pixels per mm on the board: neighbours along each row of the grid
    dc = np.linalg.norm(np.diff(c.reshape(board.rows, board.cols, 2), axis=1), axis=2)
    do = np.linalg.norm(np.diff(obj[:, :2].reshape(board.rows, board.cols, 2), axis=1), axis=2)
    ppm = float(np.median(dc / do))
    span = obj[:, :2].max(axis=0)
    found = None
    for margin in (1.5 * board.pitch_mm, 2.0 * board.pitch_mm, 2.5 * board.pitch_mm):   # the detector's search is
        xs = np.arange(-margin, span[0] + margin, 1.0 / ppm)                          # fickle: a wider margin
        ys = np.arange(-margin, span[1] + margin, 1.0 / ppm)                          # when it misses the board
        X, Y = np.meshgrid(xs, ys)
        grid = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
        q = cv2.projectPoints(grid, rv, tv, K, dist)[0].reshape(*X.shape, 2).astype(np.float32)
        rect = cv2.remap(img, q[..., 0], q[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        found = detect_corners(rect, board)
        if found is not None and len(found) == len(c):
            break
    if found is None or len(found) != len(c):
        return None
    on_board = np.column_stack([xs[0] + found[:, 0] / ppm, ys[0] + found[:, 1] / ppm, np.zeros(len(found))])
    back = cv2.projectPoints(on_board, rv, tv, K, dist)[0].reshape(-1, 2)
    # the view's detection may number the corners from another end: match each corner to its nearest
    d2 = ((c[:, None, :] - back[None, :, :]) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    if len(np.unique(j)) != len(c) or np.sqrt(d2[np.arange(len(c)), j]).max() > max_shift_px:
        return None
    return back[j]


def projector_corners(
    corners: ArrayLike,
    u: ArrayLike,
    v: ArrayLike,
    valid: ArrayLike,
    half_window_px: int,
    min_pixels: int,
    sigma_u: ArrayLike | None = None,
    sigma_v: ArrayLike | None = None,
) -> tuple[F64, NDArray[np.bool_]]:
    """Projector pixels at camera ``corners`` by local homographies (Moreno & Taubin 2012).

    Each corner's homography from camera to projector pixels is fitted by weighted least squares
    over the valid decoded pixels in its window, each pixel's ``u`` and ``v`` equations weighted by
    their inverse variance (a normalised DLT, reweighted once so that the residuals it minimises
    are projector pixels), and applied to the corner. All corners are fitted at once.

    Parameters
    ----------
    corners : array_like, shape (N, 2)
        Camera corners, pixels.
    u, v, valid : array_like, shape (H, W)
        Decoded projector column and row at every camera pixel and where they are valid.
    half_window_px : int
        The window around each corner: ``2 half_window_px + 1`` pixels square.
    min_pixels : int
        Fewest valid decoded pixels a window needs.
    sigma_u, sigma_v : array_like, shape (H, W), optional
        Standard uncertainty of ``u`` and ``v`` (projector px, e.g. ``Decoded.sigma``). Pixels
        whose sigma is not finite and positive are left out. Without them every pixel weighs alike.

    Returns
    -------
    proj : ndarray, shape (N, 2)
        Projector pixels (NaN where a window had too few pixels).
    ok : ndarray of bool, shape (N,)
    """
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    U, V, M = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64), np.asarray(valid, dtype=bool)
    M = M & np.isfinite(U) & np.isfinite(V)
    weights = []
    for s in (sigma_u, sigma_v):
        if s is None:
            weights.append(np.ones_like(U))
            continue
        s = np.asarray(s, dtype=np.float64)
        good = np.isfinite(s) & (s > 0)
        M &= good
        weights.append(np.where(good, 1.0 / np.where(good, s, 1.0), 0.0))   # sqrt of inverse variance
    r = int(half_window_px)
    out = np.full_like(c, np.nan)
    ok = np.zeros(len(c), dtype=bool)
    if len(c) == 0:
        return out, ok
    pad = [(r, r), (r, r)]
    Mp = np.pad(M, pad)
    Up, Vp = (np.pad(np.where(M, a, 0.0), pad) for a in (U, V))
    Wu, Wv = (np.pad(np.where(M, wt, 0.0), pad) for wt in weights)
    h, w = U.shape
    off = np.arange(-r, r + 1)
    cx = np.clip(np.rint(c[:, 0]), -r - 1, w + r).astype(int)
    cy = np.clip(np.rint(c[:, 1]), -r - 1, h + r).astype(int)
    ix = cx[:, None, None] + off[None, None, :] + r                    # (N, S, S) into the padded maps
    iy = cy[:, None, None] + off[None, :, None] + r
    inside = (ix >= 0) & (ix < w + 2 * r) & (iy >= 0) & (iy < h + 2 * r) & np.isfinite(c).all(axis=1)[:, None, None]
    ix, iy = np.broadcast_arrays(np.clip(ix, 0, w + 2 * r - 1), np.clip(iy, 0, h + 2 * r - 1))
    m = (Mp[iy, ix] & inside).reshape(len(c), -1)
    n_px = m.sum(axis=1)
    x = ((ix - r) - c[:, 0, None, None]).reshape(len(c), -1) / max(r, 1)   # about the corner: well conditioned
    y = ((iy - r) - c[:, 1, None, None]).reshape(len(c), -1) / max(r, 1)
    du, dv = Up[iy, ix].reshape(len(c), -1), Vp[iy, ix].reshape(len(c), -1)
    au, av = np.where(m, Wu[iy, ix].reshape(len(c), -1), 0.0), np.where(m, Wv[iy, ix].reshape(len(c), -1), 0.0)
    # normalise the projector side: weighted centroid and spread of each window
    wsum = np.maximum((au**2 + av**2).sum(axis=1), 1e-300)
    cu = (au**2 * du).sum(axis=1) / np.maximum((au**2).sum(axis=1), 1e-300)
    cv = (av**2 * dv).sum(axis=1) / np.maximum((av**2).sum(axis=1), 1e-300)
    su = np.sqrt(((au**2 * (du - cu[:, None]) ** 2).sum(axis=1) + (av**2 * (dv - cv[:, None]) ** 2).sum(axis=1)) / wsum)
    su = np.where(su > 0, su, 1.0)
    pu, pv = np.where(m, (du - cu[:, None]) / su[:, None], 0.0), np.where(m, (dv - cv[:, None]) / su[:, None], 0.0)
    one, zero = np.ones_like(x), np.zeros_like(x)
    Au = np.stack([x, y, one, zero, zero, zero, -pu * x, -pu * y, -pu], axis=-1)   # (N, P, 9)
    Av = np.stack([zero, zero, zero, x, y, one, -pv * x, -pv * y, -pv], axis=-1)
    den = np.ones_like(x)
    for _ in range(2):                  # the second pass turns algebraic residuals into projector pixels
        bu, bv = au / den, av / den
        AtA = np.einsum("npi,npj->nij", Au * bu[..., None] ** 2, Au) + np.einsum("npi,npj->nij", Av * bv[..., None] ** 2, Av)
        AtA[n_px < max(min_pixels, 4)] = np.eye(9)
        Hn = np.linalg.eigh(AtA)[1][:, :, 0].reshape(-1, 3, 3)
        den = Hn[:, 2, 0, None] * x + Hn[:, 2, 1, None] * y + Hn[:, 2, 2, None]
        den = np.where(np.abs(den) > 1e-12, np.abs(den), 1e-12)
        den = den / np.maximum(np.median(den, axis=1, keepdims=True), 1e-12)
    h22 = Hn[:, 2, 2]
    good = (n_px >= max(min_pixels, 4)) & (np.abs(h22) > 1e-12)
    safe = np.where(good, h22, 1.0)
    proj = np.column_stack([Hn[:, 0, 2] / safe * su + cu, Hn[:, 1, 2] / safe * su + cv])   # the corner is the origin
    out[good] = proj[good]
    ok[good] = True
    return out, ok


def _per_view(obj: list[NDArray[np.float32]], img: list[F64], K: F64, d: F64, rv: Any, tv: Any) -> list[float]:
    errs = []
    for o, p, r, t in zip(obj, img, rv, tv, strict=True):
        q = cv2.projectPoints(o, r, t, K, d)[0].reshape(-1, 2)
        errs.append(float(np.sqrt(np.mean(np.sum((q - p) ** 2, axis=1)))))
    return errs


def _fit(obj: list[NDArray[np.float32]], cam: list[F64], prj: list[F64], camera_size: tuple[int, int],
         projector_size: tuple[int, int], flags: int) -> tuple[RigCalibration, list[float], list[float]]:
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    c32 = [p.astype(np.float32).reshape(-1, 1, 2) for p in cam]
    p32 = [p.astype(np.float32).reshape(-1, 1, 2) for p in prj]
    rms_c, Kc, dc, *_ = cv2.calibrateCameraExtended(obj, c32, camera_size, None, None, flags=flags, criteria=crit)
    rms_p, Kp, dp, *_ = cv2.calibrateCameraExtended(obj, p32, projector_size, None, None, flags=flags, criteria=crit)
    out = cv2.stereoCalibrateExtended(obj, c32, p32, Kc, dc, Kp, dp, camera_size, None, None,
                                      flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    rms, Kc, dc, Kp, dp, R, T = out[:7]
    calib = RigCalibration(Kc, dc, Kp, dp, R, T.reshape(3), camera_size, projector_size,
                           errors={"camera": float(rms_c), "projector": float(rms_p), "stereo": float(rms)})
    # per-pose errors against the joint fit: board poses from the camera, carried to the projector
    ec, ep = [], []
    for o, c, p in zip(obj, cam, prj, strict=True):
        _, rv, tv = cv2.solvePnP(o, c, Kc, dc, flags=cv2.SOLVEPNP_ITERATIVE)
        Rb = cv2.Rodrigues(rv)[0]
        ec += _per_view([o], [c], Kc, dc, [rv], [tv])
        ep += _per_view([o], [p], Kp, dp, [cv2.Rodrigues(R @ Rb)[0]], [R @ tv + T])
    return calib, ec, ep


def calibrate_rig(
    poses: list[PoseObservation],
    board: Board,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    *,
    outlier_factor: float,
    fix_k3: bool,
    min_poses: int,
) -> tuple[RigCalibration, CalibrationReport]:
    """Calibrate camera, projector and their pose from board poses.

    Parameters
    ----------
    poses : list of PoseObservation
        Each with every board corner seen by the camera and the projector.
    board : Board
    camera_size, projector_size : (int, int)
        ``(width, height)`` in pixels.
    outlier_factor : float
        A pose whose camera or projector RMS exceeds this multiple of the poses' median is named
        in the report and the rig is fitted again without it.
    fix_k3 : bool
        Hold the sixth-order radial term at zero (``cv2.CALIB_FIX_K3``), as a few poses need.
    min_poses : int
        Fewest poses a calibration needs (also after rejection).

    Raises
    ------
    ValueError
        Too few poses, or poses with the wrong number of corners (named).
    """
    n = len(board.object_points())
    bad = [f"{p.name}: {len(p.camera)} camera / {len(p.projector)} projector corners, {n} expected"
           for p in poses if len(p.camera) != n or len(p.projector) != n or not np.isfinite(p.projector).all()]
    if bad:
        raise ValueError("poses without every corner: " + "; ".join(bad))
    if len(poses) < min_poses:
        raise ValueError(f"{len(poses)} poses; a calibration needs at least {min_poses}")
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    obj = [board.object_points()] * len(poses)
    cam = [np.asarray(p.camera, dtype=np.float64) for p in poses]
    prj = [np.asarray(p.projector, dtype=np.float64) for p in poses]
    calib, ec, ep = _fit(obj, cam, prj, camera_size, projector_size, flags)
    worst = np.maximum(np.asarray(ec) / np.median(ec), np.asarray(ep) / np.median(ep))
    keep = worst <= outlier_factor
    rejected = [p.name for p, k in zip(poses, keep, strict=True) if not k]
    if rejected and keep.sum() >= min_poses:
        sel = np.flatnonzero(keep)
        calib, _, _ = _fit([obj[i] for i in sel], [cam[i] for i in sel], [prj[i] for i in sel],
                           camera_size, projector_size, flags)
        _, ec, ep = _errors_all(calib, obj, cam, prj)
    elif rejected:
        keep[:] = True
        rejected = []
    report = CalibrationReport(
        poses=[{"name": p.name, "camera_rms_px": round(a, 4), "projector_rms_px": round(b, 4), "used": bool(k)}
               for p, a, b, k in zip(poses, ec, ep, keep, strict=True)],
        rejected=rejected,
        rms_px={k: round(v, 4) for k, v in calib.errors.items()},
        calibrated_field=calibrated_field([p for p, k in zip(poses, keep, strict=True) if k], camera_size),
    )
    return calib, report


def _errors_all(calib: RigCalibration, obj: list[NDArray[np.float32]], cam: list[F64],
                prj: list[F64]) -> tuple[None, list[float], list[float]]:
    ec, ep = [], []
    for o, c, p in zip(obj, cam, prj, strict=True):
        _, rv, tv = cv2.solvePnP(o, c, calib.camera_matrix, calib.camera_distortion)
        Rb = cv2.Rodrigues(rv)[0]
        ec += _per_view([o], [c], calib.camera_matrix, calib.camera_distortion, [rv], [tv])
        ep += _per_view([o], [p], calib.projector_matrix, calib.projector_distortion,
                        [cv2.Rodrigues(calib.R @ Rb)[0]], [calib.R @ tv + calib.T.reshape(3, 1)])
    return None, ec, ep
