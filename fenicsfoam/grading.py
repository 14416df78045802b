"""Graded foam fields: density and γ per cell, resolved through the foam table with their derivatives.

A foam region of a scene may take its relative density and its anisotropy γ as *fields*, one value per cell,
instead of one number (docs/scenes.md, ``[regions.NAME] density``/``gamma`` and ``[[blends]]``):

* a per-tag table (one value per cell tag of the region);
* a callable of the cell midpoints, ``f(points (n, 3)) -> values (n,)``;
* a smooth blend across the boundary between two foam regions A and B of a given width ``w``: with ``s`` the
  signed distance of a cell's midpoint to the A–B interface (negative in A, positive in B) and the C¹
  smoothstep ``S(t) = 3t² − 2t³`` on ``t = clip(1/2 + s/w, 0, 1)``, the weight of B is ``β = S(t)``
  and the cell takes ``density = (1 − β) density_A + β density_B`` and ``log γ = (1 − β) log γ_A + β log γ_B``
  (γ is blended in log space, as the table interpolates it). At ``w = 0`` the weight is the indicator of B:
  the sharp fields. Modelling choice: only density and γ are blended; each cell keeps its own region's fit,
  solid constants and *l* axis.

Every cell's constants are then read from the foam table as :func:`fenicsfoam.materials.foam_material` reads
them for one (density, γ), vectorised over the cells (:class:`FoamTable`): PCHIP in density per tabulated γ,
then PCHIP in log γ, moduli in log space. The PCHIP of SciPy is re-implemented here with forward-mode
derivatives (the interpolant is piecewise cubic in the query and, through its slopes, piecewise smooth in the
data), so that the derivatives of every modulus with respect to a cell's density and γ are exact (up to
round-off, away from the measure-zero set where PCHIP's slope limiter switches). :class:`CellMaterials` holds
the per-cell data of a whole scene and gives the DG0 moduli, the mass density and their derivatives with
respect to density, γ and ``E_solid``, the inputs of :mod:`fenicsfoam.sensitivity`.
"""

from __future__ import annotations

import importlib
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from fenicsfoam.materials import FOAM_FITS, Isotropic, TransverseIsotropic
from foambase.errors import InputError

__all__ = [
    "MODULI_NAMES",
    "CellMaterials",
    "FoamCells",
    "FoamTable",
    "blend_weights",
    "interface_triangles",
    "isotropic_moduli",
    "point_triangle_distance",
    "smoothstep",
    "spencer_moduli",
]

logger = logging.getLogger(__name__)

#: Names of the DG0 moduli of :class:`fenicsfoam.constitutive.MaterialField`: isotropic scenes, anisotropic ones.
MODULI_NAMES = {True: ("lmbda", "mu"), False: ("lmbda", "mu_T", "mu_L", "alpha", "beta")}
_LOG_COLUMNS = {"E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E"}


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
    """The aggregated foam table (:mod:`homogenization.tables`), interpolated per cell with derivatives.

    ``column(name, density, gamma)`` is :func:`fenicsfoam.materials.foam_material`'s interpolation of one
    column for arrays of (density, γ), with the exact derivatives of the interpolant.
    """

    def __init__(self, path: str | Path | None = None):
        from fenicsfoam.materials import _foam_table
        from homogenization.tables import TABLE_CSV

        self.path = str(Path(path) if path is not None else TABLE_CSV)
        self.data = _foam_table(self.path)
        self.gammas = np.unique(self.data["gamma"])
        self.log_gammas = np.log(self.gammas)
        self.density_range = (float(self.data["density"].min()), float(self.data["density"].max()))
        self.gamma_range = (float(self.gammas.min()), float(self.gammas.max()))

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
        log = name in _LOG_COLUMNS
        per_gamma = np.empty((density.size, self.gammas.size))
        per_gamma_d = np.empty_like(per_gamma)
        for j, g in enumerate(self.gammas):
            rows = self.data["gamma"] == g
            x, y = self.data["density"][rows], self.data[name][rows]
            order = np.argsort(x)
            y = np.log(y[order]) if log else y[order]
            per_gamma[:, j], per_gamma_d[:, j], _ = pchip(x[order], y, density)
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


