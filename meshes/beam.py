"""Cantilever beam: a gmsh box meshed with tetrahedra, with tagged clamped and tip faces.

Geometry (SI units, metres): the box ``0 ≤ x ≤ length``, ``|y| ≤ width/2``, ``|z| ≤ height/2``. The face
``x = 0`` is the clamped face, ``x = length`` the free tip; gravity is usually along −z (the scene decides).
The paper's Fig. 6 beams are 250 × 15 × 15 mm with about 20k tetrahedra (:data:`FIG6_BEAM`).

This module also holds what every gmsh-built mesh of the project shares: :class:`TaggedMesh` (the dolfinx
mesh with its cell and facet tags and how long it took) and :func:`mesh_from_gmsh`, which runs a gmsh
model builder on rank 0 only and distributes the result with ``dolfinx.io.gmshio.model_to_mesh``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import dolfinx
import dolfinx.io.gmshio
import gmsh
import numpy as np
from mpi4py import MPI

from foambase.errors import InputError
from foambase.mpi import on_rank0

__all__ = [
    "BEAM_VOLUME",
    "CLAMPED_FACE",
    "FIG6_BEAM",
    "TIP_FACE",
    "BeamMesh",
    "TaggedMesh",
    "distribute_gmsh",
    "generate_tetrahedra",
    "make_beam",
    "mesh_from_gmsh",
]

logger = logging.getLogger(__name__)

#: Cell tag of the whole beam volume.
BEAM_VOLUME: int = 1
#: Facet tag of the clamped face ``x = 0``.
CLAMPED_FACE: int = 11
#: Facet tag of the free tip face ``x = length``.
TIP_FACE: int = 12

#: The Fig. 6 beams: 250 × 15 × 15 mm; ``h = 2.4 mm`` gives 20.7k tetrahedra (the paper's "~20k").
FIG6_BEAM: dict[str, float] = {"length": 0.250, "width": 0.015, "height": 0.015, "h": 0.0024}


@dataclass(frozen=True)
class TaggedMesh:
    """A distributed dolfinx mesh built by gmsh, with its physical groups as mesh tags.

    Attributes
    ----------
    mesh : dolfinx.mesh.Mesh
        The tetrahedral mesh (geometry of degree ``order``), distributed over the communicator.
    cell_tags, facet_tags : dolfinx.mesh.MeshTags
        Physical volume and surface groups of the gmsh model (module constants of the builder).
    h : float
        Target element size (m) given to gmsh.
    order : int
        Degree of the geometry (1: straight tetrahedra, 2: quadratic tetrahedra with curved edges).
    meshing_s : float
        Wall time of the build (gmsh on rank 0 plus distribution), the maximum over ranks, in seconds.

    """

    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTagsMetaClass
    facet_tags: dolfinx.mesh.MeshTagsMetaClass
    h: float
    order: int
    meshing_s: float

    @property
    def n_cells(self) -> int:
        """Global number of tetrahedra."""
        return self.mesh.topology.index_map(self.mesh.topology.dim).size_global

    @property
    def n_vertices(self) -> int:
        """Global number of mesh vertices."""
        return self.mesh.topology.index_map(0).size_global


def mesh_from_gmsh(
    comm: MPI.Comm, name: str, build: Callable[[], None], h: float, order: int
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTagsMetaClass, dolfinx.mesh.MeshTagsMetaClass, float]:
    """Run a gmsh model builder on rank 0 and distribute the resulting mesh over ``comm``.

    Parameters
    ----------
    comm : MPI.Comm
        Communicator of the mesh; gmsh runs on its rank 0 only.
    name : str
        Name of the gmsh model.
    build : callable
        Called on rank 0 inside an initialised gmsh session with an empty current model: creates the
        geometry, synchronises it and defines the physical groups (every volume in exactly one group,
        otherwise ``model_to_mesh`` would duplicate cells).
    h : float
        Element size (m): imposed on every geometry point and as ``Mesh.MeshSizeMax``.
    order : int
        Geometry degree (1 or 2).

    Returns
    -------
    mesh, cell_tags, facet_tags, meshing_s
        As ``dolfinx.io.gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=3)``, plus the wall time (max over ranks).

    Notes
    -----
    The builder owns the gmsh session: it calls ``gmsh.initialize()`` and ``gmsh.finalize()``.

    """
    def build_and_mesh():
        build()
        generate_tetrahedra(h, order)

    return distribute_gmsh(comm, name, build_and_mesh)


def generate_tetrahedra(h: float, order: int) -> None:
    """Mesh the current gmsh model with tetrahedra of size ``h`` (every point and the maximum) and degree ``order``."""
    gmsh.model.mesh.setSize(gmsh.model.getEntities(0), h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.model.mesh.generate(3)
    if order > 1:
        gmsh.model.mesh.setOrder(order)


def distribute_gmsh(
    comm: MPI.Comm, name: str, build: Callable[[], None]
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTagsMetaClass, dolfinx.mesh.MeshTagsMetaClass, float]:
    """Run ``build`` in a gmsh session on rank 0 (it must leave a meshed model) and distribute the mesh.

    A failure of ``build`` is re-raised on rank 0 and reported on the other ranks; the session is always
    finalized. Returns ``model_to_mesh(gmsh.model, comm, 0, gdim=3)`` and the wall time (max over ranks).
    """
    start = time.perf_counter()

    def build_model():
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        build()
        logger.info("gmsh built %r in %.2f s", name, time.perf_counter() - start)

    if comm.rank == 0:
        gmsh.initialize()
    try:
        on_rank0(comm, build_model, f"gmsh failed to build {name!r}")
        mesh, cell_tags, facet_tags = dolfinx.io.gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=3)
    finally:
        if comm.rank == 0:
            gmsh.finalize()
    meshing_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    return mesh, cell_tags, facet_tags, meshing_s


def check_order(order: int) -> None:
    """Raise ``InputError`` unless ``order`` is a geometry degree the builders support (1 or 2)."""
    if order not in (1, 2):
        raise InputError(f"order must be 1 (straight tetrahedra) or 2 (quadratic geometry), got {order!r}")


@dataclass(frozen=True, kw_only=True)
class BeamMesh(TaggedMesh):
    """A tagged beam mesh (:func:`make_beam`); tags :data:`BEAM_VOLUME`, :data:`CLAMPED_FACE`, :data:`TIP_FACE`."""

    length: float
    width: float
    height: float

    @property
    def volume(self) -> float:
        """Exact volume ``length · width · height`` (m³) of the box."""
        return self.length * self.width * self.height


def make_beam(
    comm: MPI.Comm, length: float, width: float, height: float, h: float, order: int = 1
) -> BeamMesh:
    """Mesh the box ``[0, length] × [−width/2, width/2] × [−height/2, height/2]`` (m) with tetrahedra of size ``h``.

    Parameters
    ----------
    comm : MPI.Comm
        Communicator of the mesh (gmsh runs on rank 0).
    length, width, height : float
        Beam dimensions along x, y, z in metres; all positive.
    h : float
        Target tetrahedron size (m), positive and at most ``min(width, height)`` so that the cross-section
        holds at least one element. Fig. 6: :data:`FIG6_BEAM`.
    order : int
        Geometry degree, 1 or 2 (a box needs no curved edges; 2 only changes the coordinate element).

    Returns
    -------
    BeamMesh
        Cell tag :data:`BEAM_VOLUME`; facet tags :data:`CLAMPED_FACE` (x = 0) and :data:`TIP_FACE` (x = length).

    Raises
    ------
    foambase.errors.InputError
        On a non-positive size, an ``h`` larger than the smallest cross-section side, or an unsupported ``order``.

    """
    for key, value in (("length", length), ("width", width), ("height", height), ("h", h)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"beam {key} must be a positive length in metres, got {value!r}")
    if h > min(width, height):
        raise InputError(
            f"beam element size h = {h!r} m exceeds the smallest cross-section side {min(width, height)!r} m; "
            "use h ≤ min(width, height)"
        )
    check_order(order)

    def build() -> None:
        occ = gmsh.model.occ
        box = occ.addBox(0.0, -width / 2, -height / 2, length, width, height)
        occ.synchronize()
        faces = gmsh.model.getBoundary([(3, box)], oriented=False)
        tol = 1e-6 * length
        x_of = {tag: occ.getCenterOfMass(2, tag)[0] for _, tag in faces}
        clamped = [tag for tag, x in x_of.items() if abs(x) < tol]
        tip = [tag for tag, x in x_of.items() if abs(x - length) < tol]
        gmsh.model.addPhysicalGroup(3, [box], BEAM_VOLUME)
        gmsh.model.setPhysicalName(3, BEAM_VOLUME, "beam")
        gmsh.model.addPhysicalGroup(2, clamped, CLAMPED_FACE)
        gmsh.model.setPhysicalName(2, CLAMPED_FACE, "clamped")
        gmsh.model.addPhysicalGroup(2, tip, TIP_FACE)
        gmsh.model.setPhysicalName(2, TIP_FACE, "tip")

    mesh, cell_tags, facet_tags, meshing_s = mesh_from_gmsh(comm, "beam", build, h, order)
    return BeamMesh(mesh, cell_tags, facet_tags, h, order, meshing_s, length=length, width=width, height=height)
