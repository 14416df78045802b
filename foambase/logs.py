"""Logging for command lines: library code only logs (``logging.getLogger(__name__)``), entry points set it up.

Nothing in the library calls :func:`setup_logging`; the command lines (:mod:`foambase.cli`) and scripts do.

Quiet by default: rank 0 shows warnings and errors (``-v``: also INFO, ``-vv``: DEBUG), the other MPI ranks
errors only. :func:`setup_logging` replaces the root logger's handlers: FFCx installs one at import
(``logging.basicConfig()``), and the C compiler that FFCx runs through cffi raises the root logger to INFO while
it compiles a form, so that handler would print some forty ``INFO:root`` lines per fresh compilation. The handler
installed here has its own level, so those lines appear only with ``-v``.
"""

from __future__ import annotations

import logging
import os
import sys

__all__ = ["LEVELS", "launcher_rank", "setup_logging"]

#: Log level of rank 0 by verbosity (the number of ``-v``).
LEVELS = (logging.WARNING, logging.INFO, logging.DEBUG)
#: Environment variables in which MPI launchers (Open MPI, MPICH/PMI, PMIx, Slurm) give a process its rank.
_RANK_VARIABLES = ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK", "SLURM_PROCID")


def launcher_rank() -> int:
    """The rank of this process in ``MPI.COMM_WORLD``: from mpi4py if loaded, else from the launcher's environment.

    Reading the environment lets a command that never needs MPI (e.g. ``homogenize``) stay free of MPI's start-up.
    """
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None:
        return mpi.COMM_WORLD.rank
    for name in _RANK_VARIABLES:
        value = os.environ.get(name, "")
        if value.isdigit():
            return int(value)
    return 0


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a record is emitted, not when it was made.

    A command run more than once in a process (tests capturing stderr, notebooks) would otherwise keep writing to the
    stream of its first call, which may be closed by then.
    """

    def __init__(self) -> None:
        super().__init__()

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ assigns it; the property always reads sys.stderr
        pass


def setup_logging(verbosity: int = 0, rank: int | None = None) -> None:
    """Log to stderr: rank 0 at :data:`LEVELS` ``[verbosity]``, the other ranks at ERROR (with their rank).

    Parameters
    ----------
    verbosity
        0: warnings, 1: also INFO (including the compiler lines of FFCx's JIT), 2 or more: DEBUG.
    rank
        The MPI rank; default :func:`launcher_rank`.

    """
    rank = launcher_rank() if rank is None else rank
    level = LEVELS[min(max(verbosity, 0), len(LEVELS) - 1)] if rank == 0 else logging.ERROR
    prefix = "" if rank == 0 else f"[rank {rank}] "
    handler = _StderrHandler()
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter(f"%(levelname)s {prefix}%(name)s: %(message)s"))
    logging.basicConfig(level=level, handlers=[handler], force=True)
