"""Default thread counts: the CPUs this process may run on, shared among the MPI ranks of a node.

OpenBLAS threads spin against FFTW's (measured: 20 → 12 ms per FFT iteration at 48³ with OpenBLAS at one thread),
and OpenBLAS reads ``OPENBLAS_NUM_THREADS`` only when numpy first loads it. Library code never changes the
environment; the command-line entry points call :func:`single_threaded_blas_by_default` before anything imports
numpy (as the Makefile and the test suite's ``conftest.py`` set the variable themselves).
"""

from __future__ import annotations

import os
from typing import Any

__all__ = ["cpu_count", "single_threaded_blas_by_default", "threads_per_rank"]


def cpu_count() -> int:
    """The number of CPUs this process may run on (its affinity mask; ``os.cpu_count()`` elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def threads_per_rank(comm: Any = None) -> int:
    """The CPUs of this process divided among the ranks of ``comm`` (at least 1)."""
    return max(1, cpu_count() // (1 if comm is None else comm.size))


def single_threaded_blas_by_default() -> None:
    """Set ``OPENBLAS_NUM_THREADS=1`` unless the user has set it: for entry points, before numpy is imported."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
