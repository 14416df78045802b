# %% [markdown]
# # Your own robot: a pneumatic foam finger, a cable-driven finger and a blocked force
#
# This demo shows:
# - drawing a robot with gmsh and naming its parts (physical groups), in metres, and running it as a scene with
#   `builder = "file"`: a foam finger with an internal chamber, clamped at its base and inflated;
# - scene loads on named groups: a follower pressure in the chamber (`[loads.pressure.NAME]`), a tendon pulled by a
#   motor (`[loads.cable.NAME]`), a support that blocks one component (`[loads.motion.NAME]`, `components`), each
#   scaled per step by `loads = {NAME = factor}`;
# - group probes: `displacement:GROUP`, `rotation:GROUP`, `volume:GROUP` (pressure–volume curve) and
#   `reaction_force:GROUP` (blocked force), with the checks physics gives for free: the pressure in a closed chamber
#   has no net force, so the supports carry exactly the finger's weight;
# - reading the results back with `fenicsfoam.io.read_solution` (and pyvista).
#
# ## The problem
#
# *Continuous.* The finger Ω (reference configuration, metres) is clamped on Γ_base; gravity g acts on its mass;
# the chamber's walls Γ_c carry a pressure p that follows them; a tendon of tension T through via points x_i
# (attached to the body) pulls towards a motor. Find u with
#
#     −Div P(F) = ρ g in Ω,   u = 0 on Γ_base,   P N = −p cof(F) N on Γ_c,   P N = 0 elsewhere,
#
# plus the tendon's point forces f_i = T (e_{i,i−1} + e_{i,i+1}) along the deformed route (e the unit vectors to
# the neighbouring via points).
#
# *Weak form.* Find u (u = 0 on Γ_base) with, for every v vanishing there,
# ∫_Ω P : ∇v dX − ∫_Ω ρ g · v dX + s_p p ∫_Γc cof(F) N · v dA + s_T T ∂L/∂u · v = 0, L the tendon's deformed
# length and s_p, s_T the steps' load factors. Its Jacobian is the exact derivative (`ufl.derivative` of the
# pressure term; T ∂²L/∂u² for the tendon), so Newton converges quadratically.
#
# *Discrete.* P2 Lagrange (the default) on the gmsh tetrahedra, corotational model, PETSc SNES Newton with load
# stepping; the foam (TPU, 18 %) from the shipped homogenization table.
#
# Run: `python demos/your_own_robot.py --out out/your_own_robot [--ci]`, also under `mpirun -n 2`.

# %%
import sys
from pathlib import Path

import numpy as np
from _demo import load_scene_dict, parser, print0, report
from mpi4py import MPI

from fenicsfoam.io import read_solution
from fenicsfoam.scene import run_scene
from foambase.files import atomic_path

#: Mesh size (m): the shipped scenes' and the --ci one (2 mm walls need h ≤ 4 mm).
H, CI_H = 0.003, 0.004
#: Chamber pressure (Pa) at factor 1, and the steps' factors (full run, --ci).
PRESSURE = 20e3
FACTORS, CI_FACTORS = (0.25, 0.5, 0.75, 1.0), (1.0,)
#: Reactions balance the applied loads to this fraction of the weight (the solver converges to ~1e-10).
BALANCE_RTOL = 1e-8
#: The finger's material volume (m³): the 100 × 20 × 15 mm box less the 90 × 14 × 7 mm chamber (exact on the mesh,
#: whose faces are planar).
VOLUME = 0.100 * 0.020 * 0.015 - 0.090 * 0.014 * 0.007

# %% [markdown]
# ## 1. Draw the robot with gmsh, in metres, and name its parts
#
# Every name a scene uses is a gmsh *physical group*: volumes are the regions (materials), surfaces the facet
# groups (clamps, pressures, probes). Draw in metres; a CAD model in millimetres is scaled on export with
# `gmsh.option.setNumber("Mesh.ScalingFactor", 0.001)` (fenicsfoam warns when a mesh is not metre-sized).


