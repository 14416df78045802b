# %% [markdown]
# # The pipeline of `make demo`: foam → homogenized constants → the Tripod robot as built
#
# This demo shows:
# - one foam of the default foam table (`homogenization.tables.DEFAULT_TABLE`, the paper's foam: polyhedral
#   Voronoi walls, pores of modulus 0.0045 E_s) at the Tripod's material, 15 %, γ = 0.1, seed 0, homogenized by the
#   FFT solver exactly as the table's sample was made (`tables.recorded_settings(DEFAULT_TABLE, nodes=True)`,
#   `tables.homogenize_sample`), beside the table's seed-averaged row;
# - the plate's transversely isotropic constants interpolated from that table
#   (`fenicsfoam.materials.foam_material`, TPU: E_s = 12 MPa, ν_s = 0.3, 1190 kg/m³);
# - `demos/scenes/tripod_case_b.toml`, the robot as built, run through `fenicsfoam.scene.run_scene`: rest (the
#   servos' set-up motion pre-bends the plate), middle (+19°) and top (+38°); the centre's height and rotation as
#   changes from rest beside the paper's Table I.
#
# ## Stage 1: the cell problem
#
# *Continuous.* On the periodic cell Y = (γ, 1, 1) (8 Voronoi cells of the polyhedral distance, whose faces,
# thickened to the density, are the printed walls) with stiffness C(y) (the isotropic solid in the walls, an
# isotropic phase of 0.0045 E_s in the pores, both ν = 0.3), for each macroscopic strain E find the periodic
# fluctuation ũ such that
#
#     div σ = 0 in Y,     σ = C(y) : (E + ε(ũ)),     ũ periodic,     then C_hom : E = ⟨σ⟩.
#
# *Weak form.* ∫_Y ε(w) : C : (E + ε(ũ)) dy = 0 for every periodic w.
#
# *Discrete.* The foam voxelized on the table's grid for this node, 72 × 100 × 100 (voxels 3.5 times shorter
# along x, across the walls that γ = 0.1 lays nearly normal to x), solved twice on the same voxels for the six unit
# strains by preconditioned conjugate gradients (relative equilibrium residual 1e-3): with one-point trilinear
# hexahedra (`rotated`, which converges to the voxel geometry's moduli from below) and with fully integrated ones
# (`hex8`, from above). C_hom is the mean of the two (the table's "bracket"; their relative half width, 2–8 % on
# the engineering moduli of this sample, bounds its resolution error; 11–45 % on the `--ci` grid).
#
# ## Stage 2: the table
# `foam_material(density, gamma, E_solid, nu_solid)` interpolates the seed-averaged default table (PCHIP in
# density and in log γ) and returns the closest TI material with its l axis along the foam's x axis.
#
# ## Stage 3: the robot
# Quasi-static finite strain of the plate under its weight and the servo motions, as built (see `demos/tripod.py`
# for the continuous problem, the weak form and the discretization: P1, corotational TI model, SNES Newton).
#
# ## Checks (exit status 1 if one fails)
# - full size: the recomputed foam sample reproduces the shipped table's sample of the same seed and settings
#   (every engineering constant to 1e-6 relative; measured 1e-14: the table can be regenerated from its recorded
#   settings); `--ci` (the same foam on a 18 × 24 × 24 grid, not a table node): the γ = 0.1 foam is softest along x
#   and shears least in the planes that hold x (E1 / min(E2, E3) = 0.12, max(G12, G13) / G23 = 0.12 measured);
# - the plate material is transversely isotropic and soft along l (E_l < E_t);
# - the centre rises from rest to middle to top; the plate twists the real robot's way, more at the top; its
#   rise at the middle is within 15 % and its twist at the top within 5° of the real robot's (the bands of
#   `demos/tripod.py`; measured 12.25 mm against 12.3, 21.58° against 22.1°). Case B's top rise (27.19 mm against
#   20.5, +33 %) and middle twist (10.67° against 5.53°) miss the real robot: printed, not asserted.
#
# Outputs under `--out`: `tripod_case_b/` (summary.json, probes.csv, solution.xdmf, pictures) and
# `pipeline.json`. `--ci` runs the foam on the small grid and a coarser plate (h = 6 mm).
#
# Cost (the shared 2-core machine, one thread, load average 6–9): `make demo` 1 min 55 s wall (55 s CPU), of it the
# foam's two homogenizations 99 s wall (543 CG iterations in all) and the Tripod 13 s; `--ci` 33 s wall (11 s CPU).
# The Tripod's own node is cheap enough to reproduce: no cheaper node of the table is needed.
#
# Run: `python demos/pipeline.py --out out [--ci]` (`make demo`), also under `mpirun -n 2`.

