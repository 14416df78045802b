"""Elastic constants → the moduli of the UFL energy, once for every material kind, with forward derivatives.

The UFL energy (:mod:`fenicsfoam.constitutive`) takes DG0 moduli: the Lamé pair ``lmbda, mu`` when every cell is
isotropic, otherwise the five moduli ``lmbda, mu_T, mu_L, alpha, beta`` of the Spencer form of a transversely
isotropic (TI) stiffness with the structural tensor ``A = a⊗a``:

    σ = λ tr(ε) I + 2μ_T ε + α (tr(Aε) I + tr(ε) A) + 2(μ_L - μ_T)(Aε + εA) + β tr(Aε) A.

With ``a = e3`` its components give ``C12 = λ``, ``C66 = μ_T``, ``C44 = μ_L``, ``C13 = λ + α`` and
``C33 = λ + 2α + 4μ_L - 2μ_T + β``, hence (:func:`spencer_from_voigt`)

    λ = C12,  μ_T = C66 = (C11 - C12)/2,  μ_L = C44,  α = C13 - C12,  β = C11 + C33 - 2 C13 - 4 C44.

An isotropic material is the TI material with ``μ_T = μ_L = μ`` and ``α = β = 0``, whatever its axis. The
functions here take numbers or arrays (one value per cell) and, for the per-cell fields of graded foams and
designs, the tangents of the constants: ``C = S⁻¹`` per cell (the compliance of
:func:`homogenization.tensors.transverse_isotropic_compliance`) and ``dC = −C dS C``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from homogenization.tensors import transverse_isotropic_compliance

__all__ = ["MODULI_NAMES", "isotropic_moduli", "lame", "spencer_from_voigt", "spencer_moduli"]

#: Names of the DG0 moduli of :class:`fenicsfoam.constitutive.MaterialField`: isotropic scenes, anisotropic ones.
MODULI_NAMES = {True: ("lmbda", "mu"), False: ("lmbda", "mu_T", "mu_L", "alpha", "beta")}


def lame(E, nu):
    """Lamé constants ``λ = E ν / ((1 + ν)(1 - 2ν))`` and ``μ = E / (2 (1 + ν))`` (numbers or arrays)."""
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def spencer_from_voigt(C: np.ndarray) -> dict[str, np.ndarray]:
    """The Spencer moduli of TI Voigt stiffnesses ``C`` (..., 6, 6) with l = local axis 3 (module docstring)."""
    return {"lmbda": C[..., 0, 1], "mu_T": C[..., 5, 5], "mu_L": C[..., 3, 3], "alpha": C[..., 0, 2] - C[..., 0, 1],
            "beta": C[..., 0, 0] + C[..., 2, 2] - 2.0 * C[..., 0, 2] - 4.0 * C[..., 3, 3]}


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


def spencer_moduli(E_t, E_l, nu_t, nu_tl, G_l, tangents: Sequence[Sequence[np.ndarray]] = ()
                   ) -> tuple[dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """Spencer moduli of TI constants (arrays), and their tangents for each tangent of the five constants.

    ``C = S⁻¹`` per cell, ``dC = −C dS C``.
    """
    args = [np.atleast_1d(np.asarray(a, dtype=float)) for a in (E_t, E_l, nu_t, nu_tl, G_l)]
    C = np.linalg.inv(transverse_isotropic_compliance(*args))
    out = [spencer_from_voigt(-C @ _ti_compliance_tangent(*args, *t) @ C) for t in tangents]
    return spencer_from_voigt(C), out


def isotropic_moduli(E, nu, tangents: Sequence[Sequence[np.ndarray]] = (), isotropic: bool = True
                     ) -> tuple[dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """Lamé moduli (``isotropic``) or the equivalent Spencer moduli of (E, ν), and their tangents."""
    E, nu = np.atleast_1d(np.asarray(E, dtype=float)), np.atleast_1d(np.asarray(nu, dtype=float))

    def tangent(dE, dnu):
        q = (1 + nu) * (1 - 2 * nu)
        dq = dnu * (1 - 2 * nu) - 2 * (1 + nu) * dnu
        dlam = (dE * nu + E * dnu) / q - E * nu * dq / q**2
        dmu = dE / (2 * (1 + nu)) - E * dnu / (2 * (1 + nu) ** 2)
        return dlam, dmu

    def named(lam, mu):
        if isotropic:
            return {"lmbda": lam, "mu": mu}
        zero = np.zeros_like(lam)
        return {"lmbda": lam, "mu_T": mu, "mu_L": mu, "alpha": zero, "beta": zero}

    return named(*lame(E, nu)), [named(*tangent(dE, dnu)) for dE, dnu in tangents]