# %%
def write_finger_msh(path: Path, h: float) -> Path:
    """A 100 × 20 × 15 mm finger with a 90 × 14 × 7 mm chamber under a 2 mm top wall, written to ``path``."""
    import gmsh

    length, width, height = 0.100, 0.020, 0.015
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("finger")
        occ = gmsh.model.occ
        body = occ.addBox(0.0, -width / 2, -height / 2, length, width, height)
        chamber = occ.addBox(0.005, -0.007, -0.0015, 0.090, 0.014, 0.007)  # x, y, z of a corner, then the sizes
        (volume,), _ = occ.cut([(3, body)], [(3, chamber)])
        occ.synchronize()

        def strictly_inside(surface) -> bool:  # the chamber's walls lie inside the outer box in y and z
            _, y0, z0, _, y1, z1 = gmsh.model.getBoundingBox(2, surface)
            return -width / 2 < y0 - 1e-6 and y1 + 1e-6 < width / 2 and -height / 2 < z0 - 1e-6 and \
                z1 + 1e-6 < height / 2

        groups = {"base": [], "tip": [], "chamber": [], "skin": []}
        for _, surface in gmsh.model.getBoundary([volume], oriented=False):
            x0, _, _, x1, _, _ = gmsh.model.getBoundingBox(2, surface)
            name = ("base" if x1 < 1e-6 else "tip" if x0 > length - 1e-6 else
                    "chamber" if strictly_inside(surface) else "skin")
            groups[name].append(surface)
        gmsh.model.addPhysicalGroup(3, [volume[1]], 1)     # the region "finger"
        gmsh.model.setPhysicalName(3, 1, "finger")
        for tag, (name, surfaces) in enumerate(groups.items(), start=11):
            gmsh.model.addPhysicalGroup(2, surfaces, tag)  # the facet groups, by name
            gmsh.model.setPhysicalName(2, tag, name)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(3)
        with atomic_path(path) as tmp:                     # never a half-written file
            gmsh.write(str(tmp))
    finally:
        gmsh.finalize()
    return path


# %% [markdown]
# ## 2. Inflate it: pressure–volume and pressure–displacement
#
# The scene, as a TOML file would give it (`fenicsfoam run finger.toml --out DIR` runs the same):
#
# ```toml
# [geometry]
# builder = "file"
# path = "finger.msh"
#
# [regions.finger]
# tags = "finger"
# material = "foam"   # density 0.18, gamma 1, TPU
# ...
# [loads]
# gravity = [0.0, 0.0, -9.81]
# clamp = "base"
#
# [loads.pressure.chamber]
# group = "chamber"
# pressure = 20e3
#
# [[steps]]
# label = "p10kPa"
# loads = { chamber = 0.5 }
# ```


# %%
FOAM = {"tags": "finger", "material": "foam", "density": 0.18, "gamma": 1.0, "E_solid": 12e6, "nu_solid": 0.3,
        "rho_solid": 1190.0, "fit": "isotropic"}


def pneumatic_scene(msh: Path, factors) -> dict:
    return {
        "name": "finger_from_gmsh",
        "geometry": {"builder": "file", "path": str(msh)},
        "fem": {"model": "corotational"},
        "regions": {"finger": FOAM},
        "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "base",
                  "pressure": {"chamber": {"group": "chamber", "pressure": PRESSURE}}},
        "steps": [{"label": "rest", "gravity": 1.0}]
        + [{"label": f"p{f * PRESSURE / 1e3:g}kPa", "loads": {"chamber": f}} for f in factors],
        "probes": ["displacement:tip", "rotation:tip", "volume:chamber", "reaction_force:base"],
        "outputs": {"png": [f"p{factors[-1] * PRESSURE / 1e3:g}kPa"]},
    }


def support(result) -> np.ndarray:
    """What the supports must carry (N): the finger's weight ρ V g, upwards (ρ the foam's resolved density)."""
    return np.array([0.0, 0.0, 9.81 * result.materials["finger"]["rho"] * VOLUME])


def unbalanced(name: str, result, supports: tuple[str, ...]) -> list[str]:
    """The steps at which the reactions of the ``supports`` (groups) do not carry the weight to ``BALANCE_RTOL``."""
    w = support(result)
    failures = []
    for s in result.steps:
        total = sum(np.array(s.probes[f"reaction_force:{group}"]) for group in supports)
        if np.linalg.norm(total - w) > BALANCE_RTOL * np.linalg.norm(w):
            failures.append(f"{name} {s.label}: {' + '.join(supports)} carry {total.tolist()} N, not the weight "
                            f"{w.tolist()} N")
    return failures


