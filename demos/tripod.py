# %% [markdown]
# # Table I: the Tripod as built, silicone vs foam plates, against the real robot and the paper
#
# This demo shows:
# - running the robot as built, `demos/scenes/tripod_silicone.toml`, `tripod_case_a.toml` and `tripod_case_b.toml`,
#   with `fenicsfoam.scene.run_scene`: rest (the servos' set-up motion pre-bends the plate, under its weight), then
#   all three horns turned +19° (middle) and +38° (top) from rest;
# - the changes from rest of the centre's height and of its rotation about the vertical axis, side by side with
#   Table I of the paper (real robot first, the paper's simulation second), which of them agree with the real
#   robot within the stated bands and which do not, and the pictures under `--out`;
# - the symmetry check: the isotropic silicone plate, driven identically by its three servos, does not twist (to
#   round-off: the mesh is invariant under the plate's symmetry group, see `meshes/tripod.py`).
#
# ## The problem
#
# *Continuous.* The Y-shaped plate Ω (5 mm thick, three 30 mm wide arms at 120°) carries its weight; the last
# 10 mm of each arm (the tutorial's clamp box) is carried rigidly by its servo's horn: the servo body moved 35 mm
# towards the centre (t_i) and the 25 mm horn turned about the servo's tangential axle (point p_i, direction a_i) by
# the set-up angle −85.743° plus the step's angle θ (0° at rest, 19° middle, 38° top). Find u with
#
#     −Div P(F) = ρ g   in Ω,      u = R(θ_setup + θ, a_i)(X − p_i) + p_i + t_i − X on clamp i,
#     P N = 0 elsewhere,
#
# P from the corotational energy ψ = ½ ε_c : C(a) : ε_c (see `demos/beams.py`); the silicone plate is
# isotropic, case A has TI 30 % foam arms (l axis 30° counter-clockwise from each arm, seen from above: a chiral
# layout, see the scene file) around an isotropic 15 % centre, case B is a TI 15 % plate with its l axis on a 45°
# counter-clockwise spiral. The foams read the default foam table (the paper's foam, `homogenization.tables.
# DEFAULT_TABLE`: polyhedral wall foam, seed-averaged).
#
# *Weak form.* Find u in the affine space of the prescribed clamp motions such that
# ∫_Ω P(F(u)) : ∇v dX = ∫_Ω ρ g · v dX for every v vanishing on the clamps.
#
# *Discrete.* P1 Lagrange on the D3-invariant tetrahedral mesh (2694 tetrahedra at h = 5.2 mm, the paper's
# 2684; `--ci`: 2202 at h = 6 mm), DG0 material and orientation fields, PETSc SNES Newton; the rest step ramps the
# set-up and the weight in 20 increments, middle and top in 4 each.
#
# ## The paper's numbers
#
# The paper gives absolute heights above its table and angles whose zero is the real robot's rest; our heights
# are those of the plate's mid-plane (0 where it is drawn flat) and our rest is the robot's set-up pose, so the
# comparison is in differences from rest. Nothing is tuned to Table I, which `_demo.TABLE_I` holds (the paper has
# no silicone row). Our angles are counter-clockwise seen from above; Table I's real robot turns by positive
# angles, and the spiral's handedness is a choice (the paper shows it in a photograph only): so "the real robot's
# way" below means the sign of Table I's real change, with the scenes' chosen handedness.
#
# *What holds today* (P1 as shipped, default table; full size / `--ci`, changes from rest, middle / top):
#
# | scene | Δheight (mm) | Δangle (deg) | real robot |
# |---|---|---|---|
# | silicone | 12.64 / 31.03 and 12.53 / 31.33 | 0 (≈ 1e-14) | – |
# | case A | 11.32 / 26.81 and 11.19 / 26.62 | 2.26 / 4.81 and 2.41 / 4.96 | 12.8 / 21.2 mm, 3.96 / 20.49° |
# | case B | 12.25 / 27.19 and 11.98 / 26.91 | 10.67 / 21.58 and 11.13 / 22.20 | 12.3 / 20.5 mm, 5.53 / 22.1° |
#
# Asserted: every centre rises from rest to middle to top; the silicone plate does not twist; both foam plates
# twist the real robot's way, more at the top than at the middle, by more than a degree at the top. Against the real
# robot, within the bands of `_demo` (a rise within `TABLE_I_RISE_RTOL` = 15 %, a twist within
# `TABLE_I_TWIST_ATOL_DEG` = 5°: the targets of docs/paper-validation.md, not fitted to these runs):
# - **met, and asserted**: case B's middle rise (0.996 × the real robot's; `--ci` 0.974) and top twist (0.52°
#   below it; `--ci` 0.10° above). Both also hold at P2 on the 10 mm mesh (10.92 mm, 21.46°), so neither is an
#   artefact of P1's stiffness (docs/validation/2026-11-27-tripod-demos.md).
# - **missed, not asserted**: case B's top rise (+33 %), its middle twist (10.67° against 5.53°: 1.9 ×, 5.1° above);
#   case A's top rise (+26 %) and its top twist (4.81° against 20.49°, a quarter of it).
# - **met only at P1, not asserted**: case A's middle rise (−12 % here, −22 % at P2 on 8 mm) and middle twist
#   (1.7° below the real 3.96°: a 5° band around so small an angle says little).
# Why case A twists so little and what the P1 mesh hides (P1 against P2, the clamp, the layout readings of case A):
# docs/validation/2026-11-27-tripod-as-built.md.
#
# Run: `python demos/tripod.py --out out/tripod [--ci]`, also under `mpirun -n 2` (full size ≈ 30 s wall, `--ci`
# ≈ 12 s on the shared 2-core machine).

