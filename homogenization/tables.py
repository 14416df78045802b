"""Homogenized foam tables: C_hom against relative density × anisotropy γ × seed (paper Fig. 4).

One *sample* is one foam ``meshes.foam.VoronoiFoam(n_cells, density, gamma, seed, box=, distance=)`` voxelized
with cubic voxels (``N`` along the longest box edge; or, opted into with ``cubic=False``, an explicit grid of
non-cubic voxels) and homogenized in its periodic box by
:func:`homogenization.fft.homogenize_fft` (rotated scheme, ``scheme="pcg"``: the iterates of the strain CG
``"cg"`` with which the shipped tables were made, at half the FFT work) with an isotropic solid of
``E_s = 1`` and ``ν_s = 0.3`` and a void of zero stiffness, so every modulus in the table is already
normalised by the solid's Young's modulus (it scales linearly with ``E_s``; ``ν_s`` is fixed).

A row holds the inputs, the measured solid fraction, the 21 independent entries of the Voigt ``C``, the
engineering constants (E1..E3, G23, G13, G12, ν_ij), the closest transversely isotropic stiffness with its
*l* axis along the foam's distinct axis x (``ti_E_t, ti_E_l, ti_nu_t, ti_nu_tl, ti_G_l`` and its relative
error ``ti_error``), the closest isotropic one (``iso_E, iso_nu, iso_error``), the CG iterations, the wall
time and the software version. :func:`aggregate` reduces the samples to the mean and the sample standard
deviation over seeds per (density, γ); ``fenicsfoam.materials.foam_material`` interpolates that table.

Every sweep setting of box and foam writes a table of its own name (:attr:`SweepSettings.name`,
:func:`table_paths`): ``cube`` (the Euclidean strut foam in the unit cube, ``foam_table.csv``, the default),
``equiaxed`` (the same foam in the box ``(γ, 1, 1)``, ``foam_table_equiaxed.csv``), ``equiaxed_polyhedral`` (the
polyhedral wall foam), each with its samples and provenance. :func:`shipped_tables` lists those in
:data:`DATA_DIR`.

The sweep (:func:`run_sweep`) caches every finished sample as one JSON file named after its inputs and a hash of
their exact values (written to a temporary file and renamed, so a file present is complete): an interrupted sweep
resumes where it stopped and never recomputes a sample. An entry that cannot be read, or whose inputs are not the
sample's, is named in a warning and recomputed. A sample that fails (a density the foam cannot reach, CG not
converging) is recorded beside the entries as ``<entry>.failed.txt`` while the sweep goes on with the others; the
sweep then raises one error listing every failure, and the next run retries them. Under MPI the samples are
dealt round-robin to the ranks, each rank using ``cores / ranks`` FFTW threads; rank 0 assembles the table.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import math
import os
import re
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from foambase.errors import ComputationError, InputError, exit_code
from foambase.files import write_json_atomic, write_text_atomic
from foambase.threads import threads_per_rank
from homogenization.fft import homogenize_fft
from homogenization.tensors import (
    closest_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
    isotropic_voigt,
)

log = logging.getLogger(__name__)

#: The sweep of the shipped table (issue: at least these densities and γ, at least 3 seeds).
DENSITIES = (0.09, 0.12, 0.15, 0.18, 0.22, 0.26, 0.30, 0.34)
GAMMAS = (1.0, 0.5, 0.3, 0.1)
SEEDS = (0, 1, 2)
#: Poisson's ratio of the solid the table was computed with (moduli scale with E_s; ν_s cannot be rescaled).
NU_SOLID = 0.3
#: The FFT scheme of the sweep (the shipped table was made with "cg", whose iterates "pcg" reproduces).
SCHEME = "pcg"
#: The discretizations a sweep may use: the rotated scheme (one-point voxels, the shipped tables) or fully
#: integrated trilinear voxels (``"hex8"``), both solved by the nodal Green-preconditioned CG.
SWEEP_DISCRETIZATIONS = ("rotated", "hex8")
#: The shipped tables (package data).
DATA_DIR = Path(__file__).parent / "data"
SAMPLES_CSV = DATA_DIR / "foam_table_samples.csv"
TABLE_CSV = DATA_DIR / "foam_table.csv"
#: Foams with a table: the Euclidean strut foam and the polyhedral (gauge) wall foam.
FOAMS = ("euclidean", "polyhedral")

ENGINEERING = ("E1", "E2", "E3", "G23", "G13", "G12", "nu12", "nu13", "nu21", "nu23", "nu31", "nu32")
TI_FIT = ("ti_E_t", "ti_E_l", "ti_nu_t", "ti_nu_tl", "ti_G_l", "ti_error")
ISO_FIT = ("iso_E", "iso_nu", "iso_error")
C_ENTRIES = tuple(f"C{i + 1}{j + 1}" for i in range(6) for j in range(i, 6))
INPUTS = ("density", "gamma", "seed", "distance", "box", "n_cells", "resolution", "tol")
SAMPLE_COLUMNS = (INPUTS + ("measured_density", "radius") + C_ENTRIES + ENGINEERING + TI_FIT + ISO_FIT
                  + ("iterations", "wall_s", "version"))
#: Columns averaged over seeds by :func:`aggregate` (mean and ``<name>_std``).
AGGREGATED = ("measured_density",) + ENGINEERING + TI_FIT + ISO_FIT


@dataclass(frozen=True)
class SweepSettings:
    """Discretization of every sample of a sweep.

    Parameters
    ----------
    n_cells
        Voronoi cells per RVE.
    resolution
        FFT grid: an integer ``N``, voxels along the longest box edge with cubic voxels
        (:meth:`VoronoiFoam.grid_shape`); or, with ``cubic=False`` only, the grid ``(N1, N2, N3)`` itself.
    tol
        CG tolerance on the relative equilibrium residual.
    box
        ``"cube"`` (the unit cube) or ``"equiaxed"`` (``(γ, 1, 1)``: about ``n_cells^(1/3)`` cells across every
        direction at every γ; ``resolution`` must then give integer ``γ N``).
    distance
        One of :data:`FOAMS`: ``"euclidean"`` (struts) or ``"polyhedral"`` (walls, the default polytope).
    maxiter
        CG iterations per load case (``None``: the solver's default, 1000); thin voxel walls need more.
    cubic
        ``True`` (default): cubic voxels. ``False``: ``resolution`` is a grid ``(N1, N2, N3)`` whose voxels may be
        non-cubic (a numerical choice for members of one orientation, such as the polyhedral foam's walls nearly
        normal to x at γ = 0.1; :meth:`VoronoiFoam.grid_shape`). Its samples and table carry the grid in their
        names (``N60x300x300``) and ``resolution`` column.
    discretization
        ``"rotated"`` (default; one-point trilinear voxels, converging to the moduli from below) or ``"hex8"``
        (fully integrated trilinear voxels, from above; fewer CG iterations on void foams). A ``hex8`` sweep's
        table name ends in ``_hex8``, its cache entries carry it in their names and hash, and its rows hold a
        ``discretization`` column.

    """

    n_cells: int = 8
    resolution: int = 48
    tol: float = 1e-4
    box: str = "cube"
    distance: str = "euclidean"
    maxiter: int | None = None
    cubic: bool = True
    discretization: str = "rotated"

    @property
    def name(self) -> str:
        """The table's name (:func:`table_paths`).

        ``"cube"`` for the Euclidean foam in the unit cube, else ``<box>`` (Euclidean) or ``<box>_<distance>``.
        """
        suffix = "" if self.discretization == "rotated" else f"_{self.discretization}"
        if (self.box, self.distance) == ("cube", "euclidean"):
            return "cube" + suffix
        return (self.box if self.distance == "euclidean" else f"{self.box}_{self.distance}") + suffix

    def __post_init__(self):
        if self.box not in ("cube", "equiaxed"):
            raise InputError(f"box must be 'cube' or 'equiaxed', got {self.box!r}")
        if self.distance not in FOAMS:
            raise InputError(f"distance must be one of {FOAMS}, got {self.distance!r}")
        if int(self.n_cells) != self.n_cells or self.n_cells < 2:
            raise InputError(f"n_cells must be an integer >= 2, got {self.n_cells!r}")
        if self.cubic is True:
            if isinstance(self.resolution, (tuple, list, str)) or int(self.resolution) != self.resolution \
                    or self.resolution < 8:
                raise InputError(f"resolution must be an integer >= 8 (cubic voxels; a grid (N1, N2, N3) needs "
                                 f"cubic=False), got {self.resolution!r}")
        elif self.cubic is False:
            grid = _parse_grid(self.resolution)
            if grid is None:
                raise InputError(f"with cubic=False, resolution must be three integers >= 2 (N1, N2, N3) or "
                                 f"'N1xN2xN3', got {self.resolution!r}")
            object.__setattr__(self, "resolution", grid)
        else:
            raise InputError(f"cubic must be True or False, got {self.cubic!r}")
        if not 0 < self.tol < 1:
            raise InputError(f"tol must lie in (0, 1), got {self.tol!r}")
        if self.discretization not in SWEEP_DISCRETIZATIONS:
            raise InputError(f"discretization must be one of {SWEEP_DISCRETIZATIONS}, got {self.discretization!r}")


def _parse_grid(value) -> tuple[int, int, int] | None:
    """``(N1, N2, N3)`` from a triple or ``'N1xN2xN3'``; ``None`` unless three integers ≥ 2."""
    parts = value.split("x") if isinstance(value, str) else value
    try:
        grid = tuple(int(p) for p in parts)
        if len(grid) != 3 or any(g < 2 or g != float(p) for g, p in zip(grid, parts, strict=True)):
            return None
    except (TypeError, ValueError):
        return None
    return grid


def _resolution_label(settings: SweepSettings):
    """The resolution as recorded in rows and names: ``N`` (cubic voxels) or ``'N1xN2xN3'`` (``cubic=False``)."""
    return int(settings.resolution) if settings.cubic else "x".join(str(n) for n in settings.resolution)


def settings_from_row(row: dict) -> SweepSettings:
    """The sweep settings recorded in a sample row (a grid label ``'N1xN2xN3'`` means ``cubic=False``)."""
    resolution = row["resolution"]
    cubic = not (isinstance(resolution, str) and "x" in resolution)
    if cubic:
        resolution = int(float(resolution))
    return SweepSettings(n_cells=int(row["n_cells"]), resolution=resolution, tol=float(row["tol"]), box=row["box"],
                         distance=row["distance"], cubic=cubic,
                         discretization=row.get("discretization", "rotated") or "rotated")


@dataclass(frozen=True, order=True)
class Sample:
    """One foam of the sweep."""

    density: float
    gamma: float
    seed: int


def resolution_for_strut(settings: SweepSettings, density: float, gamma: float, voxels: float, *, seed: int = 0,
                         multiple: int | None = None) -> int:
    """The smallest grid ``N`` with at least ``voxels`` voxels across the strut (or wall) of one foam.

    "Across" is the diameter ``2 r`` (walls: the width) in voxels, ``2 r N / max(L)``, of the foam
    ``VoronoiFoam(settings.n_cells, density, gamma, seed, box=settings.box, distance=settings.distance)``.
    ``N`` is a multiple of ``multiple`` (default: the smallest step that gives cubic voxels in the box, e.g. 10
    for the equiaxed box at γ = 0.1, 2 at γ = 0.5, 1 at γ = 1) and at least 8.
    """
    from meshes.foam import VoronoiFoam

    if not (np.isfinite(voxels) and voxels > 0):
        raise InputError(f"voxels across the strut must be positive and finite, got {voxels!r}")
    if multiple is not None and (int(multiple) != multiple or multiple < 1):
        raise InputError(f"multiple must be a positive integer, got {multiple!r}")
    foam = VoronoiFoam(settings.n_cells, density, gamma, seed=seed,
                       box=None if settings.box == "cube" else settings.box, distance=settings.distance)
    edge = foam.box / foam.box.max()
    if multiple is None:
        multiple = next((k for k in range(1, 1001) if np.allclose(k * edge, np.rint(k * edge), atol=1e-9, rtol=0)),
                        None)
        if multiple is None:
            raise InputError(f"the box {foam.box.tolist()} admits no cubic voxels with N ≤ 1000 per edge")
    width = 2 * foam.radius / foam.box.max()
    return int(max(8, multiple * math.ceil(voxels / (width * multiple) - 1e-9)))


def grid(densities: Iterable[float] = DENSITIES, gammas: Iterable[float] = GAMMAS,
         seeds: Iterable[int] = SEEDS) -> list[Sample]:
    """All (density, γ, seed) combinations, each once (a repeated value counts once), in a fixed order."""
    return sorted({Sample(float(d), float(g), int(s)) for d in densities for g in gammas for s in seeds})


def _cache_key(sample: Sample, settings: SweepSettings) -> dict:
    """The exact inputs that change a sample's result (floats by ``repr``, so nothing is rounded)."""
    key = {"density": repr(float(sample.density)), "gamma": repr(float(sample.gamma)), "seed": int(sample.seed),
           "n_cells": int(settings.n_cells), "resolution": _resolution_label(settings),
           "tol": repr(float(settings.tol)), "box": settings.box, "distance": settings.distance}
    if not settings.cubic:  # absent for cubic voxels, so the entries of cubic sweeps keep their names
        key["cubic"] = False
    if settings.discretization != "rotated":  # likewise absent for the rotated scheme
        key["discretization"] = settings.discretization
    return key


def cache_name(sample: Sample, settings: SweepSettings) -> str:
    """File name of a sample's cache entry: its inputs, readable and rounded, then a hash of their exact values.

    Two sweeps that differ in any input (e.g. tol 1e-4 and 1.4e-4, which round alike) never share an entry.
    """
    foam = "" if (settings.box, settings.distance) == ("cube", "euclidean") else f"{settings.distance}_{settings.box}_"
    digest = hashlib.sha256(json.dumps(_cache_key(sample, settings), sort_keys=True).encode()).hexdigest()[:12]
    kind = "" if settings.discretization == "rotated" else f"_{settings.discretization}"
    return (f"{foam}d{sample.density:.4f}_g{sample.gamma:.4f}_s{sample.seed}_n{settings.n_cells}"
            f"_N{_resolution_label(settings)}_tol{settings.tol:.1e}{kind}_{digest}.json")


def _failure_record(entry: Path) -> Path:
    """Where a failed sample's error is recorded: beside its (absent) cache entry."""
    return entry.with_name(entry.stem + ".failed.txt")


def _check_cached_values(row: dict) -> None:
    """A cached row's results are finite numbers, its C is a stiffness, and its constants are those of its C.

    Raises ``ValueError`` naming the first column that fails (a hand-edited or corrupted entry).
    """
    for name in ("measured_density", "radius", *C_ENTRIES, *ENGINEERING, *TI_FIT, *ISO_FIT):
        value = row[name]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"column {name!r} is {value!r}, not a finite number")
    C = np.zeros((6, 6))
    for name in C_ENTRIES:
        i, j = int(name[1]) - 1, int(name[2]) - 1
        C[i, j] = C[j, i] = row[name]
    if np.linalg.eigvalsh(C).min() <= 0.0:
        raise ValueError("its C is not positive definite (not a stiffness)")
    expected = engineering_constants(C)
    for name, value in expected.items():
        if not math.isclose(row[name], value, rel_tol=1e-9, abs_tol=1e-12):
            raise ValueError(f"column {name!r} = {row[name]!r} is not the value of its C ({value!r})")


