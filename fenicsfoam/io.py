"""A scene's results as files a user can open: the ParaView series and ``solution.npz``, both rank-independent.

``fenicsfoam run`` writes, per load step,

* ``solution_NNN_<label>.vtu``: the mesh (VTK unstructured grid, tetrahedra of 4 or 10 nodes), the displacement as
  point data and the cell data of the step (:mod:`fenicsfoam.scene.outputs` lists them), its step label, index and
  load state as field data; one file per step, each complete on its own (meshio, pyvista, VTK read any of them);
* ``solution.pvd``: the series (a ParaView collection: ``timestep`` = the step's index, ``name`` = its label),
  rewritten after every step, so that it lists the finished steps only (ParaView's time axis; in pyvista,
  ``PVDReader`` with one time value per step);
* ``solution.npz``: the points, the cells and the displacement of every step, for numpy (:func:`read_solution`);
* ``solution.xdmf`` + ``.h5``: the displacement per step written by dolfinx (P2 fields as vertex values).

Node and cell numbering do not depend on the number of MPI ranks: cells are numbered as in the mesh's input
(dolfinx's original cell index), nodes at vertices in the order of the input nodes, then the P2 edge nodes
ordered by the input numbers of their edge's two vertices; each cell's corners are listed in increasing input
number (two swapped when that would turn the tetrahedron inside out), and the coordinates of edge nodes are the
midpoint of their two vertices (curved geometries: the input's edge node). A run on one rank and the same run on
two write the same points and cells, number for number::

    from fenicsfoam.io import read_solution
    solution = read_solution("out/finger")           # the output directory of a run
    solution.points, solution.cells                  # (n, 3) m; (m, 4 or 10) node indices in VTK order
    solution.labels                                  # the steps' labels
    u = solution.displacement("inflated")            # (n, 3) m, at solution.points
    grid = solution.to_pyvista("inflated")           # a pyvista.UnstructuredGrid with point data "displacement"

    import meshio, pyvista
    mesh = meshio.read("out/finger/solution_001_inflated.vtu")   # mesh.point_data, mesh.cell_data, field_data
    reader = pyvista.PVDReader("out/finger/solution.pvd")        # reader.time_values: the steps' indices
    reader.set_active_time_value(1.0); grid = reader.read()[0]   # the second step

:class:`NodeLayout` is the gathering the files and the pictures (:mod:`fenicsfoam.plotting`) use: each rank sends
the nodes and cells it owns with their rank-independent numbers; rank 0 places them.
"""

from __future__ import annotations

import base64
import os
import zlib
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from foambase.errors import InputError
from foambase.files import atomic_path

__all__ = ["PVD_FILE", "SOLUTION_FILE", "GatheredMesh", "NodeLayout", "Solution", "SolutionWriter", "gather_mesh",
           "gather_values", "read_solution", "write_pvd", "write_vtu"]

#: The file :class:`SolutionWriter` writes in a run's output directory.
SOLUTION_FILE = "solution.npz"
#: The ParaView collection of a run's per-step ``.vtu`` files.
PVD_FILE = "solution.pvd"
#: VTK cell types: 4-node and 10-node tetrahedra (the 10-node one has VTK's node order, edges after corners).
VTK_TETRA, VTK_QUADRATIC_TETRA = 10, 24
#: The edges of a tetrahedron in VTK's order of the 10-node element's edge nodes.
_VTK_EDGES = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))


@dataclass(frozen=True)
class GatheredMesh:
    """The nodes of a Lagrange space and its cells, in rank-independent numbers (rank 0's copy of the whole mesh)."""

    points: np.ndarray      #: (n, 3) node coordinates (m), row = node number
    cells: np.ndarray       #: (m, k) node numbers per cell, VTK order (corners first), row = input cell number
    cell_type: int          #: VTK cell type (10: tetra; 24: quadratic tetra, 10 nodes for P2)

    def to_pyvista(self, point_data: dict[str, np.ndarray] | None = None,
                   cell_data: dict[str, np.ndarray] | None = None):
        """A ``pyvista.UnstructuredGrid`` of the mesh with the given point and cell data."""
        import pyvista
        k = self.cells.shape[1]
        cells = np.hstack([np.full((len(self.cells), 1), k), self.cells]).ravel()
        grid = pyvista.UnstructuredGrid(cells, np.full(len(self.cells), self.cell_type, dtype=np.uint8),
                                        self.points)
        for name, values in (point_data or {}).items():
            grid.point_data[name] = values
        for name, values in (cell_data or {}).items():
            grid.cell_data[name] = values
        return grid

    def boundary_faces(self) -> np.ndarray:
        """(f, 3) corner nodes of the faces that belong to one cell only (the mesh's boundary)."""
        corners = self.cells[:, :4]
        faces = np.concatenate([corners[:, [1, 2, 3]], corners[:, [0, 3, 2]], corners[:, [0, 1, 3]],
                                corners[:, [0, 2, 1]]])
        key = np.sort(faces, axis=1)
        _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        return faces[index[counts == 1]]


