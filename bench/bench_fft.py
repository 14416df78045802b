"""Benchmark of the FFT homogenization solver (homogenization.fft).

1. Schemes on the study foams (meshes.foam.VoronoiFoam, 20 cells, density 0.18, gamma 1 and 0.1, ``--seed``,
   zero-stiffness void) at ``--sizes`` (default 64 128), tol ``--tol`` (default 1e-4): ``cg`` (strain-based
   Galerkin CG) and ``pcg`` (nodal displacements, Green preconditioner), both of the rotated discretization.
   Iterations per load case, wall time, time per iteration, the FFT time per iteration and the ratio of the two,
   the solver's work arrays, the peak RSS and the largest relative difference of C from the ``cg`` row.
   With ``--image a.npy [b.npy ...]`` (0 = void, 1 = solid) those images are run instead of the foams.
2. The distributed solve (``homogenize_fft(comm=...)``, ``pcg``) of one foam (``--mpi-size``, default 128,
   gamma 1) under ``mpirun -n K`` for K in ``--ranks`` (default 1 2): wall time, iterations, time per
   iteration, work arrays and peak RSS of every rank, C against the serial ``pcg`` row. Skipped with
   ``--ranks`` empty. With ``--mpi-maxiter M`` only load case 1 runs, for M iterations (not converged: a
   measurement of memory and time per iteration at sizes whose full solve would take too long).
3. ``basic`` vs ``cg`` (``spectral`` and ``rotated``) and ``pcg`` on a finite-contrast image: a stiff spherical
   inclusion (contrast ``--contrast``, default 100) at ``--contrast-n`` voxels per side.

4. With ``--sweep N``: what regenerating the shipped foam table (homogenization.tables: 8 densities × 4 gammas ×
   3 seeds, its cells and tol) at resolution N would cost with ``pcg``. A subset of its samples (``--sweep-samples``,
   default densities 0.09, 0.18, 0.34 × gamma 1, 0.1 × seed 0) is homogenized at N; their iterations, divided by
   the iterations the same samples took in the shipped table (``foam_table_samples.csv``, at its own resolution),
   scale the shipped table's total iterations, and the measured CPU time per iteration turns that into hours
   (one core; the sweep spreads samples over MPI ranks, so K cores divide it by about K).

5. With ``--kernels N``: the CPU time (``time.process_time``, minimum of 15 calls, one thread) of each pass of
   one iteration of ``cg`` and of ``pcg`` on the gamma-1 foam at N, and their sum per iteration: the cost model
   behind the rows above, measured in a way that other jobs on a shared machine do not inflate.

Each serial case runs in a fresh process so that its peak RSS (``getrusage``) is its own; every run uses
``--threads`` threads (default 1). Prints a table and writes ``DIR/bench_fft.csv``.
Usage: ``python bench/bench_fft.py --out out/bench [--sizes 64 128] [--ranks 1 2] [--threads 1]``.
"""

import os

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # before numpy loads OpenBLAS: its threads spin against FFTW's

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from foambase.files import atomic_open  # noqa: E402
from homogenization.fft import homogenize_fft  # noqa: E402
from homogenization.tensors import isotropic_voigt  # noqa: E402

COLUMNS = ["case", "N", "scheme", "discretization", "ranks", "converged", "iterations", "total_iterations", "wall_s",
           "cpu_s", "plan_s", "ms_per_iteration", "cpu_ms_per_iteration", "fft_ms_per_iteration",
           "iteration_to_fft_ratio", "work_MB", "peak_rss_MB", "C11", "C22", "C44", "dC_vs_cg"]
SOLID = isotropic_voigt(1.0, 0.3)