def read_cache_entry(path: str | os.PathLike, sample: Sample, settings: SweepSettings) -> dict | None:
    """The row cached at ``path`` for ``sample``, or ``None`` when there is none to use.

    A file that is not JSON, lacks a column, holds another sample's or setting's inputs, or results that cannot be
    this sample's (a value that is not a finite number, a C that is not positive definite, engineering constants
    that are not those of its C: a hand-edited or corrupted entry) is named in a warning and
    reported as absent, so that the sweep recomputes (and overwrites) it.
    """
    path = Path(path)
    if not path.exists():
        return None
    try:
        row = json.loads(path.read_text())
        if not isinstance(row, dict):
            raise ValueError(f"a JSON {type(row).__name__}, not an object")
        missing = [c for c in SAMPLE_COLUMNS if c not in row]
        if missing:
            raise ValueError(f"no column {missing[0]!r}")
        found = _cache_key(Sample(row["density"], row["gamma"], row["seed"]), settings_from_row(row))
        if found != _cache_key(sample, settings):
            raise ValueError(f"its inputs {found} are not this sample's")
        _check_cached_values(row)
    except (OSError, ValueError, TypeError, UnicodeDecodeError) as exc:  # JSONDecodeError is a ValueError
        log.warning("foam table cache entry %s cannot be used (%s); the sample is recomputed", path, exc)
        return None
    return row


