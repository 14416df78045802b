"""The Tripod as built with the paper's own constants: mesh convergence of Table I, and the SOFA element's Krylov solve.

Two subcommands.

``converge``: the shipped as-built scenes `demos/scenes/tripod_case_a.toml` and `tripod_case_b.toml` (the
SoftRobots Tripod's servos: set-up 35 mm inwards with the horns at −85.743°, then +19° and +38° from rest; the
tutorial's box clamp) with the foam constants of the paper's own SOFA simulation in place of the foam table's: the
peer's inputs (VannesteFelix/anisotropy, examples/SimpleCube/mechaParam/anisotropyTransverse.yaml), entry
``paramPaper`` for every transversely isotropic region (`tripod_models.PAPER_FOAM`, l as the scene sets it) and
entry ``isotropic`` (E 1390 kPa, ν 0.26162) for case A's isotropic centre. Each region keeps its scene's mass
density. With ``--table CSV [CSV ...]`` the scenes keep their own foam regions (density, γ, fit) and each reads the
first of the listed foam tables (aggregated table CSVs, a path each) that holds its γ, in place of the peer's
constants: the as-built robot on another homogenized foam (one γ per table: case A's γ = 1 centre needs a table with
γ = 1 rows). Every (case, model, degree) runs on each mesh size listed; each row gives the changes of the centre's
height and twist from rest to middle and top (Table I's quantities), the mesh, the Newton iterations and the wall and
CPU time. For every sequence of three or more meshes that all reached the top, the observed order of convergence
and the Richardson estimate are computed from the three finest (mesh size h ∝ N_cells^(−1/3)), with the relative
change between the two finest meshes. ``--layers N ...`` runs every mesh size with each number of element layers
through the plate (``[geometry] layers``; 0, the default, is the unstructured mesh) and ``--arm-end-cut straight``
puts the clamp box's inner face on a line of mesh nodes (``[geometry] arm_end_cut``); the layered rows give a second
kind of sequence, the number of layers at one in-plane size (h ∝ 1/n, ``refine = layers``).

``krylov``: the shipped case B with its own foam table (`cube`) and ``corotational_sofa`` (SOFA's element: rotation
from the element's edges, frozen-rotation tangent, never loses strong ellipticity). Newton's system is the exact
Jacobian applied matrix-free, solved by GMRES preconditioned by the frozen-rotation tangent's LU
(`ElasticityProblem.APPROXIMATE_TANGENT_OPTIONS`); each listed variant of the Krylov set-up (``--variants``, keys of
`KRYLOV_VARIANTS`) is a row with how far the rest step got and why it stopped.

Checks (exit status 1 if one fails): the Richardson estimate of the study recovers the limit and order of an exact
power law to 1e-10; with ``--ci`` (case B, P1, h = 10 mm, both elements, ≈ 9 s CPU) both runs reach the top and the
two corotational elements agree on Δheight within 10 % and on Δangle within 3° at middle and top (a cross-check of
two rotations and tangents of the same law; measured there: 0.6 % and 1.6°; on the finer P1 meshes they differ by
up to 12 % in height, P2 at 10 mm 0.7 % and 1.4°). A run whose rest step fails (the finer meshes: inverted clamp
cells, solver limits, docs/validation/2026-11-27-tripod-as-built.md) is a row with the step, the fraction reached
and why, not a failed check.

Run: ``python studies/tripod_peer.py converge --out DIR [--cases A B] [--models corotational corotational_sofa] [--p1
0.008 0.0052 0.0035] [--p2 0.010 0.008 0.006] [--p2-models corotational corotational_sofa] [--table CSV ...] [--layers
0 1 2 ...] [--arm-end-cut arc|straight] [--ci]``; ``python studies/tripod_peer.py krylov --out DIR --h 0.0052
[--degree 1] [--variants default restart300 ...]``. Rows go to ``DIR/tripod_peer_converge.csv`` (and
``tripod_peer_convergence.csv``) or ``DIR/tripod_peer_krylov_*.csv``; ``python studies/tripod_peer.py table CSV...
[--out DIR]`` merges the rows of several ``converge`` runs and prints their convergence table (one sequence per case,
model, degree and foam). """

