"""Row banding and colour flicker of the calibration captures: the signatures of a colour-sequential projector.

A single-chip DLP projector shows R, G and B one after another. A camera whose exposure is not a
whole number of the projector's colour cycles records, in each row, a share of each colour that
differs from the share in a whole cycle; with a rolling shutter that share changes from row to
row with a period of ``cycle / line_time`` rows. The decoded hue, hence the phase, then carries an
error that repeats along the image's rows (docs/capture.md, "Colour-sequential projectors").

:func:`row_banding` measures it on a flat calibration plane: the plane's phase minus a smooth
2-D polynomial (the plane's own shape), the residual's power spectrum along the rows (per column,
averaged over the columns: the error's sign changes with the fringe's hue along a row, so the
rows are not averaged first), and the power above the spectrum's noise floor at row periods
between :data:`MIN_PERIOD_ROWS` and ``height * MAX_PERIOD_FRACTION``. Its square root is the RMS of
the row-periodic component. Banding slower than that (one band per image) is taken by the smooth
fit and is not seen; a colour-balance error uniform over the image (a global shutter) is not a
row-periodic error either.

:func:`repeat_hue_flicker` measures the global shutter's signature: every image has its own
colour balance, so the repeats of one uniform hue band disagree in hue over the whole image (the
image-wide mean hue of a repeat is set by the pixels' noise only to within about 1e-4 rad).

Layer: uses :mod:`huefringe.height` (the plane's unwrap and polynomial fit) only; pure.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.height import PlaneCalibrationError, fit_poly2d, unwrap_smooth

__all__ = ["FLICKER_THRESHOLD_RAD", "MAX_PERIOD_FRACTION", "MIN_PEAK_RATIO", "MIN_PERIOD_ROWS", "THRESHOLD_RAD",
           "ColourFlicker", "RowBanding", "flicker_from_means", "mean_hue", "repeat_hue_flicker", "row_banding",
           "row_periodic_rms"]

#: shortest row period looked at (rows): below it, camera noise and demosaic patterns
MIN_PERIOD_ROWS = 4.0
#: longest row period looked at, as a fraction of the image height (slower bands go into the fit)
MAX_PERIOD_FRACTION = 0.5
#: RMS of the row-periodic phase component above which the banding is reported (rad); 0.02 rad is
#: 0.3 % of a fringe period, above the bench demo's whole phase-noise budget per pixel
THRESHOLD_RAD = 0.02
#: the spectrum's highest bin must stand this many times above its noise floor
MIN_PEAK_RATIO = 4.0
#: standard deviation of a uniform band's image-mean hue between its repeats above which the
#: colour balance is reported to change from image to image (rad)
FLICKER_THRESHOLD_RAD = 0.005


@dataclass(frozen=True)
class RowBanding:
    """The row-periodic component of one plane's phase.

    Attributes
    ----------
    amplitude_rad : float
        RMS (over the valid pixels) of the row-periodic component of the phase, rad.
    amplitude_px : float
        The same in camera pixels of the fringe on the reference plane (``period_px / 2 pi`` per rad).
    period_rows : float or None
        Row period of the spectrum's highest bin in the band (None when nothing stands out).
    peak_ratio : float
        That bin's power over the noise floor.
    noise_rad : float
        RMS of the residual (everything the smooth fit leaves: noise included), rad.
    suspected : bool
        ``amplitude_rad > threshold_rad`` and ``peak_ratio >= MIN_PEAK_RATIO``.
    threshold_rad : float
        The threshold applied.
    """

    amplitude_rad: float
    amplitude_px: float
    period_rows: float | None
    peak_ratio: float
    noise_rad: float
    suspected: bool
    threshold_rad: float

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready record."""
        return asdict(self)


