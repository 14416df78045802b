"""Benchmark: homogenizing void foams with one-point (``rotated``) and fully integrated (``hex8``) trilinear voxels.

Both are solved by the nodal Green-preconditioned CG (``scheme="pcg"`` of :func:`homogenization.fft.homogenize_fft`)
with a zero-stiffness void and a solid of E = 1, ν = 0.3, on the foams ``VoronoiFoam(--cells, --density, γ,
seed=--seed, box="equiaxed", distance=...)`` — struts (``euclidean``) and walls (``polyhedral``), γ = 1 and 0.1 —
each at two grids: ``--cubic N N'`` (struts; walls ``--cubic-walls``, default 64 96) for γ = 1 (N³ voxels) and
``--flat A B`` for γ = 0.1 (grids ``(A/5) × A × A``,
voxels twice as long along y and z as along x, as the shipped wall-foam table). Every run is one fresh process
(its peak RSS is its own), one thread, tolerance ``--tol``.

Printed and written to ``OUT/bench_void_methods.csv`` per run: iterations per load case and in total, CPU seconds of
the solving process (``time.process_time``: robust on a shared machine, where wall times are not), CPU ms per
iteration, the solver's work arrays and the process's peak RSS, the diagonal of C, the solid's hinges and islands
(:mod:`homogenization.connectivity`), and the moduli's difference from a reference:

``ref``: per foam, each discretization extrapolated to h → 0 from its two grids with the first order of a voxel
staircase (``q0 = q_f + (q_f − q_c)/(r − 1)``, r the grid ratio), and the reference the mean of the two
extrapolations (of C; the engineering moduli are then those of the extrapolated C). ``dE_max`` is the largest
relative difference of the six engineering moduli E1, E2, E3, G23, G13, G12 (from the compliance) from the
reference's (the soft moduli of γ = 0.1 count as much as the stiff ones); ``dC_fro`` the Frobenius difference of
C relative to the reference's norm. ``ref_spread`` is the largest relative difference of the two extrapolations'
moduli (how much the reference itself is to be trusted). ``--reference-moduli E1 E2 E3 G23 G13 G12`` instead gives
the reference's engineering moduli (e.g. an extrapolation from finer grids than a run can afford): ``dE_max`` is then
measured against them (``dC_fro`` is left empty).

With ``--hinges``: instead, the hinges and islands (:func:`homogenization.connectivity.connectivity`) of the foams
of the shipped tables at their own resolutions (``cube``: 8 cells, N = 48, densities 0.09, 0.18, 0.34; ``equiaxed``:
27 cells, γ = 1 at N = 60, γ = 0.1 on 15 × 150 × 150; ``equiaxed_polyhedral``: 8 cells, γ = 1 at N = 96, γ = 0.1 on
60 × 300 × 300; density 0.18 where not said; γ = 1 and 0.1; ``--hinge-seeds``, default 0 1 2), written to
``OUT/hinges.csv``.

With ``--inclusion``: instead, the finite-contrast case (no void): a sphere of radius 0.3 (11 % by volume) of an
isotropic solid ``--contrasts`` times as stiff as the matrix (E = 1, both ν = 0.3), centred in the unit cube, at the
grids ``--inclusion-grids`` N³, both methods, tolerance ``--inclusion-tol``; per run the iterations, CPU seconds and
ms per iteration, C11, C12, C44 and the largest relative difference of those three from the mean of the two methods'
first-order extrapolations from their two finest grids (a sphere's voxel staircase converges about as 1/N). Written
to ``OUT/inclusion.csv``.

With ``--gamg``: instead, multigrid on the voxel finite-element problem: the wall foam ``VoronoiFoam(8, 0.3, 1,
seed=11, box="equiaxed", distance="polyhedral")`` at 48³, meshed by :func:`meshes.voxel.voxel_mesh` (the whole box,
void voxels at 1e-4 E_s) and solved by :func:`homogenization.fem.homogenize_fem` (Q1, CG + GAMG with the rigid-body
near-null space, :func:`homogenization.fem.iterative_options`), beside ``pcg`` with both discretizations on the same
image (zero-stiffness void), tol ``--tol``: iterations, CPU seconds of this process for each (the FEM's from the mesh
to C), the FEM's own timings and C11.

Usage: ``python bench/bench_void_methods.py --out out/void [--foams walls struts] [--gammas 1 0.1]
[--cubic 32 48] [--flat 100 150] [--methods rotated hex8] [--tol 1e-3]``.
"""

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # before numpy loads OpenBLAS: its threads spin against FFTW's

