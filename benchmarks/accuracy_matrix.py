"""Accuracy on a harder bench: every case through the whole chain, each correction on and off.

Usage: ./run python benchmarks/accuracy_matrix.py [--cases NAME ...] [--tuning | --holdout] [--texture] [--variants NAME ...] [--keep DIR]
       ./run python benchmarks/accuracy_matrix.py --cameras [--keep DIR]   (the camera cases, docs/accuracy-cameras.md)
       ./run python benchmarks/accuracy_matrix.py --noise [--tuning | --holdout] [--keep DIR]   (the noise cases, docs/noise.md)
       ./run python benchmarks/accuracy_matrix.py --sources --variants "all on" [--keep DIR]   (the tuning gauge with a quieter sensor, docs/accuracy.md)

Each case is a bench preset plus overrides (plain and pre-distorted projection, periods 20-64 px,
defocus 0.5-2 camera px, 64/96/256 bands x 1-3 repeats, per-channel gamma 1.8-2.5, crosstalk,
multi-colour coatings with dark ones, a relief printed with a real photograph, 8 and 16 bit,
vibration). Cases marked HOLD-OUT were never looked at while choosing the methods' settings:
they only score. Every case is measured with the workflow's stages (``hue_table`` once per case,
then ``plane_calibration`` and ``measure_frames`` per variant, as ``stages.measure_session``)
under the variants in ``VARIANTS``; errors are against the bench's ground truth (which only
scores), averaged over the frames; ``coverage`` is the valid fraction of the pixels where the
ground truth is defined (lit, unshadowed); gauge-block cases also print the worst step error
(um) and the mean |step error| (%) from ``metrology.evaluate_session``. About 10 min on a
shared 2-core machine (6.2 min tuning, 4.3 min hold-outs at load 6-9) for the cases whose names do not start with ``tex ``.

The colour-textured and freeform cases (names starting ``tex ``; ``--texture`` runs only
them, docs/accuracy-texture.md) add the texture-edge correction's variants, and every row gives
the fraction of valid pixels with ``|error| <= 2u`` overall and per zone (edge, texture, rest:
``zones``).

The camera cases (``--cameras``: single-chip Bayer, lateral chromatic aberration,
radial distortion, a pinhole camera at 300 mm) run their own variants, ``CAMERA_VARIANTS``: the
method's correction on and off through the config keys ``camera.chromatic_registration`` and
``camera.lens_model`` (and ``camera.demosaic`` on the Bayer cases: stored RGB or re-demosaiced). A variant whose key this build's config does not have is run as the
chain is (the correction is then absent, i.e. "off") or skipped with a note ("on"); a session
whose camera block this build's reader refuses is skipped with the reader's message. Sessions
with ``ground_truth/xy`` also score X, Y at the field's corners: the 95th percentile of the
distance between the true plate point and the method's X, Y (``huefringe.camera.CameraModel``)
over four 24 x 24 px corner patches.
"""

from __future__ import annotations

import argparse
import copy
import inspect
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
import yaml
from scipy import ndimage

from huefringe import bench, metrology, pipeline, stages
from huefringe.perframe import shadow_mask
from huefringe.camera import CameraModel
from huefringe.session import SessionError, load_session, read_rgb
from huefringe.settings import load_config
from huefringe.height import accuracy

REPO = Path(__file__).resolve().parents[1]


def _case(preset: str, holdout: bool = False, variants: tuple[str, ...] | None = None, **over: dict) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    for section, values in over.items():
        cfg[section].update(values)
    cfg = bench.validate_bench_config(cfg)
    return {"cfg": cfg, "holdout": holdout, "variants": variants}


#: the photographed reliefs and tooth (docs/accuracy-texture.md): one repeat, 16 bit, plain pattern
_TEX = {"period_px": 56, "hue_bands": 72, "repeats": 1, "bit_depth": 16, "frames": 2}
_TOOTH = {"period_px": 64, "hue_bands": 128, "repeats": 1, "bit_depth": 16, "frames": 2}

