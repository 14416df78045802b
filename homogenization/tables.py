"""Homogenized foam tables: C_hom against relative density × anisotropy γ × seed (paper Fig. 4).

One *sample* is one foam ``meshes.foam.VoronoiFoam(n_cells, density, gamma, seed, box=, distance=)`` voxelized
with cubic voxels (``N`` along the longest box edge; or, opted into with ``cubic=False``, an explicit grid of
non-cubic voxels) and homogenized in its periodic box by
:func:`homogenization.fft.homogenize_fft` (``scheme="pcg"``, the nodal Green-preconditioned CG) with an isotropic
solid of
``E_s = 1`` and ``ν_s = 0.3`` and a void of zero stiffness, so every modulus in the table is already
normalised by the solid's Young's modulus (it scales linearly with ``E_s``; ``ν_s`` is fixed).

The voxels are fully integrated trilinear hexahedra (``discretization="hex8"``, :data:`DEFAULT_DISCRETIZATION`) unless
a sweep asks for the rotated scheme (one-point voxels, ``"rotated"``), with which every shipped table was made (its
rows have no ``discretization`` column and its provenance records ``"rotated"``; pcg reproduces the iterates of the
strain CG ``"cg"`` they were computed with, at half the FFT work). :func:`recorded_settings` reads back the settings
of a table from its provenance, so that regenerating a shipped table recomputes its own discretization, not
today's default.

A row holds the inputs, the measured solid fraction, the 21 independent entries of the Voigt ``C``, the
engineering constants (E1..E3, G23, G13, G12, ν_ij), the closest transversely isotropic stiffness with its
*l* axis along the foam's distinct axis x (``ti_E_t, ti_E_l, ti_nu_t, ti_nu_tl, ti_G_l`` and its relative
error ``ti_error``), the closest isotropic one (``iso_E, iso_nu, iso_error``), the CG iterations, the wall
time and the software version. :func:`aggregate` reduces the samples to the mean and the sample standard
deviation over seeds per (density, γ); ``fenicsfoam.materials.foam_material`` interpolates that table.

Every sweep setting of box and foam writes a table of its own name (:attr:`SweepSettings.name`,
:func:`table_paths`), each with its samples and provenance; :func:`shipped_tables` lists those in :data:`DATA_DIR`
and :data:`TABLE_NOTES` says what each one is; a table merged under a name of its own (:func:`merge_tables`) may
hold nodes of several settings. The default, :data:`DEFAULT_TABLE`, is the paper's foam: the polyhedral wall foam
with pores of 0.0045 E_s over the whole density × γ grid, each γ at the estimate its resolution study shows
closest to converged (``foam_table_paper_foam.csv``, docs/foam.md).

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
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
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
SWEEP_DISCRETIZATIONS = ("rotated", "hex8", "bracket")
#: The discretization of a new sweep (:class:`SweepSettings`, ``fenicsfoam table``): every table sample has a void
#: (or, with ``pore_modulus``, a soft) phase, on which fully integrated voxels reach the converged moduli on a coarser
#: grid in a fraction of the iterations (docs/benchmarks/2026-11-27-void-homogenization.md).
DEFAULT_DISCRETIZATION = "hex8"
#: what a bracket table's rows hold (:func:`bracket_samples`): the mean stiffness, or the hex8 side's
BRACKET_ESTIMATES = ("midpoint", "hex8")
#: the moduli whose rotated … hex8 bracket a ``"bracket"`` row records (``bracket_<name>``, relative half width)
BRACKETED = ("E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E")
#: The shipped tables (package data).
DATA_DIR = Path(__file__).parent / "data"
SAMPLES_CSV = DATA_DIR / "foam_table_samples.csv"
TABLE_CSV = DATA_DIR / "foam_table.csv"
#: The foam table a foam region, ``foam_material`` and the graded fields read when none is named: the paper's foam.
DEFAULT_TABLE = "paper_foam"
#: One line per shipped table: what it is (docs/foam.md has the evidence behind each).
TABLE_NOTES = {
    DEFAULT_TABLE: "the paper's foam (default): polyhedral wall foam, pores of 0.0045 E_s, density 0.09–0.35 × "
                   "γ 0.1–1, 3 seeds; the rotated … hex8 midpoint (γ 0.2 on a 1.5× finer grid), the hex8 side at γ 0.3",
    "equiaxed_polyhedral_bracket_pores0p0045": "the same samples, the midpoint at every γ (at γ 0.2–0.3 below "
                                               "20 % its in-plane and shear moduli are up to 13 % low)",
    "cube": "Euclidean strut foam, 8 cells in the unit cube (period-dominated at γ < 1; the former default)",
    "equiaxed": "Euclidean strut foam, 27 cells in the box (γ, 1, 1), where it was computed",
    "equiaxed_polyhedral": "polyhedral wall foam with void pores, 18 % only (the Fig. 6 beams' density)",
}
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
        ``"hex8"`` (default, :data:`DEFAULT_DISCRETIZATION`; fully integrated trilinear voxels, converging to the
        moduli from above, with far fewer CG iterations on void foams) or ``"rotated"`` (one-point trilinear voxels,
        from below; the shipped tables). A ``hex8`` sweep's table name ends in ``_hex8``, its cache entries carry it
        in their names and hash, and its rows hold a ``discretization`` column; a ``rotated`` sweep's names and
        rows are those of the shipped tables (no suffix, no column). ``"bracket"``: both on the same voxels, the
        sample's ``C`` their mean, and for
        each modulus of :data:`BRACKETED` the relative half width of the bracket, ``bracket_<name> = |q_hex8 −
        q_rotated| / (q_hex8 + q_rotated)`` (the two converge to the moduli from opposite sides, so the midpoint's
        resolution error is at most about that); :func:`bracket_samples` makes the same rows from a rotated and a
        hex8 sweep of the same samples.
    pore_modulus
        Young's modulus of the pores over the solid's (ν the solid's); 0 (default): void pores, the printed foam's
        air. A positive value in ``[1e-6, 0.5]`` gives the pores that stiffness, as a homogenization that needs
        a positive-definite phase everywhere does; the polyhedral wall foam reproduces the paper's Fig. 4 with
        0.0045 (docs/validation/2026-11-27-fig4.md, section 7). Its table name ends in ``_pores<value>`` (``.``
        written ``p``: ``_pores0p0045``), its cache entries carry it in their names and hash, its rows hold a
        ``pore_modulus`` column.

    """

    n_cells: int = 8
    resolution: int = 48
    tol: float = 1e-4
    box: str = "cube"
    distance: str = "euclidean"
    maxiter: int | None = None
    cubic: bool = True
    discretization: str = DEFAULT_DISCRETIZATION
    pore_modulus: float = 0.0

    @property
    def name(self) -> str:
        """The table's name (:func:`table_paths`).

        ``"cube"`` for the Euclidean foam in the unit cube, else ``<box>`` (Euclidean) or ``<box>_<distance>``.
        """
        suffix = ("" if self.discretization == "rotated" else f"_{self.discretization}") + _pores_label(self)
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
        e = self.pore_modulus
        if isinstance(e, bool) or not isinstance(e, (int, float)) or not (e == 0 or 1e-6 <= e <= 0.5):
            raise InputError(f"pore_modulus must be 0 (void pores) or a fraction of the solid's modulus in "
                             f"[1e-6, 0.5], got {e!r}")
        object.__setattr__(self, "pore_modulus", float(e))


