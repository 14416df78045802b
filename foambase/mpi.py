"""Work whose failure every rank learns: done on rank 0 only (gmsh, serial meshers, file checks), or on every rank.

Without this, a failure on one rank leaves the other ranks waiting forever in the next collective call. With
:func:`on_rank0` the outcome is broadcast: rank 0 re-raises its own exception, every other rank raises a
:class:`~foambase.errors.ComputationError` that names it and carries the same exit code, so all ranks stop together
with the same command-line exit status. :func:`on_every_rank` does the same for work done by every rank (e.g. a
user's function evaluated on each rank's cells) that may fail on some ranks only: the lowest failing rank's error is
raised everywhere, as itself on that rank and with its message and exit code on the others.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from foambase.errors import EXIT_INPUT, ComputationError, InputError, exit_code

__all__ = ["on_every_rank", "on_rank0"]

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


def on_every_rank(comm: Any, work: Callable[[], T], what: str) -> T:
    """Call ``work()`` on every rank of ``comm``; if it fails on any rank, raise on every rank (collective).

    Parameters
    ----------
    comm
        The MPI communicator.
    work
        The work, called on every rank.
    what
        What failed, as the ranks where it did not fail report it: ``"{what} on rank r (<error type>: <message>)"``.

    Raises
    ------
    Exception
        The lowest failing rank re-raises its exception; every other rank raises an error of the same exit code
        with that rank's message (an :class:`~foambase.errors.InputError` when the failure was bad input, so
        that every rank reports the same kind of error).

    """
    result, failure = None, None
    try:
        result = work()
    except Exception as exc:  # re-raised below, after every rank knows
        failure = exc
    reports = comm.allgather(None if failure is None else (f"{type(failure).__name__}: {failure}", str(failure),
                                                           exit_code(failure)))
    first = next((rank for rank, report in enumerate(reports) if report is not None), None)
    if first is None:
        return result
    if comm.rank == first:
        raise failure
    full, message, code = reports[first]
    error = (InputError(message) if code == EXIT_INPUT else
             ComputationError(f"{what} on rank {first} ({full})"))
    error.exit_code = code
    raise error