CASES = {
    # tuning set
    "flat p40 d1.6 96x2": _case("flat", session={"period_px": 40, "hue_bands": 96, "repeats": 2, "frames": 2},
                                projector={"defocus_sigma_px": 1.6}),
    "gauge plain p48 96x2 16bit": _case("plain_gauge"),
    "photo astronaut p48 96x2": _case("photo_relief"),
    "demo (pre-distorted) p60": _case("demo", session={"frames": 2}, phase_shift={"enabled": False}),
    # hold-out: only scores
    "flat p20 d0.5 256x1 8bit": _case("flat", True, session={"period_px": 20, "hue_bands": 256, "repeats": 1,
                                                             "frames": 2, "width": 320, "height": 240},
                                      projector={"defocus_sigma_px": 0.5, "gamma": [1.8, 2.5, 2.1]}),
    "gauge plain p64 d2.0 64x3 8bit": _case("plain_gauge", True, session={"period_px": 64, "hue_bands": 64, "repeats": 3,
                                                                            "bit_depth": 8, "seed": 99},
                                            projector={"defocus_sigma_px": 2.0, "gamma": [2.4, 1.9, 2.2]}),
    "photo coffee p40 d0.8 256x3": _case("photo_relief", True, session={"period_px": 40, "hue_bands": 256,
                                                                         "repeats": 3, "seed": 5},
                                         projector={"defocus_sigma_px": 0.8, "gamma": [2.5, 2.0, 1.8]},
                                         scene={"image": "coffee"}),
    "gauge pre-distorted p40 d1.2": _case("plain_gauge", True, session={"period_px": 40, "seed": 7},
                                          projector={"compensation": {"enabled": True}}),
    # colour-textured and freeform surfaces as others capture them (plain pattern, one
    # repeat, 16 bit). The hold-outs were fixed here before any setting was tuned.
    "tex astronaut p56 72x1": _case("photo_relief", session=_TEX),
    "tex chelsea p56 72x1": _case("photo_relief", session={**_TEX, "seed": 21}, scene={"image": "chelsea"}),
    "tex dental two-tone p64 128x1": _case("dental", session=_TOOTH, projector={"compensation": {"enabled": False}}),
    "tex gauge plain p40 96x2": _case("plain_gauge", session={"period_px": 40, "seed": 31}),
    "tex rocket p56 72x1": _case("photo_relief", True, session={**_TEX, "seed": 41}, scene={"image": "rocket"}),
    "tex immunohistochemistry p56 72x1": _case("photo_relief", True, session={**_TEX, "seed": 43},
                                               scene={"image": "immunohistochemistry"}),
    "tex coffee p48 72x1 blur1.1": _case("photo_relief", True, session={**_TEX, "period_px": 48, "seed": 45},
                                         camera={"lens_blur_sigma_px": 1.1}, scene={"image": "coffee"}),
    "tex dental two-tone p56 128x1 seed": _case("dental", True, session={**_TOOTH, "period_px": 56, "seed": 47},
                                                projector={"compensation": {"enabled": False}}),
    "tex gauge plain p56 72x1": _case("plain_gauge", True, session={"period_px": 56, "hue_bands": 72, "repeats": 1,
                                                                    "seed": 49}),
}

#: photo reliefs seen by the cameras labs own (read noise 2-30 e-, full wells 5,000-30,000 e-,
#: the photograph over the whole field), each with one and with two repeats (``--noise``,
#: docs/noise.md). The hold-outs were fixed here before any setting was tuned and score once.
NOISE_CASES = {
    "sensor astronaut 25e 10ke p56 72x1": _case("photo_sensor"),
    "sensor astronaut 25e 10ke p56 72x2": _case("photo_sensor", session={"repeats": 2}),
    "photo astronaut p48 96x2 (quiet bench)": _case("photo_relief"),
    "photo astronaut p48 96x1 (quiet bench)": _case("photo_relief", session={"repeats": 1}),
    # hold-out: only scores
    "sensor coffee 8e 5ke p48 72x1": _case("photo_sensor", True, session={"period_px": 48, "seed": 61},
                                           camera={"read_noise_e": 8, "full_well_e": 5000}, scene={"image": "coffee"}),
    "sensor coffee 8e 5ke p48 72x2": _case("photo_sensor", True, session={"period_px": 48, "seed": 61, "repeats": 2},
                                           camera={"read_noise_e": 8, "full_well_e": 5000}, scene={"image": "coffee"}),
    "sensor chelsea 30e 30ke p64 96x1": _case("photo_sensor", True, session={"period_px": 64, "hue_bands": 96, "seed": 62},
                                              camera={"read_noise_e": 30, "full_well_e": 30000}, scene={"image": "chelsea"}),
    "sensor chelsea 30e 30ke p64 96x2": _case("photo_sensor", True,
                                              session={"period_px": 64, "hue_bands": 96, "seed": 62, "repeats": 2},
                                              camera={"read_noise_e": 30, "full_well_e": 30000}, scene={"image": "chelsea"}),
    "sensor rocket 2e 20ke p56 72x1": _case("photo_sensor", True, session={"seed": 63},
                                            camera={"read_noise_e": 2, "full_well_e": 20000}, scene={"image": "rocket"}),
    "sensor rocket 2e 20ke p56 72x2": _case("photo_sensor", True, session={"seed": 63, "repeats": 2},
                                            camera={"read_noise_e": 2, "full_well_e": 20000}, scene={"image": "rocket"}),
}

#: the tuning gauge session with a quieter sensor, then without ambient and stray light as well,
#: and with no sensor noise at all (``--sources``, docs/accuracy.md "Gauge steps")
_QUIET = {"full_well_e": 1e6, "read_noise_dn": 0.08}
SOURCE_CASES = {
    "gauge plain p48 96x2 16bit": _case("plain_gauge"),
    "gauge plain p48 96x2 16bit, quiet sensor (1e6 e-, 0.08 DN)": _case("plain_gauge", camera=_QUIET),
    "gauge plain p48 96x2 16bit, quiet sensor, no ambient or stray light": _case(
        "plain_gauge", camera=_QUIET, light={"ambient": [0.0, 0.0, 0.0], "stray": [0.0, 0.0, 0.0]}),
    "gauge plain p48 96x2 16bit, no sensor noise (16-bit codes only)": _case(
        "plain_gauge", camera={"full_well_e": 1e9, "read_noise_dn": 0.0}),
}

