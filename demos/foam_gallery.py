# %% [markdown]
# # Foam gallery: periodic Voronoi strut foams at density 0.18 for γ = 1, 0.5, 0.1
#
# This demo shows:
# - building `meshes.foam.VoronoiFoam` foams of one seed at three anisotropies: the Voronoi diagram under the
#   metric (Δx/γ)² + Δy² + Δz² (the paper's §II-A), so γ < 1 flattens the cells along x and lays the struts in
#   the y–z plane;
# - the solid fraction, measured two independent ways (the foam's quasi-Monte-Carlo sample that sets the strut
#   radius, and a voxel count), and the strut statistics: number of struts, mean length, mean |cos| of the
#   strut directions with x, y, z;
# - pictures of each foam's surface (marching cubes, `VoronoiFoam.to_stl`) rendered offscreen by pyvista.
#
# There is no field problem here: the foam is geometry (the struts are the points within a radius r of the
# periodic Voronoi edges, r chosen so that the solid fraction is the requested density).
#
# ## Checks (exit status 1 if one fails)
# - the measured and the voxel densities are within 0.002 of the target (0.004 for the coarse voxel grid of
#   `--ci`);
# - the mean |cos| of the struts with x decreases as γ decreases (γ = 1: ≈ 0.5, the isotropic mean);
# - every PNG and STL file is written.
#
# Run: `python demos/foam_gallery.py --out out/foam_gallery [--ci]`, also under `mpirun -n 2` (the foams are
# built and drawn on rank 0; the other ranks wait for the verdict).

# %%
import os
import sys
from pathlib import Path

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

from _demo import parser, report
from mpi4py import MPI

from meshes.foam import VoronoiFoam

GAMMAS = (1.0, 0.5, 0.1)
DENSITY = 0.18
DENSITY_TOL = 0.002


# %% [markdown]
# ## Foams and their statistics


# %%
def describe(foam: VoronoiFoam, n_voxels: int) -> dict:
    """One table row: target and measured density, voxel density, radius, strut statistics."""
    return {"gamma": foam.gamma, "n_cells": foam.n_cells, "density": foam.density,
            "measured": foam.measured_density, "stderr": foam.density_stderr,
            "voxel": float(foam.voxelize(n_voxels).mean()), "radius": foam.radius,
            **foam.summary.as_dict()}


def print_table(rows: list[dict], n_voxels: int) -> None:
    print(f"{'gamma':>5s} {'cells':>5s} {'target':>6s} {'measured ± stderr':>18s} {f'voxel {n_voxels}³':>10s} "
          f"{'radius':>8s} {'struts':>6s} {'mean L':>7s} {'|cos x|':>7s} {'|cos y|':>7s} {'|cos z|':>7s}")
    for r in rows:
        print(f"{r['gamma']:5.2f} {r['n_cells']:5d} {r['density']:6.3f} {r['measured']:10.5f} ± {r['stderr']:.1e} "
              f"{r['voxel']:10.5f} {r['radius']:8.5f} {r['n_struts']:6d} {r['mean_strut_length']:7.4f} "
              f"{r['mean_abs_cos_x']:7.3f} {r['mean_abs_cos_y']:7.3f} {r['mean_abs_cos_z']:7.3f}")


def check(rows: list[dict], voxel_tol: float) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    failures = []
    for r in rows:
        if abs(r["measured"] - r["density"]) > DENSITY_TOL:
            failures.append(f"gamma={r['gamma']}: measured density {r['measured']:.5f} not within {DENSITY_TOL}")
        if abs(r["voxel"] - r["density"]) > voxel_tol:
            failures.append(f"gamma={r['gamma']}: voxel density {r['voxel']:.5f} not within {voxel_tol}")
    cos_x = [r["mean_abs_cos_x"] for r in rows]             # rows in the order of GAMMAS (decreasing)
    if not all(a > b for a, b in zip(cos_x, cos_x[1:])):
        failures.append(f"mean |cos x| does not decrease with gamma: {cos_x}")
    return failures


# %% [markdown]
# ## Pictures: the marching-cubes surface of each foam, three panels side by side


# %%
def render(stls: list[Path], titles: list[str], path: Path) -> None:
    """PNG of the STL surfaces (one panel each, same camera), written atomically. No scalar bar (vtk's label
    formatting aborts with this vtk wheel next to dolfinx's libstdc++)."""
    import pyvista

    pyvista.OFF_SCREEN = True
    plotter = pyvista.Plotter(off_screen=True, shape=(1, len(stls)), window_size=(600 * len(stls), 640), border=False)
    plotter.set_background("white")
    for k, (stl, title) in enumerate(zip(stls, titles)):
        plotter.subplot(0, k)
        plotter.add_mesh(pyvista.read(stl), color="lightsteelblue", smooth_shading=True)
        plotter.add_mesh(pyvista.Box((0, 1, 0, 1, 0, 1)), style="wireframe", color="black", line_width=1)
        plotter.add_text(title, font_size=11, color="black")
        plotter.view_vector((1.0, 0.8, 0.6), viewup=(0, 0, 1))
        plotter.reset_camera()
    tmp = path.with_name(f".{path.stem}.tmp.png")
    plotter.screenshot(str(tmp))
    plotter.close()
    os.replace(tmp, path)


def run(out: Path, n_cells: int, seed: int, n_voxels: int, n_surface: int, voxel_tol: float) -> list[str]:
    """Build, tabulate, draw and check the three foams (on the calling process); returns the failed checks."""
    out.mkdir(parents=True, exist_ok=True)
    foams = [VoronoiFoam(n_cells, DENSITY, gamma=g, seed=seed) for g in GAMMAS]
    rows = [describe(f, n_voxels) for f in foams]
    print_table(rows, n_voxels)
    stls = [f.to_stl(out / f"foam_gamma{f.gamma:g}.stl", n_surface) for f in foams]
    png = out / "foam_gallery.png"
    render(stls, [f"gamma = {f.gamma:g}, r = {f.radius:.4f}" for f in foams], png)
    failures = check(rows, voxel_tol)
    failures += [f"{p} not written" for p in [*stls, png] if not p.is_file() or p.stat().st_size == 0]
    print(f"wrote {png} and {len(stls)} STL files")
    return failures


def main(out: Path, ci: bool, seed: int = 1, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """Run the gallery on rank 0 (``ci``: 12 cells and coarse grids); returns the exit status on every rank."""
    failures = None
    if comm.rank == 0:
        if ci:
            failures = run(out, n_cells=12, seed=seed, n_voxels=48, n_surface=32, voxel_tol=0.004)
        else:
            failures = run(out, n_cells=20, seed=seed, n_voxels=128, n_surface=96, voxel_tol=DENSITY_TOL)
    return report(failures, comm)


if __name__ == "__main__":
    cli = parser("Foam gallery: Voronoi strut foams at density 0.18 for gamma = 1, 0.5, 0.1.", "out/foam_gallery",
                 "small foams and coarse grids (a few seconds)")
    cli.add_argument("--seed", type=int, default=1, help="seed of the three foams")
    args = cli.parse_args()
    sys.exit(main(args.out, args.ci, args.seed))