# %%
import dataclasses
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
from _demo import (
    SCENES,
    TABLE_I_RISE_RTOL,
    TABLE_I_TWIST_ATOL_DEG,
    deltas,
    parse_args,
    print0,
    report,
    table_i_check,
    twists_like_the_robot,
)
from mpi4py import MPI

from fenicsfoam.materials import TransverseIsotropic, foam_material
from fenicsfoam.paper import table_i_changes
from fenicsfoam.scene import run_scene
from homogenization import tables

SCENE = "tripod_case_b"
#: The recomputed sample against the shipped one (same foam, same settings): a round-off bound (measured 1e-14).
REPRODUCE_RTOL = 1e-6
CONSTANTS = ("E1", "E2", "E3", "G23", "G13", "G12")
#: --ci: the foam's grid (the table's settings otherwise) and the plate's mesh size (m).
CI_GRID = (18, 24, 24)
CI_H = 0.006
#: Why the Tripod runs at degree 1 although the mesh check warns against it (one line, printed before the run).
DEGREE_NOTE = ("Tripod at degree 1 as the paper's Table I model (2.7k linear tets, about one through the 5 mm plate), "
               "so the P1 warning below is expected; degree 2 does not reach the as-built rest on this mesh (a "
               "clamped cell inverts at 89 % of the set-up) and on a 10 mm mesh gives a rise and twist at top of "
               "31.1 mm, 21.5 deg (P1 here: 27.2 mm, 21.6 deg; real robot 20.5 mm, 22.1 deg)")


# %% [markdown]
# ## Stage 1 and 2: one foam sample, and the plate's constants from the table


# %%
def homogenize_one_foam(density: float, gamma: float, settings: tables.SweepSettings, comm: MPI.Comm
                        ) -> dict | None:
    """One foam sample (seed 0), exactly as the table's sweep computes it (rank 0; None elsewhere)."""
    if comm.rank != 0:
        return None
    return tables.homogenize_sample(tables.Sample(density, gamma, seed=0), settings)


def table_rows(path: Path, density: float, gamma: float, **match: float) -> list[dict]:
    """The rows of a shipped table CSV at (density, gamma) whose other (numeric) columns equal ``match``."""
    t = tables.read_csv(path)
    mask = np.isclose(t["density"], density) & np.isclose(t["gamma"], gamma)
    for key, value in match.items():
        mask &= np.isclose(t[key], value)
    return [{k: t[k][i] for k in t} for i in np.flatnonzero(mask)]


def foam_stage(region: dict, ci: bool, comm: MPI.Comm) -> tuple[dict | None, object, list[str]]:
    """Homogenize one foam, resolve the plate's material and check both; prints on rank 0."""
    density, gamma = region["density"], region["gamma"]
    paths = tables.table_paths(tables.DEFAULT_TABLE)
    # the full run recomputes a shipped sample, so with the settings the shipped table records for its node
    settings = tables.recorded_settings(tables.DEFAULT_TABLE, nodes=True)[(float(density), float(gamma))]
    if ci:
        settings = dataclasses.replace(settings, resolution=CI_GRID)
    sample = homogenize_one_foam(density, gamma, settings, comm)
    material = foam_material(density, gamma, region["E_solid"], region["nu_solid"], rho_solid=region["rho_solid"],
                             fit=region["fit"])
    failures = []
    if comm.rank == 0:
        mean = table_rows(paths["table"], density, gamma)[0]
        grid = "x".join(str(n) for n in np.atleast_1d(settings.resolution))
        print(f"foam {density:.0%}, gamma = {gamma} ({tables.DEFAULT_TABLE}): one RVE (n_cells = "
              f"{settings.n_cells}, grid {grid}, {settings.discretization}, {sample['wall_s']:.1f} s) vs the shipped "
              "table (mean ± std over seeds)")
        print(f"{'':8s} {'one RVE':>10s} {'table':>10s} {'± std':>9s}   (normalised by E_s)")
        for name in CONSTANTS:
            print(f"{name:8s} {sample[name]:10.3e} {mean[name]:10.3e} {mean[name + '_std']:9.1e}")
        print(f"plate material (fit = {region['fit']}): " + ", ".join(
            f"{k} = {v / 1e3:.1f} kPa" if k.startswith(("E", "G")) else f"{k} = {v:.3f}"
            for k, v in material.constants.items()) + f", rho = {material.rho:.1f} kg/m³")
        if ci:
            if not sample["E1"] < min(sample["E2"], sample["E3"]):
                failures.append(f"the gamma = 0.1 foam is not softest along its x axis: E1, E2, E3 = "
                                f"{sample['E1']:.3e}, {sample['E2']:.3e}, {sample['E3']:.3e}")
            if not max(sample["G12"], sample["G13"]) < sample["G23"]:
                failures.append(f"the gamma = 0.1 foam does not shear least in the planes holding x: G23, G13, G12 = "
                                f"{sample['G23']:.3e}, {sample['G13']:.3e}, {sample['G12']:.3e}")
        else:
            shipped = table_rows(paths["samples"], density, gamma, seed=0)
            if len(shipped) != 1:
                failures.append(f"the shipped samples hold {len(shipped)} rows for this foam, seed 0, not 1")
            else:
                failures += [f"{name}: recomputed {sample[name]:.6e} differs from the shipped sample "
                             f"{shipped[0][name]:.6e} by more than {REPRODUCE_RTOL:g} (relative)"
                             for name in CONSTANTS
                             if not abs(sample[name] - shipped[0][name]) <= REPRODUCE_RTOL * abs(shipped[0][name])]
        if not (isinstance(material, TransverseIsotropic) and material.E_l < material.E_t):
            failures.append(f"the plate material is not TI and soft along l: {material}")
    return sample, material, failures