_REG = ("registration off", "registration on")
_LENS = ("lens model ignored", "lens model used")
_CA = {"lateral_ca_px": [0.5, -0.5], "supersample": 2}
_DIST = {"distortion": [4e-6, 0.0, 0.0, 0.0, 0.0], "supersample": 2}  # telecentric, mm about the centre: 2 px at the corners
_DEM = ("demosaic stored", "demosaic lanczos")  # camera.demosaic: the driver's RGB as stored, or re-demosaiced
#: the cameras labs own (``--cameras``); each case runs its own variants
CAMERA_CASES = {
    # tuning set
    "bayer RGGB edge-aware p48": _case("bayer_gauge", variants=_DEM),
    "bayer RGGB bilinear p48": _case("bayer_gauge", variants=_DEM,
                                     camera={"sensor": {"kind": "bayer", "pattern": "RGGB", "demosaic": "bilinear"}}),
    "gauge p48 2x2 sub-samples (no CA)": _case("plain_gauge", variants=_REG, camera={"supersample": 2}),
    "gauge CA 0.5 px p48": _case("plain_gauge", variants=_REG, camera=_CA),
    "gauge distortion 2 px p48": _case("plain_gauge", variants=_LENS, camera=_DIST),
    "pinhole 300 mm p48": _case("pinhole_gauge", variants=_LENS),
    # hold-out: only scores
    "bayer GRBG edge-aware p64 8bit": _case("bayer_gauge", True, variants=_DEM,
                                            session={"period_px": 64, "bit_depth": 8, "seed": 23},
                                            camera={"sensor": {"kind": "bayer", "pattern": "GRBG", "demosaic": "edge_aware"}}),
    "gauge CA 0.3/0.2 px p40 8bit": _case("plain_gauge", True, variants=_REG,
                                          session={"period_px": 40, "bit_depth": 8, "seed": 31},
                                          camera={"lateral_ca_px": [-0.3, 0.2], "supersample": 2}),
    "gauge CA 0.6 px p64": _case("plain_gauge", True, variants=_REG, session={"period_px": 64, "seed": 32},
                                 camera={"lateral_ca_px": [0.6, -0.6], "supersample": 2}),
    "gauge distortion 4 px p40 + CA 0.4": _case("plain_gauge", True, variants=_LENS + _REG,
                                                session={"period_px": 40, "seed": 33},
                                                camera={"distortion": [-8e-6, 0.0, 1e-5, -1e-5, 0.0],
                                                        "lateral_ca_px": [0.4, -0.3], "supersample": 2}),
    # defined after the first two Bayer hold-outs had been seen (docs/accuracy-cameras.md, Bayer)
    "bayer GBRG edge-aware p56 8bit": _case("bayer_gauge", True, variants=_DEM,
                                            session={"period_px": 56, "bit_depth": 8, "seed": 57},
                                            camera={"sensor": {"kind": "bayer", "pattern": "GBRG", "demosaic": "edge_aware"}}),
    "bayer BGGR bilinear p40 blur 0.7": _case("bayer_gauge", True, variants=_DEM, session={"period_px": 40, "seed": 58},
                                              camera={"lens_blur_sigma_px": 0.7,
                                                      "sensor": {"kind": "bayer", "pattern": "BGGR", "demosaic": "bilinear"}}),
    "pinhole 300 mm p64 strong distortion bayer": _case(
        "pinhole_gauge", True, variants=_LENS + ("demosaic stored",), session={"period_px": 64, "seed": 34},
        camera={"distortion": [-0.35, 0.15, 2e-4, -1e-4, 0.0], "sensor": {"kind": "bayer", "pattern": "BGGR"}}),
}
#: the correction switches of the camera cases (the keys come with the method's camera corrections)
CAMERA_VARIANTS = {
    "registration off": {"camera": {"chromatic_registration": False}},
    "registration on": {"camera": {"chromatic_registration": True}},
    "lens model ignored": {"camera": {"lens_model": False}},
    "lens model used": {"camera": {"lens_model": True}},
    "demosaic stored": {"camera": {"demosaic": "stored"}},
    "demosaic lanczos": {"camera": {"demosaic": "lanczos"}},
}

