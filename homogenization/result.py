"""The result type shared by the FFT and FEM homogenization solvers."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from homogenization.tensors import (
    InadmissibleMaterialError,
    IsotropicFit,
    TransverseIsotropicFit,
    closest_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
)

#: Names of the six unit macroscopic strains (Voigt order, engineering shear), one load case each.
LOAD_CASES = ("11", "22", "33", "23", "13", "12")


@dataclass
class HomogenizationResult:
    """Homogenized stiffness of a periodic cell and how it was obtained.

    ``C`` is the symmetrised Voigt stiffness ``(C_raw + C_rawᵀ)/2``; column *J* of ``C_raw`` is the
    volume-averaged stress (Voigt) for the unit macroscopic strain *J*. ``asymmetry`` is
    ``max|C_raw - C_rawᵀ| / max|C_raw|``, a discretisation/solver-tolerance indicator.
    """

    C: np.ndarray
    C_raw: np.ndarray
    method: str                                     #: "fft" or "fem"
    iterations: list[int]                           #: per load case (Krylov/fixed-point iterations; 1 for direct)
    residuals: list[list[float]]                    #: per load case, the residual history
    wall_s: float                                   #: total wall time of the solve (s)
    converged: bool = True
    info: dict[str, Any] = field(default_factory=dict)  #: method-specific settings and statistics
    fields: dict[str, np.ndarray] | None = None     #: local fields, when requested

    @classmethod
    def from_columns(cls, C_raw: np.ndarray, **kwargs) -> HomogenizationResult:
        """Build a result from the raw (possibly slightly non-symmetric) stiffness."""
        C_raw = np.asarray(C_raw, dtype=float)
        scale = np.abs(C_raw).max()
        asym = float(np.abs(C_raw - C_raw.T).max() / scale) if scale > 0 else 0.0
        info = dict(kwargs.pop("info", {}) or {})
        info.setdefault("asymmetry", asym)
        return cls(C=0.5 * C_raw + 0.5 * C_raw.T, C_raw=C_raw, info=info, **kwargs)  # no overflow near 1e308

    @property
    def asymmetry(self) -> float:
        """``max|C_raw - C_rawᵀ| / max|C_raw|`` before symmetrisation."""
        return float(self.info["asymmetry"])

    def engineering_constants(self) -> dict[str, float]:
        """E1..E3, G23, G13, G12 and ν_ij of ``C`` (see :func:`homogenization.tensors.engineering_constants`)."""
        C, k = _unit_scaled(self.C)
        try:
            constants = engineering_constants(C)
        except InadmissibleMaterialError as exc:  # its eigenvalues are those of the scaled C
            raise InadmissibleMaterialError(f"{exc}{f' (eigenvalues of C × 2**{k})' if k else ''}") from exc
        return {name: float(np.ldexp(v, -k)) if name[0] in "EG" else v for name, v in constants.items()}

    def ti_fit(self, axis=0) -> TransverseIsotropicFit:
        """Closest TI stiffness; the default l axis is x, the foam's distinct axis (docs/conventions.md)."""
        C, k = _unit_scaled(self.C)
        fit = closest_transverse_isotropic(C, axis=axis)
        return replace(fit, E_t=float(np.ldexp(fit.E_t, -k)), E_l=float(np.ldexp(fit.E_l, -k)),
                       G_l=float(np.ldexp(fit.G_l, -k)), C=np.ldexp(fit.C, -k))

    def isotropic_fit(self) -> IsotropicFit:
        """Closest isotropic stiffness."""
        C, k = _unit_scaled(self.C)
        fit = closest_isotropic(C)
        return replace(fit, E=float(np.ldexp(fit.E, -k)), C=np.ldexp(fit.C, -k))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: C, engineering constants, fits, solver statistics (no local fields)."""
        ti, iso = self.ti_fit(), self.isotropic_fit()
        return {
            "method": self.method,
            "C": self.C.tolist(),
            "asymmetry": self.asymmetry,
            "engineering_constants": self.engineering_constants(),
            "ti_fit": {**ti.constants, "axis": list(ti.axis), "error": ti.error},
            "isotropic_fit": {"E": iso.E, "nu": iso.nu, "error": iso.error},
            "iterations": list(map(int, self.iterations)),
            "residuals": [list(map(float, r)) for r in self.residuals],
            "wall_s": self.wall_s,
            "converged": self.converged,
            "info": _jsonable(self.info),
        }


def _unit_scaled(C: np.ndarray) -> tuple[np.ndarray, int]:
    """``(C · 2**k, k)`` with the largest entry of ``C · 2**k`` in [1, 2).

    The inverse and the fits (products of moduli) of a stiffness in any unit, 1e200 or 1e-170, then stay within
    double precision; a power of two changes no digit.
    """
    largest = float(np.abs(C).max())
    if not (np.isfinite(largest) and largest > 0.0):
        return C, 0
    k = 1 - int(np.frexp(largest)[1])
    return np.ldexp(C, k), k


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
