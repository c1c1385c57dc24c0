"""Absolute phase along time: fringe orders from coarser information.

Every function works on *wrapped coordinates* ``w = P phi / (2 pi)`` in [0, P) (projector pixels
from the block's origin) rather than on phases, so that stages of different periods compare
directly.

``orders_from_reference``
    ``k = round((r - w) / P)``: the order that puts ``w + k P`` nearest a coarser estimate ``r``
    (a Gray-code cell centre, the coordinate of a longer period, a beat). Exact while
    ``|r - u| < P / 2``; the returned margin ``|(r - w) / P - k|`` (0 .. 0.5) says how close a
    pixel came to that limit.
``heterodyne``
    The beat of two periods ``P1 < P2``: ``w_b = (w1 / P1 - w2 / P2) mod 1 * P_b`` with
    ``P_b = P1 P2 / (P2 - P1)``, a longer synthetic period whose noise is ``P_b / P1`` times larger.
``number_theoretic``
    For periods without a useful beat: the finest period's order is chosen among all candidates
    over the projector's extent as the one the other periods agree with best (weighted least
    squares of their wrapped disagreements). Exact while the disagreements' noise stays below
    half the spacing between candidate residues.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["heterodyne", "number_theoretic", "orders_from_reference", "wrap_distance"]


def wrap_distance(d: NDArray[np.floating], period: float) -> NDArray[np.floating]:
    """``d`` wrapped to [-period / 2, period / 2)."""
    return d - period * np.floor(d / period + 0.5)


def orders_from_reference(
    wrapped: NDArray[np.floating], period: float, reference: NDArray[np.floating]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unwrap ``wrapped`` coordinates against a coarser ``reference`` coordinate.

    Parameters
    ----------
    wrapped : ndarray
        Wrapped coordinate in [0, period) (projector px).
    period : float
        The wrapped coordinate's period (projector px).
    reference : ndarray
        Coarser estimate of the absolute coordinate (same origin).

    Returns
    -------
    coord : ndarray of float64
        ``wrapped + k * period``.
    margin : ndarray of float64
        ``|(reference - wrapped) / period - k|`` in [0, 0.5].

    Examples
    --------
    >>> c, m = orders_from_reference(np.array([10.0, 99.0]), 100.0, np.array([320.0, 150.0]))
    >>> c.tolist(), m.round(2).tolist()
    ([310.0, 199.0], [0.1, 0.49])
    """
    q = (np.asarray(reference, np.float64) - wrapped) / period
    k = np.floor(q + 0.5)
    return wrapped + k * period, np.abs(q - k)


def heterodyne(
    w1: NDArray[np.floating], p1: float, w2: NDArray[np.floating], p2: float
) -> tuple[NDArray[np.float64], float]:
    """The beat of two wrapped coordinates of periods ``p1 != p2``.

    Returns
    -------
    wrapped_beat : ndarray of float64
        Wrapped coordinate of the beat, in [0, p_beat).
    p_beat : float
        ``p1 p2 / |p2 - p1|``.

    Examples
    --------
    >>> u = np.array([0.0, 50.0, 130.0, 199.0])
    >>> wb, pb = heterodyne(np.mod(u, 200 / 3), 200 / 3, np.mod(u, 100.0), 100.0)
    >>> round(pb, 9), wb.round(9).tolist()
    (200.0, [0.0, 50.0, 130.0, 199.0])
    """
    if p1 == p2:
        raise ValueError(f"a beat needs two different periods, got {p1} twice")
    if p1 > p2:
        w1, p1, w2, p2 = w2, p2, w1, p1
    pb = p1 * p2 / (p2 - p1)
    frac = np.mod(np.asarray(w1, np.float64) / p1 - np.asarray(w2, np.float64) / p2, 1.0)
    return frac * pb, float(pb)


def number_theoretic(
    wrapped: list[NDArray[np.floating]],
    periods: list[float],
    sigmas: list[NDArray[np.floating]],
    extent: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Absolute coordinate from several periods by a search over the finest period's orders.

    Parameters
    ----------
    wrapped : list of ndarray
        Wrapped coordinates, one per period.
    periods : list of float
        Their periods (projector px).
    sigmas : list of ndarray
        Their standard uncertainties (projector px), the search's weights.
    extent : float
        Length of the projector's axis (px): candidates cover [-P_finest, extent + P_finest).

    Returns
    -------
    coord : ndarray of float64
        The finest period's wrapped coordinate plus its chosen order.
    margin : ndarray of float64
        The largest disagreement of another period with the chosen coordinate, as a fraction of
        that period (0 .. 0.5).

    Examples
    --------
    >>> u = np.array([3.0, 400.0, 911.5, 1020.0])
    >>> ps = [20.0, 23.0, 29.0]
    >>> c, m = number_theoretic([np.mod(u, p) for p in ps], ps, [np.ones(4)] * 3, 1024)
    >>> c.tolist()
    [3.0, 400.0, 911.5, 1020.0]
    """
    order = np.argsort(periods)
    i0 = int(order[0])
    p0 = float(periods[i0])
    w0 = np.asarray(wrapped[i0], np.float64)
    best = np.full(w0.shape, np.inf)
    coord = np.zeros(w0.shape)
    for k in range(-1, int(np.ceil(extent / p0)) + 1):
        x = w0 + k * p0
        cost = np.zeros(w0.shape)
        for i in order[1:]:
            d = wrap_distance(x - wrapped[i], periods[i]) / np.maximum(sigmas[i], 1e-6)
            cost += d * d
        better = cost < best
        best = np.where(better, cost, best)
        coord = np.where(better, x, coord)
    margin = np.zeros(w0.shape)
    for i in order[1:]:
        margin = np.maximum(margin, np.abs(wrap_distance(coord - wrapped[i], periods[i])) / periods[i])
    return coord, margin