#: name -> changes to config.yaml's calibration / measurement sections
VARIANTS = {
    "all on": {},
    "phase-error table off": {"calibration": {"phase_error": {"enabled": False}}},
    # the table's correction scaled to each pixel's fringe frequency (measurement.phase_error_frequency)
    "phase-error frequency": {"measurement": {"phase_error_frequency": True}},
    # the variants below apply the table without the leave-one-plane-out test (it decided "apply"
    # on every case of "all on"; skipping it saves its time)
    "edge mask off": {"calibration": {"phase_error": {"enabled": True}}, "measurement": {"edge_jump_mm": 0.0}},
    "adaptive filter off": {"calibration": {"phase_error": {"enabled": True}},
                            "measurement": {"denoise_adaptive": {"enabled": False}}},
    "round 1 (sharp table, no edge mask)": {"calibration": {"phase_error": {"enabled": True, "smooth_bins": 1.5}},
                                            "measurement": {"edge_jump_mm": 0.0}},
}
VARIANTS.update({
    # camera corrections (docs/design.md, the camera block): registration of lateral chromatic
    # aberration, and X, Y from the session's lens model; "off" = not estimated / telecentric u * pitch
    "chromatic registration off": {"camera": {"chromatic_registration": False}},
    "lens model off": {"camera": {"lens_model": False}},
    # the camera's colour crosstalk left in the captures (camera.colour_demixing, docs/accuracy.md)
    "colour demixing off": {"camera": {"colour_demixing": False}},
})
VARIANTS.update({
    # the texture-edge correction (huefringe.texture): the camera blur given, or none
    "texture blur 0.81 (true)": {"calibration": {"texture_blur_px2": 0.81}},
    "texture blur 0.81, edge mask off": {"calibration": {"texture_blur_px2": 0.81}, "measurement": {"edge_jump_mm": 0.0}},
    "texture blur 0.4": {"calibration": {"texture_blur_px2": 0.4}},
    "texture blur 0.6": {"calibration": {"texture_blur_px2": 0.6}},
    "texture blur 1.2": {"calibration": {"texture_blur_px2": 1.2}},
    "texture blur 1.6": {"calibration": {"texture_blur_px2": 1.6}},
    "texture blur auto (estimated)": {"calibration": {"texture_blur_px2": "auto"}},
    "texture correction off": {"calibration": {"texture_blur_px2": 0}},
    # the uncertainty's lateral term (docs/uncertainty.md): heights identical, u without it
    "lateral term off": {"measurement": {"lateral_uncertainty_px": 0.0, "lateral_step_px": 0.0}},
    "lateral 1.75 px, no step part": {"measurement": {"lateral_uncertainty_px": 1.75, "lateral_step_px": 0.0}},
    # the lateral term's step part (measurement.lateral_step_px, 2.0 by default) on a grid
    **{f"lateral step {r} px": {"measurement": {"lateral_step_px": r}} for r in (0.0, 1.0, 1.5)},
    "texture term off": {"measurement": {"texture_uncertainty": False}},
    # the phase filter's weights (docs/uncertainty.md, "The filter's weights"): the table's pooled
    # noise alone, each pixel's own signal as captured, or the signal smoothed along the fringe
    "weights pooled": {"measurement": {"weight_blur_px": 0.0}},
    "weights own unsmoothed": {"measurement": {"own_noise": True}},
    "weights along the fringe": {"measurement": {"weight_blur_shape": "along_fringe"}},
    # the same two with the lateral term off (noise_split.py --weights)
    "lateral term off, weights pooled": {"measurement": {"lateral_uncertainty_px": 0.0, "lateral_step_px": 0.0,
                                                         "weight_blur_px": 0.0}},
    "lateral term off, weights own unsmoothed": {"measurement": {"lateral_uncertainty_px": 0.0, "lateral_step_px": 0.0,
                                                                 "own_noise": True}},
    "lateral term off, weights along the fringe": {"measurement": {"lateral_uncertainty_px": 0.0, "lateral_step_px": 0.0,
                                                                   "weight_blur_shape": "along_fringe"}},
})
VARIANTS.update({
    # the step-edge test (measurement.edge_test; docs/accuracy-texture.md, Step-edge test)
    "edge test plane": {"measurement": {"edge_test": "plane"}},
    "edge test pair": {"measurement": {"edge_test": "pair"}},
    "edge test pair 0.15": {"measurement": {"edge_test": "pair", "edge_jump_mm": 0.15}},
    # the edge tests' thresholds from the heights' own noise, or the fixed ones alone (docs/noise.md)
    "edge noise k 0": {"measurement": {"edge_noise_k": 0.0}},
    "edge noise k 5": {"measurement": {"edge_noise_k": 5.0}},
    "shadow fraction 0.06": {"measurement": {"shadow_fraction": 0.06}},
    "shadow fraction 0.03": {"measurement": {"shadow_fraction": 0.03}},
})
VARIANTS.update({
    # photo reliefs' noise (docs/accuracy-texture.md): the adaptive phase filter's reach
    "target 0.006": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.006}}},
    "target 0.004": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.004}}},
    "target 0.003": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.003}}},
    "target 0.002": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.002}}},
    "target 0.0015": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.0015}}},
    "target 0.001": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.001}}},
    "target 0.002 max 9": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.002, "max_radius": 9}}},
    "target 0.004 max 9": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.004, "max_radius": 9}}},
    "target 0.003 max 9": {"measurement": {"denoise_adaptive": {"target_sigma_rad": 0.003, "max_radius": 9}}},
    "radius 3": {"measurement": {"denoise_radius": 3}},
    "radius 3 target 0.004": {"measurement": {"denoise_radius": 3, "denoise_adaptive": {"target_sigma_rad": 0.004}}},
    # the grown rings' plane kept on curved reliefs (docs/uncertainty.md, "The plane's kink test")
    "plane kink 10": {"measurement": {"denoise_adaptive": {"plane_kink_sigma": 10.0}}},
    # the grown windows' bias term where the plane lacked a probe (docs/uncertainty.md, "The grown windows' bias")
    "posterior bias": {"measurement": {"denoise_adaptive": {"lacking_probe_bias": "posterior"}}},
})
#: variants measured on some cases only, by words of the case name (the adaptive filter acts on
#: weak signal: the photo reliefs; the camera corrections on the cases with such a camera)
ONLY = {"shadow fraction 0.06": ("tex ",), "shadow fraction 0.03": ("tex ",), "adaptive filter off": ("photo",), **{v: ("photo", "tex ") for v in VARIANTS if v.startswith("texture ")},
        "chromatic registration off": ("CA", "chromatic", "lateral"),
        "lens model off": ("pinhole", "distortion", "lens")}


