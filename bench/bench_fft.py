"""Benchmark of the FFT homogenization solver (homogenization.fft).

1. Foams (meshes.foam.VoronoiFoam, density 0.18, gamma 0.1 and 1, 20 cells) at N = 32, 64, 128 with cg/rotated:
   iterations per load case, wall time, time per iteration, the ratio of the time per iteration to the time of
   the two batched FFTs that iteration performs (goal <= 1.5), the solver's work arrays and the peak RSS.
   With ``--image a.npy [b.npy ...]`` (0 = void, 1 = solid) those images are run instead of the foams.
2. ``basic`` vs ``cg`` (both ``spectral`` and ``rotated``) on a finite-contrast image: a stiff spherical inclusion
   (contrast ``--contrast``, default 100) at ``--contrast-n`` voxels per side.

Each case runs in a fresh process so that its peak RSS (``getrusage``) is its own. Prints a table and writes
``DIR/bench_fft.csv``. Usage: ``python bench/bench_fft.py --out out/bench [--sizes 32 64] [--threads 2]``.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # OpenBLAS threads spin against FFTW's (docs/installation.md)

import argparse
import csv
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from homogenization.fft import homogenize_fft
from homogenization.tensors import isotropic_voigt

COLUMNS = ["case", "N", "scheme", "discretization", "converged", "iterations", "wall_s", "plan_s", "ms_per_iteration",
           "fft_ms_per_iteration", "iteration_to_fft_ratio", "work_MB", "peak_rss_MB", "C11", "C22", "C44"]


def solve(name, phases, materials, scheme, discretization, tol, threads):
    """One case (run in a child process): solver statistics as a table row."""
    r = homogenize_fft(phases, materials, scheme=scheme, discretization=discretization, tol=tol, threads=threads,
                       raise_on_failure=False)
    i = r.info
    return {
        "case": name, "N": phases.shape[0], "scheme": scheme, "discretization": discretization,
        "converged": r.converged,
        "iterations": "/".join(map(str, r.iterations)), "wall_s": r.wall_s, "plan_s": i["plan_s"],
        "ms_per_iteration": 1e3 * i["time_per_iteration_s"],
        "fft_ms_per_iteration": 1e3 * i["fft_time_per_iteration_s"],
        "iteration_to_fft_ratio": i["iteration_to_fft_ratio"], "work_MB": i["work_bytes"] / 2**20,
        "peak_rss_MB": i["peak_rss_bytes"] / 2**20, "C11": r.C[0, 0], "C22": r.C[1, 1], "C44": r.C[3, 3],
    }


def in_child(*args):
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(solve, *args).result()


def sphere(n, radius):
    x = (np.arange(n) + 0.5) / n - 0.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return (X**2 + Y**2 + Z**2 < radius**2).astype(np.int8)


def foam_images(sizes, gammas, cells, seed, density):
    try:
        from meshes.foam import VoronoiFoam
    except ImportError as exc:
        print(f"foam cases skipped: meshes.foam is not available ({exc}); use --image")
        return
    for gamma in gammas:
        foam = VoronoiFoam(n_cells=cells, density=density, gamma=gamma, seed=seed)
        for n in sizes:
            yield f"foam d={density} g={gamma}", foam.voxelize(n).astype(np.int8)


def main(out: Path, sizes, threads, image, contrast, contrast_n, tol):
    out.mkdir(parents=True, exist_ok=True)
    solid = isotropic_voigt(1.0, 0.3)
    porous = [np.zeros((6, 6)), solid]
    rows = []
    if image:
        cases = [(f"image {path.name}", np.load(path).astype(np.int8)) for path in image]
    else:
        cases = foam_images(sizes, (0.1, 1.0), cells=20, seed=1, density=0.18)
    for name, phases in cases:
        rows.append(in_child(name, phases, porous, "cg", "rotated", tol, threads))
        print(format_row(rows[-1]), flush=True)
    inclusion = sphere(contrast_n, 0.3)
    stiff = [solid, contrast * solid]
    for scheme in ("cg", "basic"):
        for discretization in ("rotated", "spectral"):
            rows.append(in_child(f"inclusion contrast {contrast:g}", inclusion, stiff, scheme, discretization, tol,
                                 threads))
            print(format_row(rows[-1]), flush=True)
    with open(out / "bench_fft.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    print("\n" + "\n".join(table(rows)))
    print(f"\nwritten {out / 'bench_fft.csv'}")


def _iterations(row):
    """Iterations per load case, flagged when a case stopped at maxiter (reported, never hidden)."""
    return row["iterations"] + ("" if row["converged"] else " NOT CONVERGED")


def format_row(row):
    return (f"{row['case']:<26} N={row['N']:<4} {row['scheme']:<5} {row['discretization']:<8} "
            f"it {_iterations(row):<34} wall {row['wall_s']:8.2f} s  {row['ms_per_iteration']:8.2f} ms/it  "
            f"FFT {row['fft_ms_per_iteration']:8.2f} ms/it  ratio {row['iteration_to_fft_ratio']:5.2f}  "
            f"work {row['work_MB']:7.1f} MB  RSS {row['peak_rss_MB']:7.1f} MB")


def table(rows):
    head = ("case", "N", "scheme", "disc.", "iterations per load case", "wall s", "ms/it", "FFT ms/it", "ratio",
            "work MB", "RSS MB")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(f"| {r['case']} | {r['N']} | {r['scheme']} | {r['discretization']} | {_iterations(r)} | "
                     f"{r['wall_s']:.2f} | {r['ms_per_iteration']:.2f} | {r['fft_ms_per_iteration']:.2f} | "
                     f"{r['iteration_to_fft_ratio']:.2f} | {r['work_MB']:.0f} | {r['peak_rss_MB']:.0f} |")
    return lines


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128], help="foam resolutions N")
    p.add_argument("--threads", type=int, default=None, help="solver threads (default: available CPUs)")
    p.add_argument("--image", type=Path, nargs="+", default=None, help=".npy 0/1 images to run instead of the foams")
    p.add_argument("--contrast", type=float, default=100.0, help="stiffness contrast of the inclusion case")
    p.add_argument("--contrast-n", type=int, default=32, help="voxels per side of the inclusion case")
    p.add_argument("--tol", type=float, default=1e-6)
    a = p.parse_args()
    main(a.out, a.sizes, a.threads, a.image, a.contrast, a.contrast_n, a.tol)