import argparse  # noqa: E402
import csv  # noqa: E402
import multiprocessing  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from foambase.files import atomic_open  # noqa: E402

COLUMNS = ["foam", "gamma", "grid", "voxels", "method", "iterations", "total_iterations", "cpu_s", "cpu_ms_per_it",
           "work_MB", "peak_rss_MB", "E1", "E2", "E3", "G23", "G13", "G12", "dE_max", "dE", "dC_fro", "ref_spread",
           "hinges", "hinged_islands", "floating_islands", "C"]
DISTANCE = {"struts": "euclidean", "walls": "polyhedral"}
MODULI = ("E1", "E2", "E3", "G23", "G13", "G12")


def moduli(C) -> np.ndarray:
    from homogenization.tensors import InadmissibleMaterialError, engineering_constants

    try:
        e = engineering_constants(np.asarray(C))
    except InadmissibleMaterialError:  # a voxel solid that does not percolate (walls one voxel across)
        return np.full(len(MODULI), np.nan)
    return np.array([e[m] for m in MODULI])


def _grid(gamma: float, size: int):
    return (size,) * 3 if gamma == 1.0 else (size // 5, size, size)


def foam_image(foam: str, gamma: float, size: int, a: dict, cache: Path) -> tuple[Path, tuple]:
    """The voxelized foam (saved once in ``cache`` for the methods that run it) and its box."""
    from meshes.foam import VoronoiFoam

    vf = VoronoiFoam(a["cells"], a["density"], gamma, seed=a["seed"], box="equiaxed", distance=DISTANCE[foam])
    path = cache / f"{foam}_g{gamma:g}_{size}_c{a['cells']}_d{a['density']:g}_s{a['seed']}.npy"
    if not path.exists():
        image = vf.voxelize(_grid(gamma, size) if gamma != 1.0 else size, cubic=gamma == 1.0).astype(np.int8)
        partial = path.with_suffix(f".{os.getpid()}.partial")  # renamed when whole: runs may share the cache
        with open(partial, "wb") as f:
            np.save(f, image)
        os.replace(partial, path)
    return path, tuple(float(b) for b in vf.box)


def run_one(foam: str, gamma: float, size: int, method: str, a: dict, path: Path, box: tuple) -> dict:
    """One homogenization in this (fresh) process."""
    import resource

    from homogenization.connectivity import connectivity
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt

    image = np.load(path)
    topology = connectivity(image)
    t0 = time.process_time()
    r = homogenize_fft(image, [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)], discretization=method, tol=a["tol"],
                       box=box, maxiter=a["maxiter"], threads=1, raise_on_failure=False)
    cpu = time.process_time() - t0
    total = int(sum(r.iterations))
    return {"foam": foam, "gamma": gamma, "grid": "x".join(map(str, image.shape)), "voxels": int(image.size),
            "method": method, "iterations": "/".join(map(str, r.iterations)), "total_iterations": total,
            "cpu_s": cpu, "cpu_ms_per_it": 1e3 * cpu / max(total, 1), "work_MB": r.info["work_bytes"] / 2**20,
            "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "C": r.C.tolist(), "converged": r.converged, "hinges": topology.hinges,
            "hinged_islands": topology.hinged_islands, "floating_islands": topology.floating_islands}


def given_reference(rows: list[dict], reference) -> None:
    """Fill ``dE_max`` of every row against the given engineering moduli (``--reference-moduli``)."""
    ref = np.asarray(reference, dtype=float)
    for r in rows:
        r["dE_max"] = float(np.max(np.abs(moduli(r["C"]) - ref) / np.abs(ref)))
        r["dE"] = "/".join(f"{d:+.3f}" for d in (moduli(r["C"]) - ref) / np.abs(ref))