# %%
import sys
from pathlib import Path

from _demo import (
    TABLE_I_RISE_RTOL,
    TABLE_I_TWIST_ATOL_DEG,
    deltas,
    load_scene_dict,
    parse_args,
    run_and_check,
    table_i_check,
    twists_like_the_robot,
)
from mpi4py import MPI

from fenicsfoam.paper import table_i_changes
from fenicsfoam.scene import run_scene

CASES = ("tripod_silicone", "tripod_case_a", "tripod_case_b")
FOAM_CASES = ("tripod_case_a", "tripod_case_b")
#: The changes that agree with the real robot within the bands (measured above), asserted: (scene, quantity,
#: position). The others are printed beside them as missed.
AGREES = (("tripod_case_b", "height", "middle"), ("tripod_case_b", "angle", "top"))
#: Twist bound of the mirror-symmetric silicone plate, relative to case B's torsion at the top: zero
#: by symmetry, and the mesh is D3-invariant (``meshes.tripod``), so only round-off and the solver tolerance
#: remain (measured ≈ 4e-16 relative as built, full size and --ci).
SYMMETRY_RTOL = 1e-9
#: --ci mesh size (m): 2202 tetrahedra.
CI_H = 0.006
POSITIONS = ("middle", "top")


# %% [markdown]
# ## Run the three plates