from __future__ import annotations

import argparse
import csv
import hashlib
import math
import os
import sys
import time
from pathlib import Path

from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parent))

import tripod_as_built  # noqa: E402
from tripod_models import PAPER_FOAM  # noqa: E402

from fenicsfoam.paper import table_i_changes  # noqa: E402
from fenicsfoam.scene import parse_scene  # noqa: E402
from foambase.cli import report_checks  # noqa: E402
from foambase.logs import setup_logging  # noqa: E402

#: The peer's isotropic foam (the same file, entry ``isotropic``: E 1390 kPa, ν 0.26162), for case A's centre.
PAPER_ISOTROPIC = dict(E=1390e3, nu=0.26162)
SCENES = {"A": "tripod_case_a", "B": "tripod_case_b"}
QUANTITIES = ("dh_middle_mm", "dh_top_mm", "da_middle_deg", "da_top_deg")

#: Krylov set-ups of ``corotational_sofa``'s Newton system tried by ``krylov`` (``[fem.petsc]`` options added to
#: the defaults, `ElasticityProblem.APPROXIMATE_TANGENT_OPTIONS`).
KRYLOV_VARIANTS: dict[str, dict] = {
    "default": {},
    # longer GMRES: no restart within the iteration limit
    "restart300": {"ksp_gmres_restart": 300, "ksp_max_it": 300},
    # a Newton step whose GMRES did not converge is taken anyway (PETSc stops Newton at the first by default)
    "linfail": {"snes_max_linear_solve_fail": 1000},
    # right preconditioning: GMRES minimises the true residual, not the preconditioned one
    "right": {"ksp_pc_side": "right", "ksp_gmres_restart": 300, "ksp_max_it": 300},
    # a looser Krylov tolerance (inexact Newton): the failed solves stall between 7e-5 and 0.36 (7 of 22 below 1e-2)
    "rtol1e-2": {"ksp_rtol": 1e-2},
    # a line search on the residual norm (l2: secant on ‖F‖²) keeps Newton's iterates nearer the path
    "l2": {"snes_linesearch_type": "l2"},
    "bt": {"snes_linesearch_type": "bt"},
}


def table_gammas(path: str | Path) -> set[float]:
    """The γ values of an aggregated foam table CSV (its ``gamma`` column)."""
    with open(path, newline="") as f:
        return {float(r["gamma"]) for r in csv.DictReader(f)}


def table_for(region: dict, tables: list[str], gammas: dict[str, set[float]], name: str) -> str:
    """The first of ``tables`` whose rows hold the foam region's γ; SystemExit naming the region otherwise."""
    for path in tables:
        if any(math.isclose(float(region["gamma"]), g, rel_tol=1e-9) for g in gammas[path]):
            return path
    raise SystemExit(f"region {name!r} (gamma {region['gamma']}): no --table holds that gamma "
                     f"({ {p: sorted(g) for p, g in gammas.items()} })")


