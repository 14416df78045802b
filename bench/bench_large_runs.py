"""Memory and time of a scene run against its size, direct (MUMPS LU) and iterative (Krylov + GAMG) solvers.

The Fig. 6 beam (250 × 15 × 15 mm, isotropic foam, corotational, P2, clamped, gravity in two increments) at mesh
sizes from about 20k to 150k dofs; every case runs ``fenicsfoam run`` in a subprocess of its own (serial, no field
files, no pictures), with the solver forced by ``--solver``. Recorded per case: cells, dofs, Newton iterations, the
solve's wall and CPU time (summary.json, the steps' ``wall_s`` and ``cpu_s``), the whole process's wall and CPU time
and its peak resident memory (``getrusage`` of the child). On a shared machine the CPU times are the measure.
The fit of :mod:`fenicsfoam.sizing` and the choice of the default solver come from this CSV.

    python bench/bench_large_runs.py --out out/bench_large          # writes out/bench_large/large_runs.csv
    python bench/bench_large_runs.py --fit out/bench_large/large_runs.csv [more.csv ...]   # the model's constants
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

SCENE = """name = "bench_beam"
probes = ["tip_deflection"]
[geometry]
builder = "beam"
length = 0.250
width = 0.015
height = 0.015
h = {h}
[fem]
model = "corotational"
degree = 2
[regions.beam]
tags = "beam"
material = "isotropic"
E = 2.6e5
nu = 0.3
rho = 214.0
[loads]
gravity = [0.0, 0.0, -9.81]
clamp = "clamped"
[[steps]]
label = "gravity"
gravity = 1.0
increments = 2
[outputs]
xdmf = false
png = false
"""


def run(h: float, solver: str, out: Path) -> dict:
    case = out / f"h{h:g}_{solver}"
    case.mkdir(parents=True, exist_ok=True)
    scene = case / "scene.toml"
    scene.write_text(SCENE.format(h=h))
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "fenicsfoam.cli", "run", str(scene), "--out", str(case / "run"),
                                "--solver", solver, "--force"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    log = process.stdout.read().decode(errors="replace")
    summary = json.loads((case / "run" / "summary.json").read_text())
    estimate = summary.get("estimate") or {}
    return {"h": h, "solver": solver, "status": summary["status"], "cells": summary["n_cells"],
            "dofs": summary["n_dofs"], "newton": sum(s["newton_iterations"] for s in summary["steps"]),
            "solve_s": sum(s["wall_s"] for s in summary["steps"]),
            "solve_cpu_s": sum(s.get("cpu_s", 0.0) for s in summary["steps"]), "process_s": round(wall, 2),
            "process_cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
            "peak_rss_mb": round(usage.ru_maxrss / 1024, 1),
            "estimated_mb": round(estimate.get("memory_bytes", float("nan")) / 2**20, 1),
            "estimated_s": estimate.get("solve_s"), "exit": os.waitstatus_to_exitcode(status),
            "log_tail": log.strip().splitlines()[-1] if log.strip() else ""}


def fit(paths: list[Path]) -> None:
    """Fit ``M = M0 + a n^p`` (direct; iterative with p = 1 and the same M0) and ``t = c n^q`` per Newton iteration."""
    import numpy as np
    from scipy.optimize import curve_fit

    rows = [r for path in paths for r in csv.DictReader(open(path)) if r["status"] == "complete"]
    by = {s: [r for r in rows if r["solver"] == s] for s in ("direct", "iterative")}
    n = {s: np.array([float(r["dofs"]) for r in by[s]]) for s in by}
    mem = {s: np.array([float(r["peak_rss_mb"]) for r in by[s]]) * 2**20 for s in by}
    per_newton = {s: np.array([float(r["solve_cpu_s"]) / float(r["newton"]) for r in by[s]]) for s in by}
    (m0, a, p), _ = curve_fit(lambda x, m0, a, p: m0 + a * x**p, n["direct"], mem["direct"], p0=(2e8, 1e3, 1.2))
    a_it = float(np.mean((mem["iterative"] - m0) / n["iterative"])) if len(n["iterative"]) else float("nan")
    q = {s: np.polyfit(np.log(n[s]), np.log(per_newton[s]), 1) for s in by if len(n[s]) > 1}
    print(f"baseline M0 = {m0 / 2**20:.0f} MB; direct: a = {a:.3g}, p = {p:.3f}; iterative: a = {a_it:.3g}, p = 1")
    for s, (slope, intercept) in q.items():
        print(f"{s}: t per Newton iteration = {np.exp(intercept):.3g} n^{slope:.3f} s (CPU)")
    for s in by:
        for x, m, t in zip(n[s], mem[s], per_newton[s]):
            model_m = m0 + (a * x**p if s == "direct" else a_it * x)
            slope, intercept = q.get(s, (np.nan, np.nan))
            print(f"{s:9s} {int(x):7d} dofs: memory {m / 2**20:7.0f} MB (model {model_m / 2**20:7.0f}), "
                  f"{t:7.3f} s/Newton (model {np.exp(intercept) * x**slope:7.3f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--fit", type=Path, nargs="+", help="fit the model to these CSVs instead of running")
    parser.add_argument("--h", type=float, nargs="+", default=[0.006, 0.0045, 0.0035, 0.003, 0.0026])
    parser.add_argument("--solvers", nargs="+", default=["direct", "iterative"])
    args = parser.parse_args()
    if args.fit:
        fit(args.fit)
        return
    if args.out is None:
        parser.error("--out is required to run the cases")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for h in args.h:
        for solver in args.solvers:
            row = run(h, solver, args.out)
            rows.append(row)
            print(json.dumps(row), flush=True)
    with open(args.out / "large_runs.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
