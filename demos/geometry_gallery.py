# %% [markdown]
# # Geometry gallery: the Fig. 6 beam and the paper-size Tripod plate
#
# This demo shows:
# - building the tagged meshes of the robots with `meshes.beam.make_beam` and `meshes.tripod.make_tripod`
#   (gmsh on rank 0, distributed by `dolfinx.io.gmshio.model_to_mesh`);
# - measuring them in parallel: volumes and tag counts summed over ranks (`comm.allreduce`);
# - pictures coloured by tag (pyvista offscreen): the beam's boundary by facet tag (clamped / tip), the
#   Tripod by cell tag (ring, centre, arms, arm ends).
#
# There is no field problem here: the meshes are the discrete domains of the Fig. 6 beam and of the Tripod
# that `demos/beams.py` and `demos/tripod.py` solve on.
#
# ## Checks (exit status 1 if one fails)
# - the beam's volume is the box's to 1e-12; the Tripod's is within (0, 3e-3] above the exact plate area ×
#   thickness (the hole's inscribed polygon adds a little material);
# - every tag is present: beam cell tag 1, facet tags 11 (clamped) and 12 (tip); every Tripod region tag;
# - the Tripod preset has the paper's 2684 tetrahedra within 15 % (the beam, full size: 20k within 15 %);
# - both pictures are written (more than 10 kB each).
#
# Run: `python demos/geometry_gallery.py --out out/geometry_gallery [--ci]`, also under `mpirun -n 2`.

# %%
import os
import sys
from pathlib import Path

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

import dolfinx
import dolfinx.plot
import numpy as np
import ufl
from _demo import parse_args, print0, report
from mpi4py import MPI

from meshes.beam import CLAMPED_FACE, FIG6_BEAM, TIP_FACE, TaggedMesh, make_beam
from meshes.tripod import ARM, ARM_END, CENTRE, PAPER_H, REGIONS, RING, make_tripod

PAPER_TRIPOD_TETS = 2684


# %% [markdown]
# ## Measurements: volume and tag counts, summed over ranks


# %%
def volume(tagged: TaggedMesh) -> float:
    """Mesh volume ∫ 1 dx, summed over ranks."""
    one = dolfinx.fem.Constant(tagged.mesh, 1.0)
    return tagged.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx)), op=MPI.SUM)


def tag_counts(tags, n_owned: int) -> dict[int, int]:
    """Global number of owned entities per tag value."""
    comm = tags.mesh.comm
    owned = tags.values[tags.indices < n_owned]
    local = {int(v): int(n) for v, n in zip(*np.unique(owned, return_counts=True))}
    values = sorted(set().union(*comm.allgather(set(local))))
    return {v: comm.allreduce(local.get(v, 0), op=MPI.SUM) for v in values}


def describe(name: str, tagged: TaggedMesh, exact_volume: float) -> dict:
    """One row of the table: sizes, volume and its error, tag counts, meshing time."""
    topology = tagged.mesh.topology
    topology.create_entities(2)
    return {
        "mesh": name,
        "tets": tagged.n_cells,
        "vertices": tagged.n_vertices,
        "volume": volume(tagged),
        "exact": exact_volume,
        "cell_tags": tag_counts(tagged.cell_tags, topology.index_map(3).size_local),
        "facet_tags": tag_counts(tagged.facet_tags, topology.index_map(2).size_local),
        "meshing_s": tagged.meshing_s,
    }


def print_table(rows: list[dict]) -> None:
    print(f"{'mesh':8s} {'tets':>7s} {'vertices':>8s} {'volume (m³)':>12s} {'exact (m³)':>12s} {'rel. err':>9s} "
          f"{'mesh (s)':>8s}  tags (value: count)")
    for r in rows:
        tags = " ".join(f"{v}:{n}" for v, n in r["cell_tags"].items())
        if r["facet_tags"]:
            tags += " | facets " + " ".join(f"{v}:{n}" for v, n in r["facet_tags"].items())
        print(f"{r['mesh']:8s} {r['tets']:7d} {r['vertices']:8d} {r['volume']:12.5e} {r['exact']:12.5e} "
              f"{r['volume'] / r['exact'] - 1:9.1e} {r['meshing_s']:8.2f}  {tags}")