def table_paths(name: str = "cube", directory: str | os.PathLike = DATA_DIR) -> dict[str, Path]:
    """The ``samples``, ``table`` (aggregated) and ``provenance`` files of the table ``name`` in ``directory``.

    ``name`` is :attr:`SweepSettings.name` of the sweep that wrote it: ``"cube"`` is the historical table
    (``foam_table.csv``), any other name ``foam_table_<name>.csv``.
    """
    if not (isinstance(name, str) and re.fullmatch(r"[a-z0-9_]+", name)):
        raise InputError(f"a foam table name is lower-case letters, digits and '_', got {name!r}")
    stem = "foam_table" if name == "cube" else f"foam_table_{name}"
    d = Path(directory)
    return {"samples": d / f"{stem}_samples.csv", "table": d / f"{stem}.csv",
            "provenance": d / f"{stem}_provenance.json"}


def shipped_tables() -> tuple[str, ...]:
    """Names of the tables shipped in :data:`DATA_DIR` (``foam_material(..., table=name)`` reads them)."""
    names = ["cube" if p.stem == "foam_table" else p.stem.removeprefix("foam_table_")
             for p in sorted(DATA_DIR.glob("foam_table*.csv"))
             if not p.stem.endswith("_samples") and not p.stem.startswith("foam_table_seed")]
    return tuple(sorted(names))


