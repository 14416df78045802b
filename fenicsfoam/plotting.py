"""Pictures of scene results: the deformed shape coloured by |u| and the orientation field, with colour bars and axes.

Every function is collective: the mesh and the values are gathered to rank 0 in the global node numbering
(:func:`fenicsfoam.io.gather_mesh`), so the picture is of one conforming mesh and rank boundaries do not show; rank
0 draws and writes the PNG atomically (:func:`foambase.files.atomic_path`).

A picture has a perspective view (pyvista, offscreen, with an x–y–z axes triad) and orthographic views drawn by
matplotlib with axes in millimetres (a top view x–y and a side view x–z of the deformed boundary, faces sorted back
to front), sharing one matplotlib colour bar. The colour bar is matplotlib's because vtk's scalar bar aborts with
the vtk wheel next to dolfinx's libstdc++. The orientation picture is a top view of the l axis at cell midpoints,
coloured by its vertical component ``|l · e_z|``, next to a perspective view.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from dolfinx import fem
from dolfinx.mesh import compute_midpoints

from fenicsfoam.io import gather_mesh, gather_values
from foambase.files import atomic_path

__all__ = ["plot_displacement", "plot_orientation"]

#: Camera of the perspective view: view vector and view-up, tilted from above (robots lie along x–y, gravity −z).
VIEW = ((0.6, -1.0, 0.8), (0.0, 0.0, 1.0))
#: At most this many orientation segments are drawn (every k-th cell).
MAX_GLYPHS = 1500
#: Colour map of |u|.
CMAP = "coolwarm"


def _pyvista():
    """pyvista, rendering offscreen through EGL (no X server needed, no X warning); set before vtk renders."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista
    pyvista.OFF_SCREEN = True
    return pyvista


def _render(meshes: list[tuple], size=(900, 700)) -> np.ndarray:
    """A perspective render of ``(mesh, add_mesh keyword arguments)`` pairs with an axes triad, as an RGB image."""
    pyvista = _pyvista()
    plotter = pyvista.Plotter(off_screen=True, window_size=size)
    plotter.set_background("white")
    for mesh, kwargs in meshes:
        plotter.add_mesh(mesh, **kwargs)
    plotter.add_axes(color="black")
    plotter.view_vector(VIEW[0], viewup=VIEW[1])
    plotter.reset_camera()
    image = plotter.screenshot(return_img=True)
    plotter.close()
    return image


def _projection(ax, points: np.ndarray, faces: np.ndarray, face_values: np.ndarray, plane: tuple[int, int],
                depth: np.ndarray, norm, cmap: str, title: str) -> None:
    """Faces projected on the coordinate plane ``plane`` (axes in mm), drawn back to front along ``depth``."""
    from matplotlib.collections import PolyCollection

    order = np.argsort(depth)
    polygons = 1e3 * points[faces[order]][:, :, list(plane)]
    collection = PolyCollection(polygons, array=face_values[order], cmap=cmap, norm=norm, edgecolors="face",
                                linewidths=0.2)
    ax.add_collection(collection)
    ax.autoscale_view()
    ax.set_aspect("equal")
    names = "xyz"
    ax.set_xlabel(f"{names[plane[0]]} (mm)")
    ax.set_ylabel(f"{names[plane[1]]} (mm)")
    ax.set_title(title, fontsize=10)


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def _figure(title: str):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig = plt.figure(figsize=(14, 6.5))
    fig.suptitle(title)
    grid = fig.add_gridspec(2, 3, width_ratios=(1.3, 1.0, 0.04))
    return fig, fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1]), \
        fig.add_subplot(grid[:, 2])