# %% [markdown]
# ## Pictures: the local pieces of the mesh are gathered on rank 0 and drawn offscreen


# %%
def gather_vtk(tagged: TaggedMesh, dim: int):
    """VTK topology, cell types, points and tag values (0: untagged) of the owned entities of dimension ``dim``
    (cells; for ``dim = 2`` the boundary facets), gathered on rank 0 (None on the other ranks)."""
    mesh = tagged.mesh
    tags = tagged.cell_tags if dim == 3 else tagged.facet_tags
    n_owned = mesh.topology.index_map(dim).size_local
    if dim == 3:
        entities = np.arange(n_owned, dtype=np.int32)
    else:
        mesh.topology.create_connectivity(2, 3)
        boundary = dolfinx.mesh.locate_entities_boundary(mesh, 2, lambda x: np.full(x.shape[1], True))
        entities = boundary[boundary < n_owned]
    topology, cell_types, points = dolfinx.plot.create_vtk_mesh(mesh, dim, entities)
    values = np.zeros(len(entities), dtype=np.int32)
    tagged_entities = np.isin(tags.indices, entities)
    values[np.searchsorted(entities, tags.indices[tagged_entities])] = tags.values[tagged_entities]
    pieces = mesh.comm.gather((topology, cell_types, points, values), root=0)
    if mesh.comm.rank != 0:
        return None
    merged, offset = [], 0
    for topology, cell_types, points, values in pieces:
        if len(cell_types):
            t = topology.reshape(len(cell_types), -1).copy()
            t[:, 1:] += offset
            merged.append((t.ravel(), cell_types, points, values))
        offset += len(points)
    return [np.concatenate(parts) for parts in zip(*merged)]


def plot_tags(tagged: TaggedMesh, dim: int, path: Path, title: str, labels: dict[int, str],
              views: list[tuple[tuple[float, float, float], tuple[float, float, float]]]) -> None:
    """Write a PNG of the mesh coloured by its cell (``dim = 3``) or facet (``dim = 2``) tags, atomically.

    One colour per tag value with a legend (``labels``: tag value → name); vtk's scalar bar is not used (its label
    formatting aborts with this vtk wheel next to dolfinx's libstdc++). One panel per (view vector, view up).
    """
    data = gather_vtk(tagged, dim)
    if data is None:
        return
    import matplotlib
    import pyvista

    pyvista.OFF_SCREEN = True
    topology, cell_types, points, values = data
    palette = matplotlib.colormaps["tab10"].colors
    colour = {v: palette[k % len(palette)] for k, v in enumerate(sorted(labels))}
    grid = pyvista.UnstructuredGrid(topology, cell_types, points)
    grid.cell_data["rgb"] = (255 * np.array([colour[v] for v in values])).astype(np.uint8)
    plotter = pyvista.Plotter(off_screen=True, shape=(1, len(views)), window_size=(800 * len(views) + 400, 800),
                              border=False)
    plotter.set_background("white")
    for k, (vector, up) in enumerate(views):
        plotter.subplot(0, k)
        plotter.add_mesh(grid, scalars="rgb", rgb=True, show_edges=True, edge_color="dimgray", line_width=0.5)
        plotter.view_vector(vector, viewup=up)
        plotter.reset_camera()
        plotter.camera.zoom(1.3)
    plotter.subplot(0, 0)
    plotter.add_text(title, font_size=12, color="black")
    plotter.add_legend([[f"{v}: {labels[v]}", colour[v]] for v in sorted(labels)], bcolor="white",
                       size=(0.3, 0.3), loc="lower right")
    tmp = path.with_name(f".{path.stem}.tmp.png")
    plotter.screenshot(str(tmp))
    plotter.close()
    os.replace(tmp, path)