class NodeLayout:
    """Rank-independent numbers of the nodes of a vector or scalar Lagrange space (P1, P2) and of its mesh's cells.

    Built collectively (the numbering rules: the module docstring). ``mesh`` is the whole mesh on rank 0 (None
    elsewhere); :meth:`gather_nodes` and :meth:`gather_cells` bring the owned values of every rank to rank 0 in
    those numbers.
    """

    def __init__(self, V):
        import basix

        mesh = V.mesh
        self.comm = comm = mesh.comm
        tdim = mesh.topology.dim
        if mesh.topology.cell_name() != "tetrahedron":
            raise InputError(f"results are written for tetrahedral meshes, got {mesh.topology.cell_name()}")
        degree = V.ufl_element().degree()
        if degree not in (1, 2):
            raise InputError(f"results are written for Lagrange degree 1 or 2, got {degree}")
        cell_map, node_map = mesh.topology.index_map(tdim), V.dofmap.index_map
        n_cells = cell_map.size_local
        self.n_owned = n_owned = node_map.size_local
        inputs = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
        x = mesh.geometry.x
        offsets = mesh.geometry.dofmap.offsets
        geometry = mesh.geometry.dofmap.array.reshape(-1, int(offsets[1]) if len(offsets) > 1 else 4)
        corners = inputs[geometry[:, :4]]
        count = comm.allreduce(int(inputs.max(initial=-1)) + 1, op=_max())
        dofs = V.dofmap.list.array.reshape(len(geometry), -1)
        layout = V.dofmap.dof_layout
        keys = np.full(n_owned + node_map.num_ghosts, -1, dtype=np.int64)
        coordinates = np.zeros((len(keys), 3))
        for v in range(4):
            local = dofs[:, layout.entity_dofs(0, v)[0]]
            keys[local] = corners[:, v]
            coordinates[local] = x[geometry[:, v]]
        if degree == 2:
            for e, (a, b) in enumerate(basix.topology(basix.CellType.tetrahedron)[1]):
                local = dofs[:, layout.entity_dofs(1, e)[0]]
                lo, hi = np.minimum(corners[:, a], corners[:, b]), np.maximum(corners[:, a], corners[:, b])
                keys[local] = count + lo * count + hi
                coordinates[local] = (x[geometry[:, 4 + e]] if geometry.shape[1] >= 10
                                      else 0.5 * (x[geometry[:, a]] + x[geometry[:, b]]))
        # each owned cell: corners in increasing input number, two swapped if that inverts it
        cell_corners = np.sort(corners[:n_cells], axis=1)
        order = np.argsort(corners[:n_cells], axis=1)
        p = x[np.take_along_axis(geometry[:n_cells, :4], order, axis=1)]
        inverted = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) < 0
        cell_corners[inverted] = cell_corners[inverted][:, [0, 1, 3, 2]]
        cell_keys = cell_corners
        if degree == 2:
            edges = [count + np.minimum(cell_corners[:, a], cell_corners[:, b]) * count
                     + np.maximum(cell_corners[:, a], cell_corners[:, b]) for a, b in _VTK_EDGES]
            cell_keys = np.column_stack([cell_corners, *edges])
        original = np.asarray(mesh.topology.original_cell_index, dtype=np.int64)[:n_cells]
        pieces = comm.gather((keys[:n_owned], coordinates[:n_owned], original, cell_keys), root=0)
        self.mesh: GatheredMesh | None = None
        if pieces is None:
            node_numbers, cell_numbers = None, None
        else:
            all_keys = np.concatenate([piece[0] for piece in pieces])
            sorted_keys = np.sort(all_keys)
            numbers = np.searchsorted(sorted_keys, all_keys)
            points = np.empty((len(all_keys), 3))
            points[numbers] = np.concatenate([piece[1] for piece in pieces])
            all_original = np.concatenate([piece[2] for piece in pieces])
            positions = np.empty(len(all_original), dtype=np.int64)
            positions[np.argsort(all_original, kind="stable")] = np.arange(len(all_original))
            cells = np.empty((len(all_original), cell_keys.shape[1]), dtype=np.int64)
            cells[positions] = np.searchsorted(sorted_keys, np.concatenate([piece[3] for piece in pieces]))
            self.mesh = GatheredMesh(points, cells, VTK_TETRA if degree == 1 else VTK_QUADRATIC_TETRA)
            node_numbers = np.split(numbers, np.cumsum([len(piece[0]) for piece in pieces])[:-1])
            cell_numbers = np.split(positions, np.cumsum([len(piece[2]) for piece in pieces])[:-1])
        self.node_numbers = comm.scatter(node_numbers, root=0)  #: the numbers of this rank's owned nodes
        self.cell_numbers = comm.scatter(cell_numbers, root=0)  #: the numbers of this rank's owned cells
        self.n_nodes, self.n_cells = node_map.size_global, cell_map.size_global

    def gather_nodes(self, values: np.ndarray) -> np.ndarray | None:
        """Values of the owned nodes (``n_owned`` rows, local order) on rank 0 in node numbers; None elsewhere."""
        values = np.asarray(values)
        pieces = self.comm.gather((self.node_numbers, values[:self.n_owned]), root=0)
        if pieces is None:
            return None
        out = np.empty((self.n_nodes, *values.shape[1:]), dtype=values.dtype)
        for numbers, piece in pieces:
            out[numbers] = piece
        return out

    def gather_cells(self, values: np.ndarray) -> np.ndarray | None:
        """Values of the owned cells (local order) on rank 0 in input cell order; None elsewhere."""
        values = np.asarray(values)
        pieces = self.comm.gather((self.cell_numbers, values[:len(self.cell_numbers)]), root=0)
        if pieces is None:
            return None
        out = np.empty((self.n_cells, *values.shape[1:]), dtype=values.dtype)
        for numbers, piece in pieces:
            out[numbers] = piece
        return out

    def gather_function(self, u) -> np.ndarray | None:
        """The nodal values of ``u`` (a function on this layout's space) on rank 0, (n, block size); collective."""
        bs = u.function_space.dofmap.index_map_bs
        return self.gather_nodes(u.x.array.reshape(-1, bs)[:self.n_owned])