@lru_cache(maxsize=4)
def _table(path: str | None) -> FoamTable:
    """The table of a region's ``table`` key: ``None``, a shipped table's name (``"cube"``) or a CSV path."""
    if path is not None:
        from homogenization.tables import resolve_table
        path = str(resolve_table(path)[1])
    return FoamTable(path)


# --------------------------------------------------------------------------------------------------
# Elastic constants → the moduli of the UFL energy, with derivatives
# --------------------------------------------------------------------------------------------------
def _ti_compliance(E_t, E_l, nu_t, nu_tl, G_l) -> np.ndarray:
    """Voigt compliance (m, 6, 6) of TI constants (local axis 3 = l), docs/conventions.md."""
    m = np.broadcast(E_t, E_l, nu_t, nu_tl, G_l).size
    S = np.zeros((m, 6, 6))
    S[:, 0, 0] = S[:, 1, 1] = 1.0 / E_t
    S[:, 2, 2] = 1.0 / E_l
    S[:, 0, 1] = S[:, 1, 0] = -nu_t / E_t
    S[:, 0, 2] = S[:, 2, 0] = S[:, 1, 2] = S[:, 2, 1] = -nu_tl / E_t
    S[:, 3, 3] = S[:, 4, 4] = 1.0 / G_l
    S[:, 5, 5] = 2.0 * (1.0 + nu_t) / E_t
    return S


def _ti_compliance_tangent(E_t, E_l, nu_t, nu_tl, G_l, dE_t, dE_l, dnu_t, dnu_tl, dG_l) -> np.ndarray:
    m = np.broadcast(E_t, E_l, nu_t, nu_tl, G_l).size
    dS = np.zeros((m, 6, 6))
    dS[:, 0, 0] = dS[:, 1, 1] = -dE_t / E_t**2
    dS[:, 2, 2] = -dE_l / E_l**2
    dS[:, 0, 1] = dS[:, 1, 0] = -dnu_t / E_t + nu_t * dE_t / E_t**2
    dS[:, 0, 2] = dS[:, 2, 0] = dS[:, 1, 2] = dS[:, 2, 1] = -dnu_tl / E_t + nu_tl * dE_t / E_t**2
    dS[:, 3, 3] = dS[:, 4, 4] = -dG_l / G_l**2
    dS[:, 5, 5] = 2.0 * dnu_t / E_t - 2.0 * (1.0 + nu_t) * dE_t / E_t**2
    return dS


def _spencer_from_voigt(C: np.ndarray) -> dict[str, np.ndarray]:
    """The Spencer moduli of a TI Voigt stiffness (l = axis 3), as :meth:`TransverseIsotropic.spencer_moduli`."""
    return {"lmbda": C[:, 0, 1], "mu_T": C[:, 5, 5], "mu_L": C[:, 3, 3], "alpha": C[:, 0, 2] - C[:, 0, 1],
            "beta": C[:, 0, 0] + C[:, 2, 2] - 2.0 * C[:, 0, 2] - 4.0 * C[:, 3, 3]}


