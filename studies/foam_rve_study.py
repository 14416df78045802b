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
    One RVE size (``--cells``, default 27 = 3 across) at several grids, γ = 1, 0.5, 0.1: ``N = v m`` for ``v`` in
    ``--levels`` (default 20, 30, 40, 50 voxels per cell width), or with ``--strut-voxels`` the smallest grid per γ
    with at least that many voxels across the strut diameter of the seed-0 foam
    (:func:`homogenization.tables.resolution_for_strut`), so that every γ is compared at equal strut resolution.
    Per constant (E1, E2, E3, G23, ν23, the TI fit's E_t, E_l, G_l, the isotropic E) the Richardson estimate of
    :func:`homogenization.convergence.richardson` in ``h = 1/(voxels across the strut)``: the observed order from the
    three finest levels (or the first-order fallback, flagged NOT ASYMPTOTIC with its reason), the extrapolated
    value, the GCI of the finest level, the orders of every three consecutive levels (whether the order has settled),
    the bias of every level and, with ``--bias-at``, the model's bias at other strut resolutions (a table's setting);
    and the least-squares fits to all levels (:func:`homogenization.convergence.fit_power_law`, ``p`` fitted and
    ``p = 1``), which average the level-to-level scatter of voxelized struts that the three-level estimate follows.
    ``--voxel-fraction`` adds the solid fraction of every level's voxel image (voxelizes each sample again).

Writes ``<study>.csv`` (every sample) and ``size_summary.csv`` or ``resolution_summary.csv`` (every level and
constant) and ``resolution_extrapolation.csv`` (every constant) under ``--out``. Run with nice and one thread
per process, e.g. ``OMP_NUM_THREADS=1 nice -n 10 python studies/foam_rve_study.py size --out out/rve-size``;
``mpirun -n 2`` deals the samples to two ranks. ``--ci``: one tiny case of each. The voxels are the rotated
scheme's (:data:`DISCRETIZATION`), with which the shipped tables and the pages of these studies were made.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from homogenization import tables

#: The studies' voxels: one-point (rotated), those of the shipped tables they chose the settings of.
DISCRETIZATION = "rotated"
from homogenization.convergence import fit_power_law, observed_order, richardson

MODULI = ("E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "ti_error", "nu23", "iso_E",
          "iterations", "wall_s")
