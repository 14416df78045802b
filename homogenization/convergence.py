"""Richardson extrapolation and grid-convergence uncertainty of a quantity computed at several resolutions.

A quantity ``q`` computed with grid spacing ``h`` (e.g. the voxel size ``1/N`` of an FFT homogenization) is
modelled, in the asymptotic range, by

    q(h) = q₀ + c h^p,

with ``q₀`` the converged value, ``p`` the order of convergence and ``c`` a constant.

:func:`richardson`
    The three-level estimate: ``p`` observed from the three finest levels ``h₁ > h₂ > h₃`` (any ratios) by
    solving ``(q₂ − q₁)/(q₃ − q₂) = (h₁^p − h₂^p)/(h₂^p − h₃^p)``, then ``q₀`` and ``c`` through the two finest.
    When the three values do not fit the model with an order in ``order_bounds`` (increments of alternating sign,
    increments that do not shrink, an order outside the bounds), the estimate falls back to the two finest levels
    with the assumed order ``fallback_order`` and says so in :attr:`RichardsonEstimate.asymptotic` and
    :attr:`RichardsonEstimate.reason`: it is then an indication, not a measurement.
:func:`richardson_two_level`
    The two-level estimate for a known order, ``q₀ = q_f + (q_f − q_c)/(r^p − 1)`` with ``r = h_c/h_f``.
:func:`gci`
    Roache's grid convergence index of the fine level, ``GCI = F_s |q_f − q_c| / (|q_f| (r^p − 1))``: a band
    ``|q_f − q_exact| ≤ GCI |q_f|`` meant to hold with about 95 % confidence, with the safety factor ``F_s = 1.25``
    for an order observed from three levels and ``3`` for an assumed order (P. J. Roache, *Verification and
    Validation in Computational Science and Engineering*, Hermosa, 1998; ASME V&V 20-2009).

:func:`fit_power_law`
    The least-squares fit of ``q₀ + c h^p`` to all levels (``p`` fitted, or given), for levels whose increments
    scatter about the trend (e.g. voxelized geometry, whose solid fraction jumps from one grid to the next): the
    three-level estimate follows every such jump, the fit averages them and gives the residual scatter and the
    standard error of ``q₀``.

The bias of a level is its relative distance to the extrapolated value, ``(q(h) − q₀)/q₀``
(:meth:`RichardsonEstimate.bias`); at a spacing that was not computed it follows from the model, ``c h^p/q₀``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from foambase.errors import InputError

__all__ = ["ORDER_BOUNDS", "PowerLawFit", "RichardsonEstimate", "fit_power_law", "gci", "observed_order", "richardson",
           "richardson_two_level"]

#: Orders accepted as observed (outside them the three levels are not taken as asymptotic).
ORDER_BOUNDS = (0.25, 4.0)
#: Roache's safety factors: three levels with an observed order, and two levels (or an assumed order).
SAFETY_OBSERVED, SAFETY_ASSUMED = 1.25, 3.0


@dataclass(frozen=True)
class RichardsonEstimate:
    """The extrapolation ``q(h) = q₀ + c h^p`` of one quantity (:func:`richardson`).

    Attributes
    ----------
    value
        The extrapolated ``q₀``.
    order
        ``p``: observed (``asymptotic``) or the assumed fallback order.
    coefficient
        ``c``, through the two finest levels.
    asymptotic
        Whether ``p`` was observed from three levels within the order bounds. ``False``: ``p`` is assumed and the
        estimate is indicative only (``reason`` says why).
    reason
        Why the levels were not taken as asymptotic; ``""`` when they were.
    h, q
        The levels used, coarse to fine.
    safety_factor
        ``F_s`` of :attr:`gci` (1.25 observed, 3 assumed).

    """

    value: float
    order: float
    coefficient: float
    asymptotic: bool
    reason: str
    h: tuple[float, ...]
    q: tuple[float, ...]
    safety_factor: float

    def bias(self, h: float | Sequence[float] | np.ndarray | None = None) -> float | np.ndarray:
        """Relative bias ``(q(h) − q₀)/q₀`` of a level.

        ``None``: of every level used (the computed values). A spacing ``h``: the model's ``c h^p / q₀`` (for a
        spacing that was not computed, e.g. a table's setting between the levels; outside them it extrapolates).
        """
        return _bias(self, h)

    @property
    def gci(self) -> float:
        """Roache's grid convergence index of the finest level: ``F_s |q_f − q₀| / |q_f|`` (relative)."""
        return gci(self.q[-2], self.q[-1], self.h[-2] / self.h[-1], self.order, self.safety_factor)

    @property
    def interval(self) -> tuple[float, float]:
        """The band ``q_f ∓ GCI |q_f|`` that holds the converged value with about 95 % confidence (Roache)."""
        half = self.gci * abs(self.q[-1])
        return self.q[-1] - half, self.q[-1] + half


