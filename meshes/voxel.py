"""Voxel images as dolfinx meshes: one hexahedron per voxel of the periodic box, tagged by phase.

The FFT solver (:mod:`homogenization.fft`) and the periodic FEM RVE (:mod:`homogenization.fem`) can then solve
the *same* microstructure: the voxel geometry is represented exactly by both, so their stiffnesses differ only
by discretization and converge to each other as the voxels are subdivided (``refine``), which is the two-way
check of the two solvers independent of any meshing of the smooth foam.
"""

from __future__ import annotations

import numpy as np
from dolfinx import mesh as dmesh
from mpi4py import MPI

from foambase.errors import InputError

__all__ = ["SOLID", "VOID", "upsample", "voxel_mesh"]

#: Cell tags of the two phases (as ``meshes.foam.mesh_rve``).
SOLID = 1
VOID = 2


def upsample(image: np.ndarray, refine: int) -> np.ndarray:
    """The same voxel geometry on a grid ``refine`` times finer (each voxel split into ``refine³``)."""
    if int(refine) != refine or refine < 1:
        raise InputError(f"refine must be an integer >= 1, got {refine!r}")
    for axis in range(3):
        image = np.repeat(image, refine, axis=axis)
    return image


def voxel_mesh(image: np.ndarray, comm: MPI.Comm = MPI.COMM_WORLD, refine: int = 1, box=None):
    """Hexahedral mesh of the periodic box, ``refine`` hexahedra per voxel side, cells tagged SOLID/VOID.

    Parameters
    ----------
    image
        (N1, N2, N3) bool or 0/1 array, True/1 = solid; voxel ``[i, j, k]`` is the box
        ``[i L1/N1, (i+1) L1/N1] × …`` (the convention of :meth:`meshes.foam.VoronoiFoam.voxelize` and of the FFT
        solver). The same array must be passed on every rank.
    comm
        Communicator of the mesh.
    refine
        Hexahedra per voxel and direction.
    box
        Box lengths ``(L1, L2, L3)``; default the unit cube (pass ``((0, 0, 0), box)`` to
        :func:`homogenization.fem.homogenize_fem`).

    Returns
    -------
    mesh, cell_tags
        A dolfinx mesh periodic node for node on opposite faces (a structured grid) and its cell tags.

    """
    image = np.asarray(image)
    if image.ndim != 3 or min(image.shape) < 1:
        raise InputError(f"image must be a non-empty 3D array, got shape {image.shape}")
    if not np.isin(image, (0, 1)).all():
        raise InputError(f"image must hold 0/1 (void/solid) values, got {np.unique(image)[:5].tolist()}")
    if int(refine) != refine or refine < 1:
        raise InputError(f"refine must be an integer >= 1, got {refine!r}")
    L = np.ones(3) if box is None else np.asarray(box, dtype=float)
    if L.shape != (3,) or not np.all(np.isfinite(L)) or np.any(L <= 0):
        raise InputError(f"box must be three positive lengths (L1, L2, L3), got {box!r}")
    n = [s * int(refine) for s in image.shape]
    msh = dmesh.create_box(comm, [np.zeros(3), L], n, dmesh.CellType.hexahedron)
    tdim = msh.topology.dim
    cells = np.arange(msh.topology.index_map(tdim).size_local, dtype=np.int32)
    mid = dmesh.compute_midpoints(msh, tdim, cells)
    index = np.minimum((mid / L * np.array(image.shape)).astype(int), np.array(image.shape) - 1)
    solid = image[index[:, 0], index[:, 1], index[:, 2]].astype(bool)
    tags = np.where(solid, SOLID, VOID).astype(np.int32)
    return msh, dmesh.meshtags(msh, tdim, cells, tags)