def references(rows: list[dict]) -> None:
    """Fill ``dC_diag``, ``dC_fro`` and ``ref_spread`` of every row (see the module docstring)."""
    for key in {(r["foam"], r["gamma"]) for r in rows}:
        group = [r for r in rows if (r["foam"], r["gamma"]) == key]
        extrapolated = []
        for method in {r["method"] for r in group}:
            levels = sorted((r for r in group if r["method"] == method), key=lambda r: r["voxels"])
            if len(levels) < 2:
                continue
            coarse, fine = np.array(levels[-2]["C"]), np.array(levels[-1]["C"])
            ratio = (levels[-1]["voxels"] / levels[-2]["voxels"]) ** (1 / 3)
            extrapolated.append(fine + (fine - coarse) / (ratio - 1.0))
        if not extrapolated:
            continue
        ref = np.mean(extrapolated, axis=0)
        d_ref = moduli(ref)
        spread = float("nan")
        if len(extrapolated) > 1:
            spread = float(np.max(np.abs(moduli(extrapolated[0]) - moduli(extrapolated[1])) / np.abs(d_ref)))
        for r in group:
            C = np.array(r["C"])
            r["dE_max"] = float(np.max(np.abs(moduli(C) - d_ref) / np.abs(d_ref)))
            r["dC_fro"] = float(np.linalg.norm(C - ref) / np.linalg.norm(ref))
            r["ref_spread"] = spread


#: (table, cells, box, distance, γ, grid: N (cubic voxels) or (N1, N2, N3), densities)
SHIPPED = [("cube", 8, "cube", "euclidean", g, 48, (0.09, 0.18, 0.34)) for g in (1.0, 0.1)] + [
    ("equiaxed", 27, "equiaxed", "euclidean", 1.0, 60, (0.18,)),
    ("equiaxed", 27, "equiaxed", "euclidean", 0.1, (15, 150, 150), (0.18,)),
    ("equiaxed_polyhedral", 8, "equiaxed", "polyhedral", 1.0, 96, (0.18,)),
    ("equiaxed_polyhedral", 8, "equiaxed", "polyhedral", 0.1, (60, 300, 300), (0.18,))]


def hinge_rows(seeds) -> list[dict]:
    from homogenization.connectivity import connectivity
    from meshes.foam import VoronoiFoam

    rows = []
    for table, cells, box, distance, gamma, grid, densities in SHIPPED:
        for density in densities:
            for seed in seeds:
                vf = VoronoiFoam(cells, density, gamma, seed=seed, box=None if box == "cube" else box,
                                 distance=distance)
                image = vf.voxelize(grid, cubic=not isinstance(grid, tuple))
                r = connectivity(image)
                row = {"table": table, "density": density, "gamma": gamma, "seed": seed,
                       "grid": "x".join(map(str, image.shape))} | r.as_dict()
                row["edge_contacts"] = "/".join(map(str, row["edge_contacts"]))
                rows.append(row)
                print(f"{table:20s} ρ={density:<5g} γ={gamma:<4g} seed {seed} {row['grid']:>11s}: solid "
                      f"{r.solid_voxels:9d}  edge-only {row['edge_contacts']:>14s}  "
                      f"corner-only {r.corner_contacts:5d}  "
                      f"components {r.components:4d}  hinged islands {r.hinged_islands:3d} ({r.hinged_island_voxels} "
                      f"voxels)  floating {r.floating_islands:3d} ({r.floating_island_voxels} voxels)", flush=True)
    return rows