def _pores_label(settings: SweepSettings) -> str:
    """``''`` for void pores, else ``'_pores'`` and the modulus with ``p`` for the point (``_pores0p0045``)."""
    if settings.pore_modulus == 0:
        return ""
    return "_pores" + f"{settings.pore_modulus:.6f}".rstrip("0").replace(".", "p")


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
                         discretization=row.get("discretization", "rotated") or "rotated",
                         pore_modulus=float(row.get("pore_modulus", 0.0) or 0.0))


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


def _cubic_multiple(box: str, gamma: float) -> int:
    """The smallest ``N`` step that gives cubic voxels in the sweep's box at ``gamma`` (1 for the unit cube)."""
    if box == "cube":
        return 1
    edge = np.array([gamma, 1.0, 1.0]) / max(gamma, 1.0)
    multiple = next((k for k in range(1, 1001) if np.allclose(k * edge, np.rint(k * edge), atol=1e-9, rtol=0)), None)
    if multiple is None:
        raise InputError(f"gamma = {gamma!r}: the box (γ, 1, 1) admits no cubic voxels with N ≤ 1000 per edge")
    return multiple


def scaled_resolution(resolution, density: float, reference_density: float, gamma: float = 1.0,
                      box: str = "equiaxed"):
    """The grid at ``density`` that keeps the voxels across a wall of the grid ``resolution`` at ``reference_density``.

    The rule of a density sweep at fixed wall resolution: the wall (strut) half width of the foams grows about in
    proportion to the density (``VoronoiFoam.radius``), so the spacing that resolves it is scaled by
    ``density / reference_density``, i.e. the grid by ``reference_density / density``:

    - ``N`` (cubic voxels): ``N × reference_density / density`` rounded to the nearest multiple of the step that
      keeps the voxels cubic in the box at ``gamma`` (the smallest ``k`` with ``γ k`` an integer in the equiaxed
      box: 10 at γ = 0.1 and 0.3, 5 at 0.2, 2 at 0.5), and at least 8;
    - ``(N1, N2, N3)`` or ``'N1xN2xN3'`` (non-cubic voxels, for walls nearly normal to x whose width the x spacing
      alone resolves, ``VoronoiFoam.grid_shape``): ``N1`` scaled and rounded (at least 2), ``N2`` and ``N3`` kept.

    Returns an ``int`` or a tuple, as given. Raises :class:`~foambase.errors.InputError` for a density or reference
    density outside (0, 1) or a resolution that is neither form.
    """
    for label, value in (("density", density), ("reference_density", reference_density)):
        if not (isinstance(value, (int, float)) and 0 < value < 1):
            raise InputError(f"{label} must lie in (0, 1), got {value!r}")
    factor = reference_density / density
    triple = _parse_grid(resolution) if isinstance(resolution, (tuple, list, str)) else None
    if triple is not None:
        return (max(2, int(round(triple[0] * factor))), triple[1], triple[2])
    if isinstance(resolution, (tuple, list, str)) or int(resolution) != resolution or resolution < 8:
        raise InputError(f"resolution must be an integer N >= 8 or a grid N1xN2xN3, got {resolution!r}")
    step = _cubic_multiple(box, gamma)
    n = step * max(1, round(resolution * factor / step))
    return int(n if n >= 8 else step * math.ceil(8 / step))


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
    if settings.pore_modulus != 0:  # and for void pores
        key["pore_modulus"] = repr(float(settings.pore_modulus))
    return key


