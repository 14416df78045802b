"""A robot meshed elsewhere: a gmsh ``.msh`` file whose physical groups are the regions and facet groups.

Physical volume groups become cell tags (the scene's regions refer to them by tag or by group name), physical
surface groups facet tags (e.g. a clamp). Every tetrahedron must lie in exactly one physical volume group.
:func:`physical_groups` lists the groups without building anything (used to validate a scene before
meshing, on every rank: it reads the file with meshio); :func:`read_msh` reads the mesh with gmsh on rank 0
and distributes it (``dolfinx.io.gmshio.model_to_mesh``; dolfinx 0.5.2's own ``read_from_msh`` is broken).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import gmsh
import meshio
import numpy as np
from mpi4py import MPI

from foambase.errors import InputError
from meshes.beam import TaggedMesh, distribute_gmsh

__all__ = ["MshMesh", "PhysicalGroups", "physical_groups", "read_msh"]

_VOLUME_CELLS = ("tetra", "tetra10")
_FACET_CELLS = ("triangle", "triangle6")


@dataclass(frozen=True)
class PhysicalGroups:
    """Physical group tags of a ``.msh`` file: volumes (``cells``), surfaces (``facets``), named ones (name → tag)."""

    cells: frozenset[int]
    facets: frozenset[int]
    cell_names: dict[str, int]
    facet_names: dict[str, int]


def physical_groups(path: str | Path) -> PhysicalGroups:
    """The physical groups of the tetrahedra and triangles of a gmsh ``.msh`` file.

    Raises
    ------
    foambase.errors.InputError
        The file is not a readable ``.msh`` file, has no tetrahedra, has tetrahedra outside every physical
        volume group, or triangles of a physical surface group that are faces of no tetrahedron (a volume left out
        of the physical volume groups: gmsh did not write its tetrahedra; reading such a file would crash).

    """
    path = Path(path)
    if path.suffix != ".msh":
        raise InputError(f"mesh file {path}: expected a gmsh .msh file, got suffix {path.suffix!r}")
    try:
        msh = meshio.read(path, file_format="gmsh")
    except (Exception, SystemExit) as exc:  # meshio raises many types on a broken file, even SystemExit
        raise InputError(f"mesh file {path}: cannot read it as a gmsh .msh file ({exc})") from exc
    tags = {"cells": set(), "facets": set()}
    n_tetra = 0
    physical = msh.cell_data.get("gmsh:physical", [None] * len(msh.cells))
    faces, triangles = [], []  # corner nodes, sorted: the tetrahedra's faces and the grouped triangles
    for block, data in zip(msh.cells, physical):
        kind = "cells" if block.type in _VOLUME_CELLS else "facets" if block.type in _FACET_CELLS else None
        if kind is None:
            continue
        n_tetra += len(block.data) if kind == "cells" else 0
        corners = np.asarray(block.data)[:, :4 if kind == "cells" else 3]
        if kind == "cells":
            faces += [np.sort(corners[:, [i for i in range(4) if i != drop]], axis=1) for drop in range(4)]
        elif data is not None:
            triangles.append(np.sort(corners[np.asarray(data) > 0], axis=1))
        if data is None or np.any(np.asarray(data) <= 0):
            if kind == "cells":
                raise InputError(f"mesh file {path}: some tetrahedra are in no physical volume group (every cell "
                                 "needs one, the scene's regions refer to them)")
            continue
        tags[kind].update(int(t) for t in np.unique(data))
    if n_tetra == 0:
        raise InputError(f"mesh file {path}: no tetrahedra (a 3-D tetrahedral mesh is required)")
    orphans = _orphan_triangles(faces, triangles)
    if orphans:
        raise InputError(f"mesh file {path}: {orphans} triangle(s) of the physical surface groups are faces of no "
                         "tetrahedron: a volume is missing from the physical volume groups (gmsh writes only the "
                         "elements of physical groups, so that volume's tetrahedra were left out); add it to a "
                         "physical volume group")
    names = {"cells": {}, "facets": {}}
    for name, (tag, dim) in msh.field_data.items():
        if dim in (2, 3):
            names["cells" if dim == 3 else "facets"][name] = int(tag)
    return PhysicalGroups(frozenset(tags["cells"]), frozenset(tags["facets"]), names["cells"], names["facets"])


def _orphan_triangles(faces: list[np.ndarray], triangles: list[np.ndarray]) -> int:
    """How many of the ``triangles`` (sorted corner nodes) are none of the tetrahedra's ``faces``."""
    if not triangles or not faces:
        return sum(len(t) for t in triangles)
    faces, triangles = np.concatenate(faces).astype(np.int64), np.concatenate(triangles).astype(np.int64)
    row = np.dtype((np.void, 3 * 8))
    return int(np.count_nonzero(~np.isin(np.ascontiguousarray(triangles).view(row).ravel(),
                                         np.ascontiguousarray(faces).view(row).ravel())))


@dataclass(frozen=True, kw_only=True)
class MshMesh(TaggedMesh):
    """A mesh read from a ``.msh`` file; ``h`` is its largest cell diameter, ``order`` its geometry degree."""

    path: Path


def read_msh(comm: MPI.Comm, path: str | Path) -> MshMesh:
    """Read a gmsh ``.msh`` file on rank 0 of ``comm`` and distribute it, with its physical groups as tags."""
    path = Path(path)

    def merge():
        gmsh.merge(str(path))

    mesh, cell_tags, facet_tags, meshing_s = distribute_gmsh(comm, path.stem, merge)
    n_local = mesh.topology.index_map(mesh.topology.dim).size_local
    nodes = mesh.geometry.dofmap.array.reshape(-1, mesh.geometry.dofmap.links(0).size)[:n_local, :4]
    x = mesh.geometry.x[nodes]  # (cells, 4 vertices, 3)
    edges = [np.linalg.norm(x[:, a] - x[:, b], axis=1) for a in range(4) for b in range(a + 1, 4)]
    local = float(np.max(edges, initial=0.0))
    h = comm.allreduce(local, op=MPI.MAX)
    return MshMesh(mesh=mesh, cell_tags=cell_tags, facet_tags=facet_tags, h=h if h > 0 else math.nan,
                   order=mesh.geometry.cmap.degree, meshing_s=meshing_s, path=path)
