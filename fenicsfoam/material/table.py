"""The foam table and its one interpolation: PCHIP with forward-mode derivatives.

The aggregated foam table (:mod:`homogenization.tables`) holds, per (relative density, γ), the seed-averaged
homogenized constants of foams of an isotropic solid with ``E_s = 1``, ``ν_s = 0.3``. :class:`FoamTable` reads
one and interpolates its columns; every user of the table goes through it: the uniform foam regions
(:func:`fenicsfoam.material.foam.foam_material`), the graded per-cell fields (:mod:`fenicsfoam.grading`), the
per-seed tables of :mod:`fenicsfoam.uncertainty` and the derivatives of :mod:`fenicsfoam.design`.

SciPy's PCHIP (Fritsch–Carlson, ``scipy.interpolate.PchipInterpolator``) is re-implemented here with
forward-mode derivatives (the interpolant is piecewise cubic in the query and, through its slopes, piecewise
smooth in the data), so that the derivatives of every column with respect to density and γ are exact (up to
round-off, away from the measure-zero set where PCHIP's slope limiter switches); its values equal SciPy's up
to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from foambase.errors import InputError

__all__ = ["FOAM_FITS", "LOG_COLUMNS", "FoamTable", "Interpolated", "foam_table", "pchip"]

#: How a foam's homogenized stiffness becomes the constants of a region (:func:`~fenicsfoam.material.foam_material`).
FOAM_FITS = ("transverse", "isotropic", "paper")
#: Table columns interpolated in log space (moduli); the others (Poisson's ratios) linearly.
LOG_COLUMNS = frozenset({"E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E"})


# --------------------------------------------------------------------------------------------------
# PCHIP (SciPy's Fritsch–Carlson variant) with forward-mode derivatives
# --------------------------------------------------------------------------------------------------
def _edge_slope(h0, h1, m0, m1, dm0, dm1):
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    dd = ((2 * h0 + h1) * dm0 - h0 * dm1) / (h0 + h1)
    mask = np.sign(d) != np.sign(m0)
    mmm = ~mask & (np.sign(m0) != np.sign(m1)) & (np.abs(d) > 3.0 * np.abs(m0))
    d = np.where(mask, 0.0, np.where(mmm, 3.0 * m0, d))
    dd = np.where(mask, 0.0, np.where(mmm, 3.0 * dm0, dd))
    return d, dd


def _pchip_slopes(x: np.ndarray, y: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PCHIP node slopes of data ``y`` (m, n) at nodes ``x`` (n,), and their tangents for data tangents ``dy``."""
    h = np.diff(x)
    m = np.diff(y, axis=1) / h
    dm = np.diff(dy, axis=1) / h
    if x.size == 2:
        return np.repeat(m, 2, axis=1), np.repeat(dm, 2, axis=1)
    d, dd = np.zeros_like(y), np.zeros_like(y)
    m0, m1, dm0, dm1 = m[:, :-1], m[:, 1:], dm[:, :-1], dm[:, 1:]
    flat = (np.sign(m1) != np.sign(m0)) | (m1 == 0) | (m0 == 0)
    w1, w2 = 2 * h[1:] + h[:-1], h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        whmean = (w1 / m0 + w2 / m1) / (w1 + w2)
        dwhmean = (-w1 * dm0 / m0**2 - w2 * dm1 / m1**2) / (w1 + w2)
        d[:, 1:-1] = np.where(flat, 0.0, 1.0 / whmean)
        dd[:, 1:-1] = np.where(flat, 0.0, -dwhmean / whmean**2)
    d[:, 0], dd[:, 0] = _edge_slope(h[0], h[1], m[:, 0], m[:, 1], dm[:, 0], dm[:, 1])
    d[:, -1], dd[:, -1] = _edge_slope(h[-1], h[-2], m[:, -1], m[:, -2], dm[:, -1], dm[:, -2])
    return d, dd


