"""Is a small-strain (``linear`` model) solution valid? A posteriori check of the neglected geometric term.

The linear model uses ``ε = sym ∇u`` in place of the Green–Lagrange strain ``E = sym ∇u + ½ ∇uᵀ∇u``. The
neglected term ``q = ½ ∇uᵀ∇u`` is what a rigid rotation by θ turns into spurious strain (``‖q‖₂ = 1 − cos θ``
for a pure rotation), and it is the size of the error the linear model makes in the strain. The check reads
the solution itself, so it works for any scene:

* ``quadratic_strain = max over cells of ‖½ ∇uᵀ∇u‖_F`` evaluated at the cell midpoints (exact per cell for
  P1; the midpoint value for P2);
* ``rotation_deg = max over cells of |axial(skew ∇u)|`` in degrees, the infinitesimal rotation angle (reported,
  it is what one looks at in a picture; beyond ~1 rad it no longer measures the true rotation);
* the solution is *valid for small strain* when ``quadratic_strain ≤ limit``. The default
  :data:`QUADRATIC_STRAIN_LIMIT` = 0.05 (a modelling choice, not fitted): 5 % spurious strain, which a pure
  rotation reaches at θ = arccos(0.95) ≈ 18°.

The check is collective (maxima over ranks with a buffer ``Allreduce``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import basix
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from foambase.errors import ComputationError, InputError

__all__ = ["QUADRATIC_STRAIN_LIMIT", "SmallStrainValidity", "SmallStrainValidityError", "small_strain_validity"]

logger = logging.getLogger(__name__)

#: Largest ``‖½ ∇uᵀ∇u‖_F`` accepted for a small-strain solution (a rigid rotation of about 18°).
QUADRATIC_STRAIN_LIMIT = 0.05


class SmallStrainValidityError(ComputationError):
    """A linear (small-strain) solution outside the validity of small-strain theory."""


@dataclass(frozen=True)
class SmallStrainValidity:
    """Outcome of :func:`small_strain_validity`."""

    quadratic_strain: float   #: max over cells of ‖½ ∇uᵀ∇u‖_F
    rotation_deg: float       #: max over cells of the infinitesimal rotation angle |axial(skew ∇u)|, degrees
    limit: float              #: the accepted quadratic_strain

    @property
    def valid(self) -> bool:
        """``quadratic_strain ≤ limit``."""
        return self.quadratic_strain <= self.limit

    def check(self) -> None:
        """Raise :class:`SmallStrainValidityError` naming the measured values if not :attr:`valid`."""
        if not self.valid:
            raise SmallStrainValidityError(
                f"the small-strain (linear) solution is invalid: max ‖½ ∇uᵀ∇u‖ = {self.quadratic_strain:.3g} > "
                f"{self.limit:g} (max rotation ≈ {self.rotation_deg:.1f}°); use model 'corotational' or 'svk'")


def small_strain_validity(u: fem.Function, limit: float = QUADRATIC_STRAIN_LIMIT) -> SmallStrainValidity:
    """Measure ``max ‖½ ∇uᵀ∇u‖_F`` and the largest infinitesimal rotation of ``u`` (collective).

    Parameters
    ----------
    u
        A displacement (vector Lagrange function).
    limit
        The largest accepted quadratic strain, ``> 0``.

    """
    if not (np.isfinite(limit) and limit > 0):
        raise InputError(f"limit must be a positive finite strain, got {limit!r}")
    mesh = u.function_space.mesh
    grad = ufl.grad(u)
    quadratic = 0.5 * grad.T * grad
    skew = 0.5 * (grad - grad.T)
    axial = ufl.as_vector((skew[2, 1], skew[0, 2], skew[1, 0]))
    midpoint = basix.geometry(basix.cell.string_to_type(mesh.topology.cell_name())).mean(axis=0, keepdims=True)
    norms = ufl.as_vector((ufl.sqrt(ufl.inner(quadratic, quadratic)), ufl.sqrt(ufl.dot(axial, axial))))
    measures = fem.Expression(norms, midpoint)
    cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
    local = measures.eval(cells).reshape(-1, 2).max(axis=0, initial=0.0)
    result = np.empty(2)
    mesh.comm.Allreduce(local, result, op=MPI.MAX)
    validity = SmallStrainValidity(float(result[0]), float(np.degrees(result[1])), float(limit))
    logger.info("small-strain validity: max ‖½∇uᵀ∇u‖ = %.3g (limit %g), max rotation %.1f°",
                validity.quadratic_strain, limit, validity.rotation_deg)
    return validity