# %% [markdown]
# ## Stage 3: Tripod case B as built, against Table I


# %%
def robot_stage(scene: dict, out: Path, ci: bool, comm: MPI.Comm) -> tuple[object, list[str]]:
    """Run the scene; print its table and the changes from rest beside Table I (rank 0); check them."""
    if ci:
        scene["geometry"]["h"] = CI_H
        scene["outputs"] = {"png": [scene["steps"][-1]["label"]]}
    print0(DEGREE_NOTE, comm=comm)
    result = run_scene(scene, out / SCENE, comm=comm)
    ours = {"height": deltas(1e3 * v for v in result.probe("center_height").values()),
            "angle": deltas(result.probe("center_rotation").values())}
    paper = table_i_changes(SCENE)
    sim = {q: paper[q][0] for q in paper}
    real = {q: paper[q][1] for q in paper}
    print0(result.table(), comm=comm)
    print0(f"\nTripod case B as built, change from rest ({result.n_cells} tets; Table I: real robot / paper's "
           f"simulation; agrees: rise within {TABLE_I_RISE_RTOL:.0%}, twist within {TABLE_I_TWIST_ATOL_DEG:g} deg "
           "of the real robot)", comm=comm)
    print0(f"{'':8s} {'Δheight (mm)':>13s} {'real':>7s} {'paper':>7s} {'agrees':>7s} | {'Δangle (deg)':>13s} "
           f"{'real':>7s} {'paper':>7s} {'agrees':>7s}", comm=comm)
    for k, label in enumerate(("middle", "top")):
        agrees = {q: "yes" if not table_i_check(SCENE, q, label, ours[q][k], real[q][k]) else "no"
                  for q in ("height", "angle")}
        print0(f"{label:8s} {ours['height'][k]:13.2f} {real['height'][k]:7.2f} {sim['height'][k]:7.2f} "
               f"{agrees['height']:>7s} | {ours['angle'][k]:13.2f} {real['angle'][k]:7.2f} {sim['angle'][k]:7.2f} "
               f"{agrees['angle']:>7s}", comm=comm)
    failures = []
    heights = list(result.probe("center_height").values())
    if not heights[0] < heights[1] < heights[2]:
        failures.append(f"the centre does not rise from rest to middle to top: {heights} m")
    failures += twists_like_the_robot(SCENE, ours["angle"], real["angle"])
    failures += table_i_check(SCENE, "height", "middle", ours["height"][0], real["height"][0])
    failures += table_i_check(SCENE, "angle", "top", ours["angle"][1], real["angle"][1])
    return result, failures


def main(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """The three stages; writes ``pipeline.json`` (rank 0) and returns the exit status."""
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    scene = tomllib.loads((SCENES / f"{SCENE}.toml").read_text())
    sample, material, failures = foam_stage(scene["regions"]["plate"], ci, comm)
    result, robot_failures = robot_stage(scene, out, ci, comm)
    failures += robot_failures
    if comm.rank == 0:
        record = {"foam_table": tables.DEFAULT_TABLE, "foam_sample": sample,
                  "plate_material": material.constants | {"rho": material.rho},
                  SCENE: result.summary()["steps"], "failures": failures}
        tmp = out / ".pipeline.json.tmp"
        tmp.write_text(json.dumps(record, indent=2, default=float))
        tmp.replace(out / "pipeline.json")
    return report(failures, comm)


if __name__ == "__main__":
    args = parse_args("make demo: foam → homogenized table → Tripod case B as built.", "out",
                      "smaller foam grid and coarser plate, for the test suite")
    sys.exit(main(args.out, args.ci))
