"""Reading a sequence's captures, generating its patterns, and decoding them to per-axis projector coordinates."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.codecs.graycode import decode_gray, gray_to_index, index_to_gray
from huefringe.codecs.nstep import TWO_PI, NoiseModel, wrapped_phase
from huefringe.codecs.temporal import heterodyne, number_theoretic, orders_from_reference
from ._spec import (
    Axis,
    DecodeOptions,
    Decoded,
    FlatBlock,
    GrayBlock,
    PhaseBlock,
    Reason,
    SequenceError,
    SequenceSpec,
    SkipBlock,
    HueBandsBlock,
    TrapezoidBlock,
    _check_spec,
    periods_cover,
)


_NUM = re.compile(r"(\d+)")


def _frame_key(p: Path) -> tuple[int, str]:
    nums = _NUM.findall(p.stem)
    return (int(nums[-1]) if nums else -1, p.name)


def capture_files(folder: str | Path, spec: SequenceSpec) -> tuple[list[Path], list[tuple[Path, str]]]:
    """The capture files of ``spec`` in ``folder``, in capture order, and every problem found.

    ``spec.frames`` a glob: the matching files sorted by the last number in their names, their
    count the sequence's; a list of names: those files in that order, each present.

    Returns
    -------
    files : list of Path
    problems : list of (Path, str)
        Each naming the file or folder concerned (empty when the files are usable).
    """
    folder = Path(folder)
    if not folder.is_dir():
        return [], [(folder, "not a folder of captures")]
    if not isinstance(spec.frames, str):
        files = [folder / name for name in spec.frames]
        problems = [(f, f"missing capture {i} of the sequence's frames list") for i, f in enumerate(files) if not f.is_file()]
        if len(files) != spec.n_frames:
            problems.append((folder, f"{len(files)} files listed in frames, the sequence has {spec.n_frames} frames"))
        return files, problems
    files = sorted((p for p in folder.glob(spec.frames) if p.is_file()), key=_frame_key)
    if len(files) != spec.n_frames:
        return files, [(folder, f"{len(files)} files match {spec.frames!r}, the sequence has {spec.n_frames} frames "
                                f"({', '.join(type(b).__name__ + '[' + str(b.n_frames) + ']' for b in spec.blocks)})")]
    return files, []


def read_captures(folder: str | Path, spec: SequenceSpec) -> list[NDArray[np.number]]:
    """The captures of ``spec.frames`` in ``folder`` (:func:`capture_files`), grayscale, in capture order.

    Any format OpenCV reads (PNG, TIFF, BMP, ...); colour captures are converted to grayscale
    (OpenCV's BGR -> gray weights).

    Raises
    ------
    SequenceError
        Naming the folder or file: a wrong count, an unreadable file, mixed sizes or dtypes.
    """
    files, found = capture_files(folder, spec)
    if found:
        raise SequenceError("; ".join(f"{p}: {msg}" for p, msg in found))
    problems, images = [], []
    for f in files:
        im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if im is None:
            problems.append(f"{f}: not an image OpenCV can read")
            continue
        if im.ndim == 3:
            im = cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2GRAY)
        if im.dtype not in (np.uint8, np.uint16):
            problems.append(f"{f}: {im.dtype} pixels (8- or 16-bit integers expected)")
            continue
        images.append((f, im))
    if images:
        f0, ref = images[0]
        for f, im in images[1:]:
            if im.shape != ref.shape or im.dtype != ref.dtype:
                problems.append(f"{f}: {im.shape} {im.dtype}, {f0.name} is {ref.shape} {ref.dtype}")
    if problems:
        raise SequenceError("; ".join(problems))
    return [im for _, im in images]


def generate(spec: SequenceSpec, dtype: type[np.integer] = np.uint8) -> NDArray[np.integer]:
    """The projector images of ``spec`` in capture order, shape (n_frames, height, width).

    A ``skip`` block's frames are not huefringe's to show: they come out black.

    Examples
    --------
    >>> from huefringe.codecs.sequence import FlatBlock, PhaseBlock, SequenceSpec, generate
    >>> from huefringe.codecs.nstep import equal_shifts
    >>> spec = SequenceSpec((PhaseBlock("x", 16.0, tuple(equal_shifts(4))), FlatBlock("white")), 64, 8)
    >>> generate(spec).shape, int(generate(spec)[0, 0, 0]), int(generate(spec)[2, 0, 0])
    ((5, 8, 64), 255, 0)
    """
    full = float(np.iinfo(dtype).max)
    h, w = spec.projector_height, spec.projector_width
    out = np.empty((spec.n_frames, h, w), dtype)
    coords = {"x": np.arange(w, dtype=np.float64)[None, :], "y": np.arange(h, dtype=np.float64)[:, None]}
    for b, sl in spec.slices():
        if isinstance(b, FlatBlock):
            out[sl] = full if b.level == "white" else 0
        elif isinstance(b, SkipBlock):
            out[sl] = 0
        elif isinstance(b, TrapezoidBlock | HueBandsBlock):  # a monochrome display's view: the channels' mean
            for i, img in zip(range(sl.start, sl.stop), _colour_frames(b, spec), strict=True):
                out[i] = np.round(img.mean(axis=-1) * full)
        elif isinstance(b, PhaseBlock):
            u = coords[b.axis]
            for i, d in zip(range(sl.start, sl.stop), b.shifts_rad, strict=True):
                v = (0.5 + 0.5 * np.cos(TWO_PI * (u - b.origin_px) / b.period_px + d)) ** b.encoding_gamma
                out[i] = np.broadcast_to(np.round(v * full), (h, w))
        else:
            g = index_to_gray(np.floor(coords[b.axis] / b.code_cell_px).astype(np.int64))
            i = sl.start
            for k in range(b.code_bits - 1, -1, -1):
                bit = np.broadcast_to(((g >> k) & 1).astype(bool), (h, w))
                out[i] = np.where(bit, full, 0)
                i += 1
                if b.inverse:
                    out[i] = np.where(bit, 0, full)
                    i += 1
    return out


def _colour_frames(b: TrapezoidBlock | HueBandsBlock, spec: SequenceSpec) -> NDArray[np.float64]:
    """The colour images (n_frames, height, width, 3) in [0, 1] of a one-shot block."""
    from huefringe.patterns import band_rgb, trapezoid_rgb

    h, w = spec.projector_height, spec.projector_width
    if isinstance(b, HueBandsBlock):
        cols = np.repeat(np.array([band_rgb(i, b.n) for i in range(b.n)]), b.repeats, axis=0)
        return np.broadcast_to(cols[:, None, None, :], (b.n_frames, h, w, 3))
    u = np.arange(w, dtype=np.float64)[None, :] if b.axis == "x" else np.arange(h, dtype=np.float64)[:, None]
    img = np.broadcast_to(trapezoid_rgb(TWO_PI * (u - b.origin_px) / b.period_px), (h, w, 3))
    return np.broadcast_to(img[None], (b.n_frames, h, w, 3))


def generate_rgb(spec: SequenceSpec, dtype: type[np.integer] = np.uint8) -> NDArray[np.integer]:
    """The projector images of ``spec`` in colour, shape (n_frames, height, width, 3) (R, G, B).

    Trapezoid frames show :func:`huefringe.patterns.trapezoid_rgb`, hue bands
    :func:`huefringe.patterns.band_rgb`; every other block is :func:`generate`'s image on all
    three channels.

    Examples
    --------
    >>> spec = SequenceSpec((TrapezoidBlock("x", 12.0), HueBandsBlock(12), FlatBlock("white")), 24, 4)
    >>> rgb = generate_rgb(spec)
    >>> rgb.shape, rgb[0, 0, 2].tolist(), rgb[1, 0, 0].tolist()
    ((14, 4, 24, 3), [255, 255, 0], [255, 0, 0])
    """
    full = float(np.iinfo(dtype).max)
    out = np.repeat(generate(spec, dtype)[..., None], 3, axis=-1)
    for b, sl in spec.slices():
        if isinstance(b, TrapezoidBlock | HueBandsBlock):
            for i, img in zip(range(sl.start, sl.stop), _colour_frames(b, spec), strict=True):
                out[i] = np.round(img * full)
    return out


def _as_stack(images: list[NDArray[np.number]] | NDArray[np.number], spec: SequenceSpec) -> tuple[NDArray, float]:
    if isinstance(images, np.ndarray):
        stack = images
    else:
        shapes = {np.shape(im) for im in images}
        if len(shapes) != 1:
            raise SequenceError(f"captures of different shapes {sorted(shapes)}")
        stack = np.stack(images)
    if stack.ndim != 3:
        raise SequenceError(f"expected grayscale captures (n_frames, H, W), got shape {stack.shape}")
    if stack.shape[0] != spec.n_frames:
        raise SequenceError(f"{stack.shape[0]} captures, the sequence has {spec.n_frames} frames")
    full = 65535.0 if stack.dtype == np.uint16 else 255.0
    return stack, full


def _gray_threshold(stack: NDArray, spec: SequenceSpec, block: GrayBlock, flats: dict[str, NDArray]) -> NDArray[np.float32] | None:
    """What a Gray bit is read against without inverses: the white/black mean, else the mean of the
    same axis' phase-shift frames; None with inverses."""
    if block.inverse:
        return None
    if "white" in flats and "black" in flats:
        return 0.5 * (flats["white"].astype(np.float32) + flats["black"].astype(np.float32))
    frames = [stack[sl] for b, sl in spec.slices() if isinstance(b, PhaseBlock) and b.axis == block.axis]
    return np.mean(np.concatenate(frames).astype(np.float32), axis=0)


def _gray_reference(
    stack: NDArray, block: GrayBlock, sl: slice, threshold: NDArray | None, longest: float, cells: int, opts: DecodeOptions, scale: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_], float]:
    """The Gray code's cell-centre coordinate, decoded to the bits a period ``longest`` needs."""
    drop = 0
    while drop < block.bits - 1 and block.cell_px * 2 ** (drop + 1) <= longest / 3.0:
        drop += 1
    use = block.bits - drop
    frames = stack[sl]
    if threshold is None:
        dec = decode_gray(frames[0::2], opts.min_gray_contrast_dn * scale, inverse=frames[1::2], use_bits=use)
    else:
        dec = decode_gray(frames, opts.min_gray_contrast_dn * scale, reference=threshold, use_bits=use)
    cell = block.cell_px * 2**drop
    n_eff = -(-cells // 2**drop)
    centre = dec.index * cell + 0.5 * (cell - 1.0) if cell >= 1 else (dec.index + 0.5) * cell
    return centre.astype(np.float64), dec.valid & (dec.index < n_eff), cell


def _direct_light(stack: NDArray, spec: SequenceSpec, axis: Axis, flats: dict[str, NDArray], moduli: list[NDArray]) -> NDArray[np.float32]:
    """The direct projector light a pixel receives (DN): white - black; without them the median
    ``|pattern - inverse|`` of the axis' Gray code's four coarsest bits; else twice the largest
    phase-block modulation (the fringe's peak-to-peak)."""
    if "white" in flats and "black" in flats:
        return flats["white"].astype(np.float32) - flats["black"].astype(np.float32)
    for b, sl in spec.slices():
        if isinstance(b, GrayBlock) and b.axis == axis and b.inverse:
            f = stack[sl][: 2 * min(4, b.bits)].astype(np.float32)
            return np.median(np.abs(f[0::2] - f[1::2]), axis=0).astype(np.float32)
    return (2.0 * np.max(moduli, axis=0)).astype(np.float32)


def _flag(reasons: NDArray[np.uint8], mask: NDArray[np.bool_], reason: Reason) -> None:
    reasons[mask] |= np.uint8(reason)


def _stages(periods: list[float]) -> list[tuple[float, tuple[int, ...]]]:
    """Coarse-to-fine stages: the distinct periods and their heterodyne beats (index tuples)."""
    q = sorted(set(periods), reverse=True)
    st: list[tuple[float, tuple[int, ...]]] = [(p, (periods.index(p),)) for p in q]
    if len(q) >= 2:
        beats = []
        for a, b in zip(q[:-1], q[1:], strict=True):
            pb = a * b / (a - b)
            beats.append(pb)
            st.append((pb, (periods.index(a), periods.index(b))))
        if len(beats) == 2 and beats[0] != beats[1]:
            st.append((beats[0] * beats[1] / abs(beats[0] - beats[1]), ()))
    return sorted(st, key=lambda s: -s[0])


def _decode_axis(
    stack: NDArray, spec: SequenceSpec, axis: Axis, flats: dict[str, NDArray], noise: NoiseModel, opts: DecodeOptions, full: float
) -> Decoded:
    scale = full / 255.0
    shape = stack.shape[1:]
    reasons = np.zeros(shape, np.uint8)
    extent = spec.extent(axis)
    blocks = [(b, sl) for b, sl in spec.slices() if isinstance(b, PhaseBlock) and b.axis == axis]
    gray = [(b, sl) for b, sl in spec.slices() if isinstance(b, GrayBlock) and b.axis == axis]
    phases = [wrapped_phase(stack[sl], b.shifts_rad, noise, gamma=b.encoding_gamma * spec.projector_gamma) for b, sl in blocks]

    # the projector's shadow, the signal against the pixel's own noise, saturation
    direct = _direct_light(stack, spec, axis, flats, [p.modulation for p in phases])
    _flag(reasons, ~(direct >= opts.min_direct_dn * scale), Reason.SHADOW)
    for p in phases:
        if not {"white", "black"} <= set(flats):
            _flag(reasons, ~(p.modulation >= opts.min_fringe_contrast * p.offset), Reason.SHADOW)
        low = ~(p.modulation >= opts.min_modulation_dn * scale)
        if opts.min_snr > 0:
            low |= ~(p.sigma <= 1.0 / opts.min_snr)
        _flag(reasons, low, Reason.LOW_SIGNAL)
    for _, sl in blocks:  # a clipped frame is no sinusoid
        _flag(reasons, stack[sl].max(axis=0) >= opts.saturation_dn * scale, Reason.SATURATED)

    if not blocks:
        coord, sigma, modulation, margin = _gray_only(stack, spec, gray[0], flats, opts, scale, reasons)
        absolute = True
    else:
        coord, sigma, margin, absolute = _phase_axis(stack, spec, axis, blocks, phases, gray, flats, opts, scale, reasons)
        modulation = phases[int(np.argmin([b.period_px for b, _ in blocks]))].modulation

    _flag(reasons, ~(margin < opts.order_tolerance) | ~np.isfinite(coord) | ~np.isfinite(sigma), Reason.ORDER)
    if absolute:
        with np.errstate(invalid="ignore"):
            _flag(reasons, (coord < -0.5) | (coord > extent - 0.5), Reason.OUTSIDE)
    valid = reasons == 0
    return Decoded(
        axis=axis,
        coord=np.where(valid, coord, np.nan),
        sigma=np.where(valid, sigma, np.nan),
        modulation=modulation.astype(np.float32),
        valid=valid,
        order_margin=margin.astype(np.float32),
        absolute=absolute,
        reasons=reasons,
        phases=tuple(phases),
    )


def _gray_only(
    stack: NDArray, spec: SequenceSpec, gray: tuple[GrayBlock, slice], flats: dict[str, NDArray], opts: DecodeOptions,
    scale: float, reasons: NDArray[np.uint8],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32], NDArray[np.float64]]:
    """A Gray-code-only axis: the decoded cell's centre, every bit clear, ``cell_px / sqrt(12)``."""
    gb, sl = gray
    frames = stack[sl]
    thr = _gray_threshold(stack, spec, gb, flats)
    lim = opts.min_gray_contrast_dn * scale
    if thr is None:
        dec = decode_gray(frames[0::2], lim, inverse=frames[1::2], all_bits=True)
    else:
        dec = decode_gray(frames, lim, reference=thr, all_bits=True)
    cells = int(np.ceil(spec.extent(gb.axis) / gb.cell_px))
    _flag(reasons, ~dec.valid | (dec.index >= cells), Reason.GRAY)
    c = gb.cell_px
    coord = (dec.index * c + 0.5 * (c - 1.0) if c >= 1 else (dec.index + 0.5) * c).astype(np.float64)
    sigma = np.full(coord.shape, c / np.sqrt(12.0))
    return coord, sigma, dec.contrast, np.zeros(coord.shape)