def peer_scene_dict(case: str, h: float, model: str, degree: int, petsc: dict | None = None,
                    peer: bool = True, tables: list[str] | None = None, layers: int = 0,
                    arm_end_cut: str = "arc") -> dict:
    """The shipped as-built scene of ``case`` at mesh size ``h``, degree ``degree``, with the peer's constants
    (``peer``), or with every foam region reading the first of the foam tables ``tables`` (aggregated CSV paths)
    that holds its γ, the scene otherwise unchanged; ``layers`` and ``arm_end_cut`` are the ``[geometry]`` keys
    (0 and ``"arc"``: the shipped mesh)."""
    data = tripod_as_built.scene_dict(SCENES[case], h, model)
    data["fem"]["degree"] = degree
    if layers:
        data["geometry"]["layers"] = layers
    if arm_end_cut != "arc":
        data["geometry"]["arm_end_cut"] = arm_end_cut
    if petsc:
        data["fem"]["petsc"] = dict(petsc)
    if tables:
        gammas = {path: table_gammas(path) for path in tables}
        for name, region in data["regions"].items():
            if region.get("material") == "foam":
                region["table"] = table_for(region, tables, gammas, name)
    elif peer:
        for name, region in data["regions"].items():
            rho = region["rho_solid"] * region["density"]
            if region.get("fit", "transverse") == "isotropic":
                data["regions"][name] = {"tags": region["tags"], "material": "isotropic", **PAPER_ISOTROPIC,
                                         "rho": rho}
            else:
                data["regions"][name] = {"tags": region["tags"], "material": "transverse_isotropic", **PAPER_FOAM,
                                         "rho": rho}
    return data


def run_one(case: str, h: float, model: str, degree: int, comm, petsc: dict | None = None, peer: bool = True,
            variant: str = "", tables: list[str] | None = None, layers: int = 0, arm_end_cut: str = "arc") -> dict:
    """One run; a failed step is a row (the step, the fraction of it reached, the reason), not an exception."""
    foam = "paper" if peer else "table"
    if tables:  # each table by its name and the start of its digest (two seeds' tables share a name)
        foam = "+".join(f"{Path(t).stem}@{hashlib.sha256(Path(t).read_bytes()).hexdigest()[:8]}" for t in tables)
    row = {"case": case, "foam": foam, "model": model, "degree": degree, "h_mm": h * 1e3, "layers": layers,
           "arm_end_cut": arm_end_cut, "variant": variant, "status": "ok"}
    start, cpu = time.perf_counter(), time.process_time()
    data = peer_scene_dict(case, h, model, degree, petsc, peer, tables, layers, arm_end_cut)
    result = tripod_as_built.run_changes(parse_scene(data), comm, row)
    steps = [] if result is None else result.steps
    if result is not None:
        row["n_cells"], row["n_dofs"] = result.n_cells, result.n_dofs
    row["newton"] = "/".join(str(s.newton_iterations) for s in steps)
    row["wall_s"] = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    row["cpu_s"] = comm.allreduce(time.process_time() - cpu, op=MPI.SUM)
    return row


def richardson(h: list[float], f: list[float]) -> tuple[float, float]:
    """Observed order p and limit f∞ of f = f∞ + C h^p through three points (h decreasing); (nan, nan) if the
    differences change sign (no monotone convergence) or no p in (0.05, 20) fits."""
    (h1, h2, h3), (f1, f2, f3) = h, f
    d12, d23 = f1 - f2, f2 - f3
    if d23 == 0.0 or d12 / d23 <= 0.0:
        return math.nan, math.nan
    ratio = d12 / d23

    def g(p):
        return (h1**p - h2**p) / (h2**p - h3**p) - ratio

    lo, hi = 0.05, 20.0
    if g(lo) * g(hi) > 0.0:
        return math.nan, math.nan
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if g(lo) * g(mid) <= 0.0:
            hi = mid
        else:
            lo = mid
    p = 0.5 * (lo + hi)
    C = d23 / (h2**p - h3**p)
    return p, f3 - C * h3**p


def _mesh_key(r: dict) -> tuple:
    """The mesh family of a row: its layers (0: unstructured) and arm-end cut (older rows: 0, ``"arc"``)."""
    return int(r.get("layers", 0) or 0), r.get("arm_end_cut", "arc") or "arc"