def cache_name(sample: Sample, settings: SweepSettings) -> str:
    """File name of a sample's cache entry: its inputs, readable and rounded, then a hash of their exact values.

    Two sweeps that differ in any input (e.g. tol 1e-4 and 1.4e-4, which round alike) never share an entry.
    """
    foam = "" if (settings.box, settings.distance) == ("cube", "euclidean") else f"{settings.distance}_{settings.box}_"
    digest = hashlib.sha256(json.dumps(_cache_key(sample, settings), sort_keys=True).encode()).hexdigest()[:12]
    kind = ("" if settings.discretization == "rotated" else f"_{settings.discretization}") + _pores_label(settings)
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

    ``None`` is the default, :data:`DEFAULT_TABLE`; a string not ending in ``.csv`` names a shipped table
    (:func:`shipped_tables`, its aggregated file :func:`table_paths`); anything else is the path of an aggregated
    table CSV, labelled by the path as given. Raises :class:`~foambase.errors.InputError` for an unknown name.
    """
    if table is None:
        table = DEFAULT_TABLE
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
    pores = isotropic_voigt(settings.pore_modulus, NU_SOLID) if settings.pore_modulus else np.zeros((6, 6))
    kinds = ("rotated", "hex8") if settings.discretization == "bracket" else (settings.discretization,)
    results = [homogenize_fft(image, [pores, isotropic_voigt(1.0, NU_SOLID)], scheme=SCHEME, discretization=kind,
                              tol=settings.tol, threads=threads, box=tuple(foam.box), maxiter=settings.maxiter,
                              comm=comm) for kind in kinds]
    inputs = {"density": sample.density, "gamma": sample.gamma, "seed": sample.seed, "distance": settings.distance,
              "box": settings.box, "n_cells": settings.n_cells, "resolution": _resolution_label(settings),
              "tol": settings.tol, "measured_density": float(foam.measured_density), "radius": float(foam.radius)}
    return _sample_row(inputs, settings, [r.C for r in results],
                       iterations=int(sum(sum(r.iterations) for r in results)),
                       wall_s=time.perf_counter() - start)


def _moduli_of(C: np.ndarray) -> dict:
    """The engineering constants and the TI (l along x) and isotropic fits of a Voigt stiffness."""
    out = dict(engineering_constants(C))
    ti = closest_transverse_isotropic(C, axis=(1.0, 0.0, 0.0))
    out.update(ti_E_t=ti.E_t, ti_E_l=ti.E_l, ti_nu_t=ti.nu_t, ti_nu_tl=ti.nu_tl, ti_G_l=ti.G_l, ti_error=ti.error)
    iso = closest_isotropic(C)
    out.update(iso_E=iso.E, iso_nu=iso.nu, iso_error=iso.error)
    return out


def _sample_row(inputs: dict, settings: SweepSettings, stiffnesses: Sequence[np.ndarray], *, iterations: int,
                wall_s: float) -> dict:
    """A sample's row from its inputs and its stiffness (or, for ``"bracket"``, its rotated and hex8 ones)."""
    C = np.mean(stiffnesses, axis=0)
    row = dict(inputs)
    row.update({name: float(C[int(name[1]) - 1, int(name[2]) - 1]) for name in C_ENTRIES})
    row.update(_moduli_of(C))
    row.update(iterations=iterations, wall_s=wall_s, version=_version())
    out = {k: row[k] for k in SAMPLE_COLUMNS}
    if settings.discretization != "rotated":  # the rotated scheme's rows (the shipped tables) have no such column
        out["discretization"] = settings.discretization
    if settings.pore_modulus != 0:  # nor the void-pore rows
        out["pore_modulus"] = settings.pore_modulus
    if settings.discretization == "bracket":
        out.update(_bracket_widths(*stiffnesses))
    return out


