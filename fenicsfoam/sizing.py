"""A scene's size before assembly: cells, dofs, the solver it gets, and the memory and time that solver will take.

:func:`size_of` counts the dofs of a mesh for the displacement's degree (vertices, plus edges for P2; ×3) without
building a function space. :func:`choose_solver` picks the linear solver of the Newton iterations:

* ``direct``: MUMPS LU (:meth:`fenicsfoam.solver.ElasticityProblem.default_options`), up to
  :data:`ITERATIVE_ABOVE_DOFS` dofs and as long as its estimated memory fits in the available memory;
* ``iterative``: Krylov + GAMG with the rigid-body near-null space (attached to every Jacobian), CG for models whose
  tangent is symmetric and GMRES for the corotational one (:func:`solver_options`), otherwise.

Why by memory: measured on the Fig. 6 beam at P2 (``bench/bench_large_runs.py``; the benchmark page of 2026-11-27,
"large runs"), LU is about 16× faster per Newton iteration at every measured size (10k–125k dofs; the two times
grow alike, as n^1.5), so there is no time crossover to switch at; LU's memory grows faster than linearly and
GAMG's linearly, so the iterative solver is what runs when LU would not fit, and above :data:`ITERATIVE_ABOVE_DOFS`,
where the LU model would be extrapolated far beyond the measurements.

:func:`estimate` is a model calibrated by the same measurements (serial, P2, corotational, CPU time on a shared
machine): peak resident memory ``M = ranks × M0 + a · dofs^p`` and the CPU time of one Newton iteration
``t = c · dofs^q``, with ``(a, p, c, q)`` per solver (:data:`MODEL`), divided by the number of ranks; a step is
estimated at :data:`NEWTON_PER_INCREMENT` iterations per increment. The model's error on the measured cases is on the
benchmark page; the estimate is an order of magnitude to decide with, not a promise. A run whose estimated memory
exceeds the machine's available memory (``MemAvailable``, or the cgroup's room if smaller; the environment variable
``FENICSFOAM_AVAILABLE_MEMORY``, in bytes, overrides it) is refused before assembly with :class:`TooLargeError`
(exit status 2), unless forced.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from foambase.errors import InputError

__all__ = ["ITERATIVE_ABOVE_DOFS", "MODEL", "NEWTON_PER_INCREMENT", "SOLVERS", "SizeEstimate", "TooLargeError",
           "available_memory", "choose_solver", "estimate", "size_of", "solver_options"]

#: The linear solvers a run can be given (``auto`` chooses by size).
SOLVERS = ("auto", "direct", "iterative")
#: Above this many dofs ``auto`` picks the iterative solver (the measured crossover, rounded).
ITERATIVE_ABOVE_DOFS = 1_000_000
#: Resident memory of one process before any mesh (Python, dolfinx, PETSc, the scene's forms), bytes (fitted).
BASELINE_BYTES = 207 * 2**20
#: ``solver: (a, p, c, q)``: memory ``a · dofs^p`` bytes above the baseline, ``c · dofs^q`` CPU s per Newton
#: iteration (``bench/bench_large_runs.py --fit``, the benchmark page of 2026-11-27).
MODEL: dict[str, tuple[float, float, float, float]] = {
    "direct": (86.2, 1.402, 8.9e-8, 1.502),
    "iterative": (1.29e3, 1.0, 1.72e-6, 1.480),
}
#: Newton iterations per load increment assumed by the time estimate (the scenes' median is 3–5).
NEWTON_PER_INCREMENT = 4


class TooLargeError(InputError):
    """The run's estimated memory exceeds the memory available (exit status 2); the message holds the estimate."""


