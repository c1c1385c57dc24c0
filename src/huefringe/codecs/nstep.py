"""N-step phase shifting: wrapped phase, modulation and the phase's standard uncertainty.

A frame of a phase block is ``I_n = A + B cos(phi + delta_n)``. With ``b = B cos(phi)`` and
``c = -B sin(phi)`` the model is linear, ``I_n = A + b cos(delta_n) + c sin(delta_n)``; its
least-squares solution ``(A, b, c) = M I`` for any three or more shifts that span a sinusoid
(equal shifts ``2 pi n / N`` give the textbook ``phi = atan2(-sum I sin delta, sum I cos delta)``)
is :func:`wrapped_phase`. The phase's standard uncertainty is the first-order (GUM) propagation of
each frame's noise through ``phi = atan2(-c, b)``:

    ``d phi / d I_n = (c M[1, n] - b M[2, n]) / B**2``,
    ``u(phi)**2 = sum_n (d phi / d I_n)**2 u(I_n)**2``,

with ``u(I_n)**2`` from a :class:`NoiseModel` (read noise, shot noise, quantisation). For
equal shifts this is the familiar ``u(phi) = sqrt(2 / N) u(I) / B``.

Patterns encoded with an exponent (a projector image ``(0.5 + 0.5 cos)**g`` shown by a display
of gamma ``gamma_p``) reach the camera as ``A' + B' f(phi + delta_n)`` with the fringe profile
``f(theta) = (0.5 + 0.5 cos(theta))**Gamma``, ``Gamma = g * gamma_p``, and ``A'``, ``B'`` unknown
per pixel (ambient and scattered light raise the fringes' dark parts above a black frame's: the
white and black frames do not give them). The fit above then returns ``h(phi)``, a function of
the true phase alone (offset and gain cancel in the arctangent), whose error has ``N +- 1``
harmonics of ``f``. :func:`profile_lut` tabulates ``h`` for the known shifts and ``Gamma`` and
:func:`wrapped_phase` inverts it; the uncertainty is divided by ``h'``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

TWO_PI = 2.0 * np.pi

__all__ = ["NoiseModel", "WrappedPhase", "equal_shifts", "profile_lut", "shift_matrix", "wrapped_phase"]


@dataclass(frozen=True)
class NoiseModel:
    """A camera's per-frame intensity noise in its own digital numbers (DN).

    ``u(I)**2 = read_dn**2 + I * full_scale_dn / full_well_e + 1 / 12`` (read noise, shot noise of
    a sensor whose full well maps onto the full scale, uniform quantisation).

    Parameters
    ----------
    read_dn : float
        Read noise, DN (standard deviation).
    full_well_e : float or None
        Electrons at full scale; ``None`` = no shot noise term.
    full_scale_dn : float
        The image's full scale: 255 for 8-bit, 65535 for 16-bit captures.
    """

    read_dn: float
    full_well_e: float | None
    full_scale_dn: float

    def variance(self, intensity: NDArray[np.floating]) -> NDArray[np.float32]:
        """Variance (DN^2) of a frame of mean ``intensity`` (DN)."""
        var = np.full(np.shape(intensity), self.read_dn**2 + 1.0 / 12.0, np.float32)
        if self.full_well_e:
            var += np.maximum(np.asarray(intensity, np.float32), 0.0) * np.float32(self.full_scale_dn / self.full_well_e)
        return var


@dataclass(frozen=True)
class WrappedPhase:
    """One phase block decoded.

    Attributes
    ----------
    phase : ndarray of float64
        Wrapped phase ``phi`` in [0, 2 pi).
    modulation : ndarray of float32
        Amplitude ``B`` (camera DN) of the captures' fundamental: the data-quality map.
    offset : ndarray of float32
        Background ``A`` in the same units.
    sigma : ndarray of float32
        Standard uncertainty of ``phi`` (rad) from the frames' noise.
    """

    phase: NDArray[np.float64]
    modulation: NDArray[np.float32]
    offset: NDArray[np.float32]
    sigma: NDArray[np.float32]


def equal_shifts(n: int, start: float = 0.0) -> NDArray[np.float64]:
    """``n`` shifts ``start + 2 pi k / n`` (rad), ``k = 0 .. n - 1``.

    Examples
    --------
    >>> np.degrees(equal_shifts(4)).round(6).tolist()
    [0.0, 90.0, 180.0, 270.0]
    >>> np.degrees(equal_shifts(3, -2 * np.pi / 3)).round(6).tolist()
    [-120.0, 0.0, 120.0]
    """
    if n < 3:
        raise ValueError(f"phase shifting needs at least 3 frames, got {n}")
    return start + TWO_PI * np.arange(n) / n


def shift_matrix(shifts: ArrayLike) -> NDArray[np.float64]:
    """The 3 x N least-squares matrix ``M`` with ``(A, b, c) = M I`` (see the module docstring).

    Raises
    ------
    ValueError
        Fewer than three shifts, or shifts that do not determine a sinusoid (rank < 3).
    """
    d = np.asarray(shifts, np.float64).ravel()
    if d.size < 3:
        raise ValueError(f"phase shifting needs at least 3 frames, got {d.size}")
    design = np.stack([np.ones_like(d), np.cos(d), np.sin(d)], axis=1)
    if np.linalg.matrix_rank(design, tol=1e-9) < 3:
        raise ValueError(f"shifts {np.degrees(d).round(3).tolist()} deg do not determine a sinusoid")
    return np.linalg.pinv(design)


def profile_lut(shifts: ArrayLike, gamma: float, samples: int = 4096) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The N-step fit's phase ``h(phi)`` for fringes of profile ``(0.5 + 0.5 cos)**gamma``.

    Returns
    -------
    phi : ndarray of float64
        True phases on a uniform grid over [0, 2 pi], ``samples + 1`` points.
    h : ndarray of float64
        The fitted phase, unwrapped so that it increases with ``phi`` by 2 pi in total.

    Raises
    ------
    ValueError
        When ``h`` is not increasing (the profile too distorted for these shifts).

    Examples
    --------
    >>> phi, h = profile_lut(equal_shifts(3), 1.0)
    >>> float(np.max(np.abs(h - phi))) < 1e-12
    True
    >>> phi, h = profile_lut(equal_shifts(3), 2.0)  # three cycles of error per fringe
    >>> round(float(np.max(np.abs(h - phi))), 3)
    0.253
    """
    d = np.asarray(shifts, np.float64).ravel()
    m = shift_matrix(d)
    phi = np.linspace(0.0, TWO_PI, samples + 1)
    f = (0.5 + 0.5 * np.cos(phi[:, None] + d[None, :])) ** gamma
    b = f @ m[1]
    c = f @ m[2]
    h = np.unwrap(np.arctan2(-c, b))
    if np.any(np.diff(h) <= 0):
        raise ValueError(f"a fringe profile of exponent {gamma:g} is not invertible with shifts {np.degrees(d).round(2).tolist()} deg")
    return phi, h


