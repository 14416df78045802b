"""How far does each constitutive model carry the as-built Tripod towards its real rest (horns at 85.74°)?

One run per (model, foam) of `studies/tripod_twist.py`'s case B (spiral plate, 45° pitch) with the as-built servo
kinematics (each servo moved 35 mm towards the centre and its horn turned to the rest angle in 16 loaded
increments, then +19° and +38°), on the paper's mesh size (P1), to the real rest ``REAL_REST_DEG`` = 85.74°.
Foams: ``table`` (the shipped `tripod_case_b.toml` plate, from today's foam table) and ``paper`` (the constants of
the paper's own SOFA simulation, `PAPER_FOAM`, mapped as docs/conventions.md describes). Each row reports the rest
height and twist of the centre at rest, or the step that failed, the load factor reached and why; Δheight and
Δangle of the centre from rest to middle and top; Newton iterations per step; wall and CPU time.

The arm end r ≥ 45 mm is clamped (`tripod_twist`'s region clamp). ``--shipped`` runs the shipped as-built scene
`demos/scenes/tripod_case_b.toml` instead (the tutorial's box clamp, 20 rest increments, through
`studies/tripod_as_built.py`), with its own foam (``table``) or the paper's (``paper``, the plate made a
``transverse_isotropic`` region of the same mass density).

Run (serial, ≈ 0.2–5 CPU-min per row):
`python studies/tripod_models.py [--models corotational corotational_sofa bonet_burton] [--foams table paper]
[--h 0.0052] [--rest 85.74] [--shipped]`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tripod_twist import REAL_REST_DEG, TABLE_I, Case, run_case, scene_materials  # noqa: E402

from fenicsfoam.materials import TransverseIsotropic  # noqa: E402
from meshes.tripod import PAPER_H  # noqa: E402

#: The paper's foam (15 %, γ = 0.1) as its SOFA simulation used it (VannesteFelix/anisotropy,
#: examples/SimpleCube/mechaParam/anisotropyTransverse.yaml, entry `paramPaper`, l = x, kPa): youngModulus
#: transverse 1390 → E_t, longitudinal 94.22 → E_l; poissonRatio transverse 0.26162 → nu_t (in the plane of
#: isotropy), transverseLongitudinal 0.4161 → nu_tl (contraction along l under a transverse extension, the ratio
#: SOFA's TetrahedronAnisotropicForceField reads; it derives ν_lt = nu_tl E_l/E_t = 0.0282 by symmetry, so the
#: listed longitudinalTransverse 0.02975 is not used); shearModulus longitudinal 16.28215 → G_l.
PAPER_FOAM = dict(E_t=1390e3, E_l=94.22e3, nu_t=0.26162, nu_tl=0.4161, G_l=16.28215e3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["corotational", "corotational_sofa", "bonet_burton"])
    parser.add_argument("--foams", nargs="+", default=["table", "paper"], choices=["table", "paper"])
    parser.add_argument("--h", type=float, default=PAPER_H, help="mesh size (m)")
    parser.add_argument("--rest", type=float, default=REAL_REST_DEG, help="horn angle at rest (deg)")
    parser.add_argument("--shipped", action="store_true",
                        help="run the shipped as-built scene tripod_case_b.toml (tutorial's box clamp, "
                             "studies/tripod_as_built.py) instead of tripod_twist's run_case")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    if args.shipped:
        return shipped(args, comm)
    table = scene_materials()
    foams = {"table": table, "paper": {**table, "plate": TransverseIsotropic(**PAPER_FOAM, rho=table["plate"].rho)}}
    rows = []
    for foam in args.foams:
        for model in args.models:
            case = Case("models", f"{model}, {foam} foam", case="B", model=model, kinematics="as_built",
                        rest_deg=args.rest, h=args.h)
            cpu = time.process_time()
            row = run_case(case, foams[foam], comm)
            cpu = comm.allreduce(time.process_time() - cpu, op=MPI.SUM)
            rows.append(row)
            if comm.rank == 0:
                print(f"{row.label:36s} rest h {row.rest_height:7.2f} a {row.rest_angle:7.2f}  Δh {row.dh_middle:6.2f} "
                      f"{row.dh_top:6.2f}  Δa {row.da_middle:6.2f} {row.da_top:6.2f}  Newton {row.newton:12s} "
                      f"{row.wall_s:6.1f} s wall {cpu:6.1f} s CPU  {row.status}", flush=True)
    if comm.rank == 0:
        for who, v in TABLE_I["B"].items():
            print(f"{'Table I case B, paper ' + who:36s} {'':25s} Δh {v['dh'][0]:6.2f} {v['dh'][1]:6.2f}  "
                  f"Δa {v['da'][0]:6.2f} {v['da'][1]:6.2f}")
    return 0


def shipped(args, comm) -> int:
    """The shipped as-built case B scene, each model, its foam (``table``) or the paper's (``paper``)."""
    import tripod_as_built

    scene_dict = tripod_as_built.scene_dict
    for foam in args.foams:
        for model in args.models:
            def edited(name, h, model_, layout=None, clamp="box", foam=foam):
                data = scene_dict(name, h, model_, layout, clamp)
                if foam == "paper":
                    plate = data["regions"]["plate"]
                    rho = plate["rho_solid"] * plate["density"]
                    data["regions"]["plate"] = {"tags": plate["tags"], "material": "transverse_isotropic",
                                                **PAPER_FOAM, "rho": rho}
                return data
            tripod_as_built.scene_dict = edited
            cpu = time.process_time()
            row = tripod_as_built.run("tripod_case_b", args.h, model, None, comm, "box")
            cpu = comm.allreduce(time.process_time() - cpu, op=MPI.SUM)
            if comm.rank == 0:
                print(f"shipped case B, {model}, {foam} foam, h {args.h * 1e3:g} mm: "
                      + ", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                                  if k not in ("scene", "layout", "h_mm", "model"))
                      + f", {cpu:.1f} s CPU", flush=True)
    tripod_as_built.scene_dict = scene_dict
    return 0


if __name__ == "__main__":
    sys.exit(main())