def _bracket_widths(lower: np.ndarray, upper: np.ndarray) -> dict:
    """``bracket_<q>``: the relative half width of the rotated (``lower``) … hex8 (``upper``) bracket per modulus."""
    low, high = _moduli_of(lower), _moduli_of(upper)
    return {f"bracket_{q}": abs(high[q] - low[q]) / (high[q] + low[q]) for q in BRACKETED}


def bracket_samples(lower: Sequence[dict], upper: Sequence[dict], estimate: str = "midpoint") -> list[dict]:
    """The ``"bracket"`` rows of samples computed twice, by a rotated (``lower``) and a hex8 (``upper``) sweep.

    Every sample (density, γ, seed) must be in both with the same settings but the discretization; each returned
    row is the one a ``"bracket"`` sweep of that sample gives (:class:`SweepSettings`), with the two runs'
    iterations and wall times summed. ``estimate="hex8"``: each row is instead the hex8 sample itself (its
    settings, its stiffness), with the same ``bracket_<name>`` columns: for grids on which the resolution study
    finds the hex8 side converged and the rotated side not (the default table at γ = 0.3,
    docs/validation/2026-11-27-table-convergence.md). Raises :class:`~foambase.errors.InputError` naming the first
    sample that is missing from one side or computed at other settings, or for another ``estimate``, before
    anything is returned.
    """
    if estimate not in BRACKET_ESTIMATES:
        raise InputError(f"bracket estimate must be one of {BRACKET_ESTIMATES}, got {estimate!r}")
    def by_sample(rows, kind):
        out = {}
        for row in rows:
            settings = settings_from_row(row)
            if settings.discretization != kind:
                raise InputError(f"bracket: the {'lower' if kind == 'rotated' else 'upper'} rows must be {kind}, "
                                 f"sample {_sample_label(row)} is {settings.discretization}")
            out[(float(row["density"]), float(row["gamma"]), int(row["seed"]))] = (row, settings)
        return out

    low, high = by_sample(lower, "rotated"), by_sample(upper, "hex8")
    for key in sorted(set(low) ^ set(high)):
        side = "hex8" if key in low else "rotated"
        raise InputError(f"bracket: sample density {key[0]}, gamma {key[1]}, seed {key[2]} has no {side} row")
    rows = []
    for key in sorted(low):
        (lo, s_lo), (hi, s_hi) = low[key], high[key]
        settings = replace(s_lo, discretization="bracket")
        if replace(s_hi, discretization="bracket") != settings:
            raise InputError(f"bracket: sample density {key[0]}, gamma {key[1]}, seed {key[2]} was computed at other "
                             f"settings by the two sweeps: {settings_dict(s_lo)} vs {settings_dict(s_hi)}")
        inputs = {k: lo[k] for k in (*INPUTS, "measured_density", "radius")}
        cost = {"iterations": int(lo["iterations"]) + int(hi["iterations"]),
                "wall_s": float(lo["wall_s"]) + float(hi["wall_s"])}
        pair = [row_stiffness(lo), row_stiffness(hi)]
        rows.append(_sample_row(inputs, settings, pair, **cost) if estimate == "midpoint"
                    else _sample_row(inputs, s_hi, pair[1:], **cost) | _bracket_widths(*pair))
    return rows