@dataclass(frozen=True)
class SizeEstimate:
    """A run's size and what its solver is expected to need (:func:`estimate`)."""

    cells: int
    dofs: int
    ranks: int
    solver: str                 #: ``direct`` or ``iterative``
    memory_bytes: float         #: estimated peak resident memory of all ranks together
    newton_s: float             #: estimated wall time of one Newton iteration
    solve_s: float              #: estimated wall time of the load schedule's Newton iterations
    available_bytes: float      #: the memory available on this machine now (nan if unknown)

    @property
    def fits(self) -> bool:
        """The estimated memory is within the available memory (true when that is unknown)."""
        return not self.memory_bytes > self.available_bytes

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``summary.json``'s ``estimate``)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}

    def __str__(self) -> str:
        solver = "MUMPS LU" if self.solver == "direct" else "Krylov + GAMG"
        available = ("unknown" if not math.isfinite(self.available_bytes)
                     else _bytes(self.available_bytes))
        return (f"{self.cells} cells, {self.dofs} dofs on {self.ranks} rank(s), {self.solver} solver ({solver}): "
                f"estimated {_bytes(self.memory_bytes)} of memory ({available} available), "
                f"{_seconds(self.newton_s)} per Newton iteration, about {_seconds(self.solve_s)} for the load steps")


def _bytes(n: float) -> str:
    return f"{n / 2**30:.1f} GB" if n >= 2**30 else f"{n / 2**20:.0f} MB"


def _seconds(t: float) -> str:
    return f"{t:.2g} s" if t < 60 else f"{t / 60:.1f} min" if t < 3600 else f"{t / 3600:.1f} h"


def size_of(mesh, degree: int) -> tuple[int, int]:
    """``(cells, dofs)`` of a 3D vector Lagrange field of ``degree`` (1 or 2) on ``mesh`` (collective; edges made)."""
    tdim = mesh.topology.dim
    nodes = mesh.topology.index_map(0).size_global
    if degree == 2:
        mesh.topology.create_entities(1)
        nodes += mesh.topology.index_map(1).size_global
    return mesh.topology.index_map(tdim).size_global, 3 * nodes


def choose_solver(solver: str, dofs: int, direct_fits: bool = True) -> str:
    """``direct`` or ``iterative``: ``solver`` itself, or for ``auto`` by size and memory.

    ``auto``: the direct solver up to :data:`ITERATIVE_ABOVE_DOFS` dofs while its estimated memory fits
    (``direct_fits``), the iterative one otherwise.
    """
    if solver not in SOLVERS:
        raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    if solver != "auto":
        return solver
    return "direct" if dofs <= ITERATIVE_ABOVE_DOFS and direct_fits else "iterative"


def solver_options(solver: str, symmetric: bool) -> dict[str, Any]:
    """The PETSc options (without prefix) of a solver choice; ``{}`` for ``direct`` (the problem's defaults)."""
    if solver == "direct":
        return {}
    return {"ksp_type": "cg" if symmetric else "gmres", "pc_type": "gamg", "ksp_rtol": 1e-8, "ksp_max_it": 1000}


def available_memory() -> float:
    """Bytes of memory available to new allocations now: ``MemAvailable``, or the cgroup's room if smaller."""
    available = math.inf
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                available = float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = float(Path("/sys/fs/cgroup/memory.current").read_text())
            available = min(available, float(limit) - used)
    except (OSError, ValueError):
        pass
    return available if math.isfinite(available) else math.nan


def estimate(cells: int, dofs: int, solver: str, ranks: int = 1, increments: int = 1,
             available: float | None = None) -> SizeEstimate:
    """The memory and time model of the module docstring for a run of ``increments`` load increments in all."""
    if solver not in MODEL:
        raise InputError(f"solver must be 'direct' or 'iterative', got {solver!r}")
    a, p, c, q = MODEL[solver]
    memory = ranks * BASELINE_BYTES + a * dofs**p
    newton = c * dofs**q / max(1, ranks)  # measured serially: ranks are assumed to divide the time
    available = available_memory() if available is None else available
    override = os.environ.get("FENICSFOAM_AVAILABLE_MEMORY")
    if override:
        try:
            available = float(override)
        except ValueError as exc:
            raise InputError(f"FENICSFOAM_AVAILABLE_MEMORY must be a number of bytes, got {override!r}") from exc
    return SizeEstimate(cells, dofs, ranks, solver, memory, newton, newton * NEWTON_PER_INCREMENT * increments,
                        available)
