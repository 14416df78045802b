"""Homogenization commands: ``homogenize`` (one foam or phase image → JSON) and ``table`` (the foam-table sweep).

``fenicsfoam homogenize`` and the ``homogenize`` program are the same command (:data:`HOMOGENIZE`): FFT
homogenization of a stochastic Voronoi foam (in its periodic box: ``--box`` and ``--distance`` choose the foam as for
``table``) or of a phase image, written as JSON. The solid is isotropic
(``--E-solid``, ``--nu-solid``; default 1 and 0.3, normalised like the paper's Fig. 4), the void has zero stiffness.
The JSON holds C (Voigt), engineering constants, the TI fit with l axis = x (the foam's distinct axis) and its error,
the isotropic fit, iterations and residuals per load case, timings, every input and the software versions; the same
constants and fits are printed. It is written to a temporary file beside ``--out`` and renamed, so it is never
half-written; ``--stl`` also writes the foam's surface. Defaults: ``--tol 1e-4`` (tighter tolerances move the
constants by less than the resolution error), ``--threads 1`` (considerate on a shared machine; more threads than
CPUs is a warning). Every argument and output location is checked before any work, naming the argument.
``--discretization`` defaults to ``hex8`` (fully integrated voxels, :data:`HOMOGENIZE_DISCRETIZATION`; ``rotated``
is the shipped tables' one-point scheme), ``--scheme`` to ``pcg`` with the rotated and hex8 discretizations and
``cg`` with the spectral one.

Under ``mpirun -n K`` (K > 1) ``homogenize`` distributes the one RVE over the K ranks
(``homogenize_fft(..., comm=MPI.COMM_WORLD)``, slabs of planes along x, ``pcg`` with the rotated or hex8 discretization
only): rank 0 checks the arguments and outputs, voxelizes the foam (its memory peak holds the whole ``N³`` image,
one byte per voxel) and sends each rank its planes; an ``--image`` is memory-mapped and every rank reads only its
own planes. Rank 0 prints and writes the JSON (and the STL). ``--threads`` is per rank.

``fenicsfoam table`` (:data:`TABLE`) homogenizes every (density, γ, seed) foam of a sweep
(:func:`homogenization.tables.run_sweep`: each finished sample is cached, so an interrupted sweep resumes; under
``mpirun`` the samples are dealt to the ranks) and writes the table's samples, its mean and standard deviation over
seeds and its provenance into ``--out`` (``foam_table_<name>*``, :func:`homogenization.tables.table_paths`). Its
voxels default to ``hex8`` (``--discretization``, :data:`homogenization.tables.DEFAULT_DISCRETIZATION`: the table
``cube_hex8`` by default); ``--discretization rotated`` computes as the shipped tables were made (``foam_table*``).

Exit status: 0 ok; 1 another failure (e.g. a homogenized stiffness that is not positive definite: a solid that
does not percolate); 2 bad arguments, named in the message (before any work); 3 the FFT solver did not converge.

Examples
--------
``homogenize --density 0.18 --gamma 0.1 --cells 20 --resolution 64 --seed 1 --out result.json``

``homogenize --image phases.npy --E-solid 1 --nu-solid 0.3 --out result.json``

``homogenize --density 0.4 --gamma 0.5 --cells 4 --seed 1 --resolution 24 --box equiaxed --distance polyhedral``

``mpirun -n 2 fenicsfoam homogenize --density 0.18 --gamma 0.1 --resolution 384 --out big.json``

``mpirun -n 2 fenicsfoam table --densities 0.15 0.3 --gammas 1 0.1 --seeds 0 1 2 --out out/foam-table``

"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from foambase.cli import Command, main_single, nonempty_path
from foambase.errors import InputError

if TYPE_CHECKING:
    import numpy as np

    from meshes.foam import VoronoiFoam

__all__ = ["HOMOGENIZE", "HOMOGENIZE_DISCRETIZATION", "HOMOGENIZE_THREADS", "HOMOGENIZE_TOL", "TABLE", "build_parser",
           "format_constants", "main"]

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------------
# homogenize
# --------------------------------------------------------------------------------------------------
#: Defaults of ``homogenize``: tolerances below 1e-4 change the constants by less than the foam's seed-to-seed
#: scatter (docs/homogenization.md), and one thread is the considerate default on a shared machine.
HOMOGENIZE_TOL = 1e-4
HOMOGENIZE_THREADS = 1
#: ``homogenize``'s voxels: its images always hold a void phase (0) beside the solid, on which fully integrated
#: voxels reach the converged moduli on a coarser grid in far fewer iterations than the rotated scheme
#: (docs/benchmarks/2026-11-27-void-homogenization.md); ``--discretization rotated`` gives the shipped tables' one.
HOMOGENIZE_DISCRETIZATION = "hex8"


def _foam_kind_arguments(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--box`` and ``--distance`` of ``homogenize`` and ``table``: the RVE box and the foam (struts or walls)."""
    from homogenization import tables

    p.add_argument("--box", choices=("cube", "equiaxed"), default=tables.SweepSettings.box,
                   help="RVE box: the unit cube or (gamma, 1, 1); --resolution counts voxels along y and z")
    p.add_argument("--distance", choices=tables.FOAMS, default=tables.SweepSettings.distance,
                   help="foam: euclidean struts or polyhedral walls")