def convergence(rows: list[dict]) -> list[dict]:
    """Sequences of ≥ 2 meshes that reached the top, each with its order, Richardson limit (3 meshes) and last change.

    ``refine = "mesh"``: per (case, model, degree, foam, layers, cut), the meshes by size, h ∝ N_cells^(−1/3)
    (with n ≥ 1 layers this refines in-plane only, at n elements through the thickness); ``refine = "layers"``: per
    (case, model, degree, foam, in-plane h, cut), the layered meshes by their number of layers n, h ∝ 1/n.
    """
    out = []
    done = [r for r in rows if "da_top_deg" in r]
    families = {}
    for r in done:
        base = (r["case"], r["model"], r["degree"], r.get("foam", "paper"))
        layers, cut = _mesh_key(r)
        families.setdefault(("mesh", *base, layers, cut), []).append(r)
        if layers:
            families.setdefault(("layers", *base, r["h_mm"], cut), []).append(r)
    for key in sorted(families, key=str):
        refine, case, model, degree, foam = key[:5]
        seq = sorted(families[key], key=lambda r: r["n_cells"])
        # two sizes may give the same outline triangulation (gmsh divides the wedge's short edges alike): one mesh
        seq = [r for k, r in enumerate(seq) if k == 0 or r["n_cells"] != seq[k - 1]["n_cells"]]
        if len(seq) < 2:
            continue
        seq = seq[-3:]
        heff = [r["n_cells"] ** (-1.0 / 3.0) if refine == "mesh" else 1.0 / _mesh_key(r)[0] for r in seq]
        for q in QUANTITIES:
            f = [r[q] for r in seq]
            p, limit = richardson(heff, f) if len(seq) == 3 else (math.nan, math.nan)
            out.append({"case": case, "model": model, "degree": degree, "foam": foam, "refine": refine,
                        "arm_end_cut": key[-1], "quantity": q,
                        "h_mm": " ".join(f"{r['h_mm']:g}" for r in seq),
                        "layers": " ".join(str(_mesh_key(r)[0]) for r in seq),
                        "n_cells": " ".join(str(r["n_cells"]) for r in seq),
                        "values": " ".join(f"{v:.3f}" for v in f), "order": p, "richardson": limit,
                        "last_change": abs(f[-1] - f[-2]) / abs(f[-1]) if f[-1] else math.nan})
    return out


def write_csv(rows: list[dict], path: Path) -> None:
    """Rows as CSV, atomically (a temporary file, then ``os.replace``)."""
    if not rows:
        return
    keys = list(dict.fromkeys(k for r in rows for k in r))
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def print_row(r: dict) -> None:
    nan = math.nan
    print(f"case {r['case']} {r['foam']:5s} {r['model']:17s} P{r['degree']} h {r['h_mm']:4.1f} mm "
          f"layers {r.get('layers', 0)} {r.get('arm_end_cut', 'arc')} "
          f"{r.get('n_cells', ''):>6} cells {r.get('n_dofs', ''):>7} dofs {r['variant']:10s}| rest h "
          f"{r.get('rest_h_mm', nan):6.2f} a {r.get('rest_deg', nan):7.2f} | Δh {r.get('dh_middle_mm', nan):6.2f} "
          f"{r.get('dh_top_mm', nan):6.2f} mm | Δa {r.get('da_middle_deg', nan):6.2f} {r.get('da_top_deg', nan):6.2f}° "
          f"| Newton {r['newton']} | {r['status']} | {r['wall_s']:.0f} s wall {r['cpu_s']:.0f} s CPU", flush=True)


def self_check() -> list[str]:
    """The Richardson estimate on an exact power law f = 3 − 2 h^1.7 (non-uniform refinement)."""
    h = [0.9, 0.55, 0.31]
    p, limit = richardson(h, [3.0 - 2.0 * x**1.7 for x in h])
    if not (abs(p - 1.7) < 1e-10 and abs(limit - 3.0) < 1e-10):
        return [f"Richardson on f = 3 - 2 h^1.7 gave p {p!r}, limit {limit!r}"]
    return []


#: ``--ci``: the two corotational elements (same stress–strain law in the rotated frame, different rotation and
#: tangent) agree on the changes from rest within these bounds (measured at h = 10 mm, P1: 0.6 % and 1.6°).
AGREE_RTOL_HEIGHT, AGREE_ATOL_DEG = 0.10, 3.0