def row(name, n, r, cpu_s, ranks=1):
    """A table row from a HomogenizationResult (its C kept under "_C" for the comparisons).

    ``cpu_s``: CPU seconds of the solve (of rank 0 when distributed); with one thread it is what the solve costs
    regardless of how many other jobs share the machine, and ``cpu_ms_per_iteration`` divides it by the
    iterations (set-up included).
    """
    i = r.info
    rss = i.get("peak_rss_bytes_per_rank", [i["peak_rss_bytes"]])
    work = i.get("work_bytes_per_rank", [i["work_bytes"]])
    return {
        "case": name, "N": n, "scheme": i["scheme"], "discretization": i["discretization"], "ranks": ranks,
        "converged": r.converged, "iterations": "/".join(map(str, r.iterations)),
        "total_iterations": sum(r.iterations), "wall_s": r.wall_s, "cpu_s": cpu_s, "plan_s": i["plan_s"],
        "cpu_ms_per_iteration": 1e3 * cpu_s / max(sum(r.iterations), 1),
        "ms_per_iteration": 1e3 * i["time_per_iteration_s"],
        "fft_ms_per_iteration": 1e3 * i["fft_time_per_iteration_s"],
        "iteration_to_fft_ratio": i["iteration_to_fft_ratio"], "work_MB": "/".join(f"{w / 2**20:.0f}" for w in work),
        "peak_rss_MB": "/".join(f"{m / 2**20:.0f}" for m in rss), "C11": r.C[0, 0], "C22": r.C[1, 1],
        "C44": r.C[3, 3], "dC_vs_cg": "", "_C": r.C.tolist(),
    }


def solve(name, phases, materials, scheme, discretization, tol, threads):
    """One case (run in a child process): solver statistics as a table row."""
    cpu = time.process_time()
    r = homogenize_fft(phases, materials, scheme=scheme, discretization=discretization, tol=tol, threads=threads,
                       raise_on_failure=False)
    return row(name, phases.shape[0], r, time.process_time() - cpu)


def in_child(*args):
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(solve, *args).result()


def sphere(n, radius):
    x = (np.arange(n) + 0.5) / n - 0.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return (X**2 + Y**2 + Z**2 < radius**2).astype(np.int8)


def foam_image(gamma, n, cells, seed, density):
    from meshes.foam import VoronoiFoam

    return VoronoiFoam(n_cells=cells, density=density, gamma=gamma, seed=seed).voxelize(n).astype(np.int8)


def foam_cases(sizes, gammas, cells, seed, density):
    try:
        import meshes.foam  # noqa: F401
    except ImportError as exc:
        print(f"foam cases skipped: meshes.foam is not available ({exc}); use --image")
        return
    for gamma in gammas:
        for n in sizes:
            yield f"foam d={density} g={gamma}", foam_image(gamma, n, cells, seed, density)


def relative_gap(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / np.abs(b).max())


# --------------------------------------------------------------------------------------------------
# Distributed runs: this script re-run under mpirun as a child (--mpi-child), one JSON row per run
# --------------------------------------------------------------------------------------------------
def mpi_child(args):
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    from homogenization.fft import slab_planes

    image = None
    if comm.Get_rank() == 0:
        image = foam_image(args.mpi_gamma, args.mpi_size, args.cells, args.seed, args.density)
    shape = comm.bcast(None if image is None else image.shape)
    start, stop = slab_planes(shape[0], comm)
    local = np.empty((stop - start,) + tuple(shape[1:]), dtype=np.int8)
    counts = [int(np.diff(slab_planes(shape[0], comm, r))[0]) * shape[1] * shape[2] for r in range(comm.Get_size())]
    comm.Scatterv((image, counts) if comm.Get_rank() == 0 else None, local, root=0)
    del image
    cpu = time.process_time()
    r = homogenize_fft(local, [0 * SOLID, SOLID], tol=args.tol, threads=args.threads, comm=comm, slab=True,
                       raise_on_failure=False, maxiter=args.mpi_maxiter,
                       macro_strains=np.eye(6)[:1] if args.mpi_maxiter else None)
    cpu = time.process_time() - cpu
    if comm.Get_rank() == 0:
        out = row(f"foam d={args.density} g={args.mpi_gamma} (distributed)", shape[0], r, cpu, comm.Get_size())
        Path(args.mpi_child).write_text(json.dumps(out))