def _bias(est, h) -> float | np.ndarray:
    """``(q − q₀)/q₀`` of the levels of ``est`` (``h`` None) or ``c h^p/q₀`` of its model at ``h``."""
    if est.value == 0:
        raise InputError("the extrapolated value is 0: the relative bias is undefined; use the absolute error")
    if h is None:
        return (np.asarray(est.q) - est.value) / est.value
    h = np.asarray(h, dtype=float)
    if np.any(~np.isfinite(h)) or np.any(h <= 0):
        raise InputError(f"h must be positive and finite, got {h.tolist()}")
    out = est.coefficient * h**est.order / est.value
    return float(out) if out.ndim == 0 else out


def _check_levels(h, q, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    h = np.asarray(h, dtype=float)
    q = np.asarray(q, dtype=float)
    if h.ndim != 1 or q.shape != h.shape:
        raise InputError(f"h and q must be 1-D of equal length, got shapes {h.shape} and {q.shape}")
    if len(h) < minimum:
        raise InputError(f"need at least {minimum} levels, got {len(h)} (h = {h.tolist()})")
    bad = [float(v) for v in h if not (np.isfinite(v) and v > 0)]
    if bad:
        raise InputError(f"every h must be positive and finite, got {bad[0]!r} in h = {h.tolist()}")
    bad = [float(v) for v in q if not np.isfinite(v)]
    if bad:
        raise InputError(f"every q must be finite, got {bad[0]!r} in q = {q.tolist()}")
    if np.any(np.diff(h) >= 0):
        i = int(np.argmax(np.diff(h) >= 0))
        raise InputError(f"h must decrease strictly (coarse to fine), got h[{i}] = {h[i]!r} then "
                         f"h[{i + 1}] = {h[i + 1]!r} in h = {h.tolist()}")
    return h, q


def _check_ratio_order(ratio, order) -> None:
    if not (np.isfinite(ratio) and ratio > 1):
        raise InputError(f"the refinement ratio h_coarse/h_fine must be > 1 and finite, got {ratio!r}")
    if not (np.isfinite(order) and order > 0):
        raise InputError(f"the order must be > 0 and finite, got {order!r}")


def richardson_two_level(q_coarse, q_fine, ratio: float, order: float = 1.0):
    """Two-level Richardson extrapolation for a known order: ``q_f + (q_f − q_c)/(r^p − 1)``.

    ``q_coarse``, ``q_fine``: values (scalars or arrays, elementwise) at spacings ``h_c = r h_f`` and ``h_f``;
    ``ratio`` ``r = h_c/h_f > 1``; ``order`` ``p > 0``. Exact for ``q = q₀ + c h^p``.
    """
    _check_ratio_order(ratio, order)
    q_coarse, q_fine = np.asarray(q_coarse, dtype=float), np.asarray(q_fine, dtype=float)
    if np.any(~np.isfinite(q_coarse)) or np.any(~np.isfinite(q_fine)):
        raise InputError(f"q must be finite, got coarse {q_coarse.tolist()} and fine {q_fine.tolist()}")
    out = q_fine + (q_fine - q_coarse) / (ratio**order - 1.0)
    return float(out) if out.ndim == 0 else out


def gci(q_coarse: float, q_fine: float, ratio: float, order: float, safety_factor: float = SAFETY_OBSERVED) -> float:
    """Roache's grid convergence index of the fine level: ``F_s |q_f − q_c| / (|q_f| (r^p − 1))``.

    ``ratio`` ``r = h_c/h_f``; ``safety_factor`` ``F_s``: 1.25 with an order observed from three levels, 3 with
    an assumed one. A relative band: ``|q_f − q_exact| ≤ GCI |q_f|`` with about 95 % confidence.
    """
    _check_ratio_order(ratio, order)
    if not safety_factor >= 1:
        raise InputError(f"the safety factor must be >= 1, got {safety_factor!r}")
    if q_fine == 0 or not (np.isfinite(q_fine) and np.isfinite(q_coarse)):
        raise InputError(f"q_fine must be finite and non-zero and q_coarse finite, got {q_fine!r}, {q_coarse!r}")
    return float(safety_factor * abs(q_fine - q_coarse) / (abs(q_fine) * (ratio**order - 1.0)))


def _order_ratio(p: float, h1: float, h2: float, h3: float) -> float:
    """``(h₁^p − h₂^p)/(h₂^p − h₃^p)``, increasing in ``p`` (scaled by ``h₃`` to avoid under/overflow)."""
    a, b = h1 / h3, h2 / h3
    return (a**p - b**p) / (b**p - 1.0)


def observed_order(h: Sequence[float], q: Sequence[float],
                   order_bounds: tuple[float, float] = ORDER_BOUNDS) -> tuple[float | None, str]:
    """The order ``p`` of ``q = q₀ + c h^p`` through the three finest levels, or ``(None, reason)``.

    ``p`` solves ``(q₂ − q₁)/(q₃ − q₂) = (h₁^p − h₂^p)/(h₂^p − h₃^p)`` (the right side increases with ``p``, so
    there is at most one root; found by Brent's method in ``order_bounds``). No order when the increments have
    opposite signs (oscillating, not monotone), the finest increment is zero, or the root lies outside the
    bounds (e.g. increments that do not shrink: p below the lower bound).
    """
    h, q = _check_levels(h, q, 3)
    (h1, h2, h3), (q1, q2, q3) = h[-3:], q[-3:]
    lo, hi = order_bounds
    if not 0 < lo < hi:
        raise InputError(f"order_bounds must be 0 < low < high, got {order_bounds!r}")
    d21, d32 = q2 - q1, q3 - q2
    if d32 == 0 and d21 == 0:
        return None, "the three finest values are equal (no change to extrapolate)"
    if d32 == 0:
        return None, "the finest increment is zero while the coarser is not (order unbounded)"
    ratio = d21 / d32
    if ratio <= 0:
        return None, f"not monotone: the increments {d21:.3g} and {d32:.3g} have opposite signs (or one is zero)"
    f_lo, f_hi = _order_ratio(lo, h1, h2, h3) - ratio, _order_ratio(hi, h1, h2, h3) - ratio
    if f_lo > 0:
        return None, (f"the increments shrink too little for an order ≥ {lo} (ratio {ratio:.3g}): "
                      "not yet asymptotic")
    if f_hi < 0:
        return None, f"the increments shrink faster than order {hi} (ratio {ratio:.3g})"
    p = brentq(lambda s: _order_ratio(s, h1, h2, h3) - ratio, lo, hi, xtol=1e-13, rtol=1e-13)
    return float(p), ""


def richardson(h: Sequence[float], q: Sequence[float], *, fallback_order: float = 1.0,
               order_bounds: tuple[float, float] = ORDER_BOUNDS) -> RichardsonEstimate:
    """Three-level Richardson extrapolation of ``q(h) = q₀ + c h^p`` with the observed order.

    Parameters
    ----------
    h
        Grid spacings, coarse to fine (strictly decreasing, positive), at least three; only the three finest
        are used. Any ratios.
    q
        The quantity at each ``h`` (finite).
    fallback_order
        The order assumed when the three finest levels give none (:func:`observed_order`): then ``q₀`` comes
        from the two finest levels with it (:func:`richardson_two_level`), ``asymptotic`` is False, ``reason``
        says why and the safety factor is 3. The default 1 is the order of a voxelized boundary.
    order_bounds
        Orders accepted as observed.

    Returns
    -------
    RichardsonEstimate

    Raises
    ------
    foambase.errors.InputError
        Fewer than three levels, ``h`` not strictly decreasing, a non-finite or non-positive ``h``, a
        non-finite ``q``, unequal lengths.

    """
    h, q = _check_levels(h, q, 3)
    if not (np.isfinite(fallback_order) and fallback_order > 0):
        raise InputError(f"fallback_order must be > 0 and finite, got {fallback_order!r}")
    h3, q3 = h[-3:], q[-3:]
    p, reason = observed_order(h3, q3, order_bounds)
    asymptotic = p is not None
    if not asymptotic:
        p = float(fallback_order)
    ratio = h3[1] / h3[2]
    value = richardson_two_level(q3[1], q3[2], ratio, p)
    coefficient = (q3[1] - q3[2]) / (h3[1] ** p - h3[2] ** p)
    return RichardsonEstimate(value=float(value), order=float(p), coefficient=float(coefficient),
                              asymptotic=asymptotic, reason=reason, h=tuple(map(float, h3)),
                              q=tuple(map(float, q3)),
                              safety_factor=SAFETY_OBSERVED if asymptotic else SAFETY_ASSUMED)



@dataclass(frozen=True)
class PowerLawFit:
    """The least-squares fit ``q(h) = q₀ + c h^p`` to every level (:func:`fit_power_law`).

    Attributes
    ----------
    value, order, coefficient
        ``q₀``, ``p`` and ``c``.
    order_fitted
        Whether ``p`` was fitted (``False``: given).
    asymptotic
        ``False`` when the fitted ``p`` lies on a bound of ``order_bounds`` (the levels do not determine an order
        in the bounds); ``reason`` says so. Always ``True`` for a given order.
    reason
        ``""`` or why the fit is not taken as asymptotic.
    residual_std
        ``sqrt(Σ r² / (n − k))`` of the residuals, ``k`` = 3 fitted parameters (2 with a given order); NaN when
        ``n = k`` (an exact fit).
    value_stderr
        Standard error of ``q₀`` from the linear least squares at the final ``p`` (it does not include the
        uncertainty of a fitted ``p``); NaN when ``n = k``.
    h, q
        The levels, coarse to fine.

    """

    value: float
    order: float
    coefficient: float
    order_fitted: bool
    asymptotic: bool
    reason: str
    residual_std: float
    value_stderr: float
    h: tuple[float, ...]
    q: tuple[float, ...]

    def bias(self, h: float | Sequence[float] | np.ndarray | None = None) -> float | np.ndarray:
        """Relative bias ``(q − q₀)/q₀``: of every level (``None``) or the model's ``c h^p/q₀`` at ``h``."""
        return _bias(self, h)


def _linear_fit(hp: np.ndarray, q: np.ndarray) -> tuple[float, float, float, np.ndarray]:
    """``q₀, c`` of ``q = q₀ + c hp`` by least squares, the sum of squared residuals and ``(AᵀA)⁻¹``."""
    A = np.column_stack([np.ones_like(hp), hp])
    (q0, c), *_ = np.linalg.lstsq(A, q, rcond=None)
    r = q - A @ np.array([q0, c])
    return float(q0), float(c), float(r @ r), np.linalg.inv(A.T @ A)


def fit_power_law(h: Sequence[float], q: Sequence[float], *, order: float | None = None,
                  order_bounds: tuple[float, float] = ORDER_BOUNDS) -> PowerLawFit:
    """Least-squares fit of ``q(h) = q₀ + c h^p`` to every level.

    ``p`` given: linear least squares in ``(q₀, c)`` (at least two levels). ``p`` fitted (``order=None``): the
    ``p`` in ``order_bounds`` minimising the sum of squared residuals, each ``p`` with its linear ``(q₀, c)`` (a
    scan of 400 log-spaced orders refined by a bounded scalar minimisation; at least three levels). Three levels
    and a fitted ``p`` give the three-level Richardson estimate exactly (no residual); two levels and a given
    ``p`` the two-level one. ``h`` is scaled by its smallest value internally (conditioning).
    """
    h, q = _check_levels(h, q, 3 if order is None else 2)
    lo, hi = order_bounds
    if not 0 < lo < hi:
        raise InputError(f"order_bounds must be 0 < low < high, got {order_bounds!r}")
    scale = h[-1]
    x = h / scale
    reason = ""
    if order is not None:
        if not (np.isfinite(order) and order > 0):
            raise InputError(f"the order must be > 0 and finite, got {order!r}")
        p, k = float(order), 2
    else:
        k = 3
        grid = np.geomspace(lo, hi, 400)
        ssr = [_linear_fit(x**s, q)[2] for s in grid]
        i = int(np.argmin(ssr))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        p = float(minimize_scalar(lambda s: _linear_fit(x**s, q)[2], bounds=(a, b), method="bounded",
                                  options={"xatol": 1e-12}).x) if b > a else float(grid[i])
        if i in (0, len(grid) - 1):
            reason = (f"the best order lies on the bound {p:.3g} of {order_bounds}: the levels do not determine an "
                      "order (not yet asymptotic, or increments of alternating sign)")
    q0, c, ssr, cov = _linear_fit(x**p, q)
    dof = len(h) - k
    sigma = math.sqrt(ssr / dof) if dof > 0 else math.nan
    return PowerLawFit(value=q0, order=p, coefficient=c / scale**p, order_fitted=order is None,
                       asymptotic=not reason, reason=reason, residual_std=sigma,
                       value_stderr=sigma * math.sqrt(cov[0, 0]) if dof > 0 else math.nan,
                       h=tuple(map(float, h)), q=tuple(map(float, q)))