def _config(variant: dict) -> dict:
    cfg = load_config(REPO / "config.yaml")
    for section, values in variant.items():
        for k, v in values.items():
            cfg[section][k] = {**cfg[section].get(k, {}), **v} if isinstance(v, dict) else v
    return cfg


def _camera_variant(vname: str) -> tuple[dict | None, str]:
    """The config of a camera variant and its row label; ``None`` if this build cannot run it."""
    if vname in VARIANTS:
        return _config(VARIANTS[vname]), vname
    change = CAMERA_VARIANTS[vname]["camera"]
    base = load_config(REPO / "config.yaml")
    have = base.get("camera", {})
    missing = [k for k in change if k not in have]
    if not missing:
        return _config(CAMERA_VARIANTS[vname]), vname
    if not any(change[k] for k in missing):  # the build has no such correction: its chain is "off"
        return base, f"{vname} (no camera.{missing[0]} in this build: its chain as is)"
    return None, f"{vname}: SKIPPED, no camera.{missing[0]} in this build's config (the method's camera corrections)"


_LENS_KEYS = ("model", "matrix", "distortion", "plate_pose")


def _without_lens_block(session: Path, where: Path) -> Path:
    """A view of ``session`` whose session.yaml lacks the camera block's lens keys (the session
    itself is not touched: its folders are linked): what a reader that ignores the lens sees."""
    where.mkdir(parents=True, exist_ok=True)
    meta = yaml.safe_load((session / "session.yaml").read_text(encoding="utf-8"))
    for key in _LENS_KEYS:
        meta["camera"].pop(key, None)
    for p in session.iterdir():
        if p.name != "session.yaml" and not (where / p.name).exists():
            (where / p.name).symlink_to(p.resolve())
    (where / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    return where


def _with_camera(fn, kwargs: dict, config: dict) -> dict:
    """Pass the config's ``camera`` section to a stage that takes one (the camera corrections)."""
    if "camera" in config and "camera" in inspect.signature(fn).parameters:
        kwargs["camera"] = config["camera"]
    return kwargs


def xy_corner_error(paths: dict, config: dict) -> float | None:
    """95th percentile (mm) of |(X, Y) - truth| over four 24 x 24 px corner patches, or None
    without ``ground_truth/xy``. X, Y from the measured heights by ``huefringe.camera.CameraModel``
    (``camera.lens_model`` as configured)."""
    s = paths["session"]
    errs = []
    for n, hpath in zip(s.frame_ids, paths["heights"], strict=True):
        truth = s.root / "ground_truth" / "xy" / f"frame_{n:04d}.tiff"
        if not truth.is_file():
            return None
        gt = tifffile.imread(truth)
        h = tifffile.imread(hpath)
        model = CameraModel.from_meta(s.meta, lens_model=bool(config["camera"]["lens_model"]))
        x, y = model.xy(h)
        d = np.hypot(x - gt[..., 0], y - gt[..., 1])
        d[~np.isfinite(h)] = np.nan
        c = 24
        for patch in (d[:c, :c], d[:c, -c:], d[-c:, :c], d[-c:, -c:]):
            errs.append(patch[np.isfinite(patch)])
    allv = np.concatenate(errs)
    return float(np.percentile(allv, 95)) if allv.size else float("nan")


def zones(truth: np.ndarray, white: np.ndarray) -> dict[str, np.ndarray]:
    """benchmarks/uncertainty_validation.py's zones: "edge" within 3 px of a change of the true
    height by more than 0.1 mm, "texture" within 3 px of a reflectance change by more than 1.5 x in
    the white image (not edge), "rest" the others."""
    white = white.mean(axis=-1) if white.ndim == 3 else white
    jump = ndimage.maximum_filter(truth, 7) - ndimage.minimum_filter(truth, 7) > 0.1
    lw = np.log(np.maximum(white / max(white.max(), 1e-9), 1e-3))
    texture = (ndimage.maximum_filter(lw, 7) - ndimage.minimum_filter(lw, 7) > np.log(1.5)) & ~jump
    return {"edge": jump, "texture": texture, "rest": ~jump & ~texture}


def photo_region(cfg: dict, shape: tuple[int, int]) -> np.ndarray | None:
    """The pixels of a photo relief's printed rectangle (the field minus ``scene.margin_mm``), or
    None for other scenes: the textured region that ``--noise`` scores alone."""
    sc = cfg["scene"]
    if sc["kind"] != "photo_relief":
        return None
    m = int(round(float(sc["margin_mm"]) / float(cfg["session"]["pixel_pitch_mm"])))
    out = np.zeros(shape, bool)
    out[m:shape[0] - m, m:shape[1] - m] = True
    return out


def noise_score(paths: dict, region: np.ndarray | None, lit: np.ndarray) -> dict:
    """Median, p95 |error| and coverage on ``region`` (None: the whole field), the coverage of its
    ``lit`` pixels (those the hue table and the shadow mask leave: what noise handling can reach),
    and the fraction of valid pixels with ``|error| <= 2u`` in the region's dark and bright halves
    (split at the median white-image intensity of the region's pixels with a defined truth)."""
    s = paths["session"]
    maps = [tifffile.imread(h).astype(np.float64) for h in paths["heights"]]
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    us = [tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]]
    accs = [accuracy(m, t, region) for m, t in zip(maps, truths, strict=True)]
    out = {k: float(np.mean([a[k] for a in accs])) for k in ("median_abs_mm", "p95_abs_mm", "coverage")}
    out["coverage_lit"] = float(np.mean([accuracy(m, t, lit if region is None else lit & region)["coverage"]
                                         for m, t in zip(maps, truths, strict=True)]))
    level = np.asarray(read_rgb(s.object_white), np.float64).mean(axis=-1)
    where = np.isfinite(truths[0]) if region is None else np.isfinite(truths[0]) & region
    cut = float(np.median(level[where]))
    for half, sel in (("dark", where & (level < cut)), ("bright", where & (level >= cut))):
        e = np.concatenate([(m - t)[sel] for m, t in zip(maps, truths, strict=True)])
        uu = np.concatenate([u[sel] for u in us])
        ok = np.isfinite(e) & np.isfinite(uu)
        out[f"cov2u_{half}"] = float(np.mean(np.abs(e[ok]) <= 2 * uu[ok])) if ok.any() else float("nan")
    return out