def _max():
    from mpi4py import MPI
    return MPI.MAX


def gather_mesh(V) -> GatheredMesh | None:
    """The mesh of the Lagrange space ``V`` on rank 0 (None on the other ranks); collective."""
    return NodeLayout(V).mesh


def gather_values(u, layout: NodeLayout | None = None) -> np.ndarray | None:
    """The nodal values of ``u`` (n, block size) on rank 0 in :class:`NodeLayout` order (None elsewhere); collective."""
    return (NodeLayout(u.function_space) if layout is None else layout).gather_function(u)


@dataclass(frozen=True)
class Solution:
    """A run's mesh and its displacement after every step (:func:`read_solution`)."""

    points: np.ndarray          #: (n, 3) node coordinates (m)
    cells: np.ndarray           #: (m, 4 or 10) node indices per tetrahedron, VTK order (corners first)
    cell_type: int              #: VTK cell type: 10 (P1, tetra) or 24 (P2, quadratic tetra of 10 nodes)
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
    try:
        with np.load(path, allow_pickle=False) as data:
            return Solution(points=data["points"], cells=data["cells"], cell_type=int(data["cell_type"]),
                            labels=tuple(str(label) for label in data["labels"]),
                            displacements=data["displacements"])
    except (OSError, ValueError, KeyError, EOFError, TypeError, AttributeError) as exc:  # not a run's archive
        raise InputError(f"{path}: not a solution archive written by a scene run ({type(exc).__name__}: "
                         f"{exc})") from exc