def _check_foam_grid(box: str, resolution: int, gammas, gamma_option: str) -> None:
    """Check that every ``γ N`` of an equiaxed box is an integer ≥ 2; else an :class:`InputError` naming them.

    The box ``(γ, 1, 1)`` has cubic voxels only then (:meth:`meshes.foam.VoronoiFoam.grid_shape`).
    """
    if box != "equiaxed":
        return
    bad = [g for g in gammas if abs(g * resolution - round(g * resolution)) > 1e-6 or round(g * resolution) < 2]
    if bad:
        raise InputError(f"--box equiaxed has gamma × N voxels along x, which must be an integer >= 2: --resolution "
                         f"{resolution} with {gamma_option} {' '.join(f'{g:g}' for g in bad)} gives "
                         f"{', '.join(f'{g * resolution:g}' for g in bad)}; choose --resolution a multiple of 1/gamma")


def _homogenize_arguments(p: argparse.ArgumentParser) -> None:
    from homogenization.fft import DISCRETIZATIONS, SCHEMES

    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--density", type=float, help="foam: relative density (solid fraction) in (0, 1)")
    source.add_argument("--image", type=nonempty_path,
                        help=".npy phase image (N1, N2, N3): 0 = void, 1 (or True) = solid")
    foam = p.add_argument_group("foam (with --density)")
    foam.add_argument("--gamma", type=float, default=1.0, help="degree of anisotropy in (0, 1]; 1 = isotropic")
    foam.add_argument("--cells", type=int, default=20, help="number of Voronoi cells (>= 2)")
    foam.add_argument("--seed", type=int, default=0, help="random seed (>= 0)")
    foam.add_argument("--resolution", type=int, default=64, help="voxels per side N (>= 8)")
    _foam_kind_arguments(foam)
    foam.add_argument("--stl", type=nonempty_path, default=None,
                      help="also write the foam's surface (solid ∩ box) as a binary STL, at --resolution")
    mat = p.add_argument_group("solid material")
    mat.add_argument("--E-solid", dest="E_solid", type=float, default=1.0, help="Young's modulus of the solid")
    mat.add_argument("--nu-solid", dest="nu_solid", type=float, default=0.3, help="Poisson's ratio of the solid")
    sol = p.add_argument_group("solver")
    sol.add_argument("--scheme", choices=SCHEMES, default=None,
                     help="default: pcg with the rotated and hex8 discretizations, cg with the spectral one; under "
                          "mpirun with more than one rank only pcg (rotated or hex8)")
    sol.add_argument("--discretization", choices=DISCRETIZATIONS, default=HOMOGENIZE_DISCRETIZATION,
                     help=f"default {HOMOGENIZE_DISCRETIZATION}: fully integrated trilinear voxels (moduli from "
                          "above, far fewer iterations on void foams); rotated: one-point trilinear voxels (from "
                          "below; the shipped tables); spectral: Moulinec-Suquet")
    sol.add_argument("--tol", type=float, default=HOMOGENIZE_TOL,
                     help="relative equilibrium residual ||G[σ]||/||G[C:E]||")
    sol.add_argument("--maxiter", type=int, default=None, help="iterations per load case (default: solver's)")
    sol.add_argument("--threads", type=int, default=HOMOGENIZE_THREADS,
                     help="FFTW/kernel threads (per rank under mpirun; more than the CPUs available: a warning)")
    p.add_argument("--out", type=nonempty_path, default=None, help="JSON result file (written atomically)")


