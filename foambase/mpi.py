"""Work done on rank 0 only (gmsh, serial meshers), with its failure known to every rank.

Without this, a failure on rank 0 leaves the other ranks waiting forever in the next collective call. With
:func:`on_rank0` the outcome is broadcast: rank 0 re-raises its own exception, every other rank raises a
:class:`~foambase.errors.ComputationError` that names it and carries the same exit code, so all ranks stop together
with the same command-line exit status.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from foambase.errors import ComputationError, exit_code

__all__ = ["on_rank0"]

T = TypeVar("T")


def on_rank0(comm: Any, build: Callable[[], T], what: str) -> T | None:
    """Call ``build()`` on rank 0 of ``comm``; return its result there and ``None`` on the other ranks (collective).

    Parameters
    ----------
    comm
        The MPI communicator.
    build
        The work; called on rank 0 only.
    what
        What failed, as the other ranks report it: ``"{what} on rank 0 (<error type>: <message>)"``, e.g.
        ``"gmsh failed to build 'beam'"``.

    Raises
    ------
    Exception
        On rank 0, whatever ``build`` raised; on the other ranks a ``ComputationError`` with its exit code.

    """
    result, failure = None, None
    if comm.rank == 0:
        try:
            result = build()
        except Exception as exc:  # re-raised below on rank 0, after telling the other ranks
            failure = exc
    report = comm.bcast(None if failure is None else (f"{type(failure).__name__}: {failure}", exit_code(failure)),
                        root=0)
    if report is None:
        return result
    if comm.rank == 0:
        raise failure
    error = ComputationError(f"{what} on rank 0 ({report[0]})")
    error.exit_code = report[1]
    raise error