def pchip(x: np.ndarray, y: np.ndarray, t: np.ndarray, dy: np.ndarray | None = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCHIP interpolant of data ``y`` at nodes ``x``, at the queries ``t`` (m,).

    ``y`` is (n,) (the same data for every query) or (m, n) (one data row per query). Returns the values, their
    derivatives with respect to ``t`` and their tangents for the data tangents ``dy`` (same shape as ``y``;
    zero if ``None``). Values equal SciPy's ``PchipInterpolator`` (up to round-off); ``t`` must lie in
    ``[x[0], x[-1]]`` (the foam table is never extrapolated).
    """
    x = np.asarray(x, dtype=float)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    y = np.atleast_2d(np.asarray(y, dtype=float))
    dy = np.zeros_like(y) if dy is None else np.atleast_2d(np.asarray(dy, dtype=float))
    d, dd = _pchip_slopes(x, y, dy)
    k = np.clip(np.searchsorted(x, t, side="right") - 1, 0, x.size - 2)
    h = x[k + 1] - x[k]
    s = (t - x[k]) / h
    rows = np.arange(t.size) if y.shape[0] == t.size else np.zeros(t.size, dtype=int)
    basis = (2 * s**3 - 3 * s**2 + 1, h * (s**3 - 2 * s**2 + s), -2 * s**3 + 3 * s**2, h * (s**3 - s**2))
    dbasis = ((6 * s**2 - 6 * s) / h, 3 * s**2 - 4 * s + 1, (-6 * s**2 + 6 * s) / h, 3 * s**2 - 2 * s)

    def combine(b, yy, ddd):
        return b[0] * yy[rows, k] + b[1] * ddd[rows, k] + b[2] * yy[rows, k + 1] + b[3] * ddd[rows, k + 1]

    return combine(basis, y, d), combine(dbasis, y, d), combine(basis, dy, dd)


# --------------------------------------------------------------------------------------------------
# The foam table, vectorised
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Interpolated:
    """A table column at many (density, γ): values and their derivatives with respect to density and γ."""

    value: np.ndarray
    d_density: np.ndarray
    d_gamma: np.ndarray


class FoamTable:
    """An aggregated foam table (:mod:`homogenization.tables`), interpolated with derivatives.

    The one interpolation of the foam table, for one (density, γ) (:meth:`value`, read by
    :func:`fenicsfoam.material.foam.foam_material`) or one per cell (:meth:`column`): PCHIP in density per
    tabulated γ, then PCHIP in log γ; moduli in log space, Poisson's ratios linearly. Both reproduce the table
    exactly at its nodes, and PCHIP keeps every monotone stretch of the data monotone (no overshoot between
    nodes). A table of one density (or one γ) is exact at that node only. Build it with :func:`foam_table`
    (cached per file).
    """

    def __init__(self, path: str | Path | None = None):
        from homogenization.tables import read_csv, resolve_table

        self.path = str(Path(path) if path is not None else resolve_table(None)[1])
        self.data = read_csv(self.path)
        self.gammas = np.unique(self.data["gamma"])
        self.log_gammas = np.log(self.gammas)
        self.density_range = (float(self.data["density"].min()), float(self.data["density"].max()))
        self.gamma_range = (float(self.gammas.min()), float(self.gammas.max()))
        #: the sorted densities tabulated at each γ (a full grid has the same at every γ)
        self.grid = {g: tuple(np.sort(self.data["density"][self.data["gamma"] == g])) for g in self.gammas}

    def check(self, density: np.ndarray, gamma: np.ndarray, what: str = "") -> None:
        """Raise :class:`InputError` if some (density, γ) lies outside the table (the number of such cells)."""
        for name, values, (lo, hi) in (("density", density, self.density_range), ("gamma", gamma, self.gamma_range)):
            values = np.asarray(values, dtype=float)
            bad = ~(np.isfinite(values) & (values >= lo - 1e-12) & (values <= hi + 1e-12))
            if bad.any():
                raise InputError(f"{what}{int(bad.sum())} cell(s) have {name} outside the tabulated range "
                                 f"[{lo:g}, {hi:g}] of the foam table (e.g. {float(values[bad][0])!r})")

    def column(self, name: str, density: np.ndarray, gamma: np.ndarray) -> Interpolated:
        """The column ``name`` at the points (density, γ), with derivatives (moduli per unit ``E_solid``)."""
        density = np.atleast_1d(np.asarray(density, dtype=float))
        gamma = np.atleast_1d(np.asarray(gamma, dtype=float))
        log = name in LOG_COLUMNS
        per_gamma = np.empty((density.size, self.gammas.size))
        per_gamma_d = np.empty_like(per_gamma)
        for j, g in enumerate(self.gammas):
            rows = self.data["gamma"] == g
            x, y = self.data["density"][rows], self.data[name][rows]
            order = np.argsort(x)
            y = np.log(y[order]) if log else y[order]
            if x.size > 1:
                per_gamma[:, j], per_gamma_d[:, j], _ = pchip(x[order], y, density)
            else:
                per_gamma[:, j], per_gamma_d[:, j] = y[0], 0.0
        if self.gammas.size > 1:
            t = np.log(gamma)
            value, d_t, d_density = pchip(self.log_gammas, per_gamma, t, per_gamma_d)
            d_gamma = d_t / gamma
        else:
            value, d_density, d_gamma = per_gamma[:, 0], per_gamma_d[:, 0], np.zeros_like(density)
        if log:
            value = np.exp(value)
            d_density, d_gamma = value * d_density, value * d_gamma
        return Interpolated(value, d_density, d_gamma)

    def value(self, name: str, density: float, gamma: float) -> float:
        """The column ``name`` at one (density, γ) (moduli per unit ``E_solid``)."""
        return float(self.column(name, density, gamma).value[0])


@lru_cache(maxsize=4)
def foam_table(table: str | None = None) -> FoamTable:
    """The :class:`FoamTable` of a region's ``table``: ``None`` (the default), a shipped table's name or a CSV path."""
    from homogenization.tables import resolve_table

    return FoamTable(str(resolve_table(table)[1]))