def _warn_threads(threads: int | None, per: int = 1) -> None:
    """A warning when ``threads`` exceed the CPUs this process may use, or ``threads`` × ``per`` ranks the machine's.

    Under mpirun each rank is usually bound to its own CPUs, so the per-rank threads are compared with this rank's
    affinity, and all ranks' threads with the machine's CPUs.
    """
    from foambase.threads import cpu_count

    if threads is None:
        return
    if threads > cpu_count():
        logger.warning("--threads %d is more than the %d CPU(s) this process may use: the threads will compete for "
                       "them (slower, not faster)", threads, cpu_count())
    elif threads * per > (os.cpu_count() or 1):
        logger.warning("--threads %d × %d ranks is more than the machine's %d CPU(s): the threads will compete for "
                       "them (slower, not faster)", threads, per, os.cpu_count() or 1)


def _world():
    """``MPI.COMM_WORLD`` if this process runs under mpirun with more than one rank, else None."""
    from mpi4py import MPI

    return MPI.COMM_WORLD if MPI.COMM_WORLD.Get_size() > 1 else None


#: The FFT solver's arrays per voxel (bytes; measured: about 106 for ``pcg``/``rotated``): a floor of what a run needs.
BYTES_PER_VOXEL = 100


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation on this machine (``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_size(n_voxels: int, what: str, ranks: int = 1, bytes_per_voxel: int = BYTES_PER_VOXEL) -> None:
    """:class:`InputError` naming ``what`` if ``n_voxels`` cannot fit in this machine's available memory.

    The need counted is a floor (the solver's arrays, split over ``ranks``), so a refused size never fits.
    """
    need = n_voxels * bytes_per_voxel / max(ranks, 1)
    have = available_memory()
    if have is not None and need > have:
        raise InputError(f"{what}: {n_voxels:.4g} voxels need at least {need / 2**30:.3g} GiB per rank "
                         f"({bytes_per_voxel} bytes per voxel for the FFT solver's arrays), more than the "
                         f"{have / 2**30:.3g} GiB available on this machine")


def check_cells(n_cells: int, resolution: int, what: str) -> None:
    """:class:`InputError` if a foam of ``n_cells`` Voronoi cells is not resolved by ``resolution``³ voxels.

    A cell must span at least 2 voxels across (``n_cells <= resolution³ / 8``); more cells than that cannot be
    voxelized (and the Voronoi construction alone would exhaust memory long before).
    """
    most = resolution ** 3 // 8
    if n_cells > most:
        raise InputError(f"{what}: {n_cells} Voronoi cells in {resolution}³ voxels leave less than 2 voxels across a "
                         f"cell; valid at this resolution: at most {most} cells (or a finer --resolution)")


def _read_image(path: Path, mmap: bool = False) -> np.ndarray:
    """The 0/1 phase image of ``--image``, checked; :class:`InputError` naming the argument.

    With ``mmap`` the image is checked through a read-only memory map and returned as that map (not loaded).
    """
    import numpy as np

    from foambase.files import check_input_file

    if not path.exists():
        raise InputError(f"--image {path}: no such file")
    check_input_file(path, "--image")  # a FIFO, a device or a directory is named, never opened
    try:
        with open(path, "rb") as f:  # the header first: the array's size is checked before anything is allocated
            version = np.lib.format.read_magic(f)
            read = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
            shape, _, dtype = read[version](f)
            offset = f.tell()
    except (OSError, ValueError, EOFError, KeyError):
        shape = None  # not a plain .npy file (e.g. an .npz archive): np.load says what it is below
    if shape is not None:
        n_bytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if offset + n_bytes > path.stat().st_size:
            raise InputError(f"--image {path}: its header announces an array of shape {shape} ({dtype}, "
                             f"{n_bytes} bytes) but the file holds {path.stat().st_size - offset} bytes of data "
                             "(truncated or corrupt)")
        if len(shape) == 3:
            check_size(int(np.prod(shape, dtype=object)), f"--image {path} (shape {shape})")
    try:
        image = np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"--image {path}: cannot read a .npy array ({exc})") from exc
    if not isinstance(image, np.ndarray):  # an .npz archive
        image.close()
        raise InputError(f"--image {path}: an .npz archive, not an .npy array; save one array with numpy.save")
    if image.ndim != 3 or image.size == 0:
        raise InputError(f"--image {path}: expected a non-empty 3-D array (N1, N2, N3), got shape {image.shape}")
    if not (image.dtype == bool or (np.issubdtype(image.dtype, np.integer) and np.isin(image, (0, 1)).all())):
        raise InputError(f"--image {path}: expected bool or 0/1 integer phases (0 = void, 1 = solid), "
                         f"got dtype {image.dtype} with values {np.unique(image)[:5].tolist()}")
    if not image.any():
        raise InputError(f"--image {path}: every voxel is void (0): there is no solid to homogenize")
    return image if mmap else image.astype(np.int8)


