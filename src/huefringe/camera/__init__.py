"""Camera corrections: turn a stored capture into the RGB image both per-frame chains read.

This package sits just above :mod:`huefringe.session` in the layers; its topic modules are
:mod:`~huefringe.camera.bayer`, :mod:`~huefringe.camera.model`, :mod:`~huefringe.camera.crosstalk`,
:mod:`~huefringe.camera.lateral` and :mod:`~huefringe.camera.reader`, whose public names are
importable from here. It holds what depends on the camera a lab owns rather than on the method:
demosaicing of single-chip Bayer captures
(OpenCV's edge-aware demosaic, and :class:`BayerResampling`, which re-demosaics a driver's RGB
from its native photosite values with band-limited interpolation), lens undistortion, channel
registration for lateral chromatic aberration and the pixel-to-X/Y model.

Bayer patterns are named in sensor order, the colour of the photosites of the top-left 2 x 2
block read row by row: ``RGGB`` has red at (row 0, column 0), green at (0, 1) and (1, 0), blue
at (1, 1).
"""

from __future__ import annotations

from huefringe.camera.bayer import (
    BAYER_PATTERNS, BayerResampling, DEMOSAIC_METHODS, RESAMPLE_SETTINGS, bayer_channel_map, bayer_problem,
    bayer_resampling, demosaic, lanczos_demosaic, mosaic,
)
from huefringe.camera.model import CAMERA_MODELS, CameraModel, DISTORTION_LENGTHS
from huefringe.camera.crosstalk import (
    CA_MIXING_MAX_OFF_DIAGONAL, estimate_channel_mixing, mixing_band_pairs, segment_check,
)
from huefringe.camera.lateral import (
    CA_AUTO_MIN_REACH, CA_AUTO_THRESHOLD_PX, CA_MIN_PIXELS, ChannelRegistration, estimate_lateral_ca,
)
from huefringe.camera.reader import (
    CaptureReader, DEMIX_AUTO_THRESHOLD, DEMIX_MAX_SEGMENT_SPREAD, camera_record, corrections,
    demixing_record, demosaic_record,
)