def run_pneumatic(out: Path, ci: bool, comm) -> tuple:
    msh = out / "finger.msh"
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        write_finger_msh(msh, CI_H if ci else H)
    comm.Barrier()
    result = run_scene(pneumatic_scene(msh, CI_FACTORS if ci else FACTORS), out / "pneumatic", comm=comm)
    return result, read_solution(out / "pneumatic")


# %% [markdown]
# ## 3. A cable-driven finger and 4. a blocked force, from the shipped scenes
#
# `demos/scenes/finger_cable.toml`: a solid finger of transversely isotropic foam (l axis at 30° in the horizontal
# plane) with a tendon anchored on a pad under the tip and pulled by a motor behind the base: force–displacement,
# and the twist and sideways drift that the oblique l axis couples to the bending (`rotation:tip`,
# `displacement:tip`). `demos/scenes/finger_blocked.toml`: the pneumatic finger with a load cell under its tip that
# blocks only the vertical motion of a 5 mm pad (`components = ["z"]`): the blocked force is −`reaction_force:pad`.


# %%
def shipped(name: str, out: Path, ci: bool, comm):
    """Run a shipped finger scene; with ``ci`` on the coarser mesh, at rest and at full load only."""
    scene = load_scene_dict(name, ci_h=CI_H if ci else None)
    if ci:
        scene["steps"] = [scene["steps"][0], {**scene["steps"][-1], "increments": 2}]
        scene["outputs"] = {"png": [scene["steps"][-1]["label"]]}
    return run_scene(scene, out / name, comm=comm)


# %% [markdown]
# ## Checks
# - pneumatic finger: the chamber's volume grows and the tip goes down with every pressure step (a thin top wall
#   over a thick bottom one bends the finger towards its bottom); the clamp's reaction equals the weight at every
#   pressure (the pressure's net force on the closed chamber is zero) to `BALANCE_RTOL`;
# - cable finger: the tip's displacement grows with the tension; the base carries the tension along the motor's
#   direction (x) within 1 % (the tendon leaves the body nearly horizontally);
# - blocked force: it grows with the pressure; the pad's and the base's reactions balance the weight to
#   `BALANCE_RTOL`;
# - the solution file read back: every step, and the clamped base does not move.


# %%
def check(pneumatic, solution, cable, blocked) -> list[str]:
    failures = []
    volumes = [s.probes["volume:chamber"] for s in pneumatic.steps]
    tip_z = [s.probes["displacement:tip"][2] for s in pneumatic.steps]
    if not (np.all(np.diff(volumes) > 0) and np.all(np.diff(tip_z) < 0)):
        failures.append(f"pneumatic: volumes {volumes} m³ should grow and tip z {tip_z} m fall with the pressure")
    failures += unbalanced("pneumatic", pneumatic, ("base",))
    tips = [np.linalg.norm(s.probes["displacement:tip"]) for s in cable.steps]
    if not np.all(np.diff(tips) > 0):
        failures.append(f"cable: tip displacements {tips} m should grow with the tension")
    tension = cable.scene.raw["loads"]["cable"]["tendon"]["tension"]
    for s, step in zip(cable.steps[1:], cable.scene.steps[1:]):
        expected = tension * step.loads["tendon"]
        if abs(s.probes["reaction_force:base"][0] - expected) > 0.01 * expected:
            failures.append(f"cable {s.label}: the base carries {s.probes['reaction_force:base'][0]:.4g} N along x, "
                            f"not the tension {expected:g} N")
    pressing = [s.probes["reaction_force:pad"][2] for s in blocked.steps]  # the finger presses down with R_z
    if not np.all(np.diff(pressing) > 0):
        failures.append(f"blocked: the finger's force on the load cell {pressing} N should grow with the pressure")
    failures += unbalanced("blocked", blocked, ("base", "pad"))
    if solution.labels != tuple(s.label for s in pneumatic.steps):
        failures.append(f"solution.npz has steps {solution.labels}")
    base = np.isclose(solution.points[:, 0], 0.0)
    if not (base.any() and np.abs(solution.displacements[:, base]).max() == 0.0):
        failures.append("solution.npz: the clamped base moved")
    return failures