def inclusion_rows(contrasts, grids, tol: float) -> list[dict]:
    """The finite-contrast sphere at every grid and contrast, both methods, in this process (see the docstring)."""
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt

    rows = []
    for contrast in contrasts:
        materials = [isotropic_voigt(1.0, 0.3), isotropic_voigt(float(contrast), 0.3)]
        for n in grids:
            x = (np.arange(n) + 0.5) / n - 0.5
            X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
            image = (X**2 + Y**2 + Z**2 < 0.3**2).astype(np.int8)
            for method in ("rotated", "hex8"):
                t0 = time.process_time()
                r = homogenize_fft(image, materials, discretization=method, tol=tol, threads=1)
                cpu = time.process_time() - t0
                total = int(sum(r.iterations))
                rows.append({"contrast": contrast, "N": n, "method": method, "total_iterations": total,
                             "cpu_s": cpu, "cpu_ms_per_it": 1e3 * cpu / max(total, 1), "C11": r.C[0, 0],
                             "C12": r.C[0, 1], "C44": r.C[3, 3]})
        group = [r for r in rows if r["contrast"] == contrast]
        limits = []
        for method in ("rotated", "hex8"):
            coarse, fine = sorted((r for r in group if r["method"] == method), key=lambda r: r["N"])[-2:]
            ratio = fine["N"] / coarse["N"]
            limits.append(np.array([fine[c] + (fine[c] - coarse[c]) / (ratio - 1) for c in ("C11", "C12", "C44")]))
        ref = np.mean(limits, axis=0)
        for r in group:
            r["error"] = float(np.max(np.abs(np.array([r["C11"], r["C12"], r["C44"]]) - ref) / np.abs(ref)))
            r["ref_spread"] = float(np.max(np.abs(limits[0] - limits[1]) / np.abs(ref)))
            print(f"contrast {contrast:<6g} N={r['N']:4d} {r['method']:7s} it {r['total_iterations']:5d}  CPU "
                  f"{r['cpu_s']:7.2f} s ({r['cpu_ms_per_it']:6.2f} ms/it)  C11 {r['C11']:.5f} C12 {r['C12']:.5f} "
                  f"C44 {r['C44']:.5f}  error {r['error']:.4f}  (extrapolations differ by {r['ref_spread']:.4f})",
                  flush=True)
    return rows


def gamg_rows(tol: float) -> list[dict]:
    """The voxel FE problem with GAMG against pcg on one wall foam (see the module docstring)."""
    from mpi4py import MPI

    from homogenization.fem import homogenize_fem, iterative_options
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt
    from meshes.foam import VoronoiFoam
    from meshes.voxel import SOLID, VOID, voxel_mesh

    foam = VoronoiFoam(8, 0.3, 1.0, seed=11, box="equiaxed", distance="polyhedral")
    image = foam.voxelize(48, cubic=True).astype(np.int8)
    solid = isotropic_voigt(1.0, 0.3)
    rows = []
    t0 = time.process_time()
    mesh, tags = voxel_mesh(image.astype(bool), MPI.COMM_SELF)
    r = homogenize_fem(mesh, tags, {SOLID: solid, VOID: 1e-4 * solid}, petsc_options=iterative_options(),
                       comm=MPI.COMM_SELF)
    rows.append({"method": "fem-q1-gamg", "iterations": "/".join(map(str, r.iterations)),
                 "cpu_s": time.process_time() - t0, "C11": float(r.C[0, 0]), "n_dofs": r.info["n_dofs"],
                 "timings": {k: (round(v, 2) if isinstance(v, float) else v) for k, v in r.info["timings"].items()}})
    for method in ("rotated", "hex8"):
        t0 = time.process_time()
        r = homogenize_fft(image, [np.zeros((6, 6)), solid], discretization=method, tol=tol, threads=1,
                           box=tuple(float(b) for b in foam.box))
        rows.append({"method": f"pcg-{method}", "iterations": "/".join(map(str, r.iterations)),
                     "cpu_s": time.process_time() - t0, "C11": float(r.C[0, 0])})
    for row in rows:
        print(f"{row['method']:12s} it {row['iterations']:>28s}  CPU {row['cpu_s']:7.1f} s  C11 {row['C11']:.4f}"
              + (f"  dofs {row['n_dofs']}  timings {row['timings']}" if "timings" in row else ""), flush=True)
    return rows


