"""Elastic materials of the macro model: isotropic and transversely isotropic (TI) constants.

Conventions (docs/conventions.md): SI units; Voigt order (11, 22, 33, 23, 13, 12) with engineering shear strains;
for TI the local axis 3 is the symmetry (longitudinal, *l*) axis, ``E_t = E1 = E2``, ``E_l = E3``,
``nu_t = ν12``, ``nu_tl = ν13 = ν23``, ``G_l = G13 = G23`` and ``G12 = E_t / (2 (1 + nu_t))``.

The materials are plain constants (no dolfinx here); :class:`fenicsfoam.constitutive.MaterialField` turns a
``{cell tag: material}`` map into the DG0 coefficient fields the UFL forms use. Every tensor operation
(stiffness, compliance, engineering constants, closest TI fit, admissibility) is the one of
:mod:`homogenization.tensors`. Foam constants come from the shipped table of :mod:`homogenization.tables`
(:func:`foam_material`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator

from foambase.errors import InputError
from homogenization.tensors import (
    InadmissibleMaterialError,
    check_isotropic,
    check_transverse_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
    isotropic_voigt,
    transverse_isotropic_voigt,
)

__all__ = ["InadmissibleMaterialError", "Isotropic", "Material", "TransverseIsotropic", "foam_material"]


def _check_density(rho: float) -> None:
    if not (np.isfinite(rho) and rho >= 0.0):
        raise InadmissibleMaterialError(f"mass density must be finite and >= 0 kg/m³, got rho = {rho}")


@dataclass(frozen=True)
class Isotropic:
    """Isotropic linear elastic constants.

    Parameters
    ----------
    E
        Young's modulus (Pa), ``E > 0``.
    nu
        Poisson's ratio, ``-1 < nu < 1/2``.
    rho
        Mass density in the reference configuration (kg/m³), ``rho >= 0``; used for gravity.

    """

    E: float
    nu: float
    rho: float = 0.0

    def __post_init__(self):
        check_isotropic(self.E, self.nu)
        _check_density(self.rho)

    @property
    def lame(self) -> tuple[float, float]:
        """Lamé constants ``λ = E ν / ((1 + ν)(1 - 2ν))`` and ``μ = E / (2 (1 + ν))``."""
        return (self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu)), self.E / (2 * (1 + self.nu)))

    def voigt(self) -> np.ndarray:
        """Voigt stiffness (6, 6): ``C = λ 1⊗1 + 2μ I``."""
        return isotropic_voigt(self.E, self.nu)

    def engineering_constants(self) -> dict[str, float]:
        """E1..E3, G23, G13, G12 and ν_ij (all equal to E, G = μ and ν here)."""
        return engineering_constants(self.voigt())

    def spencer_moduli(self) -> dict[str, float]:
        """The five moduli of the TI Spencer form (see :meth:`TransverseIsotropic.spencer_moduli`).

        An isotropic material is the TI material with ``μ_T = μ_L = μ`` and ``α = β = 0``, whatever its axis.
        """
        lam, mu = self.lame
        return {"lmbda": lam, "mu_T": mu, "mu_L": mu, "alpha": 0.0, "beta": 0.0}


@dataclass(frozen=True)
class TransverseIsotropic:
    """Transversely isotropic linear elastic constants, symmetry axis *l* = local axis 3.

    Parameters
    ----------
    E_t, E_l
        Young's moduli in the plane of isotropy and along *l* (Pa).
    nu_t
        Poisson's ratio ν12 in the plane of isotropy.
    nu_tl
        Poisson's ratio ν13 = ν23 (contraction along *l* under a transverse extension).
    G_l
        Shear modulus G13 = G23 of planes containing *l* (Pa).
    rho
        Mass density in the reference configuration (kg/m³), ``rho >= 0``; used for gravity.

    The constants are admissible when the compliance is positive definite:
    ``E_t, E_l, G_l > 0``, ``-1 < nu_t < 1`` and ``1 - nu_t - 2 nu_tl² E_l/E_t > 0``
    (:func:`homogenization.tensors.check_transverse_isotropic`).

    """

    E_t: float
    E_l: float
    nu_t: float
    nu_tl: float
    G_l: float
    rho: float = 0.0

    def __post_init__(self):
        check_transverse_isotropic(self.E_t, self.E_l, self.nu_t, self.nu_tl, self.G_l)
        _check_density(self.rho)

    @property
    def constants(self) -> dict[str, float]:
        """The five elastic constants as a dict (the keyword arguments of this class, without ``rho``)."""
        return {"E_t": self.E_t, "E_l": self.E_l, "nu_t": self.nu_t, "nu_tl": self.nu_tl, "G_l": self.G_l}

    def voigt(self) -> np.ndarray:
        """Voigt stiffness (6, 6) in the local frame (l = axis 3), the inverse of the closed-form compliance."""
        return transverse_isotropic_voigt(**self.constants)

    def engineering_constants(self) -> dict[str, float]:
        """E1..E3, G23, G13, G12 and ν_ij of :meth:`voigt` (local frame)."""
        return engineering_constants(self.voigt())

    def spencer_moduli(self) -> dict[str, float]:
        """Moduli of the Spencer form of the TI stiffness, read from the local Voigt stiffness.

        With the structural tensor ``A = a⊗a`` (``a`` the unit *l* axis), the stress is

            σ = λ tr(ε) I + 2μ_T ε + α (tr(Aε) I + tr(ε) A) + 2(μ_L - μ_T)(Aε + εA) + β tr(Aε) A,

        and with ``a = e3`` its components give ``C12 = λ``, ``C66 = μ_T``, ``C44 = μ_L``,
        ``C13 = λ + α`` and ``C33 = λ + 2α + 4μ_L - 2μ_T + β``, hence

            λ = C12,  μ_T = C66 = (C11 - C12)/2,  μ_L = C44,  α = C13 - C12,  β = C11 + C33 - 2 C13 - 4 C44.
        """
        C = self.voigt()
        return {
            "lmbda": C[0, 1],
            "mu_T": C[5, 5],
            "mu_L": C[3, 3],
            "alpha": C[0, 2] - C[0, 1],
            "beta": C[0, 0] + C[2, 2] - 2.0 * C[0, 2] - 4.0 * C[3, 3],
        }

    @classmethod
    def from_voigt(cls, C: np.ndarray, axis=(0.0, 0.0, 1.0), rho: float = 0.0) -> tuple[TransverseIsotropic, float]:
        """Closest TI material to a Voigt stiffness ``C``, for the l axis ``axis`` of ``C``'s frame.

        ``axis`` is a 3-vector or 0/1/2 for x/y/z. The projection is the Mandel/Frobenius least-squares
        fit of :func:`homogenization.tensors.closest_transverse_isotropic`.

        Returns
        -------
        material, error
            The TI constants (in the frame where ``axis`` is local 3) and the relative fit error
            ``‖C - C_TI‖ / ‖C‖`` (Mandel norm).

        """
        fit = closest_transverse_isotropic(C, axis=axis)
        return cls(**fit.constants, rho=rho), fit.error


#: Any material of the macro model.
Material = Isotropic | TransverseIsotropic


FOAM_FITS = ("transverse", "isotropic", "paper")
#: Table columns interpolated in log space (moduli); the others (Poisson's ratios) linearly.
_MODULI = {"E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E"}


@lru_cache(maxsize=4)
def _foam_table(path: str) -> dict[str, np.ndarray]:
    from homogenization.tables import read_csv

    return read_csv(path)


def _interpolate(table: dict[str, np.ndarray], name: str, density: float, gamma: float) -> float:
    """Monotone (PCHIP) interpolation of a table column: over density per tabulated γ, then over log γ.

    Moduli are interpolated as ``log q``, Poisson's ratios as ``q``; both reproduce the table exactly at its
    nodes, and PCHIP keeps every monotone stretch of the data monotone (no overshoot between nodes).
    """
    gammas = np.unique(table["gamma"])
    per_gamma = []
    for g in gammas:
        rows = table["gamma"] == g
        x, y = table["density"][rows], table[name][rows]
        order = np.argsort(x)
        y = np.log(y[order]) if name in _MODULI else y[order]
        # a table of one density (a selectable table computed for one scene) is exact at its node only
        per_gamma.append(float(PchipInterpolator(x[order], y)(density)) if len(x) > 1 else float(y[0]))
    value = float(PchipInterpolator(np.log(gammas), per_gamma)(np.log(gamma))) if len(gammas) > 1 else per_gamma[0]
    return float(np.exp(value)) if name in _MODULI else value


def foam_material(density: float, gamma: float, E_solid: float, nu_solid: float, *, rho_solid: float = 0.0,
                  fit: str = "transverse", table: str | Path | None = None) -> Isotropic | TransverseIsotropic:
    """Homogenized constants of a stochastic Voronoi foam, from the shipped table (:mod:`homogenization.tables`).

    The table holds, per (relative density, γ), the seed-averaged homogenized constants of foams of an
    isotropic solid with ``E_s = 1``, ``ν_s = 0.3``; moduli scale linearly with ``E_solid``, and the mass
    density is ``rho_solid · density``. Between table nodes the constants are interpolated monotonically
    (PCHIP in density, then in log γ; moduli in log space).

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
        The name of a shipped table (``homogenization.tables.shipped_tables()``: ``"cube"``, the default, the
        Euclidean strut foam with 8 cells in the unit cube; ``"equiaxed"``, the same foam with 27 cells in the
        box ``(γ, 1, 1)``, tabulated only where it was computed) or the path of an aggregated table CSV (a
        ``Path``, or a string ending in ``.csv``).

    """
    from homogenization.tables import NU_SOLID, resolve_table

    if fit not in FOAM_FITS:
        raise InputError(f"fit must be one of {FOAM_FITS}, got {fit!r}")
    label, table = resolve_table(table)
    if not (np.isfinite(E_solid) and E_solid > 0):
        raise InadmissibleMaterialError(f"E_solid must be > 0 Pa, got {E_solid!r}")
    if not (np.isfinite(rho_solid) and rho_solid >= 0):
        raise InadmissibleMaterialError(f"rho_solid must be finite and >= 0 kg/m³, got {rho_solid!r}")
    if not np.isclose(nu_solid, NU_SOLID, rtol=0, atol=1e-12):
        raise InputError(f"nu_solid = {nu_solid!r}: the foam table was computed for a solid with nu = {NU_SOLID} "
                         "(moduli scale with E_solid, Poisson's ratio cannot be rescaled); recompute the table "
                         "(homogenization.tables, NU_SOLID) for another solid")
    data = _foam_table(str(Path(table)))
    grid = {g: tuple(np.sort(data["density"][data["gamma"] == g])) for g in np.unique(data["gamma"])}
    if len(set(grid.values())) != 1:
        raise InputError(f"foam table {label!r} is not a full (density, gamma) grid: densities per gamma {grid}")
    for name, value, nodes in (("density", density, data["density"]), ("gamma", gamma, data["gamma"])):
        lo, hi = float(nodes.min()), float(nodes.max())
        if not (np.isfinite(value) and lo - 1e-12 <= value <= hi + 1e-12):
            raise InputError(f"{name} = {value!r} is outside the tabulated range [{lo:g}, {hi:g}] of the foam table "
                             f"{label!r}")

    def q(name: str) -> float:
        return _interpolate(data, name, density, gamma)

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
