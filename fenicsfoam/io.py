"""Reading a scene's results back: the mesh and the displacement of every step, without dolfinx.

``fenicsfoam run`` writes ``solution.xdmf`` + ``solution.h5`` (for ParaView) and, next to them, ``solution.npz``: the
same displacements at every node of the displacement space (the P2 edge midpoints too), on the mesh gathered to
rank 0 in the global node numbering, so that it is one conforming mesh whatever the number of ranks. numpy reads it;
:func:`read_solution` returns it as a :class:`Solution`::

    from fenicsfoam.io import read_solution
    solution = read_solution("out/finger")           # the output directory of a run
    solution.points, solution.cells                  # (n, 3) m; (m, 4 or 10) node indices in VTK order
    solution.labels                                  # the steps' labels
    u = solution.displacement("inflated")            # (n, 3) m, at solution.points
    grid = solution.to_pyvista("inflated")           # a pyvista.UnstructuredGrid with point data "displacement"
    grid.warp_by_vector("displacement").plot()

pyvista also reads the XDMF series itself (``pyvista.read("out/finger/solution.xdmf")``, the mesh with the first
step's displacement); meshio 5 does not (several grids, and it needs h5py).

:class:`GatheredMesh` and :func:`gather_values` are the gathering both this file and the pictures
(:mod:`fenicsfoam.plotting`) use: each rank sends the nodes it owns (global numbers, coordinates, values) and the
cells it owns; rank 0 places them by global number, so nodes on rank boundaries are not duplicated.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from foambase.errors import InputError
from foambase.files import atomic_path

__all__ = ["SOLUTION_FILE", "GatheredMesh", "Solution", "SolutionWriter", "gather_mesh", "gather_values",
           "read_solution"]

#: The file :class:`SolutionWriter` writes in a run's output directory.
SOLUTION_FILE = "solution.npz"


@dataclass(frozen=True)
class GatheredMesh:
    """The nodes of a Lagrange space and its cells, in global node numbers (rank 0's copy of the whole mesh)."""

    points: np.ndarray      #: (n, 3) node coordinates (m), row = global node number
    cells: np.ndarray       #: (m, k) global node numbers per cell, VTK order (corners first)
    cell_type: int          #: VTK cell type (10: tetra; 71: Lagrange tetra, 10 nodes for P2)

    def to_pyvista(self, point_data: dict[str, np.ndarray] | None = None):
        """A ``pyvista.UnstructuredGrid`` of the mesh with the given point data."""
        import pyvista
        k = self.cells.shape[1]
        cells = np.hstack([np.full((len(self.cells), 1), k), self.cells]).ravel()
        grid = pyvista.UnstructuredGrid(cells, np.full(len(self.cells), self.cell_type, dtype=np.uint8),
                                        self.points)
        for name, values in (point_data or {}).items():
            grid.point_data[name] = values
        return grid

    def boundary_faces(self) -> np.ndarray:
        """(f, 3) corner nodes of the faces that belong to one cell only (the mesh's boundary)."""
        corners = self.cells[:, :4]
        faces = np.concatenate([corners[:, [1, 2, 3]], corners[:, [0, 3, 2]], corners[:, [0, 1, 3]],
                                corners[:, [0, 2, 1]]])
        key = np.sort(faces, axis=1)
        _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        return faces[index[counts == 1]]


def _owned_nodes(V):
    index_map = V.dofmap.index_map
    n_owned = index_map.size_local
    local_to_global = index_map.local_to_global(np.arange(n_owned + index_map.num_ghosts, dtype=np.int32))
    return n_owned, local_to_global


def gather_mesh(V) -> GatheredMesh | None:
    """The mesh of the Lagrange space ``V`` on rank 0 (None on the other ranks); collective."""
    from dolfinx import plot

    n_owned, local_to_global = _owned_nodes(V)
    topology, cell_types, points = plot.create_vtk_mesh(V)
    k = V.dofmap.dof_layout.num_dofs
    cells = local_to_global[topology.reshape(-1, k + 1)[:, 1:]] if len(cell_types) else np.empty((0, k), int)
    pieces = V.mesh.comm.gather((local_to_global[:n_owned], points[:n_owned], cells,
                                 int(cell_types[0]) if len(cell_types) else -1), root=0)
    if pieces is None:
        return None
    n = V.dofmap.index_map.size_global
    coordinates = np.empty((n, 3))
    for numbers, xyz, _, _ in pieces:
        coordinates[numbers] = xyz
    cell_type = max(p[3] for p in pieces)
    return GatheredMesh(coordinates, np.concatenate([p[2] for p in pieces]).astype(np.int64), cell_type)


def gather_values(u) -> np.ndarray | None:
    """The nodal values of ``u`` (n, block size) on rank 0 in global node order (None elsewhere); collective."""
    V = u.function_space
    n_owned, local_to_global = _owned_nodes(V)
    bs = V.dofmap.index_map_bs
    pieces = V.mesh.comm.gather((local_to_global[:n_owned], u.x.array.reshape(-1, bs)[:n_owned].copy()), root=0)
    if pieces is None:
        return None
    values = np.empty((V.dofmap.index_map.size_global, bs))
    for numbers, piece in pieces:
        values[numbers] = piece
    return values


@dataclass(frozen=True)
class Solution:
    """A run's mesh and its displacement after every step (:func:`read_solution`)."""

    points: np.ndarray          #: (n, 3) node coordinates (m)
    cells: np.ndarray           #: (m, 4 or 10) node indices per tetrahedron, VTK order (corners first)
    cell_type: int              #: VTK cell type: 10 (P1, tetra) or 71 (P2, Lagrange tetra of 10 nodes)
    labels: tuple[str, ...]     #: the steps done, in order
    displacements: np.ndarray   #: (steps, n, 3) displacement (m) after each step

    def displacement(self, label: str) -> np.ndarray:
        """(n, 3) displacement (m) at the end of the step ``label``."""
        if label not in self.labels:
            raise InputError(f"no step {label!r} in the solution; steps: {', '.join(self.labels)}")
        return self.displacements[self.labels.index(label)]

    def to_pyvista(self, label: str | None = None):
        """A ``pyvista.UnstructuredGrid`` with the point data ``displacement`` of step ``label`` (default: the last)."""
        label = self.labels[-1] if label is None else label
        return GatheredMesh(self.points, self.cells, self.cell_type).to_pyvista(
            {"displacement": self.displacement(label)})


def read_solution(out_dir: str | os.PathLike) -> Solution:
    """The mesh and the per-step displacements a scene run wrote in ``out_dir`` (its ``solution.npz``)."""
    path = Path(out_dir) / SOLUTION_FILE
    if not path.is_file():
        raise InputError(f"{path} does not exist: run the scene with [outputs] xdmf = true (the default) and an "
                         "output directory")
    with np.load(path, allow_pickle=False) as data:
        return Solution(points=data["points"], cells=data["cells"], cell_type=int(data["cell_type"]),
                        labels=tuple(str(label) for label in data["labels"]), displacements=data["displacements"])


class SolutionWriter:
    """Collects the displacement after each step (gathered to rank 0) and writes ``solution.npz`` atomically."""

    def __init__(self, V, out_dir: str | os.PathLike):
        self._mesh = gather_mesh(V)
        self._comm = V.mesh.comm
        self._path = Path(out_dir) / SOLUTION_FILE
        self._labels: list[str] = []
        self._values: list[np.ndarray] = []

    def add(self, label: str, u) -> None:
        """Record the displacement ``u`` at the end of step ``label`` (collective)."""
        values = gather_values(u)
        if values is not None:
            self._labels.append(label)
            self._values.append(values)

    def commit(self) -> None:
        """Write the file (rank 0; collective only in that every rank calls it)."""
        if self._comm.rank != 0:
            return
        displacements = np.array(self._values) if self._values else np.empty((0, len(self._mesh.points), 3))
        with atomic_path(self._path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, points=self._mesh.points, cells=self._mesh.cells,
                                cell_type=np.int64(self._mesh.cell_type), labels=np.array(self._labels, dtype=str),
                                displacements=displacements)