def row_banding(phase: NDArray[np.floating], valid: NDArray[np.bool_], *, period_px: float, degree: int = 3,
                threshold_rad: float = THRESHOLD_RAD) -> RowBanding:
    """The row-periodic component of a flat plane's (wrapped) phase.

    Parameters
    ----------
    phase : ndarray (H, W)
        Wrapped code phase of a flat calibration plane (NaN where not decoded).
    valid : ndarray of bool (H, W)
        Pixels to use.
    period_px : float
        Fringe period on the reference plane in camera pixels (``pattern.period_px``).
    degree : int
        Total degree of the smooth 2-D polynomial taken as the plane's phase.
    threshold_rad : float
        Amplitude above which the banding is reported (:data:`THRESHOLD_RAD`).

    Returns
    -------
    RowBanding

    Raises
    ------
    huefringe.height.PlaneCalibrationError
        Too few valid pixels for the fit.
    """
    p = np.asarray(phase, np.float64)
    ok = np.asarray(valid, bool) & np.isfinite(p)
    un = unwrap_smooth(p, ok, degree)
    ok &= np.isfinite(un)
    if ok.sum() < 64:
        raise PlaneCalibrationError(f"only {int(ok.sum())} valid pixels for the row-banding spectrum")
    res = un - fit_poly2d(un, ok, degree)
    noise = float(np.sqrt(np.mean(res[ok] ** 2)))
    amp, period, ratio = row_periodic_rms(res, ok)
    suspected = bool(amp > threshold_rad and ratio >= MIN_PEAK_RATIO)
    return RowBanding(
        amplitude_rad=amp,
        amplitude_px=amp * float(period_px) / (2.0 * np.pi),
        period_rows=period,
        peak_ratio=ratio,
        noise_rad=noise,
        suspected=suspected,
        threshold_rad=float(threshold_rad),
    )