def _obstacle_meshes(obstacles, points: np.ndarray) -> list[tuple]:
    """The pyvista meshes of rigid obstacles (:class:`fenicsfoam.contact.Obstacle`), planes sized to the body."""
    pyvista = _pyvista()
    size = float(np.ptp(points, axis=0).max()) * 1.5
    meshes = []
    for o in obstacles:
        if o.shape == "sphere":
            mesh = pyvista.Sphere(radius=o.radius, center=o.center)
        elif o.shape == "box":
            mesh = pyvista.Box(bounds=(o.min[0], o.max[0], o.min[1], o.max[1], o.min[2], o.max[2]))
        else:
            n = np.asarray(o.normal, float) / np.linalg.norm(o.normal)
            centre = np.asarray(o.point, float) + (points.mean(axis=0) - o.point) @ (np.eye(3) - np.outer(n, n))
            mesh = pyvista.Plane(center=centre, direction=n, i_size=size, j_size=size)
        meshes.append((mesh, {"color": "lightgray", "opacity": 0.5}))
    return meshes


def _draw_obstacles(ax, obstacles, plane: tuple[int, int]) -> None:
    """Rigid obstacles in a projection (mm): a sphere's outline, a box's, a plane seen edge-on as a line."""
    import matplotlib.patches
    i, j = plane
    k = 3 - i - j
    style = {"facecolor": "lightgray", "edgecolor": "gray", "alpha": 0.5, "zorder": 0}
    for o in obstacles:
        if o.shape == "sphere":
            ax.add_patch(matplotlib.patches.Circle((1e3 * o.center[i], 1e3 * o.center[j]), 1e3 * o.radius, **style))
        elif o.shape == "box":
            ax.add_patch(matplotlib.patches.Rectangle((1e3 * o.min[i], 1e3 * o.min[j]), 1e3 * (o.max[i] - o.min[i]),
                                                      1e3 * (o.max[j] - o.min[j]), **style))
        else:
            n = np.asarray(o.normal, float) / np.linalg.norm(o.normal)
            if abs(n[k]) > 1e-9:  # not edge-on in this view
                continue
            if abs(n[j]) > 1e-12:  # n_i (x_i − p_i) + n_j (x_j − p_j) = 0
                ax.axline((1e3 * o.point[i], 1e3 * o.point[j]), slope=-n[i] / n[j], color="gray", linewidth=2,
                          zorder=0)
            else:
                ax.axvline(1e3 * o.point[i], color="gray", linewidth=2, zorder=0)
    if obstacles:
        ax.autoscale_view()


def plot_displacement(u: fem.Function, path: Path, title: str = "", obstacles=()) -> None:
    """Write a PNG of the deformed shape ``x = X + u`` coloured by ``|u|`` (mm), with the reference outline.

    Perspective view (axes triad), top view (x–y) and side view (x–z) with axes in mm, one colour bar. Collective;
    rank 0 writes ``path``. P2 fields are drawn at all their nodes (vtk subdivides the quadratic tetrahedra).
    ``obstacles`` (:class:`fenicsfoam.contact.Obstacle`, where they are) are drawn in light gray.
    """
    import matplotlib.colors

    mesh = gather_mesh(u.function_space)
    values = gather_values(u)
    if mesh is None:
        return
    magnitude = 1e3 * np.linalg.norm(values, axis=1)
    top = max(float(magnitude.max()), 1e-12)
    reference = mesh.to_pyvista()
    deformed = mesh.to_pyvista({"|u| (mm)": magnitude})
    deformed.points = mesh.points + values
    image = _render([(reference.extract_feature_edges(), {"color": "gray", "line_width": 1}),
                     (deformed, {"scalars": "|u| (mm)", "cmap": CMAP, "clim": (0.0, top), "show_scalar_bar": False,
                                 "show_edges": True, "edge_color": "dimgray", "line_width": 0.3})]
                    + _obstacle_meshes(obstacles, mesh.points + values))
    fig, ax3d, ax_top, ax_side, ax_bar = _figure(title)
    ax3d.imshow(image)
    ax3d.set_axis_off()
    ax3d.set_title("perspective (axes triad X, Y, Z)", fontsize=10)
    faces = mesh.boundary_faces()
    x = mesh.points + values
    face_values = magnitude[faces].mean(axis=1)
    norm = matplotlib.colors.Normalize(0.0, top)
    _projection(ax_top, x, faces, face_values, (0, 1), x[faces, 2].mean(axis=1), norm, CMAP, "top view (from +z)")
    _projection(ax_side, x, faces, face_values, (0, 2), -x[faces, 1].mean(axis=1), norm, CMAP, "side view (from −y)")
    for ax, plane in ((ax_top, (0, 1)), (ax_side, (0, 2))):
        _draw_obstacles(ax, obstacles, plane)
    import matplotlib.cm
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=CMAP), cax=ax_bar, label="|u| (mm)")
    fig.tight_layout()
    _save(fig, Path(path))