def elements_agree(rows: list[dict]) -> list[str]:
    """Cross-check of ``corotational`` and ``corotational_sofa`` on the same case, mesh and degree."""
    failures = []
    for r in rows:
        if r["model"] != "corotational" or "da_top_deg" not in r:
            continue
        s = next((x for x in rows if x["model"] == "corotational_sofa" and "da_top_deg" in x
                  and (x["case"], x["degree"], x["h_mm"]) == (r["case"], r["degree"], r["h_mm"])), None)
        if s is None:  # not run, or did not reach the top on this mesh
            continue
        for label in ("middle", "top"):
            dh, ds = r[f"dh_{label}_mm"], s[f"dh_{label}_mm"]
            if not abs(dh - ds) <= AGREE_RTOL_HEIGHT * abs(dh):
                failures.append(f"case {r['case']} {label}: Δheight {dh:.3f} (corotational) against {ds:.3f} mm "
                                f"(corotational_sofa), more than {AGREE_RTOL_HEIGHT:.0%} apart")
            da, dsa = r[f"da_{label}_deg"], s[f"da_{label}_deg"]
            if not abs(da - dsa) <= AGREE_ATOL_DEG:
                failures.append(f"case {r['case']} {label}: Δangle {da:.3f} (corotational) against {dsa:.3f}° "
                                f"(corotational_sofa), more than {AGREE_ATOL_DEG}° apart")
    return failures


def converge(args, comm) -> int:
    runs = [(case, model, 1, h, n) for case in args.cases for model in args.models for h in args.p1
            for n in args.layers]
    runs += [(case, model, 2, h, n) for case in args.cases for model in args.p2_models for h in args.p2
             for n in args.layers]
    rows = []
    for case, model, degree, h, n in runs:
        rows.append(run_one(case, h, model, degree, comm, tables=args.table, layers=n, arm_end_cut=args.arm_end_cut))
        if comm.rank == 0:
            print_row(rows[-1])
    failures = self_check()
    if args.ci:  # at h = 10 mm, P1, both elements reach the top (the finer meshes need not: rows, not failures)
        failures += elements_agree(rows)
        failures += [f"case {r['case']} {r['model']} P{r['degree']} h {r['h_mm']:g} mm: {r['status']}"
                     for r in rows if r["status"] != "ok"]
    table = convergence(rows)
    if comm.rank == 0:
        print_convergence(table)
        for case in args.cases:
            t = table_i_changes(SCENES[case])
            for k, who in enumerate(("paper's simulation", "real robot")):
                print(f"Table I case {case}, {who}: Δh {t['height'][k][0]} / {t['height'][k][1]} mm, "
                      f"Δa {t['angle'][k][0]} / {t['angle'][k][1]}°")
        args.out.mkdir(parents=True, exist_ok=True)
        write_csv(rows, args.out / "tripod_peer_converge.csv")
        write_csv(table, args.out / "tripod_peer_convergence.csv")
    return report_checks(failures if comm.rank == 0 else [], comm)


def krylov(args, comm) -> int:
    unknown = [v for v in args.variants if v not in KRYLOV_VARIANTS]
    if unknown:
        raise SystemExit(f"unknown --variants {unknown}: valid are {list(KRYLOV_VARIANTS)}")
    rows = []
    for variant in args.variants:
        rows.append(run_one(args.case, args.h, "corotational_sofa", args.degree, comm,
                            petsc=KRYLOV_VARIANTS[variant], peer=args.foam == "paper", variant=variant))
        if comm.rank == 0:
            print_row(rows[-1])
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
        write_csv(rows, args.out / f"tripod_peer_krylov_{args.case}_P{args.degree}_{args.h * 1e3:g}mm.csv")
    return report_checks(self_check() if comm.rank == 0 else [], comm)


