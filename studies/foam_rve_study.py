"""RVE-size and resolution studies of the homogenized foam, to choose the table's settings.

Every sample is one foam of :mod:`homogenization.tables` (density 0.18 unless ``--density``) homogenized by FFT
in its periodic box, cached as one JSON file per sample (``--cache``): an interrupted study resumes where it
stopped, and the two studies share the samples they have in common.

``size``
    Cells across each direction ``m = 2, 3, 4`` (``n = m³`` cells in the equiaxed box ``(γ, 1, 1)``) at a fixed
    number of voxels per cell width (``N = v m``, ``--voxels-per-cell``, default 30), γ = 1, 0.5, 0.1, seeds
    0, 1, 2 (``--seeds``); with ``--cube`` also the unit cube with 8 cells at N = 48 (the ``cube`` table's
    setting) for comparison.
    Prints the seed mean and standard deviation of E1, E2, E3, G23, G13, G12 and of the TI fit per (γ, m).
``resolution``
    One RVE size (``--cells``, default 27 = 3 across) at ``N = v m`` for ``v`` in ``--levels`` (default 20, 30, 40,
    50 voxels per cell width), γ = 1, 0.5, 0.1. Richardson extrapolation from the three finest levels
    (``q(h) = q₀ + c h^p``, ``p`` from the three values, see :func:`richardson`) gives the converged estimate and the
    remaining bias of each level.

Writes ``<study>.csv`` (every sample) and ``<study>_summary.csv`` under ``--out``. Run with nice and one thread
per process, e.g. ``OMP_NUM_THREADS=1 nice -n 10 python studies/foam_rve_study.py size --out out/rve-size``;
``mpirun -n 2`` deals the samples to two ranks. ``--ci``: one tiny case of each.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from homogenization import tables

MODULI = ("E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "ti_error")
GAMMAS = (1.0, 0.5, 0.1)


def run(settings: tables.SweepSettings, samples, cache: Path, comm) -> list[dict]:
    return tables.run_sweep(samples, settings, cache, comm, threads=1, progress=False)


def summarize(rows: list[dict], keys: tuple[str, ...]) -> list[dict]:
    """Seed mean and standard deviation of :data:`MODULI` per group of ``keys``."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    for key, members in sorted(groups.items()):
        row = dict(zip(keys, key)) | {"n_seeds": len(members)}
        for name in MODULI:
            v = np.array([float(m[name]) for m in members])
            row[name] = float(v.mean())
            row[f"{name}_std"] = float(v.std(ddof=1)) if len(v) > 1 else 0.0
        out.append(row)
    return out