def noise_cases(args: argparse.Namespace) -> None:
    """The noise cases (``NOISE_CASES``): "all on", scored on the whole field and on the
    photo region alone, with the 2u coverage of the dark and bright halves and the table's noise source."""
    names = [c for c in NOISE_CASES if c in args.cases or args.cases == list(CASES)]
    names = [c for c in names if not (args.tuning and NOISE_CASES[c]["holdout"])
             and not (args.holdout and not NOISE_CASES[c]["holdout"])]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        print("| case | set | field | median mm | p95 mm | coverage | coverage of lit | 2u dark | 2u bright | table noise |")
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
        for name in names:
            case = NOISE_CASES[name]
            slug = "noise-" + _slug(name)
            session, tables = _case_dirs(root / slug, case["cfg"])
            for vname in args.variants if args.variants != list(VARIANTS) else ["all on"]:
                paths = measure(session, tables, root / slug / _slug(vname), _config(VARIANTS[vname]))
                st = json.loads((paths["tables"] / "table_object.json").read_text())["stats"]["noise_rad"]
                src = f"{st.get('source', 'none (fallback 0.01)' if st.get('median') is None else 'repeats')}"
                shape = tifffile.imread(paths["heights"][0]).shape
                region = photo_region(case["cfg"], shape)
                with np.load(paths["tables"] / "table_object.maps.npz") as z:
                    m_cfg = _config(VARIANTS[vname])["measurement"]
                    lit = z["valid"] & ~shadow_mask(read_rgb(paths["session"].object_white), m_cfg["shadow_fraction"],
                                                    own_light=bool(m_cfg["shadow_own_light"]))
                for field, reg in (("whole", None), ("photo region", region)):
                    if field != "whole" and (reg is None or reg.all()):
                        continue
                    r = noise_score(paths, reg, lit)
                    label = field if vname == "all on" else f"{field}, {vname}"
                    print(f"| {name} | {'hold-out' if case['holdout'] else 'tuning'} | {label} | {r['median_abs_mm']:.4f} | "
                          f"{r['p95_abs_mm']:.4f} | {r['coverage']:.3f} | {r['coverage_lit']:.3f} | {r['cov2u_dark']:.3f} | {r['cov2u_bright']:.3f} "
                          f"| {src} |", flush=True)
            print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s so far -->", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


