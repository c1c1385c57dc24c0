"""Binary-reflected Gray code: generation, OpenCV's layout and a vectorised decoder.

Cell ``j`` of a Gray code of ``n`` bits shows bit ``k`` of ``g = j ^ (j >> 1)`` in pattern
``n - 1 - k`` (most significant bit first); a bit that differs from its neighbour's changes by one
cell only, so a misread edge costs one cell, never a wild jump. The top ``m`` bits of the code
of ``j`` are the code of ``j >> (n - m)``: decoding only the coarse bits that a phase unwrapping
needs is exact (:func:`decode_gray`, ``use_bits``).

OpenCV's ``structured_light::GrayCodePattern`` (opencv_contrib) writes, for a projector of
``width x height`` cells, ``ceil(log2(width))`` column bits then ``ceil(log2(height))`` row bits,
each as a pattern (white where the Gray bit is 1) followed by its inverse, most significant bit
first: :func:`opencv_graycode_patterns` reproduces that list image for image (see
``tests/test_codecs_graycode.py`` for the layout checks), and ``getProjPixel``'s decision (bit = 1
where pattern > inverse, a pixel refused when any pair differs by less than the light threshold)
is :func:`decode_gray` with ``inverse`` frames. The decoder here is NumPy, not OpenCV's:
``opencv-python-headless`` (the project's dependency) has no ``structured_light`` module, and
OpenCV decodes pixel by pixel in ``getProjPixel``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["GrayDecoded", "bits_for", "decode_gray", "gray_to_index", "index_to_gray", "opencv_graycode_patterns"]


@dataclass(frozen=True)
class GrayDecoded:
    """Gray-code cells per camera pixel.

    Attributes
    ----------
    index : ndarray of int32
        Cell index ``j`` of the decoded bits (with ``use_bits`` < all bits: ``j >> dropped``).
    contrast : ndarray of float32
        Second smallest ``|pattern - reference|`` (DN) over the decoded bits (the smallest with a
        single bit, or with ``all_bits``). Next to a cell edge one bit is always ambiguous and misreading it moves the
        index by one cell, which a phase unwrapping absorbs; two unclear bits mean no code.
    valid : ndarray of bool
        ``contrast >= min_contrast``.
    """

    index: NDArray[np.int32]
    contrast: NDArray[np.float32]
    valid: NDArray[np.bool_]


def bits_for(cells: int) -> int:
    """Bits of a Gray code over ``cells`` cells (OpenCV: ``ceil(log2(cells))``).

    Examples
    --------
    >>> bits_for(20), bits_for(11), bits_for(960), bits_for(540), bits_for(1024)
    (5, 4, 10, 10, 10)
    """
    if cells < 2:
        raise ValueError(f"a Gray code needs at least 2 cells, got {cells}")
    return int(np.ceil(np.log2(cells)))


def index_to_gray(index: ArrayLike) -> NDArray[np.int64]:
    """Gray code ``j ^ (j >> 1)`` of integer cell indices.

    Examples
    --------
    >>> index_to_gray(np.arange(8)).tolist()
    [0, 1, 3, 2, 6, 7, 5, 4]
    """
    j = np.asarray(index, np.int64)
    return j ^ (j >> 1)


def gray_to_index(gray: ArrayLike) -> NDArray[np.int64]:
    """Inverse of :func:`index_to_gray` (prefix XOR), vectorised.

    Examples
    --------
    >>> gray_to_index(index_to_gray(np.arange(1000))).tolist() == list(range(1000))
    True
    """
    g = np.asarray(gray, np.int64).copy()
    shift = 1
    while shift < 63:
        g ^= g >> shift
        shift *= 2
    return g


def opencv_graycode_patterns(width: int, height: int) -> NDArray[np.uint8]:
    """The images of OpenCV's ``GrayCodePattern.create(width, height).generate()``, in its order.

    Column bits first (MSB first), each pattern followed by its inverse, then the row bits the
    same way; 255 where the Gray bit is 1.

    Returns
    -------
    ndarray of uint8, shape (2 * (bits_for(width) + bits_for(height)), height, width)

    Examples
    --------
    >>> p = opencv_graycode_patterns(20, 11)
    >>> p.shape
    (18, 11, 20)
    >>> (p[0, 0] // 255).tolist()  # column MSB: Gray bit 4 of j = 0..19
    [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1]
    """
    out = []
    for n_cells, n_other, axis in ((width, height, 1), (height, width, 0)):
        nb = bits_for(n_cells)
        g = index_to_gray(np.arange(n_cells))
        for k in range(nb - 1, -1, -1):
            line = (((g >> k) & 1) * 255).astype(np.uint8)
            img = np.broadcast_to(line[None, :] if axis == 1 else line[:, None], (height, width))
            out.append(np.array(img))
            out.append(255 - img)
    return np.stack(out)


def decode_gray(
    patterns: ArrayLike,
    min_contrast: float,
    *,
    inverse: ArrayLike | None = None,
    reference: ArrayLike | None = None,
    use_bits: int | None = None,
    all_bits: bool = False,
) -> GrayDecoded:
    """Decode Gray-code captures, most significant bit first.

    Parameters
    ----------
    patterns : array, shape (n_bits, H, W)
        Captures of the bit patterns, MSB first.
    min_contrast : float
        A pixel is valid when all decoded bits but at most one differ from their reference by at
        least this (DN).
    inverse : array, shape (n_bits, H, W), optional
        Captures of each pattern's inverse: bit = pattern > inverse (OpenCV's decision).
    reference : array, shape (H, W), optional
        Without inverses: bit = pattern > reference (e.g. the mean of the white and black frames).
    use_bits : int, optional
        Decode only the ``use_bits`` most significant bits (index ``j >> (n_bits - use_bits)``);
        default all.
    all_bits : bool
        The contrast is the smallest ``|pattern - reference|`` over the decoded bits (every bit
        must be clear, OpenCV's ``getProjPixel`` rule) instead of the second smallest.

    Returns
    -------
    GrayDecoded
    """
    pats = np.asarray(patterns)
    n_bits = pats.shape[0]
    m = n_bits if use_bits is None else int(use_bits)
    if not 1 <= m <= n_bits:
        raise ValueError(f"use_bits must be 1..{n_bits}, got {use_bits}")
    if (inverse is None) == (reference is None):
        raise ValueError("give exactly one of inverse (pattern pairs) or reference (a threshold image)")
    shape = pats.shape[1:]
    gray = np.zeros(shape, np.int32)
    lo1 = np.full(shape, np.inf, np.float32)
    lo2 = np.full(shape, np.inf, np.float32)
    ref = None if reference is None else np.asarray(reference, np.float32)
    inv = None if inverse is None else np.asarray(inverse)
    for k in range(m):
        p = pats[k].astype(np.float32)
        d = p - (inv[k].astype(np.float32) if inv is not None else ref)
        gray = (gray << 1) | (d > 0)
        ad = np.abs(d)
        np.minimum(lo2, np.maximum(lo1, ad), out=lo2)
        np.minimum(lo1, ad, out=lo1)
    contrast = lo2 if m > 1 and not all_bits else lo1
    index = gray_to_index(gray).astype(np.int32)
    return GrayDecoded(index=index, contrast=contrast, valid=contrast >= np.float32(min_contrast))
