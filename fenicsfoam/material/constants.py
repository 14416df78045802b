"""Elastic constants of the macro model: isotropic and transversely isotropic (TI).

Conventions (docs/conventions.md): SI units; Voigt order (11, 22, 33, 23, 13, 12) with engineering shear strains;
for TI the local axis 3 is the symmetry (longitudinal, *l*) axis, ``E_t = E1 = E2``, ``E_l = E3``,
``nu_t = ν12``, ``nu_tl = ν13 = ν23``, ``G_l = G13 = G23`` and ``G12 = E_t / (2 (1 + nu_t))``.

The materials are plain constants (no dolfinx here); :class:`fenicsfoam.constitutive.MaterialField` turns a
``{cell tag: material}`` map into the DG0 coefficient fields the UFL forms use. Every tensor operation
(stiffness, compliance, engineering constants, closest TI fit, admissibility) is the one of
:mod:`homogenization.tensors`; the moduli of the UFL energy are those of :mod:`fenicsfoam.material.moduli`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fenicsfoam.material.moduli import lame, spencer_from_voigt
from homogenization.tensors import (
    InadmissibleMaterialError,
    check_isotropic,
    check_transverse_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
    isotropic_voigt,
    transverse_isotropic_voigt,
)

__all__ = ["MAX_MODULUS", "InadmissibleMaterialError", "Isotropic", "Material", "TransverseIsotropic"]

#: The largest elastic modulus accepted (Pa): about ten times diamond's Young's modulus (1.2e12 Pa). Anything
#: larger is a typo or a unit error, and would overflow the stiffness arithmetic long before it meant anything.
MAX_MODULUS = 1e13


def check_modulus(name: str, value: float) -> None:
    """Raise :class:`InadmissibleMaterialError` naming ``name`` unless ``0 < value <= MAX_MODULUS`` (Pa)."""
    if not (np.isfinite(value) and 0.0 < value <= MAX_MODULUS):
        raise InadmissibleMaterialError(f"{name} must be a modulus in (0, {MAX_MODULUS:g}] Pa, got {name} = {value:g}")


def _check_density(rho: float) -> None:
    if not (np.isfinite(rho) and rho >= 0.0):
        raise InadmissibleMaterialError(f"mass density must be finite and >= 0 kg/m³, got rho = {rho}")


@dataclass(frozen=True)
class Isotropic:
    """Isotropic linear elastic constants.

    Parameters
    ----------
    E
        Young's modulus (Pa), ``0 < E <= MAX_MODULUS`` (1e13 Pa).
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
        check_modulus("E", self.E)
        _check_density(self.rho)

    @property
    def lame(self) -> tuple[float, float]:
        """Lamé constants ``λ = E ν / ((1 + ν)(1 - 2ν))`` and ``μ = E / (2 (1 + ν))``."""
        return lame(self.E, self.nu)

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
    ``E_t, E_l, G_l > 0`` (and at most :data:`MAX_MODULUS`, 1e13 Pa), ``-1 < nu_t < 1`` and
    ``1 - nu_t - 2 nu_tl² E_l/E_t > 0``
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
        for name in ("E_t", "E_l", "G_l"):
            check_modulus(name, getattr(self, name))
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
        """The moduli ``lmbda, mu_T, mu_L, alpha, beta`` of the Spencer form (:mod:`fenicsfoam.material.moduli`)."""
        return {name: float(value) for name, value in spencer_from_voigt(self.voigt()).items()}

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