def resolve_table(table: str | os.PathLike | None = None) -> tuple[str, Path]:
    """A foam table as ``foam_material(table=)`` and a scene's ``table`` key take it: its label and its file.

    ``None`` is the default, ``"cube"``; a string not ending in ``.csv`` names a shipped table
    (:func:`shipped_tables`, its aggregated file :func:`table_paths`); anything else is the path of an aggregated
    table CSV, labelled by the path as given. Raises :class:`~foambase.errors.InputError` for an unknown name.
    """
    if table is None:
        table = "cube"
    if isinstance(table, str) and not table.endswith(".csv"):
        if table not in shipped_tables():
            raise InputError(f"table = {table!r} is not a shipped foam table {shipped_tables()} nor a .csv path")
        return table, table_paths(table)["table"]
    return str(table), Path(table)


def table_sha256(table: str | os.PathLike | None = None) -> str:
    """SHA-256 (hex) of a foam table's file (:func:`resolve_table`): a regenerated table has another digest.

    Raises :class:`~foambase.errors.InputError` naming the file when it cannot be read.
    """
    label, path = resolve_table(table)
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise InputError(f"foam table {label!r}: cannot read {str(path)!r} ({exc.strerror})") from exc


def _version() -> str:
    try:
        return metadata.version("fenicsfoam")
    except metadata.PackageNotFoundError:  # pragma: no cover - not installed
        return "unknown"