def distributed(args, ranks):
    rows = []
    for k in ranks:
        with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as tmp:
            target = tmp.name
        command = ["mpirun", "-n", str(k), sys.executable, "-m", "mpi4py", __file__, "--mpi-child", target,
                   "--mpi-size", str(args.mpi_size), "--mpi-gamma", str(args.mpi_gamma), "--seed", str(args.seed),
                   "--tol", str(args.tol), "--threads", str(args.threads)]
        if args.mpi_maxiter:
            command += ["--mpi-maxiter", str(args.mpi_maxiter)]
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                   OMPI_MCA_btl_vader_single_copy_mechanism="none", OMPI_MCA_rmaps_base_oversubscribe="1")
        done = subprocess.run(command, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            print(f"distributed run with {k} ranks failed:\n{done.stderr[-2000:]}")
        else:
            rows.append(json.loads(Path(target).read_text()))
            print(format_row(rows[-1]), flush=True)
        os.unlink(target)
    return rows


# --------------------------------------------------------------------------------------------------
def main(args):
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    porous = [np.zeros((6, 6)), SOLID]
    rows = []
    if args.image:
        cases = [(f"image {path.name}", np.load(path).astype(np.int8)) for path in args.image]
    else:
        cases = foam_cases(args.sizes, (1.0, 0.1), args.cells, args.seed, args.density)
    for name, phases in cases:
        reference = None
        for scheme in args.schemes:
            rows.append(in_child(name, phases, porous, scheme, "rotated", args.tol, args.threads))
            if scheme == "cg":
                reference = rows[-1]["_C"]
            elif reference is not None:
                rows[-1]["dC_vs_cg"] = f"{relative_gap(rows[-1]['_C'], reference):.1e}"
            print(format_row(rows[-1]), flush=True)
    if args.ranks:
        serial = next((r for r in rows if r["N"] == args.mpi_size and r["scheme"] == "pcg"
                       and f"g={args.mpi_gamma}" in r["case"]), None)
        for r in distributed(args, args.ranks):
            if serial is not None:
                r["dC_vs_cg"] = f"vs serial pcg {relative_gap(r['_C'], serial['_C']):.1e}"
            rows.append(r)
    if args.sweep:
        sweep_rows, estimate = sweep_estimate(args)
        rows += sweep_rows
    inclusion = sphere(args.contrast_n, 0.3)
    stiff = [SOLID, args.contrast * SOLID]
    for scheme, discretization in (("cg", "rotated"), ("pcg", "rotated"), ("basic", "rotated"), ("cg", "spectral"),
                                   ("basic", "spectral")):
        rows.append(in_child(f"inclusion contrast {args.contrast:g}", inclusion, stiff, scheme, discretization,
                             args.tol, args.threads))
        print(format_row(rows[-1]), flush=True)
    with atomic_open(out / "bench_fft.csv") as f:
        writer = csv.DictWriter(f, COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    print("\n" + "\n".join(table(rows)))
    if args.sweep:
        print(f"\ntable sweep at N={estimate['sweep_N']} with pcg: ≈ {estimate['iterations']:.0f} iterations, "
              f"{estimate['cpu_ms_per_iteration']:.1f} ms CPU each, ≈ {estimate['cpu_hours']:.1f} CPU-hours")
    print(f"\nwritten {out / 'bench_fft.csv'}")


def sweep_estimate(args):
    """Section 4: the cost of the shipped table's sweep at resolution ``args.sweep`` (see the module docstring)."""
    import csv as _csv

    from homogenization import tables

    with open(tables.SAMPLES_CSV, newline="") as fh:
        shipped = list(_csv.DictReader(fh))
    cells, tol = int(shipped[0]["n_cells"]), float(shipped[0]["tol"])
    rows, ratios, cpu, its = [], [], 0.0, 0
    for density, gamma in args.sweep_samples:
        old = next(r for r in shipped if float(r["density"]) == density and float(r["gamma"]) == gamma
                   and int(r["seed"]) == 0)
        r = in_child(f"table sample d={density} g={gamma}", foam_image(gamma, args.sweep, cells, 0, density),
                     [0 * SOLID, SOLID], "pcg", "rotated", tol, args.threads)
        r["dC_vs_cg"] = f"table N={old['resolution']}: {old['iterations']} it"
        rows.append(r)
        print(format_row(r), flush=True)
        ratios.append(r["total_iterations"] / int(old["iterations"]))
        cpu += r["cpu_s"]
        its += r["total_iterations"]
    total = sum(int(r["iterations"]) for r in shipped) * float(np.mean(ratios))
    hours = total * cpu / its / 3600
    print(f"\nsweep at N={args.sweep}: {len(shipped)} samples, {cells} cells, tol {tol:g}; iterations "
          f"{np.mean(ratios):.2f}× the shipped table's (N={shipped[0]['resolution']}, {len(ratios)} samples), "
          f"≈ {total:.0f} iterations × {1e3 * cpu / its:.1f} ms CPU ≈ {hours:.1f} CPU-hours with pcg")
    return rows, {"sweep_N": args.sweep, "iterations": total, "cpu_ms_per_iteration": 1e3 * cpu / its,
                  "cpu_hours": hours}


def _cpu_ms(f, k=15):
    """Minimum CPU time of ``k`` calls of ``f``, in ms."""
    best = np.inf
    for _ in range(k):
        t0 = time.process_time()
        f()
        best = min(best, time.process_time() - t0)
    return 1e3 * best


def _passes(scheme, image):
    """CPU ms of each pass of one iteration of ``scheme`` on ``image``, and of its FFTs."""
    from homogenization.fft import _check_inputs, _make_workspace

    run = _check_inputs(image, [0 * SOLID, SOLID], scheme=scheme, discretization="rotated", box=None, tol=1e-4,
                        maxiter=10, threads=1, macro_strains=None, checkpoints=(), return_fields=False)
    ws = _make_workspace(run)
    rng = np.random.default_rng(0)
    try:
        if scheme == "cg":
            r, p = ws.vectors[0], ws.vectors[1]
            r[...], p[...] = rng.random(r.shape), rng.random(p.shape)
            parts = {"constitutive (+ p update, <p,C:p>)": _cpu_ms(lambda: ws.constitutive(ws.real, p, update=(r, .5))),
                     "FFT forward (6 comp.)": _cpu_ms(ws.forward), "Green kernel": _cpu_ms(lambda: ws.green(0.5)),
                     "FFT backward (6 comp.)": _cpu_ms(ws.backward),
                     "residual update + norm": _cpu_ms(lambda: ws.axpy(np.ones(6), ws.real, r, norm=True))}
            return parts, parts["FFT forward (6 comp.)"] + parts["FFT backward (6 comp.)"]
        ws.p[...], ws.r[...] = rng.random(ws.p.shape), rng.random(ws.r.shape)
        forward = _cpu_ms(ws._forward)
        parts = {"stencil K p (+ <p,Kp>, <C B p>)": _cpu_ms(lambda: ws.apply(True, None)),
                 "residual update": _cpu_ms(lambda: ws.axpby(-0.1, ws.q, 1.0, ws.r)),
                 "FFT pair + Green kernel (K_I^-1, r.z)": _cpu_ms(ws.precondition),
                 "direction update": _cpu_ms(lambda: ws.axpby(1.0, ws.q, 0.5, ws.p, y_ghost=1))}
        return parts, 2 * forward
    finally:
        ws.close()


def kernel_times(args):
    """Section 5: CPU time of every pass of one cg and one pcg iteration (minimum of 15 calls)."""
    image = foam_image(1.0, args.kernels, args.cells, args.seed, args.density)
    totals = {}
    for scheme in ("cg", "pcg"):
        parts, fft = _passes(scheme, image)
        totals[scheme] = sum(parts.values())
        print(f"\n{scheme}, N={args.kernels}, CPU ms per pass (min of 15):")
        for name, t in parts.items():
            print(f"  {name:<40} {t:8.2f}")
        print(f"  {'one iteration':<40} {totals[scheme]:8.2f}   (FFTs ≈ {fft:.2f}: ratio {totals[scheme] / fft:.2f})")
    print(f"\npcg / cg CPU per iteration at N={args.kernels}: {totals['pcg'] / totals['cg']:.2f}")


def _iterations(row):
    """Iterations per load case, flagged when a case stopped at maxiter (reported, never hidden)."""
    return row["iterations"] + ("" if row["converged"] else " NOT CONVERGED")


def format_row(row):
    return (f"{row['case']:<34} N={row['N']:<4} {row['scheme']:<5} {row['discretization']:<8} ranks {row['ranks']} "
            f"it {_iterations(row):<30} (Σ {row['total_iterations']:>5}) wall {row['wall_s']:8.2f} s  "
            f"{row['ms_per_iteration']:8.2f} ms/it  CPU {row['cpu_ms_per_iteration']:8.2f} ms/it  "
            f"FFT {row['fft_ms_per_iteration']:7.2f} ms/it  "
            f"ratio {row['iteration_to_fft_ratio']:5.2f}  work {row['work_MB']} MB  RSS {row['peak_rss_MB']} MB  "
            f"{row['dC_vs_cg']}")


def table(rows):
    head = ("case", "N", "scheme", "ranks", "iterations per load case", "Σ it", "wall s", "ms/it", "CPU ms/it",
            "FFT ms/it", "ratio", "work MB", "peak RSS MB", "ΔC")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        scheme = r["scheme"] if r["discretization"] == "rotated" else f"{r['scheme']} (spectral)"
        lines.append(f"| {r['case']} | {r['N']} | {scheme} | {r['ranks']} | {_iterations(r)} | "
                     f"{r['total_iterations']} | {r['wall_s']:.1f} | {r['ms_per_iteration']:.2f} | "
                     f"{r['cpu_ms_per_iteration']:.2f} | {r['fft_ms_per_iteration']:.2f} | "
                     f"{r['iteration_to_fft_ratio']:.2f} | {r['work_MB']} | "
                     f"{r['peak_rss_MB']} | {r['dC_vs_cg']} |")
    return lines


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    p.add_argument("--sizes", type=int, nargs="*", default=[64, 128], help="foam resolutions N (none: skip)")
    p.add_argument("--schemes", nargs="+", default=["cg", "pcg"], choices=["cg", "pcg"])
    p.add_argument("--cells", type=int, default=20)
    p.add_argument("--density", type=float, default=0.18)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="solver threads per process (default 1)")
    p.add_argument("--image", type=Path, nargs="+", default=None, help=".npy 0/1 images to run instead of the foams")
    p.add_argument("--ranks", type=int, nargs="*", default=[1, 2], help="MPI rank counts of the distributed runs")
    p.add_argument("--mpi-size", type=int, default=128, help="N of the distributed foam")
    p.add_argument("--mpi-gamma", type=float, default=1.0, help="gamma of the distributed foam")
    p.add_argument("--mpi-maxiter", type=int, default=None,
                   help="distributed runs: stop after this many iterations of one load case (memory/time per "
                        "iteration at large N without the full solve)")
    p.add_argument("--mpi-child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--contrast", type=float, default=100.0, help="stiffness contrast of the inclusion case")
    p.add_argument("--contrast-n", type=int, default=32, help="voxels per side of the inclusion case")
    p.add_argument("--tol", type=float, default=1e-4)
    p.add_argument("--sweep", type=int, default=0, help="estimate the shipped table's sweep at this resolution")
    p.add_argument("--kernels", type=int, default=0, help="only time the passes of one iteration at this N")
    p.add_argument("--sweep-samples", type=lambda t: tuple(map(float, t.split(","))), nargs="+",
                   default=[(0.09, 1.0), (0.18, 1.0), (0.34, 1.0), (0.09, 0.1), (0.18, 0.1), (0.34, 0.1)],
                   help="density,gamma pairs of the sweep estimate (seed 0)")
    a = p.parse_args()
    if a.mpi_child:
        mpi_child(a)
    elif a.kernels:
        kernel_times(a)
    else:
        main(a)
