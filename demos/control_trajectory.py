# %% [markdown]
# # Inverse control: the Tripod's centre follows a trajectory of poses (case B)
#
# This demo shows:
# - `fenicsfoam.control.InverseController` on `demos/scenes/tripod_case_b_flat.toml`: for each pose of a short
#   trajectory of the centre (its height and its tilts about x and y), the three servo angles that reach it;
# - warm starts: each pose starts from the previous pose's angles and equilibrium, so that a small move costs a
#   few forward solves;
# - the check that the angles are right: a plain scene run at the angles found (the whole schedule from the flat
#   plate, nothing shared with the controller) gives the targeted probes.
#
# ## The problem
#
# *Forward.* The Tripod plate of case B (TI foam, 15 %, l on a 45° spiral) under gravity, its arm ends carried by
# three servo horns at angles θ = (θ₀, θ₁, θ₂): the discrete equilibrium R_f(u; θ) = 0, u_b = g(θ) of
# `demos/tripod.py`. The probes f(θ) are the centre ring's height and the tilts about x and y of its best-fit
# rotation (`fenicsfoam.probes`).
#
# *Inverse.* Given a target pose t, find θ in the servo range [−20°, 60°] with f(θ) = t: Newton's method with
# least-norm steps, the Jacobian ∂f/∂θ exact by the adjoint of Newton's tangent (one factorization, one
# transposed solve per probe; `docs/control-and-design.md`).
#
# *Trajectory.* The ring at a height of 20 mm, its normal tilted by 2° and turning around the vertical:
# (tilt_x, tilt_y) = 2° (sin φ, −cos φ) for φ = 0°, 90°, 180°, 270°, 360° (`--ci`: 0°, 90°, 180° on a coarser mesh).
#
# Run: `python demos/control_trajectory.py --out out/control [--ci]`, also under `mpirun -n 2`.

# %%
import math
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np
from _demo import finish, load_scene_dict, parse_args, print0
from mpi4py import MPI

from fenicsfoam.control import InverseController
from fenicsfoam.scene import parse_scene, run_scene

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HEIGHT = 0.020  # m
TILT_DEG = 2.0
#: --ci mesh size (m): 1578 tetrahedra.
CI_H = 0.008
#: The targets must be met to the controller's tolerances; a plain run at the angles found must give them to this.
FORWARD_RTOL = 1e-6


def poses(ci: bool) -> list[dict[str, float]]:
    """The trajectory: height and tilts of the centre ring."""
    angles = (0.0, 90.0, 180.0) if ci else (0.0, 90.0, 180.0, 270.0, 360.0)
    return [{"center_height": HEIGHT, "center_tilt_x": TILT_DEG * math.sin(math.radians(phi)),
             "center_tilt_y": -TILT_DEG * math.cos(math.radians(phi))} for phi in angles]


# %% [markdown]
# ## Follow the trajectory
#
# One controller keeps the scene built: the first pose runs the whole schedule (rest, middle, top) and then moves
# the last step's angles; every later pose starts from the previous solution.


# %%
def follow(ci: bool, comm: MPI.Comm) -> tuple[dict, list]:
    scene = load_scene_dict("tripod_case_b_flat", ci_h=CI_H if ci else None, png=False)
    scene["outputs"]["xdmf"] = False
    controller = InverseController(parse_scene(scene), comm)
    rows = []
    for index, target in enumerate(poses(ci)):
        t0 = time.perf_counter()
        result = controller.solve(target)
        rows.append({"pose": index, "target": target, "servo_deg": result.servo_deg, "achieved": result.achieved,
                     "iterations": result.iterations, "scene_solves": result.scene_solves,
                     "wall_s": comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)})
        print0(f"pose {index}: servo {np.round(result.servo_deg, 4).tolist()} deg, {result.iterations} iterations, "
               f"{result.scene_solves} scene solves, {rows[-1]['wall_s']:.1f} s", comm=comm)
    return scene, rows


# %% [markdown]
# ## Check with plain forward runs
#
# The last pose's angles in the scene file's last step, run from the flat plate by `run_scene`.


# %%
def forward_check(scene: dict, row: dict, comm: MPI.Comm) -> dict[str, float]:
    scene = {**scene, "probes": ["center_height", "center_rotation", "center_tilt_x", "center_tilt_y"]}
    scene["steps"] = [dict(s) for s in scene["steps"]]
    scene["steps"][-1]["servo_deg"] = list(row["servo_deg"])
    return run_scene(parse_scene(scene), comm=comm).steps[-1].probes


def picture(rows: list, path: Path, comm: MPI.Comm) -> None:
    """The horn angles per pose and the path of the tilts (on rank 0; every rank holds the rows)."""
    if comm.rank != 0:
        return
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    servo = np.array([r["servo_deg"] for r in rows])
    for i in range(3):
        ax1.plot(range(len(rows)), servo[:, i], "o-", label=f"servo {i}")
    ax1.set_xlabel("pose")
    ax1.set_ylabel("horn angle (deg)")
    ax1.legend()
    tx = [r["achieved"]["center_tilt_x"] for r in rows]
    ty = [r["achieved"]["center_tilt_y"] for r in rows]
    ax2.plot(tx, ty, "o-")
    for r, x, y in zip(rows, tx, ty):
        ax2.annotate(str(r["pose"]), (x, y))
    ax2.set_xlabel("tilt about x (deg)")
    ax2.set_ylabel("tilt about y (deg)")
    ax2.set_aspect("equal")
    fig.suptitle(f"Tripod case B: the centre at {HEIGHT * 1e3:g} mm, tilted by {TILT_DEG:g}°")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# %%
def main(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    scene, rows = follow(ci, comm)
    forward = forward_check(scene, rows[-1], comm)
    failures = []
    for row in rows:
        for name, value in row["target"].items():
            if abs(row["achieved"][name] - value) > (1e-9 if name == "center_height" else 1e-7):
                failures.append(f"pose {row['pose']}: {name} = {row['achieved'][name]!r}, target {value!r}")
    for name, value in rows[-1]["target"].items():
        if abs(forward[name] - value) > FORWARD_RTOL * max(abs(value), 1.0 if name != "center_height" else 0.0):
            failures.append(f"plain run at the last pose's angles: {name} = {forward[name]!r}, target {value!r}")
    warm = [r["scene_solves"] for r in rows[1:]]
    if max(warm) >= rows[0]["scene_solves"] + 5:
        failures.append(f"warm-started poses cost {warm} scene solves, the first {rows[0]['scene_solves']}")
    print0(f"plain forward run at pose {rows[-1]['pose']}'s angles: "
           + ", ".join(f"{k} {v:.9g}" for k, v in forward.items()), comm=comm)
    return finish(out, "trajectory.json", {"poses": rows, "forward_check": forward},
                  {"trajectory.png": lambda path: picture(rows, path, comm)}, failures, comm)


if __name__ == "__main__":
    args = parse_args("Inverse servo control of the Tripod along a trajectory of centre poses.", "out/control",
                      "coarse mesh (h = 8 mm), three poses")
    sys.exit(main(args.out, args.ci))
