"""Bench scenes: objects standing on the reference plate.

A scene answers one question: at plate coordinates ``(X, Y)`` (regular 2-D grids, rows = Y),
what are the object's height, height gradient and RGB reflectance, and is the object there at
all (``mask``)? Where the mask is False the bare reference plate (``z = 0``) is seen. The
object moves rigidly (vibration) by re-sampling the scene at ``X - dx`` and adding ``dz`` on
the mask; the plate never moves.

Kinds (``scene.kind`` in the bench YAML): ``flat`` (paper Fig. 7), ``gauge_blocks`` (Fig. 9;
``blocks: table1`` for the Table 1 experiment), ``dental`` (Fig. 10), ``heightmap`` (a TIFF in mm)
``mesh`` (STL/PLY/OBJ ray cast straight down with Open3D) and ``photo_relief`` (a smooth relief
whose reflectance is a real photograph from ``skimage.data``, dark parts included).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .radiometry import rgb3

__all__ = [
    "Block",
    "DentalScene",
    "FlatScene",
    "GaugeBlocksScene",
    "HeightmapScene",
    "MeshScene",
    "PhotoReliefScene",
    "Scene",
    "SceneSample",
    "build_scene",
    "smooth_field",
]

F64 = NDArray[np.float64]


@dataclass
class SceneSample:
    """A scene sampled on a grid (object at rest, plate not included)."""

    height: F64
    grad_x: F64
    grad_y: F64
    reflectance: F64  # (..., 3)
    mask: NDArray[np.bool_]


class Scene(Protocol):
    """Anything that can be sampled on a regular plate grid."""

    def sample(self, x: F64, y: F64) -> SceneSample:
        """Sample the object at plate coordinates ``x``, ``y`` (2-D meshgrid arrays, mm)."""
        ...


def _grid_gradient(h: F64, x: F64, y: F64) -> tuple[F64, F64]:
    """Central-difference gradient of a field sampled on a regular meshgrid."""
    gx = np.gradient(h, x[0, 1] - x[0, 0], axis=1) if h.shape[1] > 1 else np.zeros_like(h)
    gy = np.gradient(h, y[1, 0] - y[0, 0], axis=0) if h.shape[0] > 1 else np.zeros_like(h)
    return gx, gy


def smooth_field(x: F64, y: F64, seed: int, wavelength_mm: float, n_waves: int = 12) -> F64:
    """A smooth pseudo-random field of unit standard deviation, defined at any ``(x, y)``.

    A sum of ``n_waves`` plane cosines with random directions, wavelengths in
    ``[wavelength/2, 2 wavelength]`` and phases, drawn from ``numpy.random.default_rng(seed)``.
    Because it is analytic, a rigidly moved object keeps its texture.
    """
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.0, np.pi, n_waves)
    lam = wavelength_mm * 2.0 ** rng.uniform(-1.0, 1.0, n_waves)
    phase = rng.uniform(0.0, 2.0 * np.pi, n_waves)
    out = np.zeros(np.broadcast_shapes(np.shape(x), np.shape(y)))
    for t, wl, ph in zip(theta, lam, phase, strict=True):
        out += np.cos(2.0 * np.pi * (x * np.cos(t) + y * np.sin(t)) / wl + ph)
    return out * np.sqrt(2.0 / n_waves)


def _in_rect(x: F64, y: F64, rect: tuple[float, float, float, float]) -> NDArray[np.bool_]:
    x0, y0, x1, y1 = rect
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


# --------------------------------------------------------------------------------------------
@dataclass
class FlatScene:
    """A flat board of uniform colour (paper Fig. 7), optionally covering only ``extent_mm``."""

    height_mm: float
    reflectance: F64
    extent_mm: tuple[float, float, float, float] | None = None

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        mask = np.ones(x.shape, bool) if self.extent_mm is None else _in_rect(x, y, self.extent_mm)
        h = np.where(mask, self.height_mm, 0.0)
        z = np.zeros_like(h)
        refl = np.broadcast_to(self.reflectance, x.shape + (3,)).copy()
        return SceneSample(h, z, z.copy(), refl, mask)


@dataclass(frozen=True)
class Block:
    """One gauge block: top at ``base + nominal_mm`` over the plate rectangle ``rect_mm``."""

    name: str
    nominal_mm: float
    reflectance: tuple[float, float, float]
    rect_mm: tuple[float, float, float, float]


#: coating reflectances of the paper's colour-coated ceramic gauge blocks
BLOCK_COLOURS: dict[str, tuple[float, float, float]] = {
    "green": (0.12, 0.65, 0.18),
    "blue": (0.10, 0.22, 0.70),
    "red": (0.72, 0.13, 0.11),
}


def _snap(v: float, pitch: float) -> float:
    """Snap a coordinate to the nearest pixel boundary ``(k + 1/2) pitch``."""
    return (np.round(v / pitch - 0.5) + 0.5) * pitch


def block_layout(name: str, width_mm: float, height_mm: float, pitch_mm: float) -> list[Block]:
    """Named block layouts scaled to the field: ``fig9`` (three blocks) or ``table1`` (one).

    Block edges are snapped to pixel boundaries so that no camera pixel straddles an edge when
    the object is at rest.
    """
    bw, bh = 0.16 * width_mm, 0.55 * height_mm
    if name == "fig9":
        spec = [("green", 3.0, 0.2), ("blue", 1.0, 0.5), ("red", 4.0, 0.8)]
    elif name == "table1":
        spec = [("blue", 1.0, 0.5)]
    else:
        raise ValueError(f"unknown block layout {name!r}")
    cy = 0.5 * height_mm
    blocks = []
    for colour, nominal, fx in spec:
        cx = fx * width_mm
        rect = tuple(
            float(_snap(v, pitch_mm)) for v in (cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2)
        )
        blocks.append(Block(colour, nominal, BLOCK_COLOURS[colour], rect))  # type: ignore[arg-type]
    return blocks


@dataclass
class GaugeBlocksScene:
    """Colour-coated gauge blocks standing on a thin base plate (the vibrating membrane)."""

    blocks: list[Block]
    base_rect_mm: tuple[float, float, float, float]
    base_thickness_mm: float
    base_reflectance: F64
    reflectance_variation: float = 0.0
    seed: int = 0

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        base = _in_rect(x, y, self.base_rect_mm)
        h = np.where(base, self.base_thickness_mm, 0.0)
        refl = np.broadcast_to(self.base_reflectance, x.shape + (3,)).copy()
        mask = base.copy()
        for blk in self.blocks:
            inside = _in_rect(x, y, blk.rect_mm)
            h[inside] = self.base_thickness_mm + blk.nominal_mm
            refl[inside] = blk.reflectance
            mask |= inside
        if self.reflectance_variation > 0.0:
            refl *= 1.0 + self.reflectance_variation * smooth_field(x, y, self.seed, 15.0)[..., None]
            np.clip(refl, 0.0, 1.0, out=refl)
        z = np.zeros_like(h)  # piecewise flat: the vertical walls are invisible to the camera
        return SceneSample(h, z, z.copy(), refl, mask)


# --------------------------------------------------------------------------------------------
@dataclass
class DentalScene:
    """A dental-model-like freeform: tooth-like crowns on a gum ridge along a U-shaped arch.

    The arch is ``x = cx + a sin t``, ``y = y_front + b (1 - cos t)``, ``|t| <= 1.45``. The gum is
    a ridge of height ``gum_height_mm`` with a flat crest and smooth flanks along the arch; each
    tooth is a super-elliptic crown with a flat-ish top and smooth (C1) flanks, incisors narrow,
    molars wide with a central fissure. Reflectance blends pink gum into ivory teeth with a smooth
    colour variation. Everything is an analytic function of (X, Y), so the scene can move.
    """

    width_mm: float
    height_mm: float
    teeth: int = 14
    gum_height_mm: float = 2.5
    tooth_height_mm: float = 2.5
    arch_size: float = 0.8
    tooth_reflectance: F64 = field(default_factory=lambda: np.array([0.86, 0.80, 0.64]))
    gum_reflectance: F64 = field(default_factory=lambda: np.array([0.82, 0.42, 0.46]))
    colour_variation: float = 0.08
    seed: int = 0

    def __post_init__(self) -> None:
        t = np.linspace(-1.45, 1.45, 2001)
        a = 0.5 * self.arch_size * self.width_mm * 0.8
        b = self.arch_size * self.height_mm * 0.9 / (1.0 - np.cos(1.45))
        cx = 0.5 * self.width_mm
        y_front = 0.5 * self.height_mm - 0.5 * b * (1.0 - np.cos(1.45))
        self._curve = np.column_stack([cx + a * np.sin(t), y_front + b * (1.0 - np.cos(t))])
        seg = np.hypot(*np.diff(self._curve, axis=0).T)
        self._arc = np.concatenate([[0.0], np.cumsum(seg)])
        length = self._arc[-1]
        self._scale = min(self.width_mm / 80.0, self.height_mm / 60.0) * self.arch_size / 0.8
        # relative tooth widths from the midline outwards: incisors, canine, premolars, molars
        side = self.teeth // 2
        widths = np.array([0.85, 0.68, 0.80, 0.72, 0.72, 1.05, 1.0, 0.95])[:side]
        mid = [0.8] if self.teeth % 2 else []
        full = np.concatenate([widths[::-1], mid, widths])
        scale = 0.97 * length / full.sum()
        edges = np.concatenate([[0.0], np.cumsum(full * scale)]) + 0.015 * length
        self._tooth_centre = 0.5 * (edges[:-1] + edges[1:])
        self._tooth_half_len = 0.58 * full * scale
        rank = np.abs(np.arange(len(full)) - (len(full) - 1) / 2.0)  # 0 at the midline
        self._tooth_half_wid = np.interp(rank, [0.0, max(side - 1.0, 1.0)], [3.0, 5.0]) * self._scale
        self._tooth_molar = rank >= max(side - 3.5, 0.0)
        canine = np.isclose(rank, 1.5) | np.isclose(rank, 2.0)
        self._tooth_h = self.tooth_height_mm * np.where(canine, 1.1, 1.0)

    @staticmethod
    def _smoothstep(v: F64) -> F64:
        v = np.clip(v, 0.0, 1.0)
        return v * v * (3.0 - 2.0 * v)

    def _height_parts(self, x: F64, y: F64) -> tuple[F64, F64]:
        from scipy.spatial import cKDTree

        pts = np.column_stack([x.ravel(), y.ravel()])
        dist, idx = cKDTree(self._curve).query(pts)
        d = dist.reshape(x.shape)
        s = self._arc[idx].reshape(x.shape)
        # gum: flat crest of half-width 5 mm, flanks falling to the plate over 4 mm
        gum = self.gum_height_mm * self._smoothstep((9.0 * self._scale - d) / (4.0 * self._scale))
        teeth = np.zeros_like(d)
        for c, hl, hw, hh, molar in zip(
            self._tooth_centre, self._tooth_half_len, self._tooth_half_wid, self._tooth_h, self._tooth_molar, strict=True
        ):
            ds = (s - c) / hl
            dd = d / hw
            near = (np.abs(ds) < 1.0) & (dd < 1.0)
            if not near.any():
                continue
            rho = (np.abs(ds[near]) ** 2.5 + dd[near] ** 2.5) ** 0.4
            crown = self._smoothstep((1.0 - rho) / 0.5)
            if molar:
                crown = crown * (1.0 - 0.12 * np.exp(-0.5 * (dd[near] / 0.2) ** 2) * np.clip(1.0 - ds[near] ** 2, 0.0, 1.0))
            teeth[near] = np.maximum(teeth[near], hh * crown)
        return gum, teeth

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        gum, teeth = self._height_parts(x, y)
        h = gum + teeth
        gx, gy = _grid_gradient(h, x, y)
        w = self._smoothstep(teeth / 0.3)
        refl = (1.0 - w)[..., None] * self.gum_reflectance + w[..., None] * self.tooth_reflectance
        if self.colour_variation > 0.0:
            for k in range(3):
                refl[..., k] *= 1.0 + self.colour_variation * smooth_field(x, y, self.seed + 17 * k + 1, 12.0)
            np.clip(refl, 0.0, 1.0, out=refl)
        return SceneSample(h, gx, gy, refl, h > 1e-6)


# --------------------------------------------------------------------------------------------
def _read_reflectance_image(path: str | Path) -> F64:
    """An RGB image (PNG/TIFF, 8/16 bit or float in [0, 1]) as float64 ``(H, W, 3)``."""
    p = Path(path)
    if p.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        data = tifffile.imread(p)
        if data.dtype.kind == "f":
            img = data.astype(np.float64)
        else:
            img = data.astype(np.float64) / (65535.0 if data.dtype == np.uint16 else 255.0)
    else:
        from huefringe.session import read_rgb

        img = read_rgb(p).astype(np.float64)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.clip(img[..., :3], 0.0, 1.0)


def _bilinear(img: F64, rows: F64, cols: F64, cval: float) -> F64:
    from scipy.ndimage import map_coordinates

    return map_coordinates(img, [rows.ravel(), cols.ravel()], order=1, mode="constant", cval=cval).reshape(rows.shape)


@dataclass
class HeightmapScene:
    """A user height map (mm, NaN = no object) placed on the plate, bilinearly resampled."""

    heights: F64
    pixel_mm: float
    offset_mm: tuple[float, float]
    reflectance: F64
    reflectance_image: F64 | None = None

    def __post_init__(self) -> None:
        valid = np.isfinite(self.heights)
        self._valid = valid.astype(np.float64)
        self._filled = np.where(valid, self.heights, 0.0)
        self._gy, self._gx = np.gradient(self._filled, self.pixel_mm)
        if self.reflectance_image is not None and self.reflectance_image.shape[:2] != self.heights.shape:
            raise ValueError(
                f"reflectance image shape {self.reflectance_image.shape[:2]} differs from the height map's {self.heights.shape}"
            )

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        cols = (x - self.offset_mm[0]) / self.pixel_mm
        rows = (y - self.offset_mm[1]) / self.pixel_mm
        mask = _bilinear(self._valid, rows, cols, 0.0) > 0.999
        h = np.where(mask, _bilinear(self._filled, rows, cols, 0.0), 0.0)
        gx = np.where(mask, _bilinear(self._gx, rows, cols, 0.0), 0.0)
        gy = np.where(mask, _bilinear(self._gy, rows, cols, 0.0), 0.0)
        if self.reflectance_image is None:
            refl = np.broadcast_to(self.reflectance, x.shape + (3,)).copy()
        else:
            refl = np.stack([_bilinear(self.reflectance_image[..., k], rows, cols, 0.0) for k in range(3)], axis=-1)
        return SceneSample(h, gx, gy, refl, mask & (h > 0.0))


@dataclass
class MeshScene:
    """A triangle mesh (mm) ray cast straight down with Open3D's ``RaycastingScene``."""

    path: str
    scale: float = 1.0
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reflectance: F64 = field(default_factory=lambda: np.array([0.8, 0.8, 0.8]))
    reflectance_image: F64 | None = None

    def __post_init__(self) -> None:
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(str(self.path))
        if len(mesh.triangles) == 0:
            raise ValueError(f"{self.path}: no triangles in the mesh")
        verts = np.asarray(mesh.vertices, dtype=np.float64) * self.scale + np.asarray(self.offset_mm)
        tris = np.asarray(mesh.triangles, dtype=np.uint32)
        self._bounds = (verts.min(axis=0), verts.max(axis=0))
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris)
        )
        self._o3c = o3d.core

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        z_top = float(self._bounds[1][2]) + 1.0
        n = x.size
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, 0] = x.ravel()
        rays[:, 1] = y.ravel()
        rays[:, 2] = z_top
        rays[:, 3:5] = 0.0
        rays[:, 5] = -1.0
        ans = self._scene.cast_rays(self._o3c.Tensor(rays))
        t_hit = ans["t_hit"].numpy().astype(np.float64).reshape(x.shape)
        normals = ans["primitive_normals"].numpy().astype(np.float64).reshape(x.shape + (3,))
        hit = np.isfinite(t_hit)
        h = np.where(hit, z_top - np.where(hit, t_hit, 0.0), 0.0)
        mask = hit & (h > 0.0)
        nz = normals[..., 2]
        sign = np.where(nz < 0.0, -1.0, 1.0)  # orient normals upwards
        nz_safe = np.maximum(np.abs(nz), 0.05)
        gx = np.where(mask, -sign * normals[..., 0] / nz_safe, 0.0)
        gy = np.where(mask, -sign * normals[..., 1] / nz_safe, 0.0)
        if self.reflectance_image is None:
            refl = np.broadcast_to(self.reflectance, x.shape + (3,)).copy()
        else:
            img = self.reflectance_image
            (x0, y0, _), (x1, y1, _) = self._bounds
            cols = (x - x0) / max(x1 - x0, 1e-9) * (img.shape[1] - 1)
            rows = (y - y0) / max(y1 - y0, 1e-9) * (img.shape[0] - 1)
            refl = np.stack([_bilinear(img[..., k], rows, cols, 0.0) for k in range(3)], axis=-1)
        return SceneSample(np.where(mask, h, 0.0), gx, gy, refl, mask)