def _homogenize_check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Every argument and output before any work (exit status 2, naming the argument); reads ``--image``.

    Under mpirun with more than one rank the files (``--image``, ``--out``, ``--stl``) are checked on rank 0 and
    every rank stops with its verdict; the image is then read by slabs in :func:`_homogenize`.
    """
    import math

    from foambase.files import check_output_file
    from foambase.mpi import on_rank0
    from homogenization.tensors import isotropic_voigt

    def need(ok: bool, message: str):
        if not ok:
            raise InputError(message)
    if args.density is not None:
        need(math.isfinite(args.density) and 0.0 < args.density < 1.0,
             f"--density must be in (0, 1), got {args.density}")
        need(math.isfinite(args.gamma) and 0.0 < args.gamma <= 1.0, f"--gamma must be in (0, 1], got {args.gamma}")
        need(args.cells >= 2, f"--cells must be an integer >= 2, got {args.cells}")
        need(args.seed >= 0, f"--seed must be an integer >= 0, got {args.seed}")
        need(args.resolution >= 8, f"--resolution must be an integer >= 8, got {args.resolution}")
        _check_foam_grid(args.box, args.resolution, [args.gamma], "--gamma")
        check_cells(args.cells, args.resolution, f"--cells {args.cells} --resolution {args.resolution}")
        world = _world()
        check_size(args.resolution ** 3, f"--resolution {args.resolution}",
                   1 if world is None else world.size)
    else:
        need(args.stl is None, "--stl writes a foam's surface: it needs --density (not --image)")
        from homogenization.tables import SweepSettings
        need((args.box, args.distance) == (SweepSettings.box, SweepSettings.distance),
             f"--box {args.box} --distance {args.distance} describe a foam: they need --density (not --image)")
    need(math.isfinite(args.E_solid) and args.E_solid > 0, f"--E-solid must be > 0 and finite, got {args.E_solid}")
    need(math.isfinite(args.nu_solid) and -1.0 < args.nu_solid < 0.5,
         f"--nu-solid must be in (-1, 0.5), got {args.nu_solid}")
    import numpy as np
    with np.errstate(over="ignore", invalid="ignore"):
        largest = float(np.abs(isotropic_voigt(args.E_solid, args.nu_solid)).max())
    per_unit = float(np.abs(isotropic_voigt(1.0, args.nu_solid)).max())
    fp = np.finfo(float)
    need(math.isfinite(largest) and largest >= fp.tiny,
         f"--E-solid {args.E_solid:g}: the solid's largest stiffness entry {largest:.3g} "
         f"{'overflows' if not math.isfinite(largest) else 'is a subnormal number in'} double precision; valid at "
         f"--nu-solid {args.nu_solid:g}: --E-solid from {fp.tiny / per_unit:.3g} to {fp.max / per_unit:.3g} (the "
         "normalised constants, C / E_solid, do not depend on the unit)")
    need(math.isfinite(args.tol) and 0.0 < args.tol < 1.0, f"--tol must be in (0, 1), got {args.tol}")
    need(args.maxiter is None or args.maxiter >= 1, f"--maxiter must be >= 1, got {args.maxiter}")
    need(args.threads >= 1, f"--threads must be >= 1, got {args.threads}")
    args.comm = comm = _world()
    if comm is not None:
        need(args.scheme in (None, "pcg") and args.discretization in ("rotated", "hex8"),
             f"under mpirun with {comm.size} ranks homogenize distributes one RVE, which runs --scheme pcg with "
             f"--discretization rotated or hex8 only; got --scheme {args.scheme} "
             f"--discretization {args.discretization}")
    if comm is None or comm.rank == 0:
        _warn_threads(args.threads)  # per rank: under mpirun a rank's CPUs are those it is bound to

    def files():
        if args.out is not None:
            check_output_file(args.out, "--out")
        if args.stl is not None:
            check_output_file(args.stl, "--stl")
            need(args.out is None or args.stl.resolve() != args.out.resolve(), "--stl and --out name the same file")
        return None if args.image is None else _read_image(args.image, mmap=comm is not None)
    if comm is None:
        args.phases = files()
    else:
        image = on_rank0(comm, files, "checking the input and output files")
        args.phases = None
        args.image_shape = comm.bcast(None if image is None else image.shape)


def _build_foam(args: argparse.Namespace):
    """The ``VoronoiFoam`` of the arguments; a foam the library refuses is an :class:`InputError` naming them."""
    from meshes.foam import VoronoiFoam

    given = (f"--density {args.density:g} --gamma {args.gamma:g} --cells {args.cells} --seed {args.seed} "
             f"--box {args.box} --distance {args.distance}")
    try:
        return VoronoiFoam(n_cells=args.cells, density=args.density, gamma=args.gamma, seed=args.seed,
                           box=None if args.box == "cube" else args.box, distance=args.distance)
    except InputError as exc:
        raise InputError(f"{given}: {exc}") from exc


def _voxelize(args: argparse.Namespace) -> tuple[VoronoiFoam, np.ndarray]:
    """The foam of the arguments and its phase image (int8, cubic voxels); an :class:`InputError` if it is void."""
    import numpy as np

    foam = _build_foam(args)
    image = foam.voxelize(args.resolution).astype(np.int8)
    if not image.any():
        raise InputError(f"--resolution {args.resolution}: no voxel centre lies in the solid (half-thickness "
                         f"{foam.radius:.3g}); use a finer --resolution")
    return foam, image


def _slab(args: argparse.Namespace, comm) -> tuple[np.ndarray, VoronoiFoam | None, tuple | None]:
    """The planes of the phase image (int8) that this rank holds, on rank 0 of a foam run the foam, and the box.

    The foam is voxelized on rank 0 and its planes are scattered, its box lengths broadcast (None: an ``--image``,
    the unit cube); an ``--image`` is memory-mapped by every rank, which reads its own planes only.
    """
    import numpy as np

    from foambase.mpi import on_rank0
    from homogenization.fft import slab_planes

    if args.image is not None:
        start, stop = slab_planes(args.image_shape[0], comm)
        mapped = np.load(args.image, mmap_mode="r", allow_pickle=False)
        return np.asarray(mapped[start:stop]).astype(np.int8), None, None
    foam, image = on_rank0(comm, lambda: _voxelize(args), "voxelizing the foam") or (None, None)
    shape = comm.bcast(None if image is None else image.shape)
    start, stop = slab_planes(shape[0], comm)
    counts = [int(np.diff(slab_planes(shape[0], comm, rank))[0]) * shape[1] * shape[2] for rank in range(comm.size)]
    local = np.empty((stop - start, *shape[1:]), dtype=np.int8)
    comm.Scatterv((image, counts) if comm.rank == 0 else None, local, root=0)
    return local, foam, comm.bcast(None if foam is None else tuple(foam.box.tolist()))


def _versions() -> dict[str, str]:
    from importlib import metadata

    import numpy as np
    import pyfftw
    try:
        own = metadata.version("fenicsfoam")
    except metadata.PackageNotFoundError:  # pragma: no cover - not installed
        own = "unknown"
    return {"fenicsfoam": own, "numpy": np.__version__, "pyfftw": pyfftw.__version__,
            "python": sys.version.split()[0]}


def format_constants(summary: dict) -> str:
    """The engineering constants and the TI fit of a homogenization summary, as printed by ``homogenize``."""
    e = summary["engineering_constants"]
    ti = summary["ti_fit"]
    iso = summary["isotropic_fit"]
    def row(values: dict, keys: tuple[str, ...], fmt: str) -> str:
        return ", ".join(f"{k} = {values[k]:{fmt}}" for k in keys)
    lines = [f"engineering constants: {row(e, ('E1', 'E2', 'E3', 'G23', 'G13', 'G12'), '.5g')}",
             f"                       {row(e, ('nu12', 'nu13', 'nu23', 'nu21', 'nu31', 'nu32'), '.4f')}",
             f"TI fit (l = x):        {row(ti, ('E_t', 'E_l', 'nu_t', 'nu_tl', 'G_l'), '.5g')}; "
             f"error {ti['error']:.3g}",
             f"isotropic fit:         E = {iso['E']:.5g}, nu = {iso['nu']:.4f}; error {iso['error']:.3g}"]
    return "\n".join(lines)


def _homogenize(args: argparse.Namespace) -> int:
    """Homogenize the foam or image; print C, the engineering constants and the TI fit; write the JSON (and STL)."""
    import numpy as np
    from tqdm import tqdm

    from foambase.errors import ComputationError
    from foambase.files import write_json_atomic
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import InadmissibleMaterialError, isotropic_voigt

    comm = getattr(args, "comm", None)
    root = comm is None or comm.rank == 0
    phases, foam, box = args.phases, None, None
    if comm is not None:
        phases, foam, box = _slab(args, comm)
    elif phases is None:
        foam, phases = _voxelize(args)
        box = tuple(foam.box.tolist())
    materials = [np.zeros((6, 6)), isotropic_voigt(args.E_solid, args.nu_solid)]
    with tqdm(total=6, unit="case", desc="homogenize", disable=None if root else True) as bar:
        def progress(case, iteration, residual):
            if case > bar.n:
                bar.update(case - bar.n)
            bar.set_postfix(iteration=iteration, residual=f"{residual:.2e}", refresh=False)
        result = homogenize_fft(phases, materials, scheme=args.scheme, discretization=args.discretization, box=box,
                                tol=args.tol, maxiter=args.maxiter, threads=args.threads, callback=progress,
                                comm=comm, slab=comm is not None)
        bar.update(6 - bar.n)
    try:
        summary = result.to_dict()
    except (InadmissibleMaterialError, np.linalg.LinAlgError) as exc:  # e.g. a solid that does not percolate
        raise ComputationError(f"the homogenized stiffness is not positive definite ({exc}); "
                               f"C = {np.array2string(result.C, precision=4)}") from exc
    if not root:
        return 0
    unused = ("image",) if args.image is None else ("density", "gamma", "cells", "seed", "resolution", "box",
                                                      "distance", "stl")
    inputs = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()
              if k in _HOMOGENIZE_INPUTS and k not in unused}
    solid = float(sum(f for p, f in result.info["volume_fractions"].items() if p != "0"))  # all ranks' voxels
    summary.update(inputs=inputs, solid_fraction=solid, software=_versions())
    print(f"C (Voigt) =\n{np.array2string(result.C, precision=5, suppress_small=True)}")
    print(format_constants(summary))
    print(f"iterations {result.iterations}, wall {result.wall_s:.2f} s")
    if args.stl is not None:
        foam.to_stl(args.stl, args.resolution)
        print(f"written {args.stl}")
    if args.out is not None:
        write_json_atomic(args.out, summary, indent=1)
        print(f"written {args.out}")
    return 0


_HOMOGENIZE_DESCRIPTION = (
    "FFT homogenization of a stochastic Voronoi foam (--density ...) or of a 0/1 phase image (--image), written as "
    "JSON: C (Voigt), engineering constants, the TI fit with l = x and its error, the isotropic fit, iterations, "
    "timings, inputs and software versions. The solid is isotropic (--E-solid, --nu-solid), the void has zero "
    "stiffness.")
_TABLE_DESCRIPTION = (
    "The foam-table sweep: every (density, gamma, seed) foam homogenized by the FFT solver; each finished sample "
    "is cached (an interrupted sweep resumes), under mpirun the samples are dealt to the ranks. Writes the "
    "table's samples, its mean and std over seeds and its provenance into --out: foam_table_cube_hex8*.csv/.json "
    "with the default hex8 voxels, foam_table*.csv/.json (the shipped table's names) with --discretization rotated.")

#: The inputs recorded in the JSON: the arguments of the command (not the dispatcher's).
_HOMOGENIZE_INPUTS = ("density", "image", "gamma", "cells", "seed", "resolution", "box", "distance", "stl",
                      "E_solid", "nu_solid", "scheme", "discretization", "tol", "maxiter", "threads", "out")

HOMOGENIZE = Command("homogenize", "FFT homogenization of a foam (--density) or a phase image (--image) to JSON",
                     _homogenize_arguments, _homogenize, description=_HOMOGENIZE_DESCRIPTION,
                     check=_homogenize_check)


# --------------------------------------------------------------------------------------------------
# table
# --------------------------------------------------------------------------------------------------
def _table_arguments(p: argparse.ArgumentParser) -> None:
    from homogenization import tables

    p.add_argument("--out", type=nonempty_path, required=True, help="directory of the three table files")
    p.add_argument("--cache", type=nonempty_path, default=None, help="one JSON per finished sample; None: OUT/cache")
    p.add_argument("--densities", type=float, nargs="+", default=tables.DENSITIES, help="relative densities")
    p.add_argument("--gammas", type=float, nargs="+", default=tables.GAMMAS, help="degrees of anisotropy γ")
    p.add_argument("--seeds", type=int, nargs="+", default=tables.SEEDS, help="random seeds per (density, γ)")
    p.add_argument("--cells", type=int, default=tables.SweepSettings.n_cells, help="Voronoi cells per RVE")
    p.add_argument("--resolution", type=int, default=tables.SweepSettings.resolution, help="voxels per side N")
    p.add_argument("--tol", type=float, default=tables.SweepSettings.tol, help="FFT (CG) tolerance")
    _foam_kind_arguments(p)
    p.add_argument("--maxiter", type=int, default=None, help="CG iterations per load case (default: solver's)")
    p.add_argument("--discretization", choices=tables.SWEEP_DISCRETIZATIONS, default=tables.DEFAULT_DISCRETIZATION,
                   help=f"voxels, default {tables.DEFAULT_DISCRETIZATION}: hex8 (fully integrated; the table's name "
                        "ends in _hex8) or rotated (one-point, the shipped tables' and their names)")
    p.add_argument("--threads", type=int, default=None,
                   help="FFTW threads per rank; None: CPUs / ranks (more than the CPUs: a warning)")


def _table_check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Every argument and output before any work (exit status 2, naming the argument); builds ``args.settings``."""
    from foambase.files import check_output_dir
    from homogenization import tables

    bad = [d for d in args.densities if not 0.0 < d < 1.0]
    if bad:
        parser.error(f"--densities must lie in (0, 1), got {bad}")
    bad = [g for g in args.gammas if not 0.0 < g <= 1.0]
    if bad:
        parser.error(f"--gammas must lie in (0, 1], got {bad}")
    if any(s < 0 for s in args.seeds):
        parser.error(f"--seeds must be >= 0, got {args.seeds}")
    for option in ("--densities", "--gammas", "--seeds"):
        values = getattr(args, option[2:])
        repeated = sorted({v for v in values if values.count(v) > 1})
        if repeated:
            parser.error(f"{option}: {', '.join(map(str, repeated))} given more than once (a sample would count "
                         "twice in the mean and standard deviation over seeds); give each value once")
    if args.threads is not None and args.threads < 1:
        parser.error(f"--threads must be >= 1, got {args.threads}")
    for option, key in (("--cells", "n_cells"), ("--resolution", "resolution"), ("--tol", "tol")):
        try:  # one at a time, so that the message names the argument
            tables.SweepSettings(**{key: getattr(args, option[2:])})
        except ValueError as exc:
            parser.error(f"{option}: {exc}")
    if args.maxiter is not None and args.maxiter < 1:
        parser.error(f"--maxiter must be >= 1, got {args.maxiter}")
    _check_foam_grid(args.box, args.resolution, args.gammas, "--gammas")
    try:
        check_cells(args.cells, args.resolution, f"--cells {args.cells} --resolution {args.resolution}")
        check_size(args.resolution ** 3, f"--resolution {args.resolution}")
    except InputError as exc:
        parser.error(str(exc))
    args.settings = tables.SweepSettings(n_cells=args.cells, resolution=args.resolution, tol=args.tol, box=args.box,
                                         distance=args.distance, maxiter=args.maxiter,
                                         discretization=args.discretization)
    check_output_dir(args.out, "--out")
    if args.cache is not None:
        check_output_dir(args.cache, "--cache")