def homogenize_sample(sample: Sample, settings: SweepSettings, threads: int | None = None,
                      comm=None) -> dict:
    """Build, voxelize and homogenize one foam; return its table row (moduli normalised by E_s = 1).

    The TI fit takes the foam's distinct axis x as its *l* axis (docs/conventions.md): ``ti_E_l`` is along x.
    With ``comm`` of more than one rank the one sample is homogenized by all its ranks together (the distributed
    FFT of :func:`homogenization.fft.homogenize_fft`, every rank building the same foam); every rank returns the
    same row. Raises ``meshes.foam.FoamParameterError`` for a density the foam cannot reach and
    ``homogenization.fft.FFTConvergenceError`` when CG does not converge.
    """
    from meshes.foam import VoronoiFoam

    start = time.perf_counter()
    foam = VoronoiFoam(settings.n_cells, sample.density, sample.gamma, seed=sample.seed,
                       box=None if settings.box == "cube" else settings.box, distance=settings.distance)
    image = foam.voxelize(settings.resolution, cubic=settings.cubic).astype(np.int8)
    r = homogenize_fft(image, [np.zeros((6, 6)), isotropic_voigt(1.0, NU_SOLID)], scheme=SCHEME,
                       discretization=settings.discretization, tol=settings.tol, threads=threads, box=tuple(foam.box),
                       maxiter=settings.maxiter, comm=comm)
    row = {"density": sample.density, "gamma": sample.gamma, "seed": sample.seed, "distance": settings.distance,
           "box": settings.box, "n_cells": settings.n_cells, "resolution": _resolution_label(settings),
           "tol": settings.tol,
           "measured_density": float(foam.measured_density), "radius": float(foam.radius)}
    row.update({name: float(r.C[int(name[1]) - 1, int(name[2]) - 1]) for name in C_ENTRIES})
    row.update(engineering_constants(r.C))
    ti = closest_transverse_isotropic(r.C, axis=(1.0, 0.0, 0.0))
    row.update(ti_E_t=ti.E_t, ti_E_l=ti.E_l, ti_nu_t=ti.nu_t, ti_nu_tl=ti.nu_tl, ti_G_l=ti.G_l, ti_error=ti.error)
    iso = closest_isotropic(r.C)
    row.update(iso_E=iso.E, iso_nu=iso.nu, iso_error=iso.error)
    row.update(iterations=int(sum(r.iterations)), wall_s=time.perf_counter() - start, version=_version())
    out = {k: row[k] for k in SAMPLE_COLUMNS}
    if settings.discretization != "rotated":  # the rotated scheme's rows (the shipped tables) have no such column
        out["discretization"] = settings.discretization
    return out


