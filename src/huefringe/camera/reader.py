"""The camera corrections applied: :class:`CaptureReader` (re-demosaic, demixing, channel
registration) and the ``calib/camera.json`` record that decides them (:func:`camera_record`,
:func:`corrections`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.colour import any_channel_at_least
from huefringe.session import read_rgb, read_rgb_codes
from huefringe.camera.bayer import BayerResampling, bayer_resampling
from huefringe.camera.crosstalk import estimate_channel_mixing
from huefringe.camera.model import CameraModel
from huefringe.camera.lateral import CA_AUTO_MIN_REACH, CA_AUTO_THRESHOLD_PX, ChannelRegistration, estimate_lateral_ca


DEMIX_AUTO_THRESHOLD = 0.01
"""``camera.colour_demixing: auto`` demixes when the largest off-diagonal of the estimated
crosstalk matrix (columns scaled to a unit diagonal) exceeds this: 1 % of a channel's light read
by another channel (the bench's camera: 2-10 %; a camera without crosstalk reads 0.000-0.003)."""

DEMIX_MAX_SEGMENT_SPREAD = 0.01
"""``auto`` also needs the estimate's leave-out check (:func:`segment_check`) to agree: the columns
that each primary's rising and falling ramp segment give alone may differ by at most this in any
entry (the smallest crosstalk worth undoing). Bench sessions from 16 bands x 1 repeat, 8 bit, at
160 x 120 px upwards read 4e-5 - 7.1e-4 (docs/accuracy.md); a spread beyond it means the
bands do not show one fixed linear mixing (a camera's auto exposure drifting 0.2 % a band reads
0.014), and the estimate is not used."""


class CaptureReader:
    """Reads a session's captures as the per-frame chains see them: through the camera corrections.

    ``codes(path)`` gives the sensor codes (what :func:`huefringe.session.read_rgb_codes` reads,
    re-demosaiced first when a :class:`BayerResampling` is set, then registered when a
    :class:`ChannelRegistration` is set); ``rgb(path)`` the same scaled to
    float32 [0, 1] exactly as :func:`huefringe.session.read_rgb` scales it. Without corrections
    both are the session reader's own functions (byte-identical outputs for plain sessions).

    With a ``demix`` matrix (the inverse of the camera's colour crosstalk, :func:`estimate_channel_mixing`)
    ``rgb`` returns ``demix @ rgb`` per pixel: each channel then holds the light of its own
    projector channel only, so that white balance cancels the surface colour (paper eqs. 7-8) on
    coloured coatings as on the plate. A pixel with a channel at full scale keeps its clipped
    values (the chains' clipping test still sees it). ``demixed`` tells the chains to read ``rgb``.
    """

    def __init__(self, registration: ChannelRegistration | None = None, bayer: BayerResampling | None = None,
                 demix: ArrayLike | None = None):
        self.registration = registration
        self.bayer = bayer
        self.demix = None if demix is None else np.asarray(demix, np.float32).reshape(3, 3)

    @property
    def demixed(self) -> bool:
        """Whether :meth:`rgb` demixes the channels (the sensor codes then are not what the chains read)."""
        return self.demix is not None

    def codes(self, path: Any) -> NDArray:
        data = read_rgb_codes(path)
        if self.bayer is not None:
            data = self.bayer.apply(data)
        return data if self.registration is None else self.registration.apply(data)

    def rgb(self, path: Any) -> NDArray[np.float32]:
        if self.registration is None and self.bayer is None and self.demix is None:
            return read_rgb(path)
        data = self.codes(path)
        top = 255 if data.dtype == np.uint8 else 65535
        out = data.astype(np.float32) * np.float32(1.0 / top)
        if self.demix is None:
            return out
        mixed = cv2.transform(np.ascontiguousarray(out), self.demix).astype(np.float32, copy=False)
        clipped = any_channel_at_least(data, top)
        mixed[clipped] = out[clipped]  # a clipped pixel keeps its codes (the demixing needs them all)
        return mixed


def demixing_record(setting: Any, mixing: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``colour_demixing`` entry of ``calib/camera.json`` (``camera.colour_demixing``).

    ``mixing`` is :func:`estimate_channel_mixing`'s record (the camera's response to each projector
    primary, columns scaled to a unit diagonal). ``auto`` applies its inverse when the largest
    off-diagonal exceeds :data:`DEMIX_AUTO_THRESHOLD` and the estimate passes its leave-out check
    (the two ramp segments of every primary agree within :data:`DEMIX_MAX_SEGMENT_SPREAD`;
    ``not_applied_because`` says why not); ``true`` always (when estimable); ``false`` never (also
    when no mixing was estimated). When applied: ``demix`` (the inverse) and ``noise_gain`` (the
    norm of each of its rows: a demixed channel's noise against equal white noise in R, G, B).
    """
    rec: dict[str, Any] = {"setting": setting, "applied": False}
    if setting is False or setting == "false" or mixing is None:
        return rec
    m = np.asarray(mixing["matrix"], np.float64)
    off = float(np.abs(m - np.diag(np.diag(m))).max())
    est = {"matrix": m.tolist(), "max_offdiagonal": off, "estimable": bool(mixing.get("estimable"))}
    if not mixing.get("estimable"):
        est["why"] = mixing.get("why")
    spread = mixing.get("max_segment_spread")
    est["segment_spread"] = mixing.get("segment_spread")
    est["max_segment_spread"] = spread
    forced = setting is True or setting == "true"
    reliable = spread is not None and spread <= DEMIX_MAX_SEGMENT_SPREAD
    applied = bool(mixing.get("estimable")) and (forced or (off > DEMIX_AUTO_THRESHOLD and reliable))
    rec.update(applied=applied, threshold=DEMIX_AUTO_THRESHOLD, max_segment_spread=DEMIX_MAX_SEGMENT_SPREAD,
               estimate=est)
    if mixing.get("estimable") and not forced and off > DEMIX_AUTO_THRESHOLD and not reliable:
        rec["not_applied_because"] = (
            "the leave-out check has no second ramp segment for every primary (fewer than 12 hue bands)"
            if spread is None else
            f"the leave-out check failed: the rising and the falling ramp segments give columns differing by "
            f"{spread:.4f} (limit {DEMIX_MAX_SEGMENT_SPREAD}): the bands do not show one fixed linear channel mixing")
    if applied:
        demix = np.linalg.inv(m)
        rec["demix"] = demix.tolist()
        # each demixed channel's noise against the camera channel's (white, equal noise in R, G, B)
        rec["noise_gain"] = [float(x) for x in np.sqrt((demix ** 2).sum(axis=1))]
    return rec


def camera_record(meta: Mapping[str, Any], settings: Mapping[str, Any], planes: Sequence[NDArray[np.floating]],
                  white: NDArray[np.floating], shadow: NDArray[np.bool_] | None = None,
                  bands: Mapping[int, NDArray[np.floating]] | None = None) -> dict[str, Any]:
    """The results' ``calib/camera.json``: the lens model used for X, Y, the re-demosaic, the
    channel registration and the colour demixing.

    Parameters
    ----------
    meta : mapping
        The session's checked ``session.yaml``.
    settings : mapping
        The config block ``camera`` (``lens_model``, ``chromatic_registration``, ``colour_demixing``).
    planes, white
        The reference planes' captures and the reference white (float [0, 1]) for the estimate
        (read through the record's re-demosaic, :func:`demosaic_record`).
    bands : mapping of band index to image, optional
        The reference hue bands :func:`mixing_band_pairs` names (float [0, 1], repeats averaged,
        read as the planes are): the camera's channel mixing (:func:`estimate_channel_mixing`), in
        which the magnification is estimated and undone and whose inverse demixes every capture
        (:func:`demixing_record`). Without them neither.
    """
    lens = bool(settings["lens_model"])
    mode = settings["chromatic_registration"]
    model = CameraModel.from_meta(meta, lens_model=True)
    used = model if lens else CameraModel.from_meta(meta, lens_model=False)
    rec: dict[str, Any] = {"lens_model": lens, "xy_model": used.describe(),
                           "chromatic_registration": {"setting": mode, "applied": False}}
    rec["demosaic"] = demosaic_record(meta, settings)
    mixing = (estimate_channel_mixing(bands, int(meta["pattern"]["hue_bands"]), shadow=shadow) if bands
              else {"matrix": np.eye(3).tolist(), "estimable": False, "why": "no hue bands given"})
    rec["colour_demixing"] = demixing_record(settings["colour_demixing"], mixing if bands else None)
    if mode is False or mode == "false":
        return rec
    est = estimate_lateral_ca(planes, white, float(meta["pattern"]["period_px"]), model.centre, shadow=shadow,
                              mixing=mixing["matrix"] if mixing["estimable"] else None)
    est["mixing"] = mixing
    worst = max(est["corner_displacement_px"].values())
    reach = est["fit_reach_u_px"] / max(est["field_reach_u_px"], 1e-9)
    forced = mode is True or mode == "true"
    applied = forced or (worst > CA_AUTO_THRESHOLD_PX and reach >= CA_AUTO_MIN_REACH)
    rec["chromatic_registration"].update(applied=bool(applied), threshold_px=CA_AUTO_THRESHOLD_PX,
                                         min_reach=CA_AUTO_MIN_REACH, reach=float(reach), estimate=est)
    if not forced and worst > CA_AUTO_THRESHOLD_PX and reach < CA_AUTO_MIN_REACH:
        rec["chromatic_registration"]["not_applied_because"] = (
            f"the estimate reads pixels out to {reach:.2f} of the field's half-width along u only (needs {CA_AUTO_MIN_REACH}): "
            "too small a field for the fringe period to tell a magnification")
    return rec


def corrections(record: Mapping[str, Any] | None, meta: Mapping[str, Any]) -> tuple[CameraModel, CaptureReader]:
    """The X, Y model and the capture reader a ``camera.json`` record (:func:`camera_record`)
    asks for; without one (None): the session's lens model and no registration."""
    if record is None:
        return CameraModel.from_meta(meta), CaptureReader(bayer=bayer_resampling(meta))
    model = CameraModel.from_meta(meta, lens_model=bool(record.get("lens_model", True)))
    dem = record.get("demosaic") or {}
    bayer = BayerResampling(dem["pattern"], dem["method"]) if dem.get("applied") else None
    mix = record.get("colour_demixing") or {}
    demix = mix.get("demix") if mix.get("applied") else None
    reg = record.get("chromatic_registration") or {}
    if not reg.get("applied"):
        return model, CaptureReader(bayer=bayer, demix=demix)
    est = reg["estimate"]
    reg_mix = est.get("mixing") or {}  # records before the mixing estimate: the camera channels registered
    mixing = tuple(tuple(float(x) for x in row) for row in reg_mix["matrix"]) if reg_mix.get("estimable") else None
    return model, CaptureReader(ChannelRegistration(tuple(est["centre"]), float(est["scale"]["R"]),
                                                    float(est["scale"]["B"]), mixing), bayer=bayer, demix=demix)


def demosaic_record(meta: Mapping[str, Any], settings: Mapping[str, Any]) -> dict[str, Any]:
    """The ``demosaic`` entry of ``calib/camera.json``: the session's Bayer pattern (``camera.bayer``,
    None for a three-chip camera), the setting (config ``camera.demosaic``) and whether the
    stored RGB is re-demosaiced (``applied``, with ``method``)."""
    setting = settings["demosaic"]
    res = bayer_resampling(meta, setting)
    out: dict[str, Any] = {"bayer": meta.get("camera", meta).get("bayer"), "setting": setting, "applied": res is not None}
    if res is not None:
        out.update(res.describe())
    return out