#: The constants the resolution study extrapolates.
RESOLVED = ("E1", "E2", "E3", "G23", "nu23", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E")
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


def size_study(a, comm) -> list[dict]:
    rows = []
    for gamma in a.gammas:
        for m in a.across:
            settings = tables.SweepSettings(n_cells=m**3, resolution=a.voxels_per_cell * m, tol=a.tol,
                                            box="equiaxed", distance=a.distance, maxiter=a.maxiter,
                                            discretization=DISCRETIZATION)
            rows += run(settings, tables.grid((a.density,), (gamma,), a.seeds), a.cache, comm)
    if a.cube and a.distance == "euclidean" and not a.ci:
        cube = tables.SweepSettings(n_cells=8, resolution=48, tol=a.tol, maxiter=a.maxiter,
                                    discretization=DISCRETIZATION)
        rows += run(cube, tables.grid((a.density,), a.gammas, a.seeds), a.cache, comm)
    return rows


def level_resolutions(a, gamma: float) -> list[int]:
    """The grids ``N`` of the resolution study at ``gamma``: ``--strut-voxels`` or ``--levels`` (see the CLI)."""
    if a.strut_voxels:
        probe = tables.SweepSettings(n_cells=a.cells, tol=a.tol, box="equiaxed", distance=a.distance)
        return [tables.resolution_for_strut(probe, a.density, gamma, v) for v in a.strut_voxels]
    return [v * round(a.cells ** (1 / 3)) for v in a.levels]


def resolution_study(a, comm) -> list[dict]:
    rows = []
    for gamma in a.gammas:
        for N in level_resolutions(a, gamma):
            settings = tables.SweepSettings(n_cells=a.cells, resolution=N, tol=a.tol, box="equiaxed",
                                            distance=a.distance, maxiter=a.maxiter, discretization=DISCRETIZATION)
            rows += run(settings, tables.grid((a.density,), (gamma,), a.seeds), a.cache, comm)
    return rows


def report_size(rows: list[dict]) -> list[dict]:
    summary = summarize(rows, ("gamma", "box", "n_cells", "resolution"))
    print(f"{'gamma':>5} {'box':>8} {'cells':>5} {'N':>4} " + " ".join(f"{n:>16}" for n in MODULI[:7]))
    for s in summary:
        print(f"{s['gamma']:5.2f} {s['box']:>8} {s['n_cells']:5d} {s['resolution']:4d} "
              + " ".join(f"{s[n]:9.3e}±{s[n + '_std']:6.1e}" for n in MODULI[:7]))
    return summary


def voxel_fractions(rows: list[dict]) -> dict[tuple[float, int], float]:
    """Solid fraction of the voxel image of every (γ, N), mean over the rows' seeds (the samples' images)."""
    from meshes.foam import VoronoiFoam

    out: dict[tuple[float, int], list[float]] = {}
    for r in rows:
        foam = VoronoiFoam(int(r["n_cells"]), float(r["density"]), float(r["gamma"]), seed=int(r["seed"]),
                           box=None if r["box"] == "cube" else r["box"], distance=r["distance"])
        out.setdefault((r["gamma"], int(r["resolution"])), []).append(float(foam.voxelize(int(r["resolution"])).mean()))
    return {k: float(np.mean(v)) for k, v in out.items()}


def report_resolution(rows: list[dict], bias_at: list[float],
                      fractions: dict[tuple[float, int], float] | None = None) -> tuple[list[dict], list[dict]]:
    """Print and return the levels and the Richardson estimates of :data:`RESOLVED` per γ.

    The spacing is ``h = 1 / (voxels across the strut)``, ``2 r N / max(L)`` with the mean strut radius ``r`` of
    the rows (seed 0 alone by default), so that a bias can be read at any strut resolution: ``bias_at`` lists
    voxels across at which the model's bias ``c h^p / q₀`` is reported (e.g. a table's setting). Returns the
    per-level rows (seed mean, standard deviation, bias) and the per-constant estimates (value, order, asymptotic
    flag and reason, GCI of the finest level, the orders of every three consecutive levels, the biases at
    ``bias_at``, the least-squares fits).
    ``fractions`` (:func:`voxel_fractions`) adds the voxel images' solid fraction to the level table.
    """
    summary = summarize(rows, ("gamma", "n_cells", "resolution"))
    levels_out, estimates = [], []
    for gamma in sorted({s["gamma"] for s in summary}, reverse=True):
        levels = sorted((s for s in summary if s["gamma"] == gamma), key=lambda s: s["resolution"])
        radius = float(np.mean([r["radius"] for r in rows if r["gamma"] == gamma]))
        box = max(gamma, 1.0)
        across = np.array([2 * radius * s["resolution"] / box for s in levels])
        print(f"γ = {gamma}: {levels[0]['n_cells']} cells, seeds per level {[s['n_seeds'] for s in levels]}")
        fraction = [fractions[(gamma, s["resolution"])] if fractions else np.nan for s in levels]
        print(f"  {'N':>5} {'across':>6} {'voxels':>7} " + " ".join(f"{n:>9}" for n in RESOLVED)
              + f" {'iters':>6} {'wall s':>7}")
        for s, a, f in zip(levels, across, fraction):
            print(f"  {s['resolution']:5d} {a:6.2f} {f:7.4f} " + " ".join(f"{s[n]:9.4g}" for n in RESOLVED)
                  + f" {s['iterations']:6.0f} {s['wall_s']:7.1f}")
            if s["n_seeds"] > 1:
                print(f"  {'± std':>5} {'':>6} {'':>7} " + " ".join(f"{s[n + '_std']:9.2g}" for n in RESOLVED)
                      + f"   ({s['n_seeds']} seeds; scatter std/mean "
                      + " ".join(f"{s[n + '_std'] / abs(s[n]):.1%}" for n in RESOLVED) + ")")
            levels_out += [{"gamma": gamma, "n_cells": s["n_cells"], "resolution": s["resolution"], "across": float(a),
                            "voxel_fraction": f, "n_seeds": s["n_seeds"], "name": name, "value": s[name],
                            "std": s[name + "_std"], "bias": np.nan} for name in RESOLVED]
        if len(levels) < 3:
            print("  fewer than 3 levels: no extrapolation")
            continue
        h = 1.0 / across
        for name in RESOLVED:
            q = np.array([s[name] for s in levels])
            est = richardson(h, q)
            bias = (q - est.value) / est.value    # every level's, not only the three the estimate used
            triples = [observed_order(h[k - 3:k], q[k - 3:k])[0] for k in range(3, len(h) + 1)]
            fit, first = fit_power_law(h, q), fit_power_law(h, q, order=1.0)
            flag = "" if est.asymptotic else f"  NOT ASYMPTOTIC (p = {est.order:g} assumed): {est.reason}"
            print(f"  {name:>7}: → {est.value:9.4g} (p = {est.order:.2f}, GCI {est.gci:.1%}); orders of consecutive "
                  "triples " + " ".join("–" if p is None else f"{p:.2f}" for p in triples) + "; bias "
                  + " ".join(f"{b:+.1%}" for b in bias) + flag)
            print(f"  {'':>7}  least squares, all levels: → {fit.value:9.4g} ± {fit.value_stderr:.2g} (p = "
                  f"{fit.order:.2f}, residual {fit.residual_std / abs(fit.value):.1%}); bias "
                  + " ".join(f"{b:+.1%}" for b in fit.bias()) + ("" if fit.asymptotic else f"  ({fit.reason})")
                  + f"; with p = 1: → {first.value:9.4g} (residual {first.residual_std / abs(first.value):.1%})")
            for s, b in zip(levels, bias):
                next(r for r in levels_out if (r["gamma"], r["resolution"], r["name"]) == (
                    gamma, s["resolution"], name))["bias"] = float(b)
            row = {"gamma": gamma, "name": name, "extrapolated": est.value, "order": est.order,
                   "asymptotic": est.asymptotic, "reason": est.reason, "gci_finest": est.gci,
                   "finest": float(q[-1]), "finest_across": float(across[-1]),
                   "triple_orders": " ".join("nan" if p is None else f"{p:.3f}" for p in triples)}
            row |= {f"bias_at_{v:g}": float(est.bias(1.0 / v)) for v in bias_at}
            row |= {"fit_value": fit.value, "fit_stderr": fit.value_stderr, "fit_order": fit.order,
                    "fit_residual": fit.residual_std, "fit_asymptotic": fit.asymptotic,
                    "fit1_value": first.value, "fit1_stderr": first.value_stderr, "fit1_residual": first.residual_std}
            row |= {f"fit_bias_at_{v:g}": float(fit.bias(1.0 / v)) for v in bias_at}
            estimates.append(row)
        for kind in ("", "fit_") if bias_at else ():
            print(f"  model bias c h^p/q0 ({'least squares' if kind else 'three-level'}) at "
                  + ", ".join(f"{v:g}" for v in bias_at) + " voxels across: "
                  + "; ".join(f"{e['name']} " + " ".join(f"{e[f'{kind}bias_at_{v:g}']:+.1%}" for v in bias_at)
                              for e in estimates if e["gamma"] == gamma))
    return levels_out, estimates


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
    p.add_argument("--strut-voxels", type=float, nargs="+", default=None,
                   help="resolution study: levels as voxels across the strut diameter of the seed-0 foam at each γ "
                        "(N the smallest grid with cubic voxels reaching it); replaces --levels")
    p.add_argument("--tol", type=float, default=1e-4)
    p.add_argument("--voxel-fraction", action="store_true",
                   help="resolution study: also report the solid fraction of every level's voxel image")
    p.add_argument("--bias-at", type=float, nargs="*", default=[],
                   help="resolution study: also report the model's bias at these voxels across the strut")
    p.add_argument("--cube", action="store_true", help="size study: also the unit cube, 8 cells, N = 48")
    p.add_argument("--maxiter", type=int, default=10000, help="CG iterations per load case")
    p.add_argument("--ci", action="store_true", help="a tiny case (seconds)")
    a = p.parse_args(argv)
    if a.ci:
        a.gammas, a.across, a.voxels_per_cell, a.levels, a.cells = [0.5], [2], 10, [10, 12, 14], 8
        a.seeds = [0, 1] if a.study == "size" else [0]
        a.density = 0.3
        a.strut_voxels = [2.5, 3.0, 3.5] if a.study == "resolution" else None
    a.seeds = a.seeds or ([0, 1, 2] if a.study == "size" else [0])
    a.cache = a.cache or a.out / "cache"
    comm = MPI.COMM_WORLD
    rows = size_study(a, comm) if a.study == "size" else resolution_study(a, comm)
    if comm.rank == 0:
        a.out.mkdir(parents=True, exist_ok=True)
        tables.to_csv(rows, a.out / f"{a.study}.csv")
        if a.study == "size":
            tables.to_csv(report_size(rows), a.out / "size_summary.csv")
        else:
            levels, estimates = report_resolution(rows, a.bias_at, voxel_fractions(rows) if a.voxel_fraction else None)
            tables.to_csv(levels, a.out / "resolution_summary.csv")
            if estimates:
                tables.to_csv(estimates, a.out / "resolution_extrapolation.csv")
        print(f"wrote {a.out / (a.study + '.csv')}")
        off = [r for r in rows if abs(r["measured_density"] - r["density"]) > 0.002]
        if off:
            print(f"FAILED: {len(off)} samples miss their density by more than 0.002")
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