def row_periodic_rms(residual: NDArray[np.floating], valid: NDArray[np.bool_]) -> tuple[float, float | None, float]:
    """RMS of the row-periodic component of a residual map (any unit: phase, height).

    Per column with at least half its rows valid: the valid residual minus its mean, Hann-windowed
    along the rows, its one-sided power spectrum normalised so that the bins sum to the column's
    mean square (Parseval); the spectra are averaged over the columns. In the band of row periods
    from :data:`MIN_PERIOD_ROWS` to ``MAX_PERIOD_FRACTION * rows``, the power above the band's
    median (the noise floor) is summed.

    Parameters
    ----------
    residual : ndarray (H, W)
        What is left once the smooth shape is removed (invalid pixels ignored).
    valid : ndarray of bool (H, W)
        Pixels to use.

    Returns
    -------
    rms : float
        Square root of the power above the floor in the band (the residual's unit).
    period_rows : float or None
        Row period of the band's highest bin, None when it stands less than
        :data:`MIN_PEAK_RATIO` times above the floor.
    peak_ratio : float
        That bin's power over the floor.

    Raises
    ------
    huefringe.height.PlaneCalibrationError
        No column with enough valid rows, or too few rows for the band.
    """
    ok = np.asarray(valid, bool) & np.isfinite(residual)
    res = np.where(ok, np.asarray(residual, np.float64), 0.0)
    h = res.shape[0]
    use = ok.sum(axis=0) >= max(16, h // 2)
    if not use.any():
        raise PlaneCalibrationError("no column with enough valid rows for the row-banding spectrum")
    r, m = res[:, use], ok[:, use].astype(np.float64)
    r = np.where(m > 0, r - (r.sum(axis=0) / m.sum(axis=0))[None, :], 0.0)
    win = np.hanning(h)[:, None]
    spec = np.abs(np.fft.rfft(r * win, axis=0)) ** 2
    norm = h * (win**2 * m).sum(axis=0)[None, :]  # Parseval: sum_k |X_k|^2 = h sum_n |x_n|^2
    power = spec / norm
    power[1:] *= 2.0
    if h % 2 == 0:
        power[-1] /= 2.0
    power = power.mean(axis=1)
    f = np.fft.rfftfreq(h)  # cycles per row
    band = (f >= 1.0 / (MAX_PERIOD_FRACTION * h)) & (f <= 1.0 / MIN_PERIOD_ROWS)
    if band.sum() < 4:
        raise PlaneCalibrationError(f"an image of {h} rows is too short for the row-banding spectrum")
    pb, fb = power[band], f[band]
    floor = float(np.median(pb))
    k = int(np.argmax(pb))
    ratio = float(pb[k] / floor) if floor > 0 else float("inf")
    rms = float(np.sqrt(np.clip(pb - floor, 0.0, None).sum()))
    return rms, (float(1.0 / fb[k]) if ratio >= MIN_PEAK_RATIO else None), ratio


@dataclass(frozen=True)
class ColourFlicker:
    """How much a uniform band's image-wide hue changes between its repeats.

    Attributes
    ----------
    amplitude_rad : float
        Standard deviation between repeats of a band's image-mean hue, pooled over the bands (rad).
    max_rad : float
        The largest deviation of one repeat from its band's mean (rad).
    bands : int
        Bands with at least two usable repeats.
    repeats : int
        Largest number of repeats of a band.
    suspected : bool
        ``amplitude_rad > threshold_rad``.
    threshold_rad : float
        The threshold applied.
    """

    amplitude_rad: float | None
    max_rad: float | None
    bands: int
    repeats: int
    suspected: bool
    threshold_rad: float

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready record."""
        return asdict(self)


def mean_hue(hue: NDArray[np.floating]) -> float | None:
    """An image's mean hue: the angle of the mean unit vector over its finite pixels (rad, a
    circular mean); None where no pixel has a hue."""
    a = np.asarray(hue, np.float64)
    a = a[np.isfinite(a)]
    return float(np.angle(np.mean(np.exp(1j * a)))) if a.size else None


def flicker_from_means(means: list[list[float | None]], *, threshold_rad: float = FLICKER_THRESHOLD_RAD) -> ColourFlicker:
    """:func:`repeat_hue_flicker` from each repeat's image-mean hue (:func:`mean_hue`; None: no
    hue), per band: what a caller that already holds the images' means passes instead of the images."""
    sq, dof, worst, n_bands, n_rep = 0.0, 0, 0.0, 0, 0
    for reps in means:
        got = [m for m in reps if m is not None]
        if len(got) < 2:
            continue
        m = np.asarray(got, np.float64)
        dev = np.angle(np.exp(1j * (m - np.angle(np.mean(np.exp(1j * m))))))
        sq += float(np.sum(dev**2))
        dof += len(m) - 1
        worst = max(worst, float(np.max(np.abs(dev))))
        n_bands += 1
        n_rep = max(n_rep, len(m))
    if dof == 0:
        return ColourFlicker(None, None, 0, n_rep, False, float(threshold_rad))
    amp = float(np.sqrt(sq / dof))
    return ColourFlicker(amp, worst, n_bands, n_rep, bool(amp > threshold_rad), float(threshold_rad))


def repeat_hue_flicker(hues: list[list[NDArray[np.floating]]], *,
                       threshold_rad: float = FLICKER_THRESHOLD_RAD) -> ColourFlicker:
    """The spread between repeats of uniform hue bands' image-mean hue.

    Parameters
    ----------
    hues : list of list of ndarray (H, W)
        Per band, the hue (rad, NaN where undefined) of each repeat: white-balanced captures of one
        uniform band on the same surface.
    threshold_rad : float
        Spread above which a changing colour balance is reported (:data:`FLICKER_THRESHOLD_RAD`).

    Returns
    -------
    ColourFlicker
        ``amplitude_rad`` None when no band has two usable repeats.

    Notes
    -----
    Each repeat's image-mean hue is the angle of the mean unit vector over its finite pixels (a
    circular mean); the deviations from the band's circular mean over repeats are pooled into a
    standard deviation with ``sum (repeats - 1)`` degrees of freedom.
    """
    return flicker_from_means([[mean_hue(h) for h in reps] for reps in hues], threshold_rad=threshold_rad)
