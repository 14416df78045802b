"""Strong ellipticity of the models' tangent: the acoustic-tensor margin per cell (material instability).

At a deformation gradient ``F`` the tangent of a model is ``A_ijkl = ∂P_ij/∂F_kl``, ``P`` the first
Piola–Kirchhoff stress; for the corotational model this is the exact tangent that Newton uses
(:func:`fenicsfoam.constitutive.corotational_rotation_tangent` included; for ``corotational_sofa``, whose
tangent is the derivative at frozen ``R``, the tangent Newton uses, which cannot lose ellipticity). The acoustic
tensor of a unit direction ``n`` is

    Q_ik(n) = A_ijkl n_j n_l,

and the tangent is *strongly elliptic* when ``m·Q(n)·m > 0`` for all unit ``m`` and ``n``. The minimum over
``m`` is the smallest eigenvalue of ``sym Q(n)`` (``Q`` need not be symmetric: the corotational TI tangent
is not), so the **margin** computed here is

    margin = min_{|n| = 1} λ_min(sym Q(n))    (Pa).

A negative margin means the incremental equilibrium equations admit solutions whose gradient jumps across
planes of normal ``n`` with polarization ``m`` (shear or kink bands, fibre micro-buckling): the continuum
problem has no length scale there, the discrete solution depends on the mesh and Newton stops at a limit
point that moves with the mesh size. For an isotropic material at rest ``Q(n) = μ I + (λ + μ) n⊗n`` and the
margin is ``min(μ, λ + 2μ)``.

Minimisation over ``n``: ``Q(-n) = Q(n)``, so ``n`` ranges over a hemisphere. The margin is first sampled on
``directions`` Fibonacci points of the hemisphere (spacing about ``sqrt(2π / directions)`` rad), then refined
around each point's best direction by a pattern search (8 neighbours on a circle of angular radius ``r``,
``r`` halved ``refinements`` times from the sampling spacing). This finds the minimum of the basin the
sampling lands in; a narrower basin between samples could be missed (documented limitation, not observed
for the materials of this project).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import basix
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.mesh import compute_midpoints
from mpi4py import MPI

from fenicsfoam.constitutive import MaterialField, Model, PolarRotation, as_model
from fenicsfoam.orientation import cell_function
from foambase.errors import InputError

__all__ = ["EllipticityCheck", "acoustic_margin", "ellipticity_margin", "hemisphere_directions"]

logger = logging.getLogger(__name__)


def hemisphere_directions(count: int) -> np.ndarray:
    """``count`` unit vectors (count, 3) spread evenly over the hemisphere ``z >= 0`` (Fibonacci lattice)."""
    if not (isinstance(count, int) and count >= 1):
        raise InputError(f"count must be an integer >= 1, got {count!r}")
    k = np.arange(count) + 0.5
    z = 1.0 - k / count  # uniform in z on (0, 1): equal areas
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _acoustic_tensors(A: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``sym Q(n)`` (p, d, 3, 3) for tangents A (p, 9, 9) (rows ``ik``, columns ``jl``).

    The normals n are (d, 3), shared by every point, or (p, d, 3), per point.
    """
    nn = (n[..., :, None] * n[..., None, :]).reshape(*n.shape[:-1], 9)
    Q = (A.reshape(-1, 9) @ nn.T).reshape(A.shape[0], 3, 3, -1) if n.ndim == 2 \
        else np.matmul(A, nn.swapaxes(-1, -2)).reshape(A.shape[0], 3, 3, -1)
    Q = np.moveaxis(Q, -1, 1)
    return 0.5 * (Q + Q.swapaxes(-1, -2))