def run_sweep(samples: Sequence[Sample], settings: SweepSettings, cache_dir: str | os.PathLike, comm=None, *,
              threads: int | None = None, progress: bool = True, stop_after: int | None = None,
              distribute: str = "samples") -> list[dict] | None:
    """Homogenize every sample not yet in ``cache_dir``; return all rows (sorted) on every rank.

    Parameters
    ----------
    samples
        The foams to compute (see :func:`grid`).
    settings
        Resolution, cells per RVE and tolerance of every sample.
    cache_dir
        One JSON file per finished sample (:func:`cache_name`); usable entries are read, never recomputed.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    distribute
        ``"samples"``: the samples are dealt round-robin to the ranks, each computed by one rank (the cheapest
        for many small samples); ``"fft"``: every sample is computed by all ranks together (the distributed FFT,
        for a sample too slow or too large for one rank); rank 0 writes its cache entry.
    threads
        FFTW threads per rank (default: the process's CPUs divided by the number of ranks).
    progress
        tqdm bar on rank 0 (over rank 0's share of the samples), when stderr is a terminal.
    stop_after
        Stop each rank after computing this many new samples (to test and demonstrate resuming); the rows
        are then not all present and ``None`` is returned.

    """
    from mpi4py import MPI
    from tqdm import tqdm

    comm = MPI.COMM_WORLD if comm is None else comm
    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    threads = threads_per_rank(comm) if threads is None else threads
    entry = {s: cache / cache_name(s, settings) for s in samples}
    if distribute not in ("samples", "fft"):
        raise InputError(f"distribute must be 'samples' or 'fft', got {distribute!r}")
    together = distribute == "fft" and comm.size > 1
    if together:  # one list on every rank, in the same order: every rank takes part in every sample
        mine = comm.bcast([s for s in samples if read_cache_entry(entry[s], s, settings) is None]
                          if comm.rank == 0 else None, root=0)
    else:
        mine = [s for s in list(samples)[comm.rank::comm.size] if read_cache_entry(entry[s], s, settings) is None]
    if stop_after is not None:
        mine = mine[:stop_after]
    failures = []
    bar = tqdm(mine, desc=f"foam samples (rank 0 of {comm.size})", unit="sample",
               disable=None if progress and comm.rank == 0 else True)  # None: shown only on a terminal
    for sample in bar:
        writer = comm.rank == 0 or not together
        try:
            row = homogenize_sample(sample, settings, threads, comm=comm if together else None)
        except Exception as exc:  # recorded and reported below on every rank, never swallowed
            message = f"{sample}: {type(exc).__name__}: {exc}"
            if writer:
                log.warning("foam sample failed, the sweep goes on with the others: %s", message)
                write_text_atomic(_failure_record(entry[sample]), message + "\n")
                failures.append((message, exit_code(exc)))
            continue
        if writer:
            write_json_atomic(entry[sample], row, indent=1)
            _failure_record(entry[sample]).unlink(missing_ok=True)
    failures = [f for rank_failures in comm.allgather(failures) for f in rank_failures]
    if failures:
        error = ComputationError(f"foam sweep: {len(failures)} sample(s) failed, recorded as *.failed.txt in "
                                 f"{cache} and retried by the next run (finished samples stay cached): "
                                 + "; ".join(message for message, _ in failures))
        error.exit_code = failures[0][1]  # e.g. 2 for a density the foam cannot reach, 3 for no convergence
        raise error
    comm.barrier()
    if stop_after is not None:
        return None
    rows = [read_cache_entry(entry[s], s, settings) for s in sorted(samples)]
    unusable = [str(entry[s]) for s, row in zip(sorted(samples), rows, strict=True) if row is None]
    if unusable:
        raise ComputationError(f"foam sweep: cache entries changed or vanished while the sweep ran: {unusable}")
    return rows


