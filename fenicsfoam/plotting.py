"""Pictures of scene results (pyvista offscreen): deformed shape coloured by |u|, orientation field as glyphs.

Every function is collective: each rank contributes the cells it owns (``dolfinx.plot.create_vtk_mesh``),
rank 0 merges them and writes the PNG atomically (temporary file in the same directory, then ``os.replace``).
No scalar bar is drawn (vtk's scalar bar aborts with this vtk wheel next to dolfinx's libstdc++); the colour
range is written as text instead.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from dolfinx import fem, plot
from dolfinx.mesh import compute_midpoints

from foambase.files import atomic_path

__all__ = ["plot_displacement", "plot_orientation"]

#: Camera: view vector and view-up, tilted from above (both robots lie along x–y, gravity along −z).
VIEW = ((0.6, -1.0, 0.8), (0.0, 0.0, 1.0))
#: At most this many orientation glyphs are drawn (every k-th owned cell).
MAX_GLYPHS = 1500


def _gather(pieces, comm):
    """Merge (topology, cell_types, points, *point arrays) pieces from every rank on rank 0; None elsewhere."""
    pieces = comm.gather(pieces, root=0)
    if comm.rank != 0:
        return None
    merged, offset = [], 0
    for topology, cell_types, points, *arrays in pieces:
        if len(cell_types):
            t = topology.reshape(len(cell_types), -1).copy()
            t[:, 1:] += offset
            merged.append((t.ravel(), cell_types, points, *arrays))
        offset += len(points)
    return [np.concatenate(parts) for parts in zip(*merged)]


def _pyvista():
    """pyvista, rendering offscreen through EGL (no X server needed, no X warning); set before vtk renders."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista
    pyvista.OFF_SCREEN = True
    return pyvista


def _plotter(title: str):
    pyvista = _pyvista()
    plotter = pyvista.Plotter(off_screen=True, window_size=(1200, 900))
    plotter.set_background("white")
    plotter.add_text(title, font_size=12, color="black")
    return plotter


def _save(plotter, path: Path) -> None:
    plotter.view_vector(VIEW[0], viewup=VIEW[1])
    plotter.reset_camera()
    with atomic_path(path) as tmp:
        plotter.screenshot(str(tmp))
    plotter.close()


def plot_displacement(u: fem.Function, path: Path, title: str = "") -> None:
    """Write a PNG of the deformed shape ``x = X + u`` coloured by ``|u|`` (mm), with the reference outline.

    Collective; rank 0 writes ``path``. For P2 the quadratic tetrahedra are drawn (vtk subdivides them).
    """
    V = u.function_space
    topology, cell_types, points = plot.create_vtk_mesh(V)
    values = u.x.array.reshape(-1, V.dofmap.index_map_bs)[: len(points)]
    data = _gather((topology, cell_types, points, values), V.mesh.comm)
    if data is None:
        return
    pyvista = _pyvista()
    topology, cell_types, points, values = data
    magnitude = 1e3 * np.linalg.norm(values, axis=1)
    reference = pyvista.UnstructuredGrid(topology, cell_types, points)
    deformed = pyvista.UnstructuredGrid(topology, cell_types, points + values)
    deformed.point_data["|u| (mm)"] = magnitude
    plotter = _plotter(f"{title}\ndisplacement magnitude from 0 (blue) to {magnitude.max():.3g} mm (red)")
    plotter.add_mesh(reference.extract_feature_edges(), color="gray", line_width=1)
    plotter.add_mesh(deformed, scalars="|u| (mm)", cmap="coolwarm", clim=(0.0, max(magnitude.max(), 1e-12)),
                     show_scalar_bar=False, show_edges=True, edge_color="dimgray", line_width=0.3)
    _save(plotter, Path(path))


def plot_orientation(orientation: fem.Function, path: Path, title: str = "") -> None:
    """Write a PNG of the reference mesh with the DG0 *l* axis drawn as a line segment at cell midpoints.

    Collective; rank 0 writes ``path``. At most :data:`MAX_GLYPHS` segments (every k-th cell), of length
    a few mean cell sizes; a segment has no arrow head since ``a`` and ``−a`` are the same axis.
    """
    mesh = orientation.function_space.mesh
    tdim = mesh.topology.dim
    n_owned = mesh.topology.index_map(tdim).size_local
    n_global = mesh.topology.index_map(tdim).size_global
    topology, cell_types, points = plot.create_vtk_mesh(mesh, tdim, np.arange(n_owned, dtype=np.int32))
    stride = max(1, -(-n_global // MAX_GLYPHS))
    cells = np.arange(0, n_owned, stride, dtype=np.int32)
    midpoints = compute_midpoints(mesh, tdim, cells)
    V = orientation.function_space
    dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[cells, 0]
    directions = orientation.x.array.reshape(-1, V.dofmap.index_map_bs)[dofs]
    gathered = mesh.comm.gather((midpoints, directions), root=0)
    data = _gather((topology, cell_types, points), mesh.comm)
    if data is None:
        return
    pyvista = _pyvista()
    topology, cell_types, points = data
    midpoints = np.concatenate([g[0] for g in gathered])
    directions = np.concatenate([g[1] for g in gathered])
    grid = pyvista.UnstructuredGrid(topology, cell_types, points)
    extent = np.ptp(points, axis=0)
    length = 1.5 * (np.prod(extent[extent > 0]) / n_global) ** (1.0 / np.count_nonzero(extent > 0))
    cloud = pyvista.PolyData(midpoints)
    cloud.point_data["l"] = directions
    glyphs = cloud.glyph(orient="l", scale=False, factor=length, geom=pyvista.Line((-0.5, 0, 0), (0.5, 0, 0)))
    plotter = _plotter(f"{title}\nl axis at {len(midpoints)} cell midpoints")
    plotter.add_mesh(grid, color="lightgray", opacity=0.25)
    plotter.add_mesh(glyphs, color="darkred", line_width=2)
    _save(plotter, Path(path))