def _table(args: argparse.Namespace) -> int:
    """Run the sweep (MPI-aware), then write and print the aggregated table on rank 0."""
    import time
    from datetime import UTC, datetime

    from mpi4py import MPI

    from homogenization import tables

    comm = MPI.COMM_WORLD
    if comm.rank == 0:
        _warn_threads(args.threads, comm.size)
    settings = args.settings
    start = time.perf_counter()
    rows = tables.run_sweep(tables.grid(args.densities, args.gammas, args.seeds), settings,
                            args.cache or args.out / "cache", comm, threads=args.threads)
    wall = time.perf_counter() - start
    if comm.rank != 0:
        return 0
    launcher = f"mpirun -n {comm.size} " if comm.size > 1 else ""
    provenance = {"command": launcher + " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                  "software": _versions(), "date": datetime.now(UTC).isoformat(timespec="seconds"),
                  "ranks": comm.size, "wall_s_this_run": wall,
                  "sample_wall_s_total": float(sum(r["wall_s"] for r in rows)), "n_samples": len(rows),
                  "settings": tables.settings_dict(settings)}
    paths = tables.write_tables(rows, args.out, provenance, settings.name)
    table = tables.aggregate(rows)
    print(f"{len(rows)} samples, {len(table)} (density, gamma) points; table {settings.name!r}, "
          f"N = {settings.resolution}, "
          f"n_cells = {settings.n_cells}, tol = {settings.tol:g}; this run {wall:.0f} s on {comm.size} rank(s)")
    print(tables.format_table(table))
    print("written:", ", ".join(str(p) for p in paths.values()))
    return 0


TABLE = Command("table", "the foam-table sweep: density × γ × seed → foam_table*.csv (resumable, MPI-aware)",
                _table_arguments, _table, description=_TABLE_DESCRIPTION, check=_table_check)


# --------------------------------------------------------------------------------------------------
# The ``homogenize`` program
# --------------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    """The parser of the ``homogenize`` program (the arguments of :data:`HOMOGENIZE`)."""
    parser = argparse.ArgumentParser(prog="homogenize", description=HOMOGENIZE.description,
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _homogenize_arguments(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``homogenize`` console script (= ``fenicsfoam homogenize``); returns the exit status."""
    return main_single(HOMOGENIZE, "homogenize", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