def score(paths: dict) -> dict:
    s = paths["session"]
    lens = pipeline.session_corrections(s, paths["camera"])[0]
    maps = [tifffile.imread(h) for h in paths["heights"]]
    accs = [accuracy(m, tifffile.imread(s.ground_truth[n])) for n, m in zip(s.frame_ids, maps, strict=True)]
    out = {k: float(np.mean([a[k] for a in accs])) for k in ("median_abs_mm", "p95_abs_mm", "coverage")}
    if paths.get("uncertainties"):  # |error| <= 2u over the valid pixels, and by zone
        truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
        us = [tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]]
        zs = zones(np.where(np.isfinite(truths[0]), truths[0], 0.0), np.asarray(read_rgb(s.object_white), np.float64))
        errs = [m.astype(np.float64) - t for m, t in zip(maps, truths, strict=True)]
        for zname, zm in {"all": None, **zs}.items():
            e = np.concatenate([(x if zm is None else x[zm]).ravel() for x in errs])
            uu = np.concatenate([(x if zm is None else x[zm]).ravel() for x in us])
            ok = np.isfinite(e) & np.isfinite(uu)
            out[f"cov2u_{zname}"] = float(np.mean(np.abs(e[ok]) <= 2 * uu[ok])) if ok.any() else float("nan")
    if s.ground_truth_xy:  # X, Y of the cloud points against the bench's truth, at the field's corners
        out["xy_corner_max_mm"] = stages.xy_block(s, lens, paths["heights"])["summary"]["corner_max_mm"]
    if s.specimen is not None:
        try:
            ev = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=max(s.planes_mm) - min(s.planes_mm),
                                            camera=lens)
        except metrology.MetrologyError as exc:
            print(f"  (steps not evaluated: {exc})")
            return out
        errs = [st["error_mm"] for st in ev["steps"]]
        out["step_worst_um"] = 1e3 * float(np.max(np.abs(errs)))
        out["step_mean_pct"] = float(np.mean([abs(st["error_pct"]) for st in ev["steps"]]))
    return out


def tables_dir(tables: Path, config: dict) -> Path:
    """The folder under a case's ``tables`` that holds the hue tables :func:`measure` reads for
    ``config``: they depend on the camera corrections they are read through (channel registration,
    colour demixing), one set per setting (tables of demixed bands decode raw frames 0.3-0.5 mm off
    at p95), so a case measured with several settings has several."""
    demix = config["camera"].get("colour_demixing", False)
    return tables / (f"registration-{config['camera']['chromatic_registration']}"
                     + ("" if demix is False or demix == "false" else f"-demixing-{demix}"))


def measure(session: Path, tables: Path, out: Path, config: dict) -> dict:
    """``stages.measure_session`` with the hue tables of ``tables`` (built once per case and camera
    setting, :func:`tables_dir`: the variants change only the plane calibration and the per-frame
    chain). Returns the session, the height and uncertainty maps, the camera record and the tables'
    folder."""
    out.mkdir(parents=True, exist_ok=True)
    s = load_session(session)
    model, cal = config["hue_model"], config["calibration"]
    cam = str(out / "camera.json")
    stages.camera_calibration(str(session), config["camera"], cal, record=cam)
    tables = tables_dir(tables, config)
    tables.mkdir(parents=True, exist_ok=True)
    for which in ("reference", "object"):
        if not (tables / f"table_{which}.json").exists():
            stages.hue_table(str(session), which, model, cal, table=str(tables / f"table_{which}.json"),
                             stats=str(tables / f"table_{which}.stats.json"), camera_json=cam)
    stages.plane_calibration(str(session), str(tables / "table_reference.json"), model, cal,
                             model=str(out / "model.npz"), stats=str(out / "planes.json"),
                             phase_error_summary=str(out / "phase_error.json"), camera_json=cam,
                             object_table=str(tables / "table_object.json"))
    heights = [str(out / f"frame_{n:04d}.tiff") for n in s.frame_ids]
    us = [h.replace(".tiff", ".u.tiff") for h in heights]
    stages.measure_frames(str(session), s.frame_ids, str(tables / "table_object.json"), str(out / "model.npz"), model,
                          config["measurement"], cal, heights=heights, qa=[h.replace(".tiff", ".json") for h in heights],
                          map_frames=[], camera_json=cam, uncertainties=us)
    return {"session": s, "heights": heights, "camera": cam, "uncertainties": us, "tables": tables}


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in name)