class SolutionWriter:
    """Collects the displacement after each step (gathered to rank 0) and writes ``solution.npz`` atomically."""

    def __init__(self, V, out_dir: str | os.PathLike, layout: NodeLayout | None = None):
        self.layout = NodeLayout(V) if layout is None else layout
        self._comm = V.mesh.comm
        self._path = Path(out_dir) / SOLUTION_FILE
        self._labels: list[str] = []
        self._values: list[np.ndarray] = []

    def add(self, label: str, u) -> None:
        """Record the displacement ``u`` at the end of step ``label`` (collective)."""
        values = self.layout.gather_function(u)
        if values is not None:
            self._labels.append(label)
            self._values.append(values)

    def commit(self) -> None:
        """Write the file (rank 0; collective only in that every rank calls it)."""
        if self._comm.rank != 0:
            return
        mesh = self.layout.mesh
        displacements = np.array(self._values) if self._values else np.empty((0, len(mesh.points), 3))
        with atomic_path(self._path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, points=mesh.points, cells=mesh.cells, cell_type=np.int64(mesh.cell_type),
                                labels=np.array(self._labels, dtype=str), displacements=displacements)


# --------------------------------------------------------------------------------------------------
# VTK XML files
# --------------------------------------------------------------------------------------------------
_VTK_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32", np.dtype(np.int64): "Int64",
              np.dtype(np.int32): "Int32", np.dtype(np.uint8): "UInt8"}


def _data_array(name: str, values: np.ndarray) -> str:
    """One ``DataArray`` element: zlib-compressed binary (one block), little-endian, UInt64 header."""
    values = np.ascontiguousarray(values)
    if values.dtype.byteorder == ">":
        values = values.astype(values.dtype.newbyteorder("<"))
    kind = _VTK_TYPES.get(values.dtype)
    if kind is None:
        raise InputError(f"{name}: cannot write a {values.dtype} array to a VTK file")
    raw = values.tobytes()
    packed = zlib.compress(raw, 6)
    header = np.array([1, len(raw), len(raw), len(packed)], dtype="<u8").tobytes()
    components = values.shape[1] if values.ndim == 2 else 1
    data = base64.b64encode(header).decode() + base64.b64encode(packed).decode()
    tuples = values.shape[0] if values.ndim else 1
    return (f'<DataArray type="{kind}" Name={quoteattr(name)} NumberOfComponents="{components}" '
            f'NumberOfTuples="{tuples}" format="binary">{data}</DataArray>\n')


def write_vtu(path: str | os.PathLike, mesh: GatheredMesh, point_data: dict[str, np.ndarray] | None = None,
              cell_data: dict[str, np.ndarray] | None = None, field_data: dict[str, np.ndarray] | None = None) -> None:
    """A VTK XML unstructured grid (``.vtu``), written atomically (call on one rank)."""
    k = mesh.cells.shape[1]
    parts = ['<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
             'header_type="UInt64" compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n']
    if field_data:
        parts.append("<FieldData>\n")
        parts += [_data_array(name, np.atleast_1d(values)) for name, values in field_data.items()]
        parts.append("</FieldData>\n")
    parts.append(f'<Piece NumberOfPoints="{len(mesh.points)}" NumberOfCells="{len(mesh.cells)}">\n')
    parts += ["<Points>\n", _data_array("Points", np.asarray(mesh.points, dtype=np.float64)), "</Points>\n"]
    parts += ["<Cells>\n", _data_array("connectivity", mesh.cells.astype(np.int64).ravel()),
              _data_array("offsets", k * np.arange(1, len(mesh.cells) + 1, dtype=np.int64)),
              _data_array("types", np.full(len(mesh.cells), mesh.cell_type, dtype=np.uint8)), "</Cells>\n"]
    for tag, data in (("PointData", point_data), ("CellData", cell_data)):
        if data:
            parts.append(f"<{tag}>\n")
            parts += [_data_array(name, values) for name, values in data.items()]
            parts.append(f"</{tag}>\n")
    parts.append("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    with atomic_path(path) as tmp:
        Path(tmp).write_text("".join(parts), encoding="ascii")


def write_pvd(path: str | os.PathLike, entries: list[tuple[float, str, str]]) -> None:
    """A ParaView collection (``.pvd``) of ``(timestep, name, file)`` entries, written atomically (one rank)."""
    lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "<Collection>"]
    lines += [f'<DataSet timestep="{t!r}" group="" part="0" name={quoteattr(name)} file={quoteattr(file)}/>'
              for t, name, file in entries]
    lines += ["</Collection>", "</VTKFile>", ""]
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines), encoding="utf-8")
