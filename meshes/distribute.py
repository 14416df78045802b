"""A distributed dolfinx mesh with its tags, from node, cell and tag arrays built on rank 0.

The serial builders (the Tripod's mirrored wedge, the foam RVE's cut Kuhn grid) produce plain arrays on rank 0;
:func:`mesh_from_arrays` hands them to ``dolfinx.mesh.create_mesh``, which partitions and distributes the mesh, and
carries the cell and facet tags along with ``distribute_entity_data``, as ``dolfinx.io.gmshio.model_to_mesh`` does
for a gmsh model.
"""

from __future__ import annotations

import dolfinx
import dolfinx.cpp
import dolfinx.io.gmshio
import numpy as np
from mpi4py import MPI

__all__ = ["GMSH_TETRAHEDRON", "mesh_from_arrays"]

#: gmsh element type of the 4-node tetrahedron (11: the 10-node one).
GMSH_TETRAHEDRON = 4


def _tags(mesh: dolfinx.mesh.Mesh, dim: int, entities: np.ndarray, values: np.ndarray, name: str):
    """Mesh tags of the ``dim``-entities given by their nodes (rank 0's arrays; empty on the other ranks)."""
    local, local_values = dolfinx.cpp.io.distribute_entity_data(mesh._mesh, dim, entities, values)
    mesh.topology.create_connectivity(dim, 0 if dim == mesh.topology.dim else mesh.topology.dim)
    tags = dolfinx.mesh.meshtags_from_entities(mesh, dim, dolfinx.cpp.graph.AdjacencyList_int32(local),
                                               local_values.astype(np.int32))
    tags.name = name
    return tags


def mesh_from_arrays(comm: MPI.Comm, x: np.ndarray | None, cells: np.ndarray | None, cell_values: np.ndarray | None,
                     facets: np.ndarray | None = None, facet_values: np.ndarray | None = None,
                     gmsh_cell_type: int = GMSH_TETRAHEDRON):
    """Distribute a tetrahedral mesh given on rank 0; returns ``(mesh, cell_tags, facet_tags)`` (collective).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    x, cells, cell_values
        On rank 0: nodes (n, 3), cells (m, k) in gmsh's node order (``k`` = 4 or 10) and their tags (m,). The other
        ranks pass ``None`` (or empty arrays).
    facets, facet_values
        On rank 0, optionally: tagged facets by their corner nodes (f, 3) and their tags; without them the facet
        tags are empty.
    gmsh_cell_type
        gmsh's element type of the cells (rank 0's value is used): 4 straight, 11 quadratic tetrahedra.

    """
    info = None
    if comm.rank == 0:
        info = (int(gmsh_cell_type), int(np.shape(cells)[1]), facets is not None)
    gmsh_cell_type, n_nodes, has_facets = comm.bcast(info, root=0)
    if comm.rank != 0:
        x, cells, cell_values = np.empty((0, 3)), np.empty((0, n_nodes), dtype=np.int64), np.empty(0, np.int32)
        facets, facet_values = np.empty((0, 3), dtype=np.int64), np.empty(0, dtype=np.int32)
    perm = dolfinx.io.gmshio.cell_perm_array(dolfinx.mesh.CellType.tetrahedron, n_nodes)
    cells = np.asarray(cells, dtype=np.int64)[:, perm]
    domain = dolfinx.io.gmshio.ufl_mesh(gmsh_cell_type, 3)
    mesh = dolfinx.mesh.create_mesh(comm, cells, np.asarray(x, dtype=float), domain)
    cell_tags = _tags(mesh, 3, cells, np.asarray(cell_values, dtype=np.int32), "Cell tags")
    if has_facets:
        facet_tags = _tags(mesh, 2, np.asarray(facets, dtype=np.int64), np.asarray(facet_values, dtype=np.int32),
                           "Facet tags")
    else:
        facet_tags = dolfinx.mesh.meshtags(mesh, 2, np.empty(0, dtype=np.int32), np.empty(0, dtype=np.int32))
        facet_tags.name = "Facet tags"
    return mesh, cell_tags, facet_tags