def wrapped_phase(
    frames: NDArray[np.number] | ArrayLike,
    shifts: ArrayLike,
    noise: NoiseModel,
    *,
    gamma: float = 1.0,
) -> WrappedPhase:
    """Wrapped phase, modulation and phase uncertainty of one phase block.

    Parameters
    ----------
    frames : array, shape (N, H, W)
        The block's captures (any numeric dtype, in DN), in the order of ``shifts``.
    shifts : array of N floats
        Each frame's phase shift ``delta_n`` (rad) in ``I_n = A + B cos(phi + delta_n)``.
    noise : NoiseModel
        The camera's noise, for ``sigma``.
    gamma : float
        The fringe profile's exponent ``Gamma`` (1 = sinusoidal), undone by :func:`profile_lut`.

    Returns
    -------
    WrappedPhase

    Examples
    --------
    >>> u = np.arange(64.0)
    >>> d = equal_shifts(4)
    >>> frames = [100 + 50 * np.cos(2 * np.pi * u / 16 + dn)[None, :] for dn in d]
    >>> w = wrapped_phase(frames, d, NoiseModel(0.5, None, 255))
    >>> bool(np.allclose(w.phase[0], np.mod(2 * np.pi * u / 16, 2 * np.pi)))
    True
    >>> float(w.modulation[0, 0]), round(float(w.sigma[0, 0]), 5)  # sqrt(2 / 4) sqrt(0.5**2 + 1 / 12) / 50
    (50.0, 0.00816)
    """
    m = shift_matrix(shifts)
    stack = np.asarray(frames, np.float32)
    if stack.ndim != 3 or stack.shape[0] != m.shape[1]:
        raise ValueError(f"expected {m.shape[1]} frames of shape (H, W), got an array of shape {stack.shape}")
    var_s = noise.variance(stack)
    sig = stack
    m32 = m.astype(np.float32)
    a = np.tensordot(m32[0], sig, axes=1)
    b = np.tensordot(m32[1], sig, axes=1)
    c = np.tensordot(m32[2], sig, axes=1)
    amp2 = b * b + c * c
    phase = np.mod(np.arctan2(-c, b).astype(np.float64), TWO_PI)
    # d phi / d s_n = (c M1n - b M2n) / B^2 ;  u^2 = sum_n (.)^2 u(s_n)^2
    acc = np.zeros_like(a)
    for n in range(stack.shape[0]):
        g = c * m32[1, n] - b * m32[2, n]
        acc += g * g * var_s[n]
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.sqrt(acc) / np.maximum(amp2, np.float32(1e-30))
    sigma = np.where(amp2 > 0, sigma, np.float32(np.pi)).astype(np.float32)
    if gamma != 1.0:
        grid, h = profile_lut(shifts, gamma)
        slope = np.gradient(h, grid)
        # h(phi) -> phi: h spans [h0, h0 + 2 pi); bring the fitted phase into that window first
        hp = h[0] + np.mod(phase - h[0], TWO_PI)
        phase = np.mod(np.interp(hp, h, grid), TWO_PI)
        sigma = (sigma / np.interp(hp, h, slope)).astype(np.float32)
    modulation = np.sqrt(amp2).astype(np.float32)
    return WrappedPhase(phase=phase, modulation=modulation, offset=a.astype(np.float32), sigma=sigma)