def tip_rows(result, row) -> list[str]:
    """One line per step: its label, then ``row(step, tip displacement (m), tip rotation (deg))``."""
    return [f"{s.label:>8s} {row(s, s.probes['displacement:tip'], s.probes['rotation:tip'])}" for s in result.steps]


def table(pneumatic, cable, blocked) -> str:
    lines = ["pneumatic finger (gmsh file): pressure–volume and pressure–displacement",
             f"{'step':>8s} {'volume (cm3)':>12s} {'tip x (mm)':>10s} {'tip z (mm)':>10s} {'tip rot y (deg)':>15s}"]
    lines += tip_rows(pneumatic, lambda s, d, r: f"{1e6 * s.probes['volume:chamber']:12.3f} {1e3 * d[0]:10.2f} "
                                                 f"{1e3 * d[2]:10.2f} {r[1]:15.2f}")
    lines += ["cable-driven TI finger: force–displacement, and the twist the oblique l axis couples",
              f"{'step':>8s} {'tip x (mm)':>10s} {'tip y (mm)':>10s} {'tip z (mm)':>10s} {'rot x (deg)':>11s} "
              f"{'rot y (deg)':>11s} {'rot z (deg)':>11s}"]
    lines += tip_rows(cable, lambda s, d, r: f"{1e3 * d[0]:10.2f} {1e3 * d[1]:10.2f} {1e3 * d[2]:10.2f} "
                                             f"{r[0]:11.2f} {r[1]:11.2f} {r[2]:11.2f}")
    lines += ["blocked force: a load cell under the tip; the finger presses down on it with reaction_force:pad z",
              f"{'step':>8s} {'pressing down (N)':>17s} {'change from rest (N)':>20s}"]
    rest = blocked.steps[0].probes["reaction_force:pad"][2]
    for s in blocked.steps:
        f = s.probes["reaction_force:pad"][2]
        lines.append(f"{s.label:>8s} {f:17.4f} {f - rest:20.4f}")
    lines.append("sizes: " + ", ".join(f"{r.scene.name} {r.n_cells} tets / {r.n_dofs} dofs / {r.wall_s:.1f} s"
                                       for r in (pneumatic, cable, blocked)))
    return "\n".join(lines)


# %% [markdown]
# ## 5. Reading the results back
#
# Every run writes `solution.npz` next to the ParaView series `solution.pvd` (one `.vtu` per step, with stress and
# strain per cell): `read_solution(out_dir)` gives the mesh (`points`,
# `cells` in VTK order) and each step's displacement at every node, on any number of ranks. With pyvista:
#
# ```python
# from fenicsfoam.io import read_solution
# solution = read_solution("out/your_own_robot/pneumatic")
# grid = solution.to_pyvista("p20kPa")                    # point data "displacement" (m)
# grid.warp_by_vector("displacement").plot(scalars="displacement")
# ```
#
# ParaView opens `solution.xdmf` (the time series); `pyvista.read("solution.xdmf")` reads its mesh and first step.


# %%
def main(argv=None) -> int:
    args = parser("Your own robot: pneumatic and cable-driven foam fingers, blocked force.", "out/your_own_robot",
                  f"coarser mesh (h = {CI_H * 1e3:g} mm) and fewer steps for a fast run").parse_args(argv)
    comm = MPI.COMM_WORLD
    pneumatic, solution = run_pneumatic(args.out, args.ci, comm)
    cable = shipped("finger_cable", args.out, args.ci, comm)
    blocked = shipped("finger_blocked", args.out, args.ci, comm)
    print0(table(pneumatic, cable, blocked), comm=comm)
    print0(f"outputs (summary.json, probes.csv, solution.xdmf/.npz, PNGs) in {args.out}/<scene>/", comm=comm)
    return report(check(pneumatic, solution, cable, blocked) if comm.rank == 0 else [], comm)


if __name__ == "__main__":
    sys.exit(main())