def plot_orientation(orientation: fem.Function, path: Path, title: str = "") -> None:
    """Write a PNG of the DG0 *l* axis as segments at cell midpoints: a top view (x–y, mm) and a perspective view.

    Segments are coloured by ``|l · e_z|`` (0: in the horizontal plane, 1: vertical) and have no arrow head, ``a``
    and ``−a`` being the same axis. At most :data:`MAX_GLYPHS` segments (every k-th cell), of length a few mean cell
    sizes. Collective; rank 0 writes ``path``.
    """
    import matplotlib.cm
    import matplotlib.colors
    from matplotlib.collections import LineCollection

    domain = orientation.function_space.mesh
    tdim = domain.topology.dim
    n_owned = domain.topology.index_map(tdim).size_local
    n_global = domain.topology.index_map(tdim).size_global
    stride = max(1, -(-n_global // MAX_GLYPHS))
    cells = np.arange(0, n_owned, stride, dtype=np.int32)
    midpoints = compute_midpoints(domain, tdim, cells)
    V = orientation.function_space
    dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[cells, 0]
    directions = orientation.x.array.reshape(-1, V.dofmap.index_map_bs)[dofs]
    gathered = domain.comm.gather((midpoints, directions), root=0)
    mesh = gather_mesh(fem.VectorFunctionSpace(domain, ("CG", 1)))
    if mesh is None:
        return
    pyvista = _pyvista()
    midpoints = np.concatenate([g[0] for g in gathered])
    directions = np.concatenate([g[1] for g in gathered])
    extent = np.ptp(mesh.points, axis=0)
    length = 1.5 * (np.prod(extent[extent > 0]) / n_global) ** (1.0 / np.count_nonzero(extent > 0))
    vertical = np.abs(directions[:, 2])
    norm = matplotlib.colors.Normalize(0.0, 1.0)
    cmap = "viridis"
    cloud = pyvista.PolyData(midpoints)
    cloud.point_data["l"] = directions
    cloud.point_data["|l_z|"] = vertical
    glyphs = cloud.glyph(orient="l", scale=False, factor=length, geom=pyvista.Line((-0.5, 0, 0), (0.5, 0, 0)))
    image = _render([(mesh.to_pyvista(), {"color": "lightgray", "opacity": 0.25}),
                     (glyphs, {"scalars": "|l_z|", "cmap": cmap, "clim": (0.0, 1.0), "show_scalar_bar": False,
                               "line_width": 2})])
    fig, ax3d, ax_top, ax_side, ax_bar = _figure(f"{title}\nl axis at {len(midpoints)} cell midpoints")
    ax3d.imshow(image)
    ax3d.set_axis_off()
    ax3d.set_title("perspective (axes triad X, Y, Z)", fontsize=10)
    faces = mesh.boundary_faces()
    outline = np.full(len(faces), 0.0)
    gray = matplotlib.colors.ListedColormap(["#e6e6e6"])
    for ax, plane, depth, name in ((ax_top, (0, 1), 2, "top view (from +z)"),
                                   (ax_side, (0, 2), 1, "side view (from −y)")):
        sign = 1.0 if depth == 2 else -1.0
        _projection(ax, mesh.points, faces, outline, plane, sign * mesh.points[faces, depth].mean(axis=1), None, gray,
                    name)
        ends = np.stack([midpoints - 0.5 * length * directions, midpoints + 0.5 * length * directions], axis=1)
        order = np.argsort(sign * midpoints[:, depth])
        segments = LineCollection(1e3 * ends[order][:, :, list(plane)], array=vertical[order], cmap=cmap, norm=norm,
                                  linewidths=1.2)
        ax.add_collection(segments)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), cax=ax_bar, label="|l · e_z|")
    fig.tight_layout()
    _save(fig, Path(path))
