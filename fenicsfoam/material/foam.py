"""The foam kind: homogenized constants of a stochastic Voronoi foam from the foam table, uniform or per cell.

:func:`foam_material` gives the constants of a foam region of one relative density and one γ; :class:`FoamCells`
gives the DG0 moduli of a region whose density and γ vary from cell to cell, with their derivatives with respect
to each cell's density and γ (the inputs of :mod:`fenicsfoam.sensitivity` and :mod:`fenicsfoam.design`). Both read
the table through the one interpolation of :class:`~fenicsfoam.material.table.FoamTable` and turn constants into
moduli with :mod:`fenicsfoam.material.moduli`, so a graded region whose fields are uniform has the moduli of the
uniform region, up to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fenicsfoam.material.constants import (
    MAX_MODULUS,
    InadmissibleMaterialError,
    Isotropic,
    TransverseIsotropic,
    check_modulus,
)
from fenicsfoam.material.moduli import MODULI_NAMES, isotropic_moduli, spencer_moduli
from fenicsfoam.material.table import FOAM_FITS, foam_table
from foambase.errors import InputError

__all__ = ["FoamCells", "foam_material"]


def foam_material(density: float, gamma: float, E_solid: float, nu_solid: float, *, rho_solid: float = 0.0,
                  fit: str = "transverse", table: str | Path | None = None) -> Isotropic | TransverseIsotropic:
    """Homogenized constants of a stochastic Voronoi foam, from the shipped table (:mod:`homogenization.tables`).

    The table holds, per (relative density, γ), the seed-averaged homogenized constants of foams of an
    isotropic solid with ``E_s = 1``, ``ν_s = 0.3``; moduli scale linearly with ``E_solid``, and the mass
    density is ``rho_solid · density``. Between table nodes the constants are interpolated monotonically
    (:class:`~fenicsfoam.material.table.FoamTable`: PCHIP in density, then in log γ; moduli in log space).

    Parameters
    ----------
    density
        Relative density (solid volume fraction) within the tabulated range.
    gamma
        Degree of anisotropy γ within the tabulated range (γ = 1 isotropic).
    E_solid, nu_solid
        The printed solid's Young's modulus (Pa) and Poisson's ratio; ``nu_solid`` must be the table's (0.3).
    rho_solid
        The solid's mass density (kg/m³).
    fit
        ``"transverse"``: the closest TI stiffness with *l* = the foam's distinct (soft for γ < 1) axis x
        (``TransverseIsotropic``, local axis 3 = *l*: orient it with the foam's x axis).
        ``"isotropic"``: the closest isotropic stiffness. ``"paper"``: the paper's averaging of engineering
        constants — for γ = 1 ``Isotropic(E = mean(E1, E2, E3), ν = mean of the six ν_ij)``, otherwise
        ``TransverseIsotropic(E_t = mean(E2, E3), E_l = E1, nu_t = mean(ν23, ν32), nu_tl = mean(ν21, ν31),
        G_l = mean(G12, G13))``.
    table
        ``None`` (the default): ``homogenization.tables.DEFAULT_TABLE``, the paper's foam over density
        0.09–0.35 × γ 0.1–1. Else the name of a shipped table (``homogenization.tables.shipped_tables()``, each
        described in ``TABLE_NOTES``: e.g. ``"cube"``, the former default, the Euclidean strut foam with 8 cells in
        the unit cube) or the path of an aggregated table CSV (a ``Path``, or a string ending in ``.csv``).

    """
    from homogenization.tables import NU_SOLID, resolve_table

    for name, value in (("density", density), ("gamma", gamma), ("E_solid", E_solid), ("nu_solid", nu_solid),
                        ("rho_solid", rho_solid)):
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise InputError(f"{name} must be a number, got {type(value).__name__} {value!r:.80}")
    if fit not in FOAM_FITS:
        raise InputError(f"fit must be one of {FOAM_FITS}, got {fit!r}")
    label, table = resolve_table(table)
    check_modulus("E_solid", E_solid)
    if not (np.isfinite(rho_solid) and rho_solid >= 0):
        raise InadmissibleMaterialError(f"rho_solid must be finite and >= 0 kg/m³, got {rho_solid!r}")
    if not np.isclose(nu_solid, NU_SOLID, rtol=0, atol=1e-12):
        raise InputError(f"nu_solid = {nu_solid!r}: the foam table was computed for a solid with nu = {NU_SOLID} "
                         "(moduli scale with E_solid, Poisson's ratio cannot be rescaled); recompute the table "
                         "(homogenization.tables, NU_SOLID) for another solid")
    data = foam_table(str(Path(table)))
    if len(set(data.grid.values())) != 1:
        raise InputError(f"foam table {label!r} is not a full (density, gamma) grid: densities per gamma {data.grid}")
    for name, value, (lo, hi) in (("density", density, data.density_range), ("gamma", gamma, data.gamma_range)):
        if not (np.isfinite(value) and lo - 1e-12 <= value <= hi + 1e-12):
            raise InputError(f"{name} = {value!r} is outside the tabulated range [{lo:g}, {hi:g}] of the foam table "
                             f"{label!r}")

    def q(name: str) -> float:
        return data.value(name, density, gamma)

    rho = rho_solid * density
    if fit == "transverse":
        return TransverseIsotropic(E_t=E_solid * q("ti_E_t"), E_l=E_solid * q("ti_E_l"), nu_t=q("ti_nu_t"),
                                   nu_tl=q("ti_nu_tl"), G_l=E_solid * q("ti_G_l"), rho=rho)
    if fit == "isotropic":
        return Isotropic(E=E_solid * q("iso_E"), nu=q("iso_nu"), rho=rho)
    if gamma == 1.0:
        E = np.mean([q("E1"), q("E2"), q("E3")])
        nu = np.mean([q(n) for n in ("nu12", "nu13", "nu21", "nu23", "nu31", "nu32")])
        return Isotropic(E=E_solid * float(E), nu=float(nu), rho=rho)
    return TransverseIsotropic(E_t=E_solid * (q("E2") + q("E3")) / 2, E_l=E_solid * q("E1"),
                               nu_t=(q("nu23") + q("nu32")) / 2, nu_tl=(q("nu21") + q("nu31")) / 2,
                               G_l=E_solid * (q("G12") + q("G13")) / 2, rho=rho)


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
        if not (np.isfinite(self.E_solid) and 0 < self.E_solid <= MAX_MODULUS):
            raise InputError(f"region {self.name!r}: E_solid must be a modulus in (0, {MAX_MODULUS:g}] Pa, "
                             f"got {self.E_solid!r}")
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
        table = foam_table(None if self.table is None else str(self.table))
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