def spencer_moduli(E_t, E_l, nu_t, nu_tl, G_l, tangents: Sequence[Sequence[np.ndarray]] = ()
                   ) -> tuple[dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """Spencer moduli of TI constants (arrays), and their tangents for each tangent of the five constants.

    ``C = S⁻¹`` per cell, ``dC = −C dS C``.
    """
    args = [np.atleast_1d(np.asarray(a, dtype=float)) for a in (E_t, E_l, nu_t, nu_tl, G_l)]
    C = np.linalg.inv(_ti_compliance(*args))
    out = [_spencer_from_voigt(-C @ _ti_compliance_tangent(*args, *t) @ C) for t in tangents]
    return _spencer_from_voigt(C), out


def isotropic_moduli(E, nu, tangents: Sequence[Sequence[np.ndarray]] = (), isotropic: bool = True
                     ) -> tuple[dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """Lamé moduli (``isotropic``) or the equivalent Spencer moduli of (E, ν), and their tangents."""
    E, nu = np.atleast_1d(np.asarray(E, dtype=float)), np.atleast_1d(np.asarray(nu, dtype=float))

    def moduli(E, nu, dE, dnu):
        q = (1 + nu) * (1 - 2 * nu)
        lam = E * nu / q
        mu = E / (2 * (1 + nu))
        dq = dnu * (1 - 2 * nu) - 2 * (1 + nu) * dnu
        dlam = (dE * nu + E * dnu) / q - E * nu * dq / q**2
        dmu = dE / (2 * (1 + nu)) - E * dnu / (2 * (1 + nu) ** 2)
        return (lam, mu), (dlam, dmu)

    def named(lam, mu):
        if isotropic:
            return {"lmbda": lam, "mu": mu}
        zero = np.zeros_like(lam)
        return {"lmbda": lam, "mu_T": mu, "mu_L": mu, "alpha": zero, "beta": zero}

    (lam, mu), _ = moduli(E, nu, 0.0, 0.0)
    out = [named(*moduli(E, nu, dE, dnu)[1]) for dE, dnu in tangents]
    return named(lam, mu), out


# --------------------------------------------------------------------------------------------------
# Per-cell materials of a scene
# --------------------------------------------------------------------------------------------------
@dataclass
class FoamCells:
    """The foam cells of one region: their local indices, per-cell density and γ, and the region's solid."""

    name: str
    cells: np.ndarray            #: local indices of the owned cells
    density: np.ndarray          #: relative density per cell
    gamma: np.ndarray            #: anisotropy γ per cell
    E_solid: float
    nu_solid: float
    rho_solid: float = 0.0
    fit: str = "transverse"
    table: str | None = None

    def __post_init__(self):
        if self.fit not in FOAM_FITS:
            raise InputError(f"region {self.name!r}: fit must be one of {FOAM_FITS}, got {self.fit!r}")
        from homogenization.tables import NU_SOLID
        if not np.isclose(self.nu_solid, NU_SOLID, rtol=0, atol=1e-12):
            raise InputError(f"region {self.name!r}: nu_solid = {self.nu_solid!r}, the foam table's solid has "
                             f"nu = {NU_SOLID}")
        if not (np.isfinite(self.E_solid) and self.E_solid > 0):
            raise InputError(f"region {self.name!r}: E_solid must be > 0 Pa, got {self.E_solid!r}")
        self.cells = np.asarray(self.cells, dtype=np.int64)
        self.density = np.broadcast_to(np.asarray(self.density, dtype=float), self.cells.shape).copy()
        self.gamma = np.broadcast_to(np.asarray(self.gamma, dtype=float), self.cells.shape).copy()

    def isotropic_cells(self) -> np.ndarray:
        """Which cells get an isotropic material (fit ``isotropic``; ``paper`` at γ = 1)."""
        if self.fit == "isotropic":
            return np.ones(self.cells.size, dtype=bool)
        if self.fit == "paper":
            return self.gamma == 1.0
        return np.zeros(self.cells.size, dtype=bool)

    def moduli(self, isotropic: bool, with_derivatives: bool = False):
        """Moduli (Pa) per cell, and (optionally) their derivatives with respect to the cell's density and γ.

        Returns ``(moduli, d_density, d_gamma)``, each a dict name → (n_cells,) array (the derivatives
        ``None`` unless ``with_derivatives``).
        """
        table = _table(None if self.table is None else str(self.table))
        table.check(self.density, self.gamma, f"region {self.name!r}: ")
        rho, E = self.density, self.E_solid

        def col(name):
            return table.column(name, rho, self.gamma)

        names = MODULI_NAMES[isotropic]
        values = {n: np.zeros(self.cells.size) for n in names}
        d_rho = {n: np.zeros(self.cells.size) for n in names}
        d_gam = {n: np.zeros(self.cells.size) for n in names}

        def put(mask, result, tangents):
            for n in names:
                values[n][mask] = result[n]
                d_rho[n][mask] = tangents[0][n]
                d_gam[n][mask] = tangents[1][n]

        iso = self.isotropic_cells()
        if isotropic and not iso.all():
            raise InputError(f"region {self.name!r}: {int((~iso).sum())} cell(s) became anisotropic in a field of "
                             "isotropic moduli (a paper fit whose γ left 1); rebuild the field")
        if self.fit == "isotropic":
            c_E, c_nu = col("iso_E"), col("iso_nu")
            put(iso, *isotropic_moduli(E * c_E.value, c_nu.value,
                                       [(E * c_E.d_density, c_nu.d_density), (E * c_E.d_gamma, c_nu.d_gamma)],
                                       isotropic=isotropic))
        elif self.fit == "transverse":
            cols = [col(n) for n in ("ti_E_t", "ti_E_l", "ti_nu_t", "ti_nu_tl", "ti_G_l")]
            scale = (E, E, 1.0, 1.0, E)
            put(~iso, *spencer_moduli(*[s * c.value for s, c in zip(scale, cols)],
                                      tangents=[[s * c.d_density for s, c in zip(scale, cols)],
                                                [s * c.d_gamma for s, c in zip(scale, cols)]]))
        else:  # paper
            c = {n: col(n) for n in ("E1", "E2", "E3", "G12", "G13", "nu12", "nu13", "nu21", "nu23", "nu31", "nu32")}

            def mean(names, attr, mask):
                return np.mean([getattr(c[n], attr)[mask] for n in names], axis=0)

            if iso.any():
                nus = ("nu12", "nu13", "nu21", "nu23", "nu31", "nu32")
                put(iso, *isotropic_moduli(
                    E * mean(("E1", "E2", "E3"), "value", iso), mean(nus, "value", iso),
                    [(E * mean(("E1", "E2", "E3"), a, iso), mean(nus, a, iso)) for a in ("d_density", "d_gamma")],
                    isotropic=isotropic))
            if (~iso).any():
                ti = ~iso
                groups = ((("E2", "E3"), E), (("E1",), E), (("nu23", "nu32"), 1.0), (("nu21", "nu31"), 1.0),
                          (("G12", "G13"), E))
                put(ti, *spencer_moduli(*[s * mean(g, "value", ti) for g, s in groups],
                                        tangents=[[s * mean(g, a, ti) for g, s in groups]
                                                  for a in ("d_density", "d_gamma")]))
        if not with_derivatives:
            return values, None, None
        return values, d_rho, d_gam


class CellMaterials:
    """The materials of every owned cell of a scene: fixed constants, or foam data per cell.

    Parameters
    ----------
    n_cells
        Number of owned cells.
    fixed
        ``{name: (cells, material)}``: regions of explicit :class:`~fenicsfoam.materials.Isotropic` or
        :class:`~fenicsfoam.materials.TransverseIsotropic` constants, on the given owned cells.
    foams
        The foam regions (:class:`FoamCells`).

    Every owned cell must belong to exactly one region. ``isotropic`` is true when every cell's material is
    isotropic (the MaterialField then holds Lamé moduli).

    """

    def __init__(self, n_cells: int, fixed: Mapping[str, tuple[np.ndarray, object]] = (),
                 foams: Sequence[FoamCells] = (), descriptions: Mapping[str, dict] | None = None,
                 blend_weight: Mapping[str, tuple[str, str, np.ndarray]] | None = None):
        self.n_cells = n_cells
        self.fixed = dict(fixed)
        self.foams = {f.name: f for f in foams}
        count = np.zeros(n_cells, dtype=int)
        for cells, _ in self.fixed.values():
            count[np.asarray(cells, dtype=np.int64)] += 1
        for f in self.foams.values():
            count[f.cells] += 1
        if np.any(count != 1):
            raise InputError(f"{int(np.sum(count == 0))} cell(s) have no material and {int(np.sum(count > 1))} "
                             "more than one")
        self.isotropic = (all(isinstance(m, Isotropic) for _, m in self.fixed.values())
                          and all(f.isotropic_cells().all() for f in self.foams.values()))
        #: foam region → {"density": description, "gamma": description} (a number, per-tag table or function)
        self.descriptions = {name: dict(d) for name, d in (descriptions or {}).items()}
        #: foam region in a blend → (A, B, weight of B on the region's cells)
        self.blend_weight = dict(blend_weight or {})

    @classmethod
    def from_regions(cls, mesh, cell_tags, regions: Sequence, materials: Mapping[str, object] | None = None,
                     blends: Sequence[Mapping[str, object]] = ()) -> CellMaterials:
        """The cells of a scene's regions, foam densities and γ resolved per cell.

        ``regions`` are :class:`fenicsfoam.scene.Region`-like (``name, tags, material, parameters``), a foam's
        density and γ a number, a per-tag table or a function (module docstring); ``materials`` gives the
        resolved material of non-foam regions (default: built from their parameters); ``blends`` are
        ``{"regions": (A, B), "width": w}`` between two foam regions whose density and γ are numbers.
        """
        from fenicsfoam.orientation import owned_cell_tags

        tags = owned_cell_tags(mesh, cell_tags)
        fixed, foams, descriptions = {}, [], {}
        for region in regions:
            cells = np.flatnonzero(np.isin(tags, list(region.tags)))
            if region.material != "foam":
                material = (materials or {}).get(region.name)
                if material is None:
                    kind = Isotropic if region.material == "isotropic" else TransverseIsotropic
                    material = kind(**region.parameters)
                fixed[region.name] = (cells, as_material(material))
                continue
            p = dict(region.parameters)
            descriptions[region.name] = {"density": p.pop("density"), "gamma": p.pop("gamma")}
            foams.append(FoamCells(region.name, cells, 0.0, 1.0, **p))
        by_name = {f.name: f for f in foams}
        weights = {}
        for blend in blends:
            a, b = blend["regions"]
            for name in (a, b):
                if name not in by_name:
                    raise InputError(f"blend {a!r}–{b!r}: {name!r} is not a foam region")
                if name in weights:
                    raise InputError(f"blend {a!r}–{b!r}: region {name!r} is already in a blend")
                for key in ("density", "gamma"):
                    if not _is_number(descriptions[name][key]):
                        raise InputError(f"blend {a!r}–{b!r}: region {name!r} must give {key} as a number to be "
                                         "blended")
            tags_a = next(r.tags for r in regions if r.name == a)
            tags_b = next(r.tags for r in regions if r.name == b)
            for name in (a, b):
                weights[name] = (a, b, blend_weights(mesh, cell_tags, tags_a, tags_b, float(blend["width"]),
                                                     by_name[name].cells))
        self = cls(tags.size, fixed, foams, descriptions, weights)
        for name in self.foams:
            self.resolve(name, mesh, cell_tags)
        self.isotropic = (all(isinstance(m, Isotropic) for _, m in self.fixed.values())
                          and all(f.isotropic_cells().all() for f in self.foams.values()))
        return self

    def resolve(self, name: str, mesh=None, cell_tags=None) -> None:
        """Recompute the per-cell density and γ of the foam region ``name`` from its descriptions."""
        foam, spec = self.foams[name], self.descriptions[name]
        if name in self.blend_weight:
            a, b, weight = self.blend_weight[name]
            da, db = self.descriptions[a], self.descriptions[b]
            foam.density = (1.0 - weight) * float(da["density"]) + weight * float(db["density"])
            foam.gamma = blend_log(float(da["gamma"]), float(db["gamma"]), weight)
            return
        for key in ("density", "gamma"):
            if _is_number(spec[key]):
                setattr(foam, key, np.full(foam.cells.size, float(spec[key])))
            elif mesh is not None:
                setattr(foam, key, field_values(spec[key], mesh, cell_tags, foam.cells, f"regions.{name}.{key}"))

    def set_region_value(self, key: str, name: str, value: float) -> None:
        """Set the number ``key`` (``"density"`` or ``"gamma"``) of foam region ``name`` and re-resolve the cells."""
        if name not in self.foams or not _is_number(self.descriptions[name][key]):
            raise InputError(f"{key}:{name}: not a foam region whose {key} is a number "
                             f"(foam regions: {sorted(self.foams)})")
        self.descriptions[name][key] = float(value)
        for region in self.foams:
            if region == name or (region in self.blend_weight and name in self.blend_weight[region][:2]):
                self.resolve(region)

    def region_derivative(self, key: str, name: str) -> np.ndarray:
        """``∂(cell density or γ)/∂(region value)`` on every owned cell (zero outside the region and its blend)."""
        out = np.zeros(self.n_cells)
        if name not in self.foams or not _is_number(self.descriptions[name][key]):
            raise InputError(f"{key}:{name}: not a foam region whose {key} is a number "
                             f"(foam regions: {sorted(self.foams)})")
        for region, foam in self.foams.items():
            if region in self.blend_weight and name in self.blend_weight[region][:2]:
                a, _, weight = self.blend_weight[region]
                share = 1.0 - weight if name == a else weight
            elif region == name:
                share = np.ones(foam.cells.size)
            else:
                continue
            value = float(self.descriptions[name][key])
            out[foam.cells] = share if key == "density" else share * foam.gamma / value
        return out

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the DG0 moduli."""
        return MODULI_NAMES[self.isotropic]

    def _fixed_moduli(self, material) -> dict[str, float]:
        if self.isotropic:
            return dict(zip(MODULI_NAMES[True], material.lame))
        return material.spencer_moduli()

    def rho(self) -> np.ndarray:
        """Mass density per cell (kg/m³): the fixed materials' ``rho``, ``rho_solid · density`` of the foams."""
        rho = np.zeros(self.n_cells)
        for cells, material in self.fixed.values():
            rho[np.asarray(cells, dtype=np.int64)] = material.rho
        for f in self.foams.values():
            rho[f.cells] = f.rho_solid * f.density
        return rho

    def moduli(self) -> dict[str, np.ndarray]:
        """The DG0 moduli (Pa) per cell."""
        out = {n: np.zeros(self.n_cells) for n in self.names}
        for cells, material in self.fixed.values():
            for n, v in self._fixed_moduli(material).items():
                out[n][np.asarray(cells, dtype=np.int64)] = v
        for f in self.foams.values():
            values, _, _ = f.moduli(self.isotropic)
            for n in self.names:
                out[n][f.cells] = values[n]
        return out

    def derivatives(self) -> dict[str, dict[str, np.ndarray]]:
        """Per-cell derivatives of the moduli and of ``rho``: with respect to each cell's density and γ.

        Returns ``{"density": {name: (n_cells,)}, "gamma": {...}, "E_solid": {...}}``, the names being the
        moduli and ``"rho"``; ``E_solid`` is the derivative when every foam region's ``E_solid`` changes by the
        same amount (moduli scale linearly with it). Zero on the cells of fixed materials.
        """
        out = {k: {n: np.zeros(self.n_cells) for n in (*self.names, "rho")} for k in ("density", "gamma", "E_solid")}
        for f in self.foams.values():
            values, d_rho, d_gam = f.moduli(self.isotropic, with_derivatives=True)
            for n in self.names:
                out["density"][n][f.cells] = d_rho[n]
                out["gamma"][n][f.cells] = d_gam[n]
                out["E_solid"][n][f.cells] = values[n] / f.E_solid
            out["density"]["rho"][f.cells] = f.rho_solid
        return out

    def material_field(self, mesh, materials: Mapping[int, object] | None = None):
        """The :class:`~fenicsfoam.constitutive.MaterialField` of these cells (DG0 functions on ``mesh``)."""
        from fenicsfoam.constitutive import MaterialField
        from fenicsfoam.orientation import cell_function

        moduli = self.moduli()
        return MaterialField(materials=dict(materials or {}), isotropic=self.isotropic,
                             moduli={n: cell_function(mesh, moduli[n], name=n) for n in self.names},
                             rho=cell_function(mesh, self.rho(), name="rho"))

    def update(self, field) -> None:
        """Write the current per-cell data into an existing MaterialField (its DG0 values; ghosts updated)."""
        from fenicsfoam.orientation import set_cell_values

        moduli = self.moduli()
        for n in self.names:
            set_cell_values(field.moduli[n], moduli[n])
        set_cell_values(field.rho, self.rho())


# --------------------------------------------------------------------------------------------------
# Blends across a region boundary
# --------------------------------------------------------------------------------------------------
def smoothstep(t: np.ndarray) -> np.ndarray:
    """``3t² − 2t³`` on ``clip(t, 0, 1)``: C¹, 0 below 0, 1 above 1."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def interface_triangles(mesh, cell_tags, tags_a: Sequence[int], tags_b: Sequence[int]) -> np.ndarray:
    """Coordinates (k, 3, 3) of the facets shared by a cell tagged in ``tags_a`` and one in ``tags_b``.

    Every rank lists the facets of its owned cells of either set as sorted global vertex triples; the lists are
    gathered on every rank and intersected, so the result is the whole interface on every rank, whatever the
    partition and ghosting (facets are keyed by the input indices of their vertices' geometry nodes).
    Tetrahedral meshes.
    """
    from fenicsfoam.orientation import owned_cell_tags

    tags = owned_cell_tags(mesh, cell_tags)
    x = mesh.geometry.x
    geometry_dofs = mesh.geometry.dofmap
    global_node = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)

    def faces(selected):
        cells = np.flatnonzero(np.isin(tags, list(selected)))
        if cells.size == 0:
            return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3, 3))
        nodes = np.array([geometry_dofs.links(c)[:4] for c in cells])  # (n, 4): the vertices' geometry nodes
        keys, coords = [], []
        for drop in range(4):
            keep = [i for i in range(4) if i != drop]
            keys.append(np.sort(global_node[nodes[:, keep]], axis=1))
            coords.append(x[nodes[:, keep]])
        return np.concatenate(keys), np.concatenate(coords)

    comm = mesh.comm
    ka, ca = faces(tags_a)
    kb, _ = faces(tags_b)
    ka_all = np.concatenate(comm.allgather(ka))
    ca_all = np.concatenate(comm.allgather(ca))
    kb_all = np.concatenate(comm.allgather(kb))
    if ka_all.size == 0 or kb_all.size == 0:
        return np.zeros((0, 3, 3))
    view = np.dtype((np.void, ka_all.dtype.itemsize * 3))
    va = np.ascontiguousarray(ka_all).view(view).ravel()
    vb = np.ascontiguousarray(kb_all).view(view).ravel()
    shared = np.isin(va, vb)
    _, first = np.unique(va[shared], return_index=True)
    return ca_all[np.flatnonzero(shared)[first]]


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Distance from each point (n, 3) to the nearest of the triangles (k, 3, 3), exactly (closest-point regions)."""
    points = np.asarray(points, dtype=float)
    out = np.full(points.shape[0], np.inf)
    if triangles.shape[0] == 0:
        return out
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac = b - a, c - a
    for start in range(0, points.shape[0], chunk):
        p = points[start:start + chunk, None, :]
        out[start:start + chunk] = np.sqrt(np.min(_squared_distance(p, a, b, c, ab, ac), axis=1))
    return out


def _squared_distance(p, a, b, c, ab, ac):
    """Squared distance from points p (n, 1, 3) to triangles (k, 3): Ericson's closest point, vectorised."""
    def dot(u, v):
        return np.einsum("...i,...i->...", u, v)

    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # default: inside the face
    q = a + v_in[..., None] * ab + w_in[..., None] * ac
    regions = [
        ((d1 <= 0) & (d2 <= 0), a + 0 * p),
        ((d3 >= 0) & (d4 <= d3), b + 0 * p),
        ((d6 >= 0) & (d5 <= d6), c + 0 * p),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[..., None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[..., None] * ac),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[..., None] * (c - b)),
    ]
    decided = np.zeros(q.shape[:-1], dtype=bool)
    for mask, point in regions:
        use = mask & ~decided
        q = np.where(use[..., None], point, q)
        decided |= use
    return dot(p - q, p - q)


def blend_weights(mesh, cell_tags, tags_a: Sequence[int], tags_b: Sequence[int], width: float,
                  cells: np.ndarray | None = None) -> np.ndarray:
    """Weight of region B in the owned ``cells`` (default: all) for a blend of width ``width`` (m), module docstring.

    0 deep in A, 1 deep in B, ``S(1/2 + s/w)`` within ``w/2`` of the interface (``s``: signed distance of the
    cell's midpoint, positive in B); the indicator of B for ``w = 0``. Cells in neither region get the weight
    of their side as if they were in A (callers pass cells of A or B only).
    """
    from dolfinx.mesh import compute_midpoints

    from fenicsfoam.orientation import owned_cell_tags

    if not (np.isfinite(width) and width >= 0):
        raise InputError(f"blend width must be a length >= 0 (m), got {width!r}")
    n = mesh.topology.index_map(mesh.topology.dim).size_local
    cells = np.arange(n) if cells is None else np.asarray(cells, dtype=np.int64)
    in_b = np.isin(owned_cell_tags(mesh, cell_tags)[cells], list(tags_b))
    if width == 0.0:
        return in_b.astype(float)
    triangles = interface_triangles(mesh, cell_tags, tags_a, tags_b)
    if triangles.shape[0] == 0:
        raise InputError(f"regions with tags {list(tags_a)} and {list(tags_b)} share no facet: nothing to blend")
    midpoints = compute_midpoints(mesh, mesh.topology.dim, cells.astype(np.int32))
    s = point_triangle_distance(midpoints, triangles) * np.where(in_b, 1.0, -1.0)
    return smoothstep(0.5 + s / width)


# --------------------------------------------------------------------------------------------------
# Field descriptions of a scene
# --------------------------------------------------------------------------------------------------
def import_callable(spec: str) -> Callable[[np.ndarray], np.ndarray]:
    """The function named ``"module:name"``."""
    module, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except Exception as exc:  # ImportError, AttributeError, or whatever the module raises when imported
        raise InputError(f"cannot import {spec!r}: {type(exc).__name__}: {exc}") from exc


def field_values(spec, mesh, cell_tags, cells: np.ndarray, what: str) -> np.ndarray:
    """Per-cell values of a field description on the owned ``cells``.

    ``spec``: a number; ``{"per_tag": {tag: value}}`` (every cell's tag must be listed); or
    ``{"function": "module:name"}``, called with the cells' midpoints (n, 3) and returning (n,) values.
    """
    from dolfinx.mesh import compute_midpoints

    from fenicsfoam.orientation import owned_cell_tags

    if isinstance(spec, int | float) and not isinstance(spec, bool):
        return np.full(cells.size, float(spec))
    if "per_tag" in spec:
        tags = owned_cell_tags(mesh, cell_tags)[cells]
        table = {int(t): float(v) for t, v in spec["per_tag"].items()}
        missing = sorted(set(np.unique(tags).tolist()) - set(table))
        missing = sorted(set().union(*mesh.comm.allgather(set(missing))))
        if missing:
            raise InputError(f"{what}: cell tags {missing} have no value (values given for {sorted(table)})")
        return np.array([table[int(t)] for t in tags])
    from foambase.mpi import on_every_rank

    midpoints = compute_midpoints(mesh, mesh.topology.dim, cells.astype(np.int32))

    def evaluate() -> np.ndarray:
        try:
            f = import_callable(spec["function"]) if isinstance(spec["function"], str) else spec["function"]
        except InputError as exc:
            raise InputError(f"{what}: {exc}") from exc
        try:
            values = np.asarray(f(midpoints))
        except (Exception, SystemExit) as exc:  # the user's function: named, on every rank (it may fail on one)
            raise InputError(f"{what}: {spec['function']}(x) raised {type(exc).__name__}: {exc}") from exc
        if np.iscomplexobj(values):
            raise InputError(f"{what}: the function returned complex values (e.g. {values.ravel()[:1]}); "
                             "it must return real numbers")
        values = np.asarray(values, dtype=float)
        if values.shape != (cells.size,):
            raise InputError(f"{what}: the function must map points ({cells.size}, 3) to values ({cells.size},), "
                             f"got shape {values.shape}")
        return values
    return on_every_rank(mesh.comm, evaluate, f"{what}: the function failed")


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def blend_log(a: float, b: float, weight: np.ndarray) -> np.ndarray:
    """``exp((1 − β) log a + β log b)`` (exactly ``a`` where β = 0 and ``b`` where β = 1)."""
    weight = np.asarray(weight, dtype=float)
    mixed = np.exp((1.0 - weight) * math.log(a) + weight * math.log(b))
    return np.where(weight == 0.0, a, np.where(weight == 1.0, b, mixed))


def as_material(material) -> object:
    """Pass-through check that ``material`` is a fixed material of the macro model."""
    if not isinstance(material, Isotropic | TransverseIsotropic):
        raise InputError(f"expected Isotropic or TransverseIsotropic, got {material!r}")
    return material