def _sample_label(row: dict) -> str:
    return f"density {row['density']}, gamma {row['gamma']}, seed {row['seed']}"


def row_stiffness(row) -> np.ndarray:
    """The Voigt ``C`` of a sample row (its 21 ``C_ij`` columns; a dict or any mapping of them)."""
    C = np.zeros((6, 6))
    for name in C_ENTRIES:
        i, j = int(name[1]) - 1, int(name[2]) - 1
        C[i, j] = C[j, i] = float(row[name])
    return C


def run_sweep(samples: Sequence[Sample], settings: SweepSettings, cache_dir: str | os.PathLike, comm=None, *,
              threads: int | None = None, progress: bool = True, stop_after: int | None = None,
              distribute: str = "samples") -> list[dict] | None:
    """Homogenize every sample not yet in ``cache_dir``; return all rows (sorted) on every rank.

    Parameters
    ----------
    samples
        The foams to compute (see :func:`grid`).
    settings
        Resolution, cells per RVE and tolerance of every sample; or a callable ``settings(sample)`` giving each
        sample its own (e.g. a grid per (density, γ), :func:`scaled_resolution`). All samples of one call are dealt
        to the ranks together, whatever their settings.
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
    settings_of = settings if callable(settings) else (lambda _sample: settings)
    entry = {s: cache / cache_name(s, settings_of(s)) for s in samples}
    if distribute not in ("samples", "fft"):
        raise InputError(f"distribute must be 'samples' or 'fft', got {distribute!r}")
    together = distribute == "fft" and comm.size > 1
    if together:  # one list on every rank, in the same order: every rank takes part in every sample
        mine = comm.bcast([s for s in samples if read_cache_entry(entry[s], s, settings_of(s)) is None]
                          if comm.rank == 0 else None, root=0)
    else:
        mine = [s for s in list(samples)[comm.rank::comm.size]
                if read_cache_entry(entry[s], s, settings_of(s)) is None]
    if stop_after is not None:
        mine = mine[:stop_after]
    failures = []
    bar = tqdm(mine, desc=f"foam samples (rank 0 of {comm.size})", unit="sample",
               disable=None if progress and comm.rank == 0 else True)  # None: shown only on a terminal
    for sample in bar:
        writer = comm.rank == 0 or not together
        try:
            row = homogenize_sample(sample, settings_of(sample), threads, comm=comm if together else None)
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
    rows = [read_cache_entry(entry[s], s, settings_of(s)) for s in sorted(samples)]
    unusable = [str(entry[s]) for s, row in zip(sorted(samples), rows, strict=True) if row is None]
    if unusable:
        raise ComputationError(f"foam sweep: cache entries changed or vanished while the sweep ran: {unusable}")
    return rows


def aggregate(rows: Sequence[dict]) -> list[dict]:
    """Mean and sample standard deviation (``<name>_std``) over seeds for every (density, γ).

    Rows of a ``"bracket"`` sweep add, per modulus, the widest relative half width of the bracket over the seeds
    (``bracket_<name>``).
    """
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
        for name in (k for k in members[0] if k.startswith("bracket_")):  # the widest bracket over the seeds
            out[name] = max(float(m[name]) for m in members)
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


def _node_key(density: float, gamma: float) -> str:
    """The key of one (density, γ) node in a provenance's ``settings_per_node``."""
    return f"density={density:g},gamma={gamma:g}"