def richardson(h: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """``(q0, p)`` of ``q = q0 + c h^p`` through the three finest points (``h`` decreasing).

    ``p`` solves ``(q2 − q1)/(q3 − q2) = (h1^p − h2^p)/(h2^p − h3^p)`` (bisection on [0.25, 4]); when the three
    values are not monotone or no order in [0.25, 4] fits (increments that do not shrink: not yet asymptotic),
    ``p = 1`` is assumed (first order, the voxel staircase) and the estimate is only indicative.
    """
    (h1, h2, h3), (q1, q2, q3) = h[-3:], q[-3:]
    ratio = (q2 - q1) / (q3 - q2) if q3 != q2 else np.inf
    if not np.isfinite(ratio) or ratio <= 0:
        p = 1.0
    else:
        def f(p):
            return (h1**p - h2**p) / (h2**p - h3**p) - ratio
        lo, hi = 0.25, 4.0
        if f(lo) * f(hi) > 0:        # no order in [0.25, 4] fits (e.g. increments that grow): first order
            p = 1.0
        else:
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if f(lo) * f(mid) > 0 else (lo, mid)
            p = 0.5 * (lo + hi)
    q0 = q3 - (q2 - q3) * h3**p / (h2**p - h3**p)
    return float(q0), float(p)


def size_study(a, comm) -> list[dict]:
    rows = []
    for gamma in a.gammas:
        for m in a.across:
            settings = tables.SweepSettings(n_cells=m**3, resolution=a.voxels_per_cell * m, tol=a.tol,
                                            box="equiaxed", distance=a.distance, maxiter=a.maxiter)
            rows += run(settings, tables.grid((a.density,), (gamma,), a.seeds), a.cache, comm)
    if a.cube and a.distance == "euclidean" and not a.ci:
        cube = tables.SweepSettings(n_cells=8, resolution=48, tol=a.tol, maxiter=a.maxiter)
        rows += run(cube, tables.grid((a.density,), a.gammas, a.seeds), a.cache, comm)
    return rows


def resolution_study(a, comm) -> list[dict]:
    rows = []
    m = round(a.cells ** (1 / 3))
    for gamma in a.gammas:
        for v in a.levels:
            settings = tables.SweepSettings(n_cells=a.cells, resolution=v * m, tol=a.tol, box="equiaxed",
                                            distance=a.distance, maxiter=a.maxiter)
            rows += run(settings, tables.grid((a.density,), (gamma,), a.seeds), a.cache, comm)
    return rows


def report_size(rows: list[dict]) -> list[dict]:
    summary = summarize(rows, ("gamma", "box", "n_cells", "resolution"))
    print(f"{'gamma':>5} {'box':>8} {'cells':>5} {'N':>4} " + " ".join(f"{n:>16}" for n in MODULI[:7]))
    for s in summary:
        print(f"{s['gamma']:5.2f} {s['box']:>8} {s['n_cells']:5d} {s['resolution']:4d} "
              + " ".join(f"{s[n]:9.3e}±{s[n + '_std']:6.1e}" for n in MODULI[:7]))
    return summary


def report_resolution(rows: list[dict]) -> list[dict]:
    summary = summarize(rows, ("gamma", "n_cells", "resolution"))
    out = []
    for gamma in sorted({s["gamma"] for s in summary}, reverse=True):
        levels = sorted((s for s in summary if s["gamma"] == gamma), key=lambda s: s["resolution"])
        if len(levels) < 3:
            continue
        h = 1.0 / np.array([s["resolution"] for s in levels], dtype=float)
        print(f"γ = {gamma}: N = {[s['resolution'] for s in levels]}")
        for name in MODULI[:9]:
            q = np.array([s[name] for s in levels])
            q0, p = richardson(h, q)
            bias = (q - q0) / q0
            print(f"  {name:>7}: " + " ".join(f"{v:9.4e}" for v in q) + f" → {q0:9.4e} (p = {p:.2f}); bias "
                  + " ".join(f"{b:+.1%}" for b in bias))
            for s, b in zip(levels, bias):
                out.append({"gamma": gamma, "n_cells": s["n_cells"], "resolution": s["resolution"], "name": name,
                            "value": s[name], "extrapolated": q0, "order": p, "bias": float(b)})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study", choices=("size", "resolution"), nargs="?", default="size")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default OUT/cache)")
    p.add_argument("--distance", choices=tables.FOAMS, default="euclidean")
    p.add_argument("--density", type=float, default=0.18)
    p.add_argument("--gammas", type=float, nargs="+", default=list(GAMMAS))
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="default 0 1 2 (size), 0 (resolution)")
    p.add_argument("--across", type=int, nargs="+", default=[2, 3, 4], help="cells across (size study)")
    p.add_argument("--voxels-per-cell", type=int, default=30)
    p.add_argument("--cells", type=int, default=27, help="cells per RVE (resolution study)")
    p.add_argument("--levels", type=int, nargs="+", default=[20, 30, 40, 50], help="voxels per cell width")
    p.add_argument("--tol", type=float, default=1e-4)
    p.add_argument("--cube", action="store_true", help="size study: also the unit cube, 8 cells, N = 48")
    p.add_argument("--maxiter", type=int, default=10000, help="CG iterations per load case")
    p.add_argument("--ci", action="store_true", help="a tiny case (seconds)")
    a = p.parse_args(argv)
    if a.ci:
        a.gammas, a.seeds, a.across, a.voxels_per_cell, a.levels, a.cells = [0.5], [0, 1], [2], 10, [10, 12, 14], 8
        a.density = 0.3
    a.seeds = a.seeds or ([0, 1, 2] if a.study == "size" else [0])
    a.cache = a.cache or a.out / "cache"
    comm = MPI.COMM_WORLD
    rows = size_study(a, comm) if a.study == "size" else resolution_study(a, comm)
    if comm.rank == 0:
        a.out.mkdir(parents=True, exist_ok=True)
        tables.to_csv(rows, a.out / f"{a.study}.csv")
        summary = report_size(rows) if a.study == "size" else report_resolution(rows)
        if summary:
            tables.to_csv(summary, a.out / f"{a.study}_summary.csv")
        print(f"wrote {a.out / (a.study + '.csv')}")
        off = [r for r in rows if abs(r["measured_density"] - r["density"]) > 0.002]
        if off:
            print(f"FAILED: {len(off)} samples miss their density by more than 0.002")
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