def aggregate(rows: Sequence[dict]) -> list[dict]:
    """Mean and sample standard deviation (``<name>_std``) over seeds for every (density, γ)."""
    groups: dict[tuple[float, float], list[dict]] = {}
    for row in rows:
        groups.setdefault((float(row["density"]), float(row["gamma"])), []).append(row)
    table = []
    for (density, gamma), members in sorted(groups.items()):
        out = {"density": density, "gamma": gamma, "n_seeds": len(members)}
        for name in AGGREGATED:
            values = np.array([float(m[name]) for m in members])
            out[name] = float(values.mean())
            out[f"{name}_std"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
        table.append(out)
    return table


def format_table(table: Sequence[dict]) -> str:
    """The aggregated table (:func:`aggregate`) as text: moduli along x, y, z and G23 over E_s, fit errors."""
    lines = [f"{'density':>8} {'gamma':>6} {'E1/Es':>10} {'E2/Es':>10} {'E3/Es':>10} {'G23/Es':>10} {'TI err':>7} "
             f"{'iso err':>7}"]
    for t in table:
        lines.append(f"{t['density']:8.2f} {t['gamma']:6.2f} {t['E1']:10.3e} {t['E2']:10.3e} {t['E3']:10.3e} "
                     f"{t['G23']:10.3e} {t['ti_error']:7.3f} {t['iso_error']:7.3f}")
    return "\n".join(lines)


def to_csv(rows: Sequence[dict], path: str | os.PathLike) -> Path:
    """Write rows (dicts with the same keys) as CSV, atomically.

    Floats are written with ``repr`` (they read back exactly); a text field holding a comma, a quote or a line break
    is quoted (RFC 4180), so :func:`read_csv` and any CSV reader get the same columns back.
    """
    path = Path(path)
    columns = list(rows[0])
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([repr(row[c]) if isinstance(row[c], float) else str(row[c]) for c in columns] for row in rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, text.getvalue())
    return path


def read_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a table written by :func:`to_csv` as ``{column: array}`` (numeric columns as float)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise InputError(f"{path}: empty table")
    out = {}
    for name in rows[0]:
        values = [r[name] for r in rows]
        try:
            out[name] = np.array([float(v) for v in values])
        except ValueError:
            out[name] = np.array(values)
    return out


def write_tables(rows: Sequence[dict], out_dir: str | os.PathLike, provenance: dict,
                 name: str = "cube") -> dict[str, Path]:
    """Write the table ``name``'s samples, aggregated table and provenance (:func:`table_paths`) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = table_paths(name, out)
    return {"samples": to_csv(rows, paths["samples"]), "table": to_csv(aggregate(rows), paths["table"]),
            "provenance": write_json_atomic(paths["provenance"], provenance)}


def settings_dict(settings: SweepSettings) -> dict:
    """The settings as recorded in the provenance, with the fixed solver choices."""
    return asdict(settings) | {"nu_solid": NU_SOLID, "scheme": SCHEME}