def _recorded(provenance, density: float, gamma: float) -> dict | None:
    """The settings a provenance records for the node (density, γ), or ``None``.

    A sweep's provenance holds ``settings_per_node``, ``settings_per_gamma`` or one ``settings``; a merged table's
    (:func:`merge_tables`) lists its sources' under ``merged_from`` (the first that has the node); a bracket
    table's (:func:`bracket_tables`) holds its rotated and hex8 sources' under ``bracketed_from``: the node's
    settings are the rotated source's with ``discretization = "bracket"`` (they must be the hex8 source's but for
    the discretization).
    """
    if not isinstance(provenance, dict):
        return None
    for key, value in (("settings_per_node", _node_key(density, gamma)), ("settings_per_gamma", str(float(gamma)))):
        recorded = (provenance.get(key) or {}).get(value)
        if isinstance(recorded, dict):
            return recorded
    if isinstance(provenance.get("settings"), dict):
        return provenance["settings"]
    for source in provenance.get("merged_from") or ():
        recorded = _recorded(source.get("provenance") if isinstance(source, dict) else None, density, gamma)
        if recorded is not None:
            return recorded
    pair = provenance.get("bracketed_from")
    if isinstance(pair, dict):
        low, high = (_recorded((pair.get(k) or {}).get("provenance"), density, gamma) for k in ("rotated", "hex8"))
        if low is None or high is None:
            return None
        if {k: v for k, v in low.items() if k != "discretization"} != {
                k: v for k, v in high.items() if k != "discretization"}:
            raise InputError(f"bracket provenance, node {_node_key(density, gamma)}: its rotated and hex8 sources "
                             f"record other settings ({low} and {high})")
        return high if provenance.get("estimate") == "hex8" else low | {"discretization": "bracket"}
    return None


def recorded_settings(name: str, directory: str | os.PathLike = DATA_DIR, *,
                      nodes: bool = False) -> dict[float, SweepSettings] | dict[tuple[float, float], SweepSettings]:
    """The sweep settings with which the table ``name`` in ``directory`` was made, read from its provenance.

    Per γ (``{gamma: settings}``), or with ``nodes=True`` per node (``{(density, gamma): settings}``): a table
    whose grid is scaled with density (``studies/wall_foam.py table --reference-density``) has one setting per
    node, and asking it per γ is refused. Regenerating a table (a shipped one by default) with these settings
    recomputes its own samples, whatever today's defaults: a provenance that records no discretization (tables made
    before the choice existed) means ``"rotated"``. The provenance's settings (:func:`_recorded`: per node, per γ or
    one for all; through merged and bracket provenances) must agree with the inputs recorded in every sample row
    (:func:`settings_from_row`); ``maxiter``, which rows do not record, comes from the provenance. Raises
    :class:`~foambase.errors.InputError` naming the table for a provenance that is missing, unreadable, has no
    settings for a node of its samples or disagrees with its rows.
    """
    paths = table_paths(name, directory)
    try:
        provenance = json.loads(paths["provenance"].read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"foam table {name!r}: provenance {str(paths['provenance'])!r} unreadable ({exc})") from exc
    try:
        with open(paths["samples"], newline="") as f:  # the oldest tables have no box, distance columns
            rows = [{"box": "cube", "distance": "euclidean"} | {k: _parse_cell(v) for k, v in row.items()}
                    for row in csv.DictReader(f)]
    except OSError as exc:
        raise InputError(f"foam table {name!r}: samples {str(paths['samples'])!r} unreadable ({exc})") from exc
    fields = SweepSettings.__dataclass_fields__
    per_node: dict[tuple[float, float], SweepSettings] = {}
    for row in rows:
        density, gamma = float(row["density"]), float(row["gamma"])
        recorded = _recorded(provenance, density, gamma)
        if not isinstance(recorded, dict):
            raise InputError(f"foam table {name!r}: its provenance records no settings for density {density:g}, "
                             f"gamma {gamma:g}")
        from_row = settings_from_row(row)
        kwargs = {k: v for k, v in recorded.items() if k in fields} | {"discretization": recorded.get(
            "discretization", "rotated")}
        if isinstance(kwargs.get("resolution"), list):
            kwargs["resolution"] = tuple(kwargs["resolution"])
        kwargs.setdefault("cubic", from_row.cubic)
        try:
            settings = SweepSettings(**kwargs)
        except InputError as exc:
            raise InputError(f"foam table {name!r}, gamma {gamma:g}: recorded settings unusable ({exc})") from exc
        if _cache_key(Sample(row["density"], gamma, row["seed"]), settings) != _cache_key(
                Sample(row["density"], gamma, row["seed"]), from_row):
            raise InputError(f"foam table {name!r}, gamma {gamma:g}: the provenance's settings {settings} are not "
                             f"those of its sample rows {from_row}")
        per_node.setdefault((density, gamma), settings)
    if nodes:
        return dict(sorted(per_node.items()))
    out: dict[float, SweepSettings] = {}
    for (_, gamma), settings in sorted(per_node.items()):
        if out.setdefault(gamma, settings) != settings:
            raise InputError(f"foam table {name!r}: its settings vary with density at gamma {gamma:g} "
                             f"({out[gamma].resolution} and {settings.resolution}): ask them per node "
                             "(recorded_settings(..., nodes=True))")
    return out