# %%
def run_tripods(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Run every Tripod scene (coarser with ``ci``); returns ``{scene: SceneResult}``."""
    results = {}
    for name in CASES:
        # --ci: pictures (≈1 s each) only of case B's last step
        png = (True if name == "tripod_case_b" else False) if ci else None
        scene = load_scene_dict(name, ci_h=CI_H if ci else None, png=png)
        results[name] = run_scene(scene, out / name, comm=comm)
    return results


def changes(result) -> dict[str, tuple[float, float]]:
    """Our changes from rest at middle and top: height (mm) and angle (deg)."""
    return {"height": deltas(1e3 * v for v in result.probe("center_height").values()),
            "angle": deltas(result.probe("center_rotation").values())}


def versus_robot(results: dict) -> tuple[list[str], list[str]]:
    """The foam plates' changes against the real robot's, within the bands: (met, missed), as short labels."""
    met, missed = [], []
    for name in FOAM_CASES:
        ours, real = changes(results[name]), table_i_changes(name)
        for quantity in ("height", "angle"):
            for k, position in enumerate(POSITIONS):
                label = f"{name.removeprefix('tripod_')} {quantity} at {position}"
                ok = not table_i_check(name, quantity, position, ours[quantity][k], real[quantity][1][k])
                (met if ok else missed).append(label)
    return met, missed


def table(results: dict) -> str:
    """Δ from rest at middle and top: ours, the real robot and the paper's simulation (Table I)."""
    lines = [f"{'scene':16s} {'quantity':14s} | {'Δmiddle: ours':>13s} {'real':>6s} {'paper':>6s} | "
             f"{'Δtop: ours':>10s} {'real':>6s} {'paper':>6s}"]
    for name, r in results.items():
        ours = changes(r)
        for quantity, unit in (("height", "mm"), ("angle", "deg")):
            if name in FOAM_CASES:
                sim, real = table_i_changes(name)[quantity]
                paper = [f"{real[0]:6.2f}", f"{sim[0]:6.2f}", f"{real[1]:6.2f}", f"{sim[1]:6.2f}"]
            else:
                paper = ["     -"] * 4
            lines.append(f"{name:16s} {quantity + ' (' + unit + ')':14s} | {ours[quantity][0]:13.2f} {paper[0]} "
                         f"{paper[1]} | {ours[quantity][1]:10.2f} {paper[2]} {paper[3]}")
    met, missed = versus_robot(results)
    lines.append(f"against the real robot (rise within {TABLE_I_RISE_RTOL:.0%}, twist within "
                 f"{TABLE_I_TWIST_ATOL_DEG:g} deg of it): met: {', '.join(met) or 'none'}")
    lines.append(f"  missed: {', '.join(missed) or 'none'}")
    lines.append("sizes: " + ", ".join(f"{n} {r.n_cells} tets / {r.n_dofs} dofs / {r.wall_s:.1f} s"
                                       for n, r in results.items()))
    return "\n".join(lines)


# %% [markdown]
# ## Checks
# - every plate rises from rest to middle to top (the horns turn back towards the vertical and lift the plate);
# - the silicone plate does not twist (mirror symmetry of the plate and of its mesh):
#   |twist| < 1e-9 × case B's torsion at the top;
# - the two chiral foam plates twist the real robot's way (the sign of Table I's real change) at middle and top,
#   more at the top than at the middle, by more than a degree at the top;
# - `AGREES`: case B's rise at the middle within 15 % and its twist at the top within 5° of the real robot's.


# %%
def check(results: dict) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    failures = []
    for name, r in results.items():
        heights = list(r.probe("center_height").values())
        if not heights[0] < heights[1] < heights[2]:
            failures.append(f"{name}: centre heights {heights} m do not rise from rest to middle to top")
    twist = abs(changes(results["tripod_case_b"])["angle"][1])
    bound = SYMMETRY_RTOL * twist
    angles = results["tripod_silicone"].probe("center_rotation")
    if not max(abs(v) for v in angles.values()) < bound:
        failures.append(f"tripod_silicone twists: {angles} deg (symmetry bound {bound:.3g} deg = "
                        f"{SYMMETRY_RTOL:g} × case B's torsion at top)")
    for name in FOAM_CASES:
        failures += twists_like_the_robot(name, changes(results[name])["angle"], table_i_changes(name)["angle"][1])
    for name, quantity, position in AGREES:
        k = POSITIONS.index(position)
        failures += table_i_check(name, quantity, position, changes(results[name])[quantity][k],
                                  table_i_changes(name)[quantity][1][k])
    return failures


if __name__ == "__main__":
    args = parse_args("Table I Tripod as built: centre height and torsion against the paper.", "out/tripod",
                      f"coarser mesh (h = {CI_H * 1e3:g} mm) for a fast run")
    sys.exit(run_and_check(run_tripods, check, table, args.out, args.ci))
