"""``homogenize``: FFT homogenization of a stochastic Voronoi foam or of a phase image, written as JSON.

The solid is isotropic (``--E-solid``, ``--nu-solid``; default 1 and 0.3, normalised like the paper's Fig. 4), the
void has zero stiffness. The JSON holds C (Voigt), engineering constants, the TI fit with l axis = x (the foam's
distinct axis) and its error, the isotropic fit, iterations and residuals per load case, timings, every input and
the software versions. It is written to a temporary file beside ``--out`` and renamed, so it is never half-written.
Bad arguments exit with status 2 and a message naming the argument; a solver failure (no convergence, or a
homogenized stiffness that is not positive definite, e.g. a solid that does not percolate) exits with status 1.

Examples
--------
``homogenize --density 0.18 --gamma 0.1 --cells 20 --resolution 64 --seed 1 --out result.json``

``homogenize --image phases.npy --E-solid 1 --nu-solid 0.3 --out result.json``

"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # OpenBLAS threads spin against FFTW's (DESIGN.md)

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from importlib import metadata  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from foambase.files import write_json_atomic  # noqa: E402
from homogenization.fft import DISCRETIZATIONS, SCHEMES, FFTConvergenceError, homogenize_fft  # noqa: E402
from homogenization.tensors import InadmissibleMaterialError, isotropic_voigt  # noqa: E402

logger = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface (see the module docstring)."""
    p = argparse.ArgumentParser(prog="homogenize", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--density", type=float, help="foam: relative density (solid fraction) in (0, 1)")
    source.add_argument("--image", type=Path, help=".npy phase image (N1, N2, N3): 0 = void, 1 (or True) = solid")
    foam = p.add_argument_group("foam (with --density)")
    foam.add_argument("--gamma", type=float, default=1.0, help="degree of anisotropy in (0, 1]; 1 = isotropic")
    foam.add_argument("--cells", type=int, default=20, help="number of Voronoi cells")
    foam.add_argument("--seed", type=int, default=0, help="random seed")
    foam.add_argument("--resolution", type=int, default=64, help="voxels per side N")
    mat = p.add_argument_group("solid material")
    mat.add_argument("--E-solid", dest="E_solid", type=float, default=1.0, help="Young's modulus of the solid")
    mat.add_argument("--nu-solid", dest="nu_solid", type=float, default=0.3, help="Poisson's ratio of the solid")
    sol = p.add_argument_group("solver")
    sol.add_argument("--scheme", choices=SCHEMES, default="cg")
    sol.add_argument("--discretization", choices=DISCRETIZATIONS, default="rotated")
    sol.add_argument("--tol", type=float, default=1e-6, help="relative equilibrium residual ||G[σ]||/||G[C:E]||")
    sol.add_argument("--maxiter", type=int, default=None, help="iterations per load case (default: solver's)")
    sol.add_argument("--threads", type=int, default=None, help="FFTW/kernel threads (default: available CPUs)")
    p.add_argument("--out", type=Path, default=None, help="JSON result file (written atomically)")
    return p


def _check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    def need(ok: bool, message: str):
        if not ok:
            parser.error(message)  # exit code 2
    if args.density is not None:
        need(0.0 < args.density < 1.0, f"--density must be in (0, 1), got {args.density}")
        need(0.0 < args.gamma <= 1.0, f"--gamma must be in (0, 1], got {args.gamma}")
        need(args.cells >= 1, f"--cells must be >= 1, got {args.cells}")
        need(args.resolution >= 2, f"--resolution must be >= 2, got {args.resolution}")
    else:
        need(args.image.is_file(), f"--image {args.image}: no such file")
    need(np.isfinite(args.E_solid) and args.E_solid > 0, f"--E-solid must be > 0, got {args.E_solid}")
    need(-1.0 < args.nu_solid < 0.5, f"--nu-solid must be in (-1, 0.5), got {args.nu_solid}")
    need(0.0 < args.tol < 1.0, f"--tol must be in (0, 1), got {args.tol}")
    need(args.maxiter is None or args.maxiter >= 1, f"--maxiter must be >= 1, got {args.maxiter}")
    need(args.threads is None or args.threads >= 1, f"--threads must be >= 1, got {args.threads}")
    if args.out is not None:
        need(args.out.parent.is_dir(), f"--out {args.out}: directory {args.out.parent} does not exist")


def _phases(parser: argparse.ArgumentParser, args: argparse.Namespace) -> np.ndarray:
    if args.density is not None:
        try:
            from meshes.foam import VoronoiFoam
        except ImportError as exc:
            parser.error(f"--density: the foam generator meshes.foam is not available ({exc}); use --image")
        foam = VoronoiFoam(n_cells=args.cells, density=args.density, gamma=args.gamma, seed=args.seed)
        return foam.voxelize(args.resolution).astype(np.int8)
    try:
        image = np.load(args.image, allow_pickle=False)
    except (OSError, ValueError) as exc:
        parser.error(f"--image {args.image}: cannot read a .npy array ({exc})")
    if image.ndim != 3:
        parser.error(f"--image {args.image}: expected a 3-D array, got shape {image.shape}")
    if image.dtype != bool and not (np.issubdtype(image.dtype, np.integer) and np.isin(image, (0, 1)).all()):
        parser.error(f"--image {args.image}: expected bool or 0/1 integer phases (0 = void, 1 = solid), "
                     f"got dtype {image.dtype} with values {np.unique(image)[:5].tolist()}")
    return image.astype(np.int8)


def _versions() -> dict[str, str]:
    import pyfftw
    try:
        own = metadata.version("fenicsfoam")
    except metadata.PackageNotFoundError:  # pragma: no cover - not installed
        own = "unknown"
    return {"fenicsfoam": own, "numpy": np.__version__, "pyfftw": pyfftw.__version__,
            "python": sys.version.split()[0]}


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 ok, 1 solver failure; 2 bad arguments via argparse)."""
    from tqdm import tqdm

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    parser = build_parser()
    args = parser.parse_args(argv)
    _check_args(parser, args)
    phases = _phases(parser, args)
    materials = [np.zeros((6, 6)), isotropic_voigt(args.E_solid, args.nu_solid)]
    with tqdm(total=6, unit="case", desc="homogenize", disable=None) as bar:
        def progress(case, iteration, residual):
            if case > bar.n:
                bar.update(case - bar.n)
            bar.set_postfix(iteration=iteration, residual=f"{residual:.2e}", refresh=False)
        try:
            result = homogenize_fft(phases, materials, scheme=args.scheme, discretization=args.discretization,
                                    tol=args.tol, maxiter=args.maxiter, threads=args.threads, callback=progress)
        except FFTConvergenceError as exc:
            print(f"homogenize: error: {exc}", file=sys.stderr)
            return 1
        bar.update(6 - bar.n)
    try:
        summary = result.to_dict()
    except InadmissibleMaterialError as exc:  # e.g. a solid that does not percolate: C is singular
        print(f"homogenize: error: the homogenized stiffness is not positive definite ({exc}); "
              f"C = {np.array2string(result.C, precision=4)}", file=sys.stderr)
        return 1
    unused = ("image",) if args.image is None else ("density", "gamma", "cells", "seed", "resolution")
    inputs = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k not in unused}
    summary.update(inputs=inputs, solid_fraction=float(phases.mean()), software=_versions())
    ti = summary["ti_fit"]
    print(f"C (Voigt) =\n{np.array2string(result.C, precision=5, suppress_small=True)}")
    print("TI fit (l = x): " + ", ".join(f"{k} = {ti[k]:.5g}" for k in ("E_t", "E_l", "nu_t", "nu_tl", "G_l"))
          + f"; error {ti['error']:.3g}")
    print(f"iterations {result.iterations}, wall {result.wall_s:.2f} s")
    if args.out is not None:
        write_json_atomic(args.out, summary, indent=1)
        print(f"written {args.out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