def print_convergence(table: list[dict]) -> None:
    for c in table:
        print(f"case {c['case']} {c['model']:17s} P{c['degree']} {c.get('arm_end_cut', 'arc'):8s} by "
              f"{c.get('refine', 'mesh'):6s} {c['quantity']:14s} h {c['h_mm']:14s} mm "
              f"layers {c.get('layers', '0'):7s}: "
              f"{c['values']:24s} order {c['order']:5.2f} Richardson {c['richardson']:8.3f} "
              f"last change {c['last_change']:.2%}", flush=True)


def tabulate(args) -> int:
    """The convergence table of the rows of earlier ``converge`` runs (their CSV files), merged."""
    rows = []
    for path in args.csv:
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                row = {k: v for k, v in r.items() if v != ""}
                for k in ("h_mm", *QUANTITIES):
                    if k in row:
                        row[k] = float(row[k])
                for k in ("degree", "n_cells", "layers"):
                    if k in row:
                        row[k] = int(row[k])
                rows.append(row)
    table = convergence(rows)
    print_convergence(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        write_csv(table, args.out / "tripod_peer_convergence.csv")
    return report_checks(self_check(), MPI.COMM_SELF)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="count", default=0)
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("converge", help="mesh convergence as built with the paper's constants")
    c.add_argument("--out", type=Path, default=Path("out/tripod_peer"))
    c.add_argument("--cases", nargs="+", default=["A", "B"], choices=list(SCENES))
    c.add_argument("--models", nargs="+", default=["corotational", "corotational_sofa"],
                   choices=["corotational", "corotational_sofa"], help="models of the P1 rows")
    c.add_argument("--p2-models", nargs="+", default=["corotational", "corotational_sofa"],
                   choices=["corotational", "corotational_sofa"], help="models of the P2 rows")
    c.add_argument("--p1", type=float, nargs="*", default=[0.008, 0.0052, 0.0035], help="P1 mesh sizes (m)")
    c.add_argument("--p2", type=float, nargs="*", default=[0.010, 0.008, 0.006], help="P2 mesh sizes (m)")
    c.add_argument("--table", nargs="+", default=None, metavar="CSV",
                   help="foam tables (aggregated CSV paths) in place of the paper's constants: each foam region "
                        "reads the first that holds its gamma")
    c.add_argument("--layers", type=int, nargs="+", default=[0], metavar="N",
                   help="element layers through the plate's thickness ([geometry] layers; 0: unstructured "
                        "tetrahedra of size h); every mesh size runs with each")
    c.add_argument("--arm-end-cut", default="arc", choices=["arc", "straight"],
                   help="[geometry] arm_end_cut: straight puts the clamp box's inner face on a line of mesh nodes")
    c.add_argument("--ci", action="store_true", help="case B, P1, h = 10 mm, both models, checked against each other")
    k = sub.add_parser("krylov", help="corotational_sofa's Krylov set-ups on the as-built rest step")
    k.add_argument("--out", type=Path, default=Path("out/tripod_peer"))
    k.add_argument("--case", default="B", choices=list(SCENES))
    k.add_argument("--foam", default="table", choices=["table", "paper"])
    k.add_argument("--h", type=float, default=0.0052)
    k.add_argument("--degree", type=int, default=1, choices=[1, 2])
    k.add_argument("--variants", nargs="+", default=list(KRYLOV_VARIANTS))
    t = sub.add_parser("table", help="the convergence table of earlier converge runs' CSV files, merged")
    t.add_argument("csv", type=Path, nargs="+")
    t.add_argument("--out", type=Path)
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "-v", "--verbose")):
        argv = ["converge", *argv]  # `tripod_peer.py --ci --out DIR`, as every study is run: the convergence study
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    comm = MPI.COMM_WORLD
    if args.command == "converge":
        if args.ci:
            args.cases, args.models, args.p1, args.p2 = ["B"], ["corotational", "corotational_sofa"], [0.010], []
        return converge(args, comm)
    if args.command == "table":
        return tabulate(args)
    return krylov(args, comm)


if __name__ == "__main__":
    sys.exit(main())
