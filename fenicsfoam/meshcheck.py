"""Cheap checks of a built mesh that catch common set-up mistakes before a solve: units and P1 through thin parts.

* :func:`check_units` — fenicsfoam works in metres (docs/conventions.md). A mesh whose bounding box is smaller than
  :data:`UNITS_RANGE` ``[0]`` (1 mm) or larger than ``[1]`` (10 m) across is almost certainly in other units (a
  robot drawn in millimetres is 1000× too large: its weight grows 10⁹-fold against a stiffness 10³-fold, and the
  solve fails with a material instability instead of an error about units). It warns, naming metres. The upper
  bound is 10 m, not more, so that a 10–100 mm robot drawn in millimetres (10–100 units across) is caught too.
* :func:`elements_through_thickness` and :func:`check_degree` — linear (P1) tetrahedra are far too stiff in bending
  when only a few of them span the thinnest dimension (shear locking). The thinnest dimension is the smallest extent
  of the vertex cloud along the coordinate axes or along its principal axes (so a rotated plate is measured
  through its thickness), divided by the mean edge length. With ``degree = 1`` and fewer than
  :data:`MIN_P1_LAYERS` elements through it, a warning recommends ``degree = 2``. The estimate sees the body's
  overall shape only, not thin walls inside it.

Both are collective (bounding boxes, sums and maxima over ranks) and log on rank 0 only.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

__all__ = ["MIN_P1_LAYERS", "UNITS_RANGE", "MeshExtent", "check_degree", "check_units", "elements_through_thickness",
           "mesh_extent"]

logger = logging.getLogger(__name__)

#: A mesh smaller than the first (m) or larger than the second across is reported as probably not in metres.
UNITS_RANGE = (1e-3, 10.0)
#: P1 with fewer elements than this through the thinnest dimension is reported as too stiff in bending.
MIN_P1_LAYERS = 3.0


@dataclass(frozen=True)
class MeshExtent:
    """Bounding box (m), extents along the principal axes (m, ascending) and mean edge length (m) of a mesh."""

    lower: np.ndarray
    upper: np.ndarray
    principal: np.ndarray
    mean_edge: float

    @property
    def size(self) -> float:
        """The largest side of the bounding box (m)."""
        return float(np.max(self.upper - self.lower))

    @property
    def thinnest(self) -> float:
        """The smallest extent along the coordinate axes or the principal axes (m)."""
        return float(min(np.min(self.upper - self.lower), self.principal[0]))


def mesh_extent(mesh) -> MeshExtent:
    """The :class:`MeshExtent` of a dolfinx mesh (collective; the same on every rank)."""
    comm = mesh.comm
    n_nodes = mesh.geometry.index_map().size_local
    x = mesh.geometry.x[:n_nodes]
    lower = np.empty(3)
    upper = np.empty(3)
    comm.Allreduce(x.min(axis=0, initial=np.inf), lower, op=MPI.MIN)
    comm.Allreduce(x.max(axis=0, initial=-np.inf), upper, op=MPI.MAX)
    sums = np.concatenate([[len(x)], x.sum(axis=0), (x.T @ x).ravel()])
    total = np.empty_like(sums)
    comm.Allreduce(sums, total, op=MPI.SUM)
    n, mean = total[0], total[1:4] / total[0]
    covariance = total[4:].reshape(3, 3) / n - np.outer(mean, mean)
    _, axes = np.linalg.eigh(covariance)
    projected = (x - mean) @ axes
    low = np.empty(3)
    high = np.empty(3)
    comm.Allreduce(projected.min(axis=0, initial=np.inf), low, op=MPI.MIN)
    comm.Allreduce(projected.max(axis=0, initial=-np.inf), high, op=MPI.MAX)
    tdim = mesh.topology.dim
    n_cells = mesh.topology.index_map(tdim).size_local
    dofmap = mesh.geometry.dofmap
    corners = dofmap.array.reshape(-1, dofmap.links(0).size)[:n_cells, : tdim + 1]
    vertices = mesh.geometry.x[corners]
    edges = [np.linalg.norm(vertices[:, a] - vertices[:, b], axis=1) for a in range(tdim + 1)
             for b in range(a + 1, tdim + 1)]
    edge_sum = np.array([float(np.sum(edges)), float(len(edges) * n_cells)])
    edge_total = np.empty(2)
    comm.Allreduce(edge_sum, edge_total, op=MPI.SUM)
    return MeshExtent(lower, upper, np.sort(high - low), edge_total[0] / max(edge_total[1], 1.0))


def check_units(mesh, extent: MeshExtent | None = None) -> bool:
    """Warn (rank 0) if the mesh is smaller than 1 mm or larger than 100 m across; returns whether it did."""
    extent = mesh_extent(mesh) if extent is None else extent
    size = extent.size
    if UNITS_RANGE[0] <= size <= UNITS_RANGE[1]:
        return False
    if mesh.comm.rank == 0:
        sides = " × ".join(f"{s:.4g}" for s in extent.upper - extent.lower)
        hint = ("a mesh drawn in millimetres must be scaled by 0.001 (gmsh: Mesh.ScalingFactor = 0.001 before "
                "writing the .msh file)" if size > UNITS_RANGE[1] else "check the units of the mesh file")
        logger.warning("the mesh is %.4g m across (bounding box %s m): fenicsfoam works in metres (SI units), so "
                       "a robot is expected to be between %g m and %g m; %s", size, sides, *UNITS_RANGE, hint)
    return True


def elements_through_thickness(mesh, extent: MeshExtent | None = None) -> float:
    """The thinnest extent of the mesh (:attr:`MeshExtent.thinnest`) over its mean edge length (collective)."""
    extent = mesh_extent(mesh) if extent is None else extent
    return extent.thinnest / extent.mean_edge


def check_degree(mesh, degree: int, extent: MeshExtent | None = None) -> bool:
    """Warn (rank 0) if ``degree`` is 1 with few elements through the thinnest dimension; returns whether it did.

    Few: fewer than :data:`MIN_P1_LAYERS`, by :func:`elements_through_thickness`.
    """
    if degree != 1:
        return False
    extent = mesh_extent(mesh) if extent is None else extent
    layers = elements_through_thickness(mesh, extent)
    if layers >= MIN_P1_LAYERS:
        return False
    if mesh.comm.rank == 0:
        logger.warning("degree 1 (linear tetrahedra) with about %.1f elements through the thinnest dimension "
                       "(%.3g m, mean edge %.3g m): P1 is much too stiff in bending there (shear locking); use "
                       "[fem] degree = 2 (the default) or at least %g elements through it", layers,
                       extent.thinnest, extent.mean_edge, MIN_P1_LAYERS)
    return True