# --------------------------------------------------------------------------------------------
@dataclass
class PhotoReliefScene:
    """A smooth relief printed with a real photograph (``skimage.data``, shipped offline).

    Height: ``base_mm + amplitude_mm * (1 + tanh(f / 1.5)) / 2`` with ``f`` a :func:`smooth_field`
    of wavelength ``wavelength_mm``, over ``rect_mm``; reflectance: the photograph stretched over
    the rectangle, times ``reflectance_scale``, floored at ``min_reflectance`` (its dark parts
    stay dark). Analytic in ``(X, Y)``, so the relief can move; the photograph moves with it.
    """

    image: F64
    rect_mm: tuple[float, float, float, float]
    base_mm: float = 0.3
    amplitude_mm: float = 2.5
    wavelength_mm: float = 30.0
    reflectance_scale: float = 0.9
    min_reflectance: float = 0.01
    seed: int = 0

    def sample(self, x: F64, y: F64) -> SceneSample:
        """See :class:`Scene`."""
        mask = _in_rect(x, y, self.rect_mm)
        f = smooth_field(x, y, self.seed, self.wavelength_mm)
        h = np.where(mask, self.base_mm + self.amplitude_mm * 0.5 * (1.0 + np.tanh(f / 1.5)), 0.0)
        gx, gy = _grid_gradient(h, x, y)
        gx, gy = np.where(mask, gx, 0.0), np.where(mask, gy, 0.0)
        x0, y0, x1, y1 = self.rect_mm
        img = self.image
        cols = (x - x0) / (x1 - x0) * (img.shape[1] - 1)
        rows = (y - y0) / (y1 - y0) * (img.shape[0] - 1)
        refl = np.stack([_bilinear(img[..., k], rows, cols, 0.0) for k in range(3)], axis=-1)
        refl = np.clip(refl * self.reflectance_scale, self.min_reflectance, 1.0)
        return SceneSample(h, gx, gy, refl, mask)