def _parse_cell(text: str):
    """A CSV cell written by :func:`to_csv` back as the value: ``int``, ``float`` (``repr``, exact) or text."""
    if re.fullmatch(r"-?\d+", text):
        return int(text)
    try:
        return float(text)
    except ValueError:
        return text


def read_samples(path: str | os.PathLike) -> list[dict]:
    """The sample rows of a ``*_samples.csv`` written by :func:`write_tables`, with their values' types restored."""
    try:
        with open(path, newline="") as f:
            rows = [{k: _parse_cell(v) for k, v in row.items()} for row in csv.DictReader(f)]
    except OSError as exc:
        raise InputError(f"foam table samples {str(path)!r} cannot be read ({exc.strerror})") from exc
    missing = [c for c in INPUTS if rows and c not in rows[0]]
    if not rows or missing:
        raise InputError(f"{str(path)!r} is not a foam table's samples file (no rows, or no column {missing[:1]})")
    return rows


def _row_settings(row: dict) -> dict:
    return settings_dict(settings_from_row(row))


def merge_samples(sources: Sequence[tuple[str, Sequence[dict]]], *, mixed: bool = False) -> list[dict]:
    """The samples of several tables as one table's samples, refusing any mix of settings at one grid node.

    ``sources`` are ``(label, rows)`` pairs (e.g. per-density tables of one sweep). A (density, γ) node may come
    from several sources only with the same settings (cells, grid, tolerance, box, foam, discretization) for every
    seed; a sample (density, γ, seed) given twice must have the same settings and the same stiffness, and is kept
    once. All rows must belong to one table (:attr:`SweepSettings.name`), unless ``mixed``: then nodes of
    different tables, with the same columns, may be put together (e.g. each γ at the discretization its
    resolution study chose; every row keeps its own settings columns). Raises
    :class:`~foambase.errors.InputError` naming the node, the sources and the differing settings, before anything
    is written.
    """
    nodes: dict[tuple[float, float], tuple[str, dict]] = {}
    samples: dict[tuple[float, float, int], tuple[str, dict]] = {}
    names: dict[str, str] = {}
    for label, rows in sources:
        for row in rows:
            settings = _row_settings(row)
            names.setdefault(settings_from_row(row).name, label)
            node = (float(row["density"]), float(row["gamma"]))
            first_label, first = nodes.setdefault(node, (label, settings))
            if first != settings:
                diff = {k: (first[k], settings[k]) for k in first if first[k] != settings[k]}
                raise InputError(f"cannot merge: density {node[0]}, gamma {node[1]} has other settings in "
                                 f"{label!r} than in {first_label!r}: " + ", ".join(
                                     f"{k} {a!r} vs {b!r}" for k, (a, b) in diff.items()))
            key = node + (int(row["seed"]),)
            if key in samples:
                other_label, other = samples[key]
                if any(other[c] != row[c] for c in C_ENTRIES):
                    raise InputError(f"cannot merge: sample density {key[0]}, gamma {key[1]}, seed {key[2]} "
                                     f"differs between {other_label!r} and {label!r} at the same settings")
                continue
            samples[key] = (label, row)
    if len(names) > 1 and not mixed:
        raise InputError(f"cannot merge rows of different tables: {sorted(names)} (from {sorted(names.values())}); "
                         "give the merged table a name to put them together")
    columns = {label: list(rows[0]) for label, rows in sources if rows}
    if mixed and len({tuple(c) for c in columns.values()}) > 1:
        first, *others = columns.items()
        other = next(o for o in others if o[1] != first[1])
        raise InputError(f"cannot merge tables of other columns: {other[0]!r} has "
                         f"{sorted(set(other[1]) ^ set(first[1])) or 'them in another order'} unlike {first[0]!r}")
    if not samples:
        raise InputError("cannot merge: no samples")
    return [row for _, (_, row) in sorted(samples.items())]