def _smallest_eigenvalue(S: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of symmetric 3×3 matrices (..., 3, 3), in closed form (trigonometric solution).

    ``S = q I + p B`` with ``q = tr S / 3``, ``p = sqrt(|S - qI|² / 6)``; the eigenvalues are
    ``q + 2p cos(φ + 2πk/3)``, ``φ = arccos(det B / 2) / 3``, the smallest for ``k = 1``. Used to screen
    directions (about 10× faster than LAPACK on many tiny matrices); the reported margin uses ``eigh``.
    """
    q = np.trace(S, axis1=-2, axis2=-1) / 3.0
    D = S - q[..., None, None] * np.eye(3)
    p = np.sqrt(np.einsum("...ij,...ij->...", D, D) / 6.0)
    det = (D[..., 0, 0] * (D[..., 1, 1] * D[..., 2, 2] - D[..., 1, 2] ** 2)
           - D[..., 0, 1] * (D[..., 0, 1] * D[..., 2, 2] - D[..., 1, 2] * D[..., 0, 2])
           + D[..., 0, 2] * (D[..., 0, 1] * D[..., 1, 2] - D[..., 1, 1] * D[..., 0, 2]))
    det /= np.where(p > 0.0, p, 1.0) ** 3
    phi = np.arccos(np.clip(0.5 * det, -1.0, 1.0)) / 3.0
    return q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)


def _best(A: np.ndarray, n: np.ndarray, margin: np.ndarray, normal: np.ndarray) -> None:
    """Lower ``margin`` and update ``normal`` (in place) where one of the normals ``n`` does better."""
    values = _smallest_eigenvalue(_acoustic_tensors(A, n))
    best = values.argmin(axis=1)
    rows = np.arange(A.shape[0])
    better = values[rows, best] < margin
    margin[better] = values[better, best[better]]
    normal[better] = (n[best] if n.ndim == 2 else n[rows, best])[better]


def acoustic_margin(A: np.ndarray, directions: int = 256, refinements: int = 10
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Strong-ellipticity margin ``min_n λ_min(sym Q(n))`` of a stack of tangents (module docstring).

    Parameters
    ----------
    A
        Tangents ``A_ijkl = ∂P_ij/∂F_kl``, shape (p, 3, 3, 3, 3).
    directions
        Number of sampled normals on the hemisphere before the local refinement.
    refinements
        Halvings of the pattern-search radius around each point's best sampled normal.

    Returns
    -------
    margin, normal, polarization
        Per point: the margin (units of ``A``), the minimising unit normal ``n`` (p, 3) and the unit
        polarization ``m`` (p, 3), eigenvector of ``sym Q(n)`` for the margin.

    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 5 or A.shape[1:] != (3, 3, 3, 3):
        raise InputError(f"A must have shape (p, 3, 3, 3, 3), got {A.shape}")
    p = A.shape[0]
    A = A.transpose(0, 1, 3, 2, 4).reshape(p, 9, 9)  # rows ik, columns jl: Q_ik(n) = A[ik, jl] n_j n_l
    samples = hemisphere_directions(directions)
    margin, normal = np.full(p, np.inf), np.zeros((p, 3))
    for chunk in np.array_split(samples, max(1, directions // 32)):  # bounded memory: p × 32 3×3 problems
        _best(A, chunk, margin, normal)
    # Pattern search: 8 neighbours of the current best normal on a circle of angular radius r.
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    radius = np.sqrt(2.0 * np.pi / directions)
    for _ in range(refinements):
        e1 = np.cross(normal, np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(normal, e1)
        candidates = (np.cos(radius) * normal[:, None, :]
                      + np.sin(radius) * (np.cos(angles)[None, :, None] * e1[:, None, :]
                                          + np.sin(angles)[None, :, None] * e2[:, None, :]))
        _best(A, candidates, margin, normal)
        radius *= 0.5
    values, vectors = np.linalg.eigh(_acoustic_tensors(A, normal[:, None, :])[:, 0])
    return values[:, 0], normal, vectors[:, :, 0]


@dataclass(frozen=True)
class EllipticityCheck:
    """Where a displacement has lost strong ellipticity (:func:`ellipticity_margin`).

    ``margin`` is a DG0 field (the minimum over each cell's quadrature points); the other attributes are
    global (identical on every rank). ``location``, ``normal`` and ``polarization`` belong to the point with
    the smallest margin.
    """

    margin: fem.Function        #: DG0 margin per cell (Pa)
    min_margin: float           #: smallest margin over the mesh (Pa)
    lost_cells: int             #: number of cells with a margin <= 0
    n_cells: int                #: number of cells of the mesh
    location: np.ndarray        #: midpoint (m) of the cell with the smallest margin
    normal: np.ndarray          #: its band normal n
    polarization: np.ndarray    #: its polarization m

    @property
    def lost(self) -> bool:
        """Strong ellipticity is lost somewhere."""
        return self.lost_cells > 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of everything but the field.

        Keys ``lost_cells``, ``n_cells``, ``min_margin_Pa``, ``location_m``, ``normal``, ``polarization``.
        """
        return {"lost_cells": self.lost_cells, "n_cells": self.n_cells, "min_margin_Pa": self.min_margin,
                "location_m": self.location.tolist(), "normal": self.normal.tolist(),
                "polarization": self.polarization.tolist()}

    def __str__(self) -> str:
        def vector(v, scale=1.0):
            return "(" + ", ".join(f"{scale * c:.3g}" for c in v) + ")"
        state = f"strong ellipticity lost in {self.lost_cells} of {self.n_cells} cells" if self.lost \
            else f"strongly elliptic in all {self.n_cells} cells"
        return (f"{state} (min margin {self.min_margin:.4g} Pa at x = {vector(self.location, 1e3)} mm, "
                f"band normal n = {vector(self.normal)}, polarization m = {vector(self.polarization)})")


def _tangent_expression(u: fem.Function, model: Model, material: MaterialField, orientation: fem.Function | None,
                        rotation: PolarRotation | None, points: np.ndarray) -> tuple[fem.Expression, fem.Function]:
    """``dP = A : ∇w`` at ``points``: the model's exact tangent at ``u`` applied to a displacement ``w``.

    The directional derivative of ``P`` along ``w`` (``ufl.derivative`` at frozen ``R``, plus the model's
    :meth:`~fenicsfoam.constitutive.Model.rotation_tangent`). With ``w = G x`` (exact in P1 and P2), ``∇w = G``;
    evaluating it for the nine unit matrices ``G = e_k⊗e_l`` gives ``A_ijkl`` with one compiled form.
    """
    w = fem.Function(u.function_space, name="direction")
    dP = ufl.derivative(model.first_piola_kirchhoff(u, material, orientation, rotation), u, w)
    extra = model.rotation_tangent(u, w, material, orientation, rotation)
    if extra is not None:
        dP += extra
    return fem.Expression(dP, points), w


def ellipticity_margin(u: fem.Function, model: str | Model, material: MaterialField,
                       orientation: fem.Function | None = None, *, rotation: PolarRotation | None = None,
                       quadrature_degree: int | None = None, directions: int = 256, refinements: int = 10
                       ) -> EllipticityCheck:
    """The strong-ellipticity margin of a model's tangent at the displacement ``u``, per cell (collective).

    ``A = ∂P/∂F`` is evaluated at the quadrature points of degree ``quadrature_degree`` (default
    ``2 (degree - 1)`` of ``u``'s element, the stress integral's of :class:`~fenicsfoam.solver.ElasticityProblem`:
    one point per cell for P1) of the owned cells, the margin computed there by :func:`acoustic_margin` and
    reduced per cell (minimum) and over the mesh. The corotational rotation is recomputed from ``u`` (whose ghost
    values must be up to date) in ``rotation`` if given (the solver passes its own), else in a new
    :class:`~fenicsfoam.constitutive.PolarRotation`. Costs one form compilation (cached by FFCx afterwards) and
    nine evaluations.

    Parameters
    ----------
    u
        The displacement (vector Lagrange function).
    model
        The constitutive model or its name (:data:`fenicsfoam.constitutive.MODELS`).
    material, orientation
        The DG0 material data and, for a transversely isotropic material, the l-axis field.
    rotation, quadrature_degree
        As the solver has them (see above).
    directions, refinements
        Of :func:`acoustic_margin`.

    """
    model = as_model(model)
    if quadrature_degree is None:
        quadrature_degree = 2 * (u.function_space.ufl_element().degree() - 1)
    if model.needs_rotation and rotation is None:
        rotation = model.rotation_field(u, quadrature_degree)
    mesh = u.function_space.mesh
    comm = mesh.comm
    tdim = mesh.topology.dim
    cells = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    points, _ = basix.make_quadrature(basix.cell.string_to_type(mesh.topology.cell_name()), quadrature_degree)
    if rotation is not None:
        rotation.update()
    expression, w = _tangent_expression(u, model, material, orientation, rotation, points)
    A = np.empty((cells.size, points.shape[0], 3, 3, 3, 3))
    for k in range(3):
        for l in range(3):  # noqa: E741
            w.interpolate(lambda x, k=k, l=l: np.where(np.arange(3)[:, None] == k, x[l], 0.0))  # w = (e_k⊗e_l) x
            A[..., k, l] = expression.eval(cells).reshape(cells.size, points.shape[0], 3, 3)
    margin, normal, polarization = acoustic_margin(A.reshape(-1, 3, 3, 3, 3), directions, refinements)
    margin = margin.reshape(cells.size, -1)
    cell_margin = margin.min(axis=1, initial=np.inf)

    # The worst point of this rank, then of the mesh (small objects: gathered).
    if cells.size:
        worst = int(np.argmin(margin))
        cell, point = divmod(worst, margin.shape[1])
        local = (float(margin.flat[worst]), compute_midpoints(mesh, tdim, cells[cell:cell + 1])[0],
                 normal[worst], polarization[worst])
    else:
        local = (np.inf, np.zeros(3), np.zeros(3), np.zeros(3))
    min_margin, location, n, m = min(comm.allgather(local), key=lambda item: item[0])
    lost = comm.allreduce(int(np.count_nonzero(cell_margin <= 0.0)), op=MPI.SUM)
    n_cells = mesh.topology.index_map(tdim).size_global
    check = EllipticityCheck(margin=cell_function(mesh, cell_margin, name="ellipticity_margin"),
                             min_margin=min_margin, lost_cells=lost, n_cells=n_cells,
                             location=np.asarray(location), normal=np.asarray(n), polarization=np.asarray(m))
    logger.info("%s", check)
    return check