def _phase_axis(
    stack: NDArray, spec: SequenceSpec, axis: Axis, blocks: list[tuple[PhaseBlock, slice]], phases: list,
    gray: list[tuple[GrayBlock, slice]], flats: dict[str, NDArray], opts: DecodeOptions, scale: float,
    reasons: NDArray[np.uint8],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], bool]:
    """An axis with phase blocks: orders from the Gray code, the beats or the number-theoretic
    search, every block unwrapped and averaged with weights ``1 / u**2``."""
    periods = [b.period_px for b, _ in blocks]
    # wrapped coordinates u mod P (origins folded in) and their standard uncertainties (px)
    wraps = [np.mod(b.origin_px + p.phase * (b.period_px / TWO_PI), b.period_px) for (b, _), p in zip(blocks, phases, strict=True)]
    sig = [p.sigma.astype(np.float64) * (b.period_px / TWO_PI) for (b, _), p in zip(blocks, phases, strict=True)]
    margin = np.zeros(stack.shape[1:], np.float64)
    extent = spec.extent(axis)

    stages = _stages(periods)
    beat_w: dict[tuple[int, ...], NDArray[np.float64]] = {}

    def stage_wrap(pst: float, idx: tuple[int, ...]) -> NDArray[np.float64]:
        if len(idx) == 1:
            return wraps[idx[0]]
        if len(idx) == 2:
            w, _ = heterodyne(wraps[idx[0]], periods[idx[0]], wraps[idx[1]], periods[idx[1]])
            beat_w[idx] = w
            return w
        two = [(p, i) for p, i in stages if len(i) == 2]
        for _, i in two:
            if i not in beat_w:
                stage_wrap(0.0, i)
        w, _ = heterodyne(beat_w[two[0][1]], two[0][0], beat_w[two[1][1]], two[1][0])
        return w

    absolute = True
    ref: NDArray[np.float64] | None = None
    if gray and gray[0][0].complementary:
        ref, m = _complementary_reference(stack, spec, gray[0], blocks, wraps, flats, opts, scale, reasons)
        margin = np.maximum(margin, m)
        chain = [s for s in stages if s[0] < gray[0][0].cell_px]
    elif gray:
        gb, gsl = gray[0]
        cells = int(np.ceil(extent / gb.cell_px))
        # start at the finest stage the full Gray code resolves with room to spare, else the coarsest
        start = next((i for i in range(len(stages) - 1, -1, -1) if stages[i][0] >= 3.0 * gb.cell_px), 0)
        thr = _gray_threshold(stack, spec, gb, flats)
        ref, gvalid, _ = _gray_reference(stack, gb, gsl, thr, stages[start][0], cells, opts, scale)
        _flag(reasons, ~gvalid, Reason.GRAY)
        chain = stages[start:]
    elif stages[0][0] >= extent:
        ref = stage_wrap(*stages[0])
        chain = stages[1:]
    elif len(set(periods)) >= 2:
        uniq = sorted(set(periods))
        idx = [periods.index(p) for p in uniq]
        ref, m = number_theoretic([wraps[i] for i in idx], uniq, [sig[i] for i in idx], extent)
        margin = np.maximum(margin, m)
        chain = []
        absolute = periods_cover(uniq, extent)  # else known only modulo the periods' repeat
    else:
        absolute = False
        chain = []
    if ref is not None:
        for pst, idx in chain:
            ref, m = orders_from_reference(stage_wrap(pst, idx), pst, ref)
            margin = np.maximum(margin, m)
        coords = []
        for w, pp in zip(wraps, periods, strict=True):
            c, m = orders_from_reference(w, pp, ref)
            margin = np.maximum(margin, m)
            coords.append(c)
    else:
        finest = int(np.argmin(periods))
        coords = [wraps[finest]]
        sig = [sig[finest]]
    inv = [1.0 / np.maximum(s, 1e-12) ** 2 for s in sig]
    wsum = np.sum(inv, axis=0)
    coord = np.sum([c * i for c, i in zip(coords, inv, strict=True)], axis=0) / wsum
    sigma = 1.0 / np.sqrt(wsum)
    return coord, sigma, margin, absolute


