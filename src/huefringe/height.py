"""Phase-to-height calibration on planes at known heights, and accuracy against ground truth.

Model
-----
A telecentric camera looks straight down; a pinhole projector sits at ``(Xp, H)`` and casts a
fringe of period ``P`` onto the reference plane. A surface point at ``(X, h)`` is lit by the ray
that meets the reference plane at ``X0 = Xp + (X - Xp) H / (H - h)``, so its phase exceeds the
reference phase at the same pixel by

    dphi = k (X - Xp) h / (H - h),        k = 2 pi / P,

which solves to ``h = dphi / (a + b dphi)`` with ``a = k (X - Xp) / H`` and ``b = 1 / H``. Neither
``Xp`` nor ``H`` is known (the session gives no projector pose), so ``a`` and ``b`` are fitted per
pixel by linear least squares over the calibration planes: each plane ``z_j`` with measured
``dphi_j`` gives one equation ``a z_j + b z_j dphi_j = dphi_j``. With a single plane besides the
reference, ``b`` is set to 0 (a linear model) and the report says so.

Noise in the plane phases is removed by fitting each plane's phase with a low-order 2-D
polynomial (degree 3 by default): for a flat plate the phase is exactly linear in ``X`` under
the model above, and a cubic absorbs smooth lens distortion. ``smooth_degree=None`` keeps the
raw per-pixel phases instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.phase import unwrap_rows, wrap


class PlaneCalibrationError(ValueError):
    """Plane calibration failed: the calibration planes cannot give a phase-to-height model.

    (Hue-table calibration has its own: :class:`huefringe.huetable.HueTableError`.)
    """


@dataclass
class PlaneCalibration:
    """Per-pixel phase-to-height model ``h = dphi / (a + b dphi)`` and the reference phase."""

    phi_ref: NDArray[np.float32]
    """Wrapped phase of the reference plane z = 0, [0, 2 pi)."""
    a: NDArray[np.float32]
    b: NDArray[np.float32]
    planes_mm: list[float]
    stats: dict[str, Any] = field(default_factory=dict)
    phase_error: NDArray[np.float64] | None = None
    """The phase-error table ``e(phi)`` the planes and frames are corrected with
    (:mod:`huefringe.phase_error`), or None (no correction)."""
    budget: dict[str, NDArray[np.float32]] | None = None
    """Uncertainty inputs (:mod:`huefringe.uncertainty`): ``u_ref_rad`` (the smoothed reference
    phase's standard uncertainty) and ``cov_aa``, ``cov_ab``, ``cov_bb`` (covariance of a, b)."""
    texture_blur_px2: float | None = None
    """The camera's blur variance (px^2) estimated from the session's object frames
    (:func:`huefringe.texture.estimate_blur`) for the texture-edge correction, or None."""
    texture_blur_u_px2: float | None = None
    """Its standard uncertainty (px^2, :func:`huefringe.texture.blur_uncertainty`), which the
    per-pixel texture term of the uncertainty propagates, or None (unknown: no term)."""
    projector_off: NDArray[np.float32] | None = None
    """The light the object sends the camera with the projector's code at 0 (H, W, 3; ambient light,
    stray light, the projector's black level; :func:`huefringe.texture.projector_off_light`), which
    the texture-edge correction takes out of capture and white, or None (not taken out)."""

    def height(self, dphi: NDArray[np.floating]) -> NDArray[np.float32]:
        """Height in mm from an unwrapped phase difference (NaN stays NaN)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return (dphi / (self.a + self.b * dphi)).astype(np.float32)

    def unambiguous_range_mm(self) -> tuple[float, float]:
        """Heights reachable with ``|dphi|`` < pi (reference-relative unwrapping): the worst pixel."""
        lo = self.height(np.full(self.a.shape, -np.pi, np.float32))
        hi = self.height(np.full(self.a.shape, np.pi, np.float32))
        both = np.stack([lo, hi])
        return float(np.nanmax(np.nanmin(both, axis=0))), float(np.nanmin(np.nanmax(both, axis=0)))

    def save(self, path: str) -> None:
        from huefringe.io import atomic_path

        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                extra = {f"budget_{k}": v for k, v in (self.budget or {}).items()}
                if self.phase_error is not None:
                    extra["phase_error"] = np.asarray(self.phase_error, np.float64)
                if self.texture_blur_px2 is not None:
                    extra["texture_blur_px2"] = np.float64(self.texture_blur_px2)
                if self.texture_blur_u_px2 is not None:
                    extra["texture_blur_u_px2"] = np.float64(self.texture_blur_u_px2)
                if self.projector_off is not None:
                    extra["projector_off"] = np.asarray(self.projector_off, np.float32)
                np.savez(f, phi_ref=self.phi_ref, a=self.a, b=self.b, planes_mm=np.asarray(self.planes_mm), **extra)

    @classmethod
    def load(cls, path: str) -> PlaneCalibration:
        with np.load(path) as z:
            pe = z["phase_error"] if "phase_error" in z.files else None
            budget = {k[len("budget_"):]: z[k] for k in z.files if k.startswith("budget_")} or None
            blur = float(z["texture_blur_px2"]) if "texture_blur_px2" in z.files else None
            blur_u = float(z["texture_blur_u_px2"]) if "texture_blur_u_px2" in z.files else None
            off = z["projector_off"] if "projector_off" in z.files else None
            return cls(z["phi_ref"], z["a"], z["b"], [float(v) for v in z["planes_mm"]], phase_error=pe, budget=budget,
                       texture_blur_px2=blur, texture_blur_u_px2=blur_u, projector_off=off)


def fit_poly2d(values: NDArray[np.floating], valid: NDArray[np.bool_], degree: int = 3,
               *, step: int = 2, clip_sigma: float = 3.0, iterations: int = 3) -> NDArray[np.float64]:
    """Robust least-squares fit of a 2-D polynomial of total degree ``degree``; evaluated everywhere.

    Outliers beyond ``clip_sigma`` robust standard deviations are dropped and the fit repeated.
    """
    shape = values.shape
    sub_vals = values[::step, ::step]
    keep = valid[::step, ::step] & np.isfinite(sub_vals)
    n_terms = (degree + 1) * (degree + 2) // 2
    if keep.sum() < 4 * n_terms:
        raise PlaneCalibrationError(f"only {int(keep.sum())} valid samples for a degree-{degree} fit")
    A = _design_grid(shape, degree, step)[keep]
    y = sub_vals[keep].astype(np.float64)
    use = np.ones(y.shape, bool)
    coef = np.zeros(n_terms)
    for _ in range(iterations):
        coef, *_ = np.linalg.lstsq(A[use], y[use], rcond=None)
        r = y - A @ coef
        mad = 1.4826 * np.median(np.abs(r[use] - np.median(r[use])))
        if mad == 0:
            break
        new = np.abs(r) < clip_sigma * mad
        if new.sum() < 4 * n_terms or np.array_equal(new, use):
            break
        use = new
    return _design_grid(shape, degree) @ coef


def _design_grid(shape: tuple[int, int], degree: int, step: int = 1) -> NDArray[np.float64]:
    """The polynomial's design at every ``step``-th row and column of an ``(H, W)`` grid, shape
    ``(ceil(H / step), ceil(W / step), terms)``: ``x^i y^j`` for ``i + j <= degree`` (``i``
    outer), ``x`` and ``y`` the column and row scaled to [-1, 1] over the grid. Each power of a
    column's ``x`` and a row's ``y`` is taken once, their products broadcast: the values of the
    pointwise products, bit for bit (tests/test_phase_height.py)."""
    h, w = shape
    x = (np.arange(0, w, step).astype(np.float64) / max(w - 1, 1)) * 2.0 - 1.0
    y = (np.arange(0, h, step).astype(np.float64) / max(h - 1, 1)) * 2.0 - 1.0
    terms = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]
    xp = np.stack([x**i for i, _ in terms], axis=-1)  # (columns, terms)
    yp = np.stack([y**j for _, j in terms], axis=-1)  # (rows, terms)
    return yp[:, None, :] * xp[None, :, :]


def _row_unwrap(phi: NDArray[np.float64], valid: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Rows unwrapped along u over their valid pixels (``np.unwrap``), each row's 2 pi offset set
    to the row above's (median over shared columns); NaN where invalid."""
    out = np.full(phi.shape, np.nan)
    prev = None
    for v in range(phi.shape[0]):
        ok = valid[v]
        if ok.sum() < 2:
            continue
        row = np.full(phi.shape[1], np.nan)
        row[ok] = np.unwrap(phi[v, ok])
        if prev is not None:
            both = np.isfinite(prev) & ok
            if both.any():
                row -= (2 * np.pi) * np.round(np.median(row[both] - prev[both]) / (2 * np.pi))
        out[v] = row
        prev = row
    return out


def unwrap_smooth(phi: NDArray[np.floating], valid: NDArray[np.bool_], degree: int = 3, *,
                  step: int = 2) -> NDArray[np.float64]:
    """Unwrap the phase of a smooth surface (a calibration plane): NaN where invalid.

    Rows are unwrapped along u (:func:`_row_unwrap`), a robust 2-D polynomial of total degree
    ``degree`` is fitted (:func:`fit_poly2d`), and the phase is taken as that fit plus the
    wrapped difference to it (twice), which repairs any row slip. Fast where a 2-D
    quality-guided unwrapper on a noisy, short-period plane is not (a 320 x 240 plane at 20 px,
    8 bit: minutes in ``skimage.restoration.unwrap_phase``); where that unwrapper does not slip
    the two agree.
    """
    p = np.asarray(phi, np.float64)
    ok = np.asarray(valid, bool) & np.isfinite(p)
    un = _row_unwrap(p, ok)
    for _ in range(2):
        fit = fit_poly2d(un, ok, degree, step=step)
        un = np.where(ok, fit + np.angle(np.exp(1j * (p - fit))), np.nan)
    return un


def calibrate_planes(
    plane_phases: dict[float, NDArray[np.floating]],
    plane_valid: dict[float, NDArray[np.bool_]],
    *,
    smooth_degree: int | None = 3,
    min_valid_fraction: float = 0.2,
    min_shift_rad: float = 0.02,
) -> PlaneCalibration:
    """Fit the per-pixel model ``h = dphi / (a + b dphi)`` to the calibration planes.

    Parameters
    ----------
    plane_phases : dict
        Wrapped code phase [0, 2 pi) of each plane, keyed by its height in mm; must include 0.0.
    plane_valid : dict
        Valid-pixel mask of each plane.
    smooth_degree : int or None
        Degree of the 2-D polynomial fitted to each plane's phase, or None for raw pixels.

    Raises
    ------
    PlaneCalibrationError
        Missing reference plane, too few valid pixels, planes too close to tell apart.
    """
    zs = sorted(plane_phases)
    if 0.0 not in plane_phases:
        raise PlaneCalibrationError("the reference plane z = 0 is missing")
    others = sorted((z for z in zs if z != 0.0), key=abs)
    if not others:
        raise PlaneCalibrationError("at least one plane besides z = 0 is needed")
    shape = plane_phases[0.0].shape
    for z in zs:
        frac = float(np.mean(plane_valid[z]))
        if frac < min_valid_fraction:
            raise PlaneCalibrationError(f"plane z = {z:.3f} mm has only {100 * frac:.1f} % valid pixels")

    v0 = plane_valid[0.0]
    phi0 = np.asarray(plane_phases[0.0], np.float64)
    if smooth_degree is not None:
        phi0_model = fit_poly2d(unwrap_smooth(phi0, v0, smooth_degree), v0, smooth_degree)
        phi_ref = np.mod(phi0_model, 2 * np.pi)
    else:
        phi_ref = phi0

    # sequential (temporal) unwrapping of the plane differences, nearest plane first
    dphis: dict[float, NDArray[np.float64]] = {}
    raw: dict[float, NDArray[np.float64]] = {}
    slope: NDArray[np.float64] | None = None
    for z in others:
        d = wrap(np.asarray(plane_phases[z], np.float64) - phi_ref)
        valid = plane_valid[z] & v0 if smooth_degree is None else plane_valid[z]
        if slope is not None:
            pred = slope * z
            d = pred + wrap(d - pred)
        else:
            # nearest plane: unwrap spatially (its difference may cross +-pi somewhere in the
            # field) and take the 2 pi offset that puts the median within (-pi, pi]
            d = unwrap_rows(d, valid) if smooth_degree is None else unwrap_smooth(d, valid, smooth_degree)
            d -= 2 * np.pi * np.round(np.nanmedian(d[valid]) / (2 * np.pi))
            d = np.where(valid, d, 0.0)
        raw[z] = np.where(valid, d, np.nan)
        model = fit_poly2d(d, valid, smooth_degree) if smooth_degree is not None else raw[z]
        dphis[z] = model
        slope = model / z

    # every plane must shift the phase, in the same direction, and more the further it is from z = 0
    med = {z: float(np.nanmedian(raw[z])) if np.isfinite(raw[z]).any() else float("nan") for z in others}
    for z in others:
        if not np.isfinite(med[z]) or abs(med[z]) < min_shift_rad:
            raise PlaneCalibrationError(
                f"plane z = {z:.3f} mm shifts the phase by only {med[z]:.4f} rad relative to z = 0 "
                f"(less than {min_shift_rad} rad): the same image as the reference plane, or a plane too close to it"
            )
    if len({np.sign(med[z] / z) for z in others}) > 1:
        raise PlaneCalibrationError(f"the planes shift the phase in opposite directions ({med} rad): planes_mm mislabelled?")
    ordered = sorted(others)
    for z1, z2 in zip(ordered, ordered[1:], strict=False):
        if np.sign(med[z2] - med[z1]) == -np.sign(med[z1] / z1):  # equal shifts: "too close" below
            raise PlaneCalibrationError(
                f"planes out of order: plane z = {z2:.3f} mm shifts the phase by {med[z2]:.3f} rad, no more than "
                f"plane z = {z1:.3f} mm ({med[z1]:.3f} rad): plane images swapped or planes_mm mislabelled?"
            )

    # per-pixel least squares: a z + b z dphi = dphi
    def solve(dphis: dict[float, NDArray[np.float64]]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if len(others) == 1:
            (z1,) = others
            return dphis[z1] / z1, np.zeros(shape)
        s_zz = sum(z * z for z in others) * np.ones(shape)
        s_zzd = sum(z * z * dphis[z] for z in others)
        s_zzdd = sum(z * z * dphis[z] ** 2 for z in others)
        s_zd = sum(z * dphis[z] for z in others)
        s_zdd = sum(z * dphis[z] ** 2 for z in others)
        det = s_zz * s_zzdd - s_zzd**2
        with np.errstate(divide="ignore", invalid="ignore"):
            return (s_zd * s_zzdd - s_zdd * s_zzd) / det, (s_zz * s_zdd - s_zzd * s_zd) / det

    if len(others) == 1:
        model_kind = "linear (one plane besides the reference: b = 0)"
    else:
        s_zz = sum(z * z for z in others) * np.ones(shape)
        s_zzd = sum(z * z * dphis[z] for z in others)
        s_zzdd = sum(z * z * dphis[z] ** 2 for z in others)
        det = s_zz * s_zzdd - s_zzd**2
        spread = float(np.nanmedian(np.abs(det)) / max(float(np.nanmedian(s_zz * s_zzdd)), 1e-30))
        if spread < 1e-8:
            raise PlaneCalibrationError(
                "the calibration planes are too close together to fit the rational model; "
                f"planes_mm = {zs}"
            )
        model_kind = "rational h = dphi / (a + b dphi)"
    a, b = solve(dphis)

    cal = PlaneCalibration(phi_ref.astype(np.float32), a.astype(np.float32), b.astype(np.float32), zs)
    # residuals: heights of the raw (unsmoothed) plane phases against the known z
    per_plane = {}
    all_res = []
    for z in others:
        res = cal.height(raw[z]) - z
        res = res[np.isfinite(res)]
        all_res.append(res)
        per_plane[f"{z:.3f}"] = {
            "rms_mm": float(np.sqrt(np.mean(res**2))),
            "median_mm": float(np.median(res)),
            "valid_fraction": float(np.mean(plane_valid[z])),
        }
    res_all = np.concatenate(all_res)
    lo, hi = cal.unambiguous_range_mm()
    sensitivity = float(np.nanmedian(np.abs(a)))
    cal.stats = {
        "model": model_kind,
        "smooth_degree": smooth_degree,
        "planes_mm": zs,
        "fit_residual_rms_mm": float(np.sqrt(np.mean(res_all**2))),
        "fit_residual_p95_mm": float(np.percentile(np.abs(res_all), 95)),
        "per_plane": per_plane,
        "unambiguous_range_mm": [lo, hi],
        "sensitivity_rad_per_mm": sensitivity,
        "projector_height_mm_estimate": float(1.0 / np.nanmedian(b)) if np.nanmedian(b) > 0 else None,
    }
    cal.budget, cal.stats["uncertainty"] = _budget(solve, phi0, phi_ref, v0, raw, dphis, plane_valid, smooth_degree)
    return cal


def _budget(solve: Any, phi0: NDArray[np.float64], phi_ref: NDArray[np.float64], v0: NDArray[np.bool_],
            raw: dict[float, NDArray[np.float64]], dphis: dict[float, NDArray[np.float64]],
            plane_valid: dict[float, NDArray[np.bool_]], smooth_degree: int | None
            ) -> tuple[dict[str, NDArray[np.float32]], dict[str, Any]]:
    """The calibration's uncertainty inputs (:mod:`huefringe.uncertainty`) and their summary."""
    from huefringe import uncertainty as unc

    n_terms = 1 if smooth_degree is None else (smooth_degree + 1) * (smooth_degree + 2) // 2
    if smooth_degree is None:  # raw pixels: the reference is one capture, its noise is the frame's
        u_ref = np.zeros(phi0.shape)
        u_d = {z: np.zeros(phi0.shape) for z in dphis}
        sig0 = 0.0
    else:
        u_ref, sig0 = unc.systematic_rms(wrap(phi0 - phi_ref), v0, n_terms=n_terms)
        u_d = {z: unc.systematic_rms(raw[z] - dphis[z], plane_valid[z], n_terms=n_terms)[0] for z in dphis}
    fill = float(np.nanmedian(u_ref)) if np.isfinite(u_ref).any() else 0.0
    budget = {"u_ref_rad": np.where(np.isfinite(u_ref), u_ref, fill).astype(np.float32)}
    budget.update(unc.calibration_terms(solve, dphis, {z: np.where(np.isfinite(u), u, np.nanmedian(u)) for z, u in u_d.items()}))
    summary = {
        "residual_box_px": unc.RESIDUAL_BOX_PX,
        "reference_phase_u_rad_median": float(np.median(budget["u_ref_rad"])),
        "reference_phase_noise_rad": sig0,
        "plane_phase_u_rad_median": {f"{z:.3f}": float(np.nanmedian(u)) for z, u in u_d.items()},
    }
    return budget, summary


def coverage(height: NDArray[np.floating], truth: NDArray[np.floating],
             region: NDArray[np.bool_] | None = None) -> float:
    """Fraction of the pixels with a finite truth (inside ``region`` when given) that have a
    finite height: :func:`accuracy`'s ``coverage`` alone."""
    where = np.isfinite(truth) if region is None else (np.isfinite(truth) & region)
    return float(np.count_nonzero(where & np.isfinite(height)) / max(int(np.count_nonzero(where)), 1))


def accuracy(height: NDArray[np.floating], truth: NDArray[np.floating],
             region: NDArray[np.bool_] | None = None) -> dict[str, float]:
    """Height error statistics against ground truth.

    ``coverage`` is the valid fraction of the pixels where the truth is finite (and inside
    ``region`` when given); the error figures use the pixels valid in both.
    """
    truth = np.asarray(truth, np.float64)
    height = np.asarray(height, np.float64)
    where = np.isfinite(truth) if region is None else (np.isfinite(truth) & region)
    both = where & np.isfinite(height)
    n = int(where.sum())
    if not both.any():
        return {"rms_mm": float("nan"), "median_abs_mm": float("nan"), "p95_abs_mm": float("nan"),
                "mean_mm": float("nan"), "coverage": 0.0, "pixels": n}
    err = height[both] - truth[both]
    return {
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "median_abs_mm": float(np.median(np.abs(err))),
        "p95_abs_mm": float(np.percentile(np.abs(err), 95)),
        "mean_mm": float(np.mean(err)),
        "coverage": float(both.sum() / max(n, 1)),
        "pixels": n,
    }


def xy_accuracy(x: NDArray[np.floating], y: NDArray[np.floating], truth_xy: NDArray[np.floating],
                corner_fraction: float = 0.9) -> dict[str, float]:
    """X, Y error of a measured cloud against ground truth (mm).

    Parameters
    ----------
    x, y : (H, W) float
        The measured X, Y of every pixel (:meth:`huefringe.camera.CameraModel.xy` of the measured
        height; NaN where there is no height).
    truth_xy : (H, W, 2) float
        The true X, Y of each pixel's surface point (the bench's ``ground_truth/xy/frame_NNNN.tiff``),
        NaN where unseen.
    corner_fraction : float
        The "corners" are the pixels at least this fraction of the corner radius from the image
        centre (the field's four corner regions).

    Returns
    -------
    dict
        ``rms_mm``, ``p95_mm``, ``max_mm`` of the distance ``|(X, Y) - truth|`` over the pixels
        where both are finite, the same over the corners (``corner_*``), and ``pixels`` /
        ``corner_pixels`` (how many were scored).
    """
    truth = np.asarray(truth_xy, np.float64)
    h, w = truth.shape[:2]
    d = np.hypot(np.asarray(x, np.float64) - truth[..., 0], np.asarray(y, np.float64) - truth[..., 1])
    ok = np.isfinite(d)
    vv, uu = np.mgrid[0:h, 0:w]
    r = np.hypot(uu - (w - 1) / 2.0, vv - (h - 1) / 2.0)
    corner = ok & (r >= corner_fraction * r.max())
    out: dict[str, float] = {}
    for prefix, m in (("", ok), ("corner_", corner)):
        e = d[m]
        out[f"{prefix}rms_mm"] = float(np.sqrt(np.mean(e**2))) if e.size else float("nan")
        out[f"{prefix}p95_mm"] = float(np.percentile(e, 95)) if e.size else float("nan")
        out[f"{prefix}max_mm"] = float(e.max()) if e.size else float("nan")
        out[f"{prefix}pixels"] = int(e.size)
    return out