def _case_dirs(where: Path, cfg: dict) -> tuple[Path, Path]:
    """The case's bench session (written unless ``--keep`` already holds it) and its tables folder."""
    session = where / "session"
    if not (session / "session.yaml").exists():
        bench.write_session(cfg, session)
    tables = where / "tables"
    tables.mkdir(parents=True, exist_ok=True)
    return session, tables


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--tuning", action="store_true", help="the tuning cases only (no hold-out)")
    ap.add_argument("--holdout", action="store_true", help="the hold-out cases only")
    ap.add_argument("--texture", action="store_true", help="the colour-textured and freeform cases only (names starting 'tex ')")
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS))
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    ap.add_argument("--cameras", action="store_true", help="the camera cases instead of the method's")
    ap.add_argument("--noise", action="store_true", help="the noise cases instead of the method's")
    ap.add_argument("--sources", action="store_true",
                    help="the tuning gauge session with a quieter sensor, without ambient and stray light, without noise")
    args = ap.parse_args()
    if args.noise:
        noise_cases(args)
        return
    if args.cameras:
        cameras(args)
        return
    pool = SOURCE_CASES if args.sources else CASES
    names = list(pool) if args.sources and args.cases == list(CASES) else args.cases
    cases = [c for c in names if not (args.tuning and pool[c]["holdout"])
             and not (args.holdout and not pool[c]["holdout"]) and not (args.texture and not c.startswith("tex "))]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        print("| case | set | variant | median mm | p95 mm | coverage | worst step um | mean step % "
              "| 2u all | 2u edge | 2u texture | 2u rest |")
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for name in cases:
            case = pool[name]
            slug = _slug(name)
            session, tables = _case_dirs(root / slug, case["cfg"])
            for vname in args.variants:
                if vname in ONLY and not any(word in name for word in ONLY[vname]):
                    continue
                out = root / slug / "".join(c if c.isalnum() else "-" for c in vname)
                r = score(measure(session, tables, out, _config(VARIANTS[vname])))
                pe = json.loads((out / "phase_error.json").read_text())
                if vname == "all on" and not pe["applied"]:
                    name_v = f"{vname} (table not applied: hold-out planes)"
                else:
                    name_v = vname
                steps = (f"{r['step_worst_um']:.1f} | {r['step_mean_pct']:.2f}" if "step_worst_um" in r else "- | -")
                if "xy_corner_max_mm" in r:
                    steps += f" (X, Y at the corners: max {r['xy_corner_max_mm']:.3f} mm)"
                cov2u = " | ".join(f"{r[f'cov2u_{z}']:.3f}" for z in ("all", "edge", "texture", "rest"))
                print(f"| {name} | {'hold-out' if case['holdout'] else 'tuning'} | {name_v} | {r['median_abs_mm']:.4f} | "
                      f"{r['p95_abs_mm']:.4f} | {r['coverage']:.3f} | {steps} | {cov2u} |", flush=True)
            print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s so far -->", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


def cameras(args: argparse.Namespace) -> None:
    """The camera cases: each with its own variants (``CAMERA_CASES``)."""
    names = [c for c in CAMERA_CASES if c in args.cases or args.cases == list(CASES)]
    names = [c for c in names if not (args.tuning and CAMERA_CASES[c]["holdout"])
             and not (args.holdout and not CAMERA_CASES[c]["holdout"])]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        print("| case | set | variant | median mm | p95 mm | coverage | worst step um | mean step % | corner XY p95 mm |")
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
        for name in names:
            case = CAMERA_CASES[name]
            slug = "cam-" + _slug(name)
            session, tables = _case_dirs(root / slug, case["cfg"])
            kind = "hold-out" if case["holdout"] else "tuning"
            for vname in case["variants"]:
                config, label = _camera_variant(vname)
                if config is None:
                    print(f"| {name} | {kind} | {label} | - | - | - | - | - | - |", flush=True)
                    continue
                vslug = "".join(c if c.isalnum() else "-" for c in label)[:60]
                tdir = tables / vslug if "camera" in config else tables
                tdir.mkdir(parents=True, exist_ok=True)
                try:
                    paths = measure(session, tdir, root / slug / vslug, config)
                except SessionError as exc:
                    if vname != "lens model ignored":
                        print(f"| {name} | {kind} | {vname}: SKIPPED, this build's reader refuses the session "
                              f"({str(exc).splitlines()[0][-100:]}) | - | - | - | - | - | - |", flush=True)
                        continue
                    # this build has no lens model: read the session as if its lens block were absent
                    view = _without_lens_block(session, root / slug / "session-without-lens-block")
                    label = f"{vname} (this build: session read without its lens block)"
                    ttab = tables / "without-lens-block"
                    ttab.mkdir(parents=True, exist_ok=True)
                    paths = measure(view, ttab, root / slug / "without-lens-block", config)
                r = score(paths)
                xy = xy_corner_error(paths, config)
                steps = (f"{r['step_worst_um']:.1f} | {r['step_mean_pct']:.2f}" if "step_worst_um" in r else "- | -")
                print(f"| {name} | {kind} | {label} | {r['median_abs_mm']:.4f} | {r['p95_abs_mm']:.4f} | "
                      f"{r['coverage']:.3f} | {steps} | {'-' if xy is None else f'{xy:.3f}'} |", flush=True)
            print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s so far -->", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