# %% [markdown]
# ## The gallery and its checks


# %%
def check(beam, tripod, rows: list[dict], out: Path, ci: bool) -> list[str]:
    """Failed checks, as messages (empty if all pass); the pictures are looked at on rank 0."""
    beam_row, tripod_row = rows
    failures = []
    if not abs(beam_row["volume"] / beam.volume - 1) < 1e-12:
        failures.append(f"beam volume {beam_row['volume']:.6e} is not the box's {beam.volume:.6e}")
    if not 0 < tripod_row["volume"] / tripod.geometry.volume - 1 < 3e-3:
        failures.append(f"Tripod volume {tripod_row['volume']:.6e} is not in (0, 3e-3] above the exact "
                        f"{tripod.geometry.volume:.6e}")
    if set(beam_row["facet_tags"]) != {CLAMPED_FACE, TIP_FACE} or set(beam_row["cell_tags"]) != {1}:
        failures.append(f"beam tags: cells {set(beam_row['cell_tags'])}, facets {set(beam_row['facet_tags'])}")
    if set(tripod_row["cell_tags"]) != set(REGIONS["plate"]):
        failures.append(f"Tripod cell tags {set(tripod_row['cell_tags'])} are not {set(REGIONS['plate'])}")
    if not abs(tripod.n_cells / PAPER_TRIPOD_TETS - 1) < 0.15:
        failures.append(f"Tripod preset has {tripod.n_cells} tetrahedra, not {PAPER_TRIPOD_TETS} within 15 %")
    if not ci and not abs(beam.n_cells / 20_000 - 1) < 0.15:
        failures.append(f"Fig. 6 beam has {beam.n_cells} tetrahedra, not 20k within 15 %")
    if beam.mesh.comm.rank == 0:
        failures += [f"{name} not written" for name in ("beam_facet_tags.png", "tripod_cell_tags.png")
                     if not (out / name).is_file() or (out / name).stat().st_size <= 10_000]
    return failures


def main(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """Build, measure, draw and check both meshes (``ci``: the beam at h = 7.5 mm); returns the exit status."""
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    beam_args = FIG6_BEAM | ({"h": 0.0075} if ci else {})
    beam = make_beam(comm, **beam_args)
    tripod = make_tripod(comm, PAPER_H)
    rows = [describe("beam", beam, beam.volume), describe("tripod", tripod, tripod.geometry.volume)]
    if comm.rank == 0:
        print_table(rows)
    plot_tags(beam, 2, out / "beam_facet_tags.png", "Fig. 6 beam: boundary facets by tag",
              {0: "untagged", CLAMPED_FACE: "clamped", TIP_FACE: "tip"},
              [((-1, -0.7, 0.6), (0, 0, 1)), ((1, -0.7, 0.6), (0, 0, 1))])  # clamped end, tip end
    tripod_labels = {RING: "probe ring", CENTRE: "centre"}
    tripod_labels |= {tag: f"arm {i}" for i, tag in enumerate(ARM)}
    tripod_labels |= {tag: f"arm end {i} (servo horn)" for i, tag in enumerate(ARM_END)}
    plot_tags(tripod, 3, out / "tripod_cell_tags.png", "Tripod plate: cells by tag", tripod_labels,
              [((0, -0.7, 1), (0, 1, 0))])  # from above, tilted towards −y
    print0(f"pictures in {out}", comm=comm)
    return report(check(beam, tripod, rows, out, ci), comm)


if __name__ == "__main__":
    args = parse_args("Tagged meshes of the beam and the Tripod: table and pictures.", "out/geometry_gallery",
                      "coarse beam (h = 7.5 mm) for a fast run")
    sys.exit(main(args.out, args.ci))