def merge_tables(sources: Sequence[str | os.PathLike], out_dir: str | os.PathLike,
                 name: str | None = None) -> dict[str, Path]:
    """Merge the tables written by :func:`write_tables` in the directories ``sources`` into one in ``out_dir``.

    Each source holds one table (one ``foam_table*_samples.csv``); the merged samples (:func:`merge_samples`),
    their aggregate over seeds and a provenance listing every source's provenance are written under that table's
    name, or under ``name`` (a word of letters, digits and ``_``), which also lets the sources be different tables
    whose nodes do not overlap (``merge_samples(mixed=True)``; each node's settings stay its source's,
    :func:`recorded_settings`). Raises :class:`~foambase.errors.InputError` before writing anything for a source
    without exactly one table, with conflicting settings, or for an invalid ``name``.
    """
    if name is not None and not re.fullmatch(r"[A-Za-z0-9_]+", str(name)):
        raise InputError(f"a merged table's name must be letters, digits and '_', got {name!r}")
    loaded, provenance = [], []
    for source in sources:
        rows, prov = _read_table_dir(source, "merge")
        loaded.append((str(source), rows))
        provenance.append({"source": str(source), "provenance": prov})
    rows = merge_samples(loaded, mixed=name is not None)
    name = name or settings_from_row(rows[0]).name
    merged = {"merged_from": provenance, "date": datetime.now(UTC).isoformat(timespec="seconds"),
              "n_samples": len(rows), "sample_wall_s_total": float(sum(float(r["wall_s"]) for r in rows))}
    return write_tables(rows, out_dir, merged, name)


def _read_table_dir(source: str | os.PathLike, what: str) -> tuple[list[dict], dict]:
    """The samples and provenance of the one table that :func:`write_tables` wrote into ``source``."""
    found = sorted(Path(source).glob("foam_table*_samples.csv"))
    if len(found) != 1:
        raise InputError(f"{what} source {str(source)!r} must hold exactly one foam_table*_samples.csv, found "
                         f"{[p.name for p in found]}")
    prov_path = found[0].with_name(found[0].name.replace("_samples.csv", "_provenance.json"))
    try:
        prov = json.loads(prov_path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{what} source {str(source)!r}: provenance {prov_path.name} unreadable ({exc})") from exc
    return read_samples(found[0]), prov


def bracket_tables(lower: str | os.PathLike, upper: str | os.PathLike, out_dir: str | os.PathLike,
                   estimate: str = "midpoint") -> dict[str, Path]:
    """The ``"bracket"`` table of a rotated table (directory ``lower``) and a hex8 table (``upper``).

    Both must hold the same samples (:func:`bracket_samples`, with its ``estimate``); the table is written into
    ``out_dir`` with a provenance holding both sources' and the estimate.
    """
    (low, low_prov), (high, high_prov) = _read_table_dir(lower, "bracket"), _read_table_dir(upper, "bracket")
    rows = bracket_samples(low, high, estimate)
    provenance = {"bracketed_from": {"rotated": {"source": str(lower), "provenance": low_prov},
                                     "hex8": {"source": str(upper), "provenance": high_prov}},
                  "estimate": estimate,
                  "date": datetime.now(UTC).isoformat(timespec="seconds"), "n_samples": len(rows),
                  "sample_wall_s_total": float(sum(float(r["wall_s"]) for r in rows))}
    return write_tables(rows, out_dir, provenance, settings_from_row(rows[0]).name)