def _complementary_reference(
    stack: NDArray, spec: SequenceSpec, gray: tuple[GrayBlock, slice], blocks: list[tuple[PhaseBlock, slice]],
    wraps: list[NDArray[np.float64]], flats: dict[str, NDArray], opts: DecodeOptions, scale: float,
    reasons: NDArray[np.uint8],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The absolute coordinate of the phase block of period ``cell_px`` from a complementary Gray code.

    The ``bits + 1`` patterns are one Gray code ``V2`` of half cells: ``k1 = V2 >> 1`` is the
    ``bits``-bit cell, ``k2 = (V2 + 1) >> 1`` the period edge nearest the pixel. In the middle
    half of a period (wrapped coordinate ``P / 4 < w < 3 P / 4``) the order is ``k1``, whose
    stripe edges are a quarter period away: every one of its bits must be clear of its threshold.
    In the edge quarters it is ``k2`` (``w <= P / 4``) or ``k2 - 1`` (``w >= 3 P / 4``), which a
    misread of the one Gray bit that changes at that cell edge leaves unchanged: the extra bit
    (its stripe edges lie mid-period) and every other bit must be clear. A pixel failing this is
    flagged ``GRAY``. Returns the coordinate and the order margin (at most 0.25 + noise where
    the codes are read right).
    """
    gb, sl = gray
    thr = _gray_threshold(stack, spec, gb, flats)
    frames = stack[sl]
    pats = frames[0::2] if thr is None else frames
    n = gb.bits
    code = np.zeros(stack.shape[1:], np.int64)
    contrast = []
    for j in range(n + 1):
        d = pats[j].astype(np.float32) - (frames[2 * j + 1].astype(np.float32) if thr is None else thr)
        code = (code << 1) | (d > 0)
        contrast.append(np.abs(d))
    v2 = gray_to_index(code)  # the bits + 1-bit code of half cells
    k1 = v2 >> 1
    k2 = (v2 + 1) >> 1
    # the Gray bit that changes between cells k2 - 1 and k2: the lowest set bit of k2 (pattern n - 1 - it)
    low = k2 & -k2
    edge_bit = np.where((k2 > 0) & (k2 < 2**n), n - 1 - np.log2(np.maximum(low, 1)).round().astype(np.int64), -1)
    lim = np.float32(opts.min_gray_contrast_dn * scale)
    mid_clear = np.ones(k1.shape, bool)
    edge_clear = contrast[n] >= lim
    for j in range(n):
        ok = contrast[j] >= lim
        mid_clear &= ok
        edge_clear &= ok | (edge_bit == j)
    i = next(j for j, (b, _) in enumerate(blocks) if np.isclose(b.period_px, gb.cell_px, rtol=1e-9, atol=1e-9))
    period, w = blocks[i][0].period_px, wraps[i]
    middle = (w > 0.25 * period) & (w < 0.75 * period)
    cells = int(np.ceil(spec.extent(gb.axis) / gb.cell_px))
    _flag(reasons, ~np.where(middle, mid_clear, edge_clear) | (k1 >= cells), Reason.GRAY)
    ref = np.where(middle, (k1 + 0.5) * period, k2 * period)
    return orders_from_reference(w, period, ref)


def decode_sequence(
    images: list[NDArray[np.number]] | NDArray[np.number],
    spec: SequenceSpec,
    options: DecodeOptions | None = None,
) -> dict[Axis, Decoded]:
    """Decode captures of ``spec`` into the absolute projector coordinate of each axis.

    Parameters
    ----------
    images : list of ndarray or ndarray, shape (n_frames, H, W)
        Grayscale captures in capture order (8- or 16-bit integers, or floats on a 0..255 scale).
    spec : SequenceSpec
    options : DecodeOptions, optional
        Thresholds and noise model; default the configuration's ``codecs`` block. Thresholds and
        read noise are on an 8-bit scale, multiplied by 257 for 16-bit captures.

    Returns
    -------
    dict
        ``{"x": Decoded, "y": Decoded}`` for the axes the sequence encodes; each pixel's
        :attr:`~Decoded.reasons` say which validity test (:class:`Reason`) dropped it.

    Raises
    ------
    SequenceError
        A wrong number or shape of captures, or a spec that cannot be decoded.
    """
    opts = options if options is not None else DecodeOptions.from_config()
    _check_spec(spec)
    stack, full = _as_stack(images, spec)
    scale = full / 255.0
    noise = opts.noise(full)
    noise = NoiseModel(noise.read_dn * scale, noise.full_well_e, full)
    flats: dict[str, NDArray] = {}
    for b, sl in spec.slices():
        if isinstance(b, FlatBlock) and b.level not in flats:
            flats[b.level] = stack[sl.start]
    return {axis: _decode_axis(stack, spec, axis, flats, noise, opts, full) for axis in spec.axes()}