def write_rows(rows: list[dict], path: Path) -> None:
    """Rows as CSV (the first row's columns), written atomically; says where."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {path}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--foams", nargs="+", choices=tuple(DISTANCE), default=list(DISTANCE))
    p.add_argument("--gammas", type=float, nargs="+", default=[1.0, 0.1])
    p.add_argument("--cubic", type=int, nargs="+", default=[32, 48], help="N of the struts' γ = 1 grids N³")
    p.add_argument("--cubic-walls", type=int, nargs="+", default=[64, 96], help="N of the walls' γ = 1 grids N³")
    p.add_argument("--flat", type=int, nargs="+", default=[100, 150], help="A of the γ = 0.1 grids (A/5) × A × A")
    p.add_argument("--methods", nargs="+", choices=("rotated", "hex8"), default=["rotated", "hex8"])
    p.add_argument("--cells", type=int, default=8)
    p.add_argument("--density", type=float, default=0.18)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tol", type=float, default=1e-3)
    p.add_argument("--maxiter", type=int, default=20000)
    p.add_argument("--hinges", action="store_true", help="count hinges and islands of the shipped tables' foams")
    p.add_argument("--hinge-seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--inclusion", action="store_true", help="the finite-contrast sphere instead of the foams")
    p.add_argument("--contrasts", type=float, nargs="+", default=[20.0, 0.05])
    p.add_argument("--inclusion-grids", type=int, nargs="+", default=[16, 32, 64])
    p.add_argument("--inclusion-tol", type=float, default=1e-5)
    p.add_argument("--reference-moduli", type=float, nargs=6, default=None, metavar="M",
                   help="E1 E2 E3 G23 G13 G12 of the reference (default: extrapolated from the runs)")
    p.add_argument("--gamg", action="store_true", help="voxel FEM + GAMG against pcg on one wall foam")
    a = p.parse_args(argv)
    if a.gamg:
        gamg_rows(a.tol)
        return 0
    if a.inclusion:
        write_rows(inclusion_rows(a.contrasts, a.inclusion_grids, a.inclusion_tol), a.out / "inclusion.csv")
        return 0
    if a.hinges:
        write_rows(hinge_rows(a.hinge_seeds), a.out / "hinges.csv")
        return 0
    settings = {"cells": a.cells, "density": a.density, "seed": a.seed, "tol": a.tol, "maxiter": a.maxiter}
    jobs = [(foam, gamma, size, method) for foam in a.foams for gamma in a.gammas
            for size in ((a.cubic if foam == "struts" else a.cubic_walls) if gamma == 1.0 else a.flat)
            for method in a.methods]
    rows = []
    ctx = multiprocessing.get_context("spawn")
    images = a.out / "images"
    images.mkdir(parents=True, exist_ok=True)
    for job in jobs:  # one fresh process per run: its peak RSS is its own
        path, box = foam_image(*job[:3], settings, images)
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
            row = pool.submit(run_one, *job, settings, path, box).result()
        rows.append(row)
        print(f"{row['foam']:6s} γ={row['gamma']:<4g} {row['grid']:>12s} {row['method']:7s} "
              f"it {row['iterations']:>32s} = {row['total_iterations']:6d}  CPU {row['cpu_s']:8.1f} s "
              f"({row['cpu_ms_per_it']:6.2f} ms/it)  RSS {row['peak_rss_MB']:6.0f} MB  "
              f"E1..G12 {[float(f'{m:.4g}') for m in moduli(row['C'])]}"
              f"{'' if row['converged'] else '  NOT CONVERGED'}",
              flush=True)
    if a.reference_moduli:
        given_reference(rows, a.reference_moduli)
    else:
        references(rows)
    print(f"\n{'foam':6s} {'γ':>4s} {'grid':>12s} {'method':7s} {'Σ it':>6s} {'CPU s':>8s} {'ms/it':>6s} "
          f"{'RSS MB':>6s} {'dE_max':>8s} {'dC_fro':>8s} {'spread':>7s} {'hinges':>6s}")
    for r in rows:
        C = np.array(r["C"])
        r.update(dict(zip(MODULI, map(float, moduli(C)))))
        r["C"] = " ".join(repr(float(c)) for c in C.ravel())
        print(f"{r['foam']:6s} {r['gamma']:4g} {r['grid']:>12s} {r['method']:7s} {r['total_iterations']:6d} "
              f"{r['cpu_s']:8.1f} {r['cpu_ms_per_it']:6.2f} {r['peak_rss_MB']:6.0f} {r.get('dE_max', np.nan):8.3f} "
              f"{r.get('dC_fro', np.nan):8.3f} {r.get('ref_spread', np.nan):7.3f} {r['hinges']:6d}")
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / "bench_void_methods.csv"
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