def photo_image(name: str) -> F64:
    """A colour photograph of ``skimage.data`` (e.g. ``astronaut``, ``coffee``, ``chelsea``) in [0, 1]."""
    import skimage.data

    img = np.asarray(getattr(skimage.data, name)(), dtype=np.float64) / 255.0
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return img[..., :3]


# --------------------------------------------------------------------------------------------
def build_scene(cfg: dict[str, Any]) -> Scene:
    """The scene of a validated bench configuration."""
    sc = cfg["scene"]
    s = cfg["session"]
    pitch = float(s["pixel_pitch_mm"])
    w_mm, h_mm = s["width"] * pitch, s["height"] * pitch
    kind = sc["kind"]
    if kind == "flat":
        ext = sc["extent_mm"]
        return FlatScene(float(sc["height_mm"]), rgb3(sc["reflectance"]), None if ext is None else tuple(ext))
    if kind == "gauge_blocks":
        return GaugeBlocksScene(
            blocks=gauge_blocks(cfg),
            base_rect_mm=base_rect(cfg),
            base_thickness_mm=float(sc["base_thickness_mm"]),
            base_reflectance=rgb3(sc["base_reflectance"]),
            reflectance_variation=float(sc["reflectance_variation"]),
            seed=int(s["seed"]),
        )
    if kind == "dental":
        return DentalScene(
            width_mm=w_mm,
            height_mm=h_mm,
            teeth=int(sc["teeth"]),
            gum_height_mm=float(sc["gum_height_mm"]),
            tooth_height_mm=float(sc["tooth_height_mm"]),
            arch_size=float(sc["arch_size"]),
            tooth_reflectance=rgb3(sc["tooth_reflectance"]),
            gum_reflectance=rgb3(sc["gum_reflectance"]),
            colour_variation=float(sc["colour_variation"]),
            seed=int(s["seed"]),
        )
    if kind == "heightmap":
        import tifffile

        heights = np.asarray(tifffile.imread(sc["path"]), dtype=np.float64)
        if heights.ndim != 2:
            raise ValueError(f"{sc['path']}: the height map must be a single-channel image, got shape {heights.shape}")
        refl_img = _read_reflectance_image(sc["reflectance_path"]) if sc["reflectance_path"] else None
        return HeightmapScene(
            heights=heights * float(sc["height_scale"]),
            pixel_mm=float(sc["pixel_mm"] if sc["pixel_mm"] is not None else pitch),
            offset_mm=(float(sc["offset_mm"][0]), float(sc["offset_mm"][1])),
            reflectance=rgb3(sc["reflectance"]),
            reflectance_image=refl_img,
        )
    if kind == "photo_relief":
        m = float(sc["margin_mm"])
        rect = tuple(float(_snap(v, pitch)) for v in (-0.5 * pitch + m, -0.5 * pitch + m,
                                                       w_mm - 0.5 * pitch - m, h_mm - 0.5 * pitch - m))
        return PhotoReliefScene(
            image=photo_image(sc["image"]),
            rect_mm=rect,  # type: ignore[arg-type]
            base_mm=float(sc["base_mm"]),
            amplitude_mm=float(sc["amplitude_mm"]),
            wavelength_mm=float(sc["wavelength_mm"]),
            reflectance_scale=float(sc["reflectance_scale"]),
            min_reflectance=float(sc["min_reflectance"]),
            seed=int(s["seed"]),
        )
    if kind == "mesh":
        refl_img = _read_reflectance_image(sc["reflectance_path"]) if sc["reflectance_path"] else None
        return MeshScene(
            path=sc["path"],
            scale=float(sc["scale"]),
            offset_mm=tuple(float(v) for v in sc["offset_mm"]),  # type: ignore[arg-type]
            reflectance=rgb3(sc["reflectance"]),
            reflectance_image=refl_img,
        )
    raise ValueError(f"unknown scene kind {kind!r}")  # pragma: no cover - schema guards this


def gauge_blocks(cfg: dict[str, Any]) -> list[Block]:
    """The blocks of a gauge-block configuration (named layout or explicit list)."""
    sc, s = cfg["scene"], cfg["session"]
    pitch = float(s["pixel_pitch_mm"])
    if isinstance(sc["blocks"], str):
        return block_layout(sc["blocks"], s["width"] * pitch, s["height"] * pitch, pitch)
    return [
        Block(b["name"], float(b["nominal_mm"]), tuple(rgb3(b["reflectance"])), tuple(float(v) for v in b["rect_mm"]))  # type: ignore[arg-type]
        for b in sc["blocks"]
    ]


def base_rect(cfg: dict[str, Any]) -> tuple[float, float, float, float]:
    """The base plate's rectangle: the field minus ``base_margin_mm``, snapped to pixel edges."""
    s = cfg["session"]
    pitch = float(s["pixel_pitch_mm"])
    m = float(cfg["scene"]["base_margin_mm"])
    x1 = (s["width"] - 0.5) * pitch - m
    y1 = (s["height"] - 0.5) * pitch - m
    return tuple(float(_snap(v, pitch)) for v in (-0.5 * pitch + m, -0.5 * pitch + m, x1, y1))  # type: ignore[return-value]
