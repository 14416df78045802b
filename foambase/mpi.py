"""Work whose failure every rank learns: done on rank 0 only (gmsh, serial meshers, file checks), or on every rank.

Without this, a failure on one rank leaves the other ranks waiting forever in the next collective call. With
:func:`on_rank0` the outcome is broadcast: rank 0 re-raises its own exception, every other rank raises a
:class:`~foambase.errors.ComputationError` that names it and carries the same exit code, so all ranks stop together
with the same command-line exit status. :func:`on_every_rank` does the same for work done by every rank (e.g. a
user's function evaluated on each rank's cells) that may fail on some ranks only: the lowest failing rank's error is
raised everywhere, as itself on that rank and with its message and exit code on the others. A ``sys.exit`` called
inside the work is a failure like any other (:func:`exited`), never a silent end of the program.

What these two do not cover (an error raised on one rank anywhere else) is caught by the command lines
(:func:`foambase.cli.dispatch`): a failing rank asks the others whether they are failing too
(:func:`failed_together`); if they are not, it prints its error itself and stops the job (:func:`abort`,
``MPI_Abort`` with the error's exit status) instead of leaving them waiting.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from foambase.errors import EXIT_INPUT, ComputationError, InputError, exit_code

__all__ = ["FAILURE_GRACE_S", "abort", "exited", "failed_together", "on_every_rank", "on_rank0"]

T = TypeVar("T")


def exited(exc: SystemExit, what: str) -> ComputationError:
    """The error that stands for a ``sys.exit`` called inside work (e.g. by a user's function): a failure, exit 1.

    A ``SystemExit`` raised inside a computation would otherwise end the program with its code (0 for
    ``sys.exit()``) and no output; it is reported as ``"{what}: sys.exit(CODE) was called ..."`` instead.
    """
    error = ComputationError(f"{what}: sys.exit({exc.code!r}) was called inside the computation (e.g. by a "
                             "user's function); the work was not done")
    error.__cause__ = exc
    return error


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
        except SystemExit as exc:
            failure = exited(exc, what)
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
        Every failing rank re-raises its own exception; every other rank raises an error of the same exit code
        with the lowest failing rank's message (an :class:`~foambase.errors.InputError` when the failure was bad
        input, so that every rank reports the same kind of error).

    """
    result, failure = None, None
    try:
        result = work()
    except Exception as exc:  # re-raised below, after every rank knows
        failure = exc
    except SystemExit as exc:  # e.g. a user's function calling sys.exit: a failure, not the end of the run
        failure = exited(exc, what)
    reports = comm.allgather(None if failure is None else (f"{type(failure).__name__}: {failure}", str(failure),
                                                           exit_code(failure)))
    first = next((rank for rank, report in enumerate(reports) if report is not None), None)
    if first is None:
        return result
    if failure is not None:  # a rank that failed itself raises its own error (its type, e.g. a SceneError)
        raise failure
    full, message, code = reports[first]
    error = (InputError(message) if code == EXIT_INPUT else
             ComputationError(f"{what} on rank {first} ({full})"))
    error.exit_code = code
    raise error


#: Seconds a failing rank waits for every other rank to report a failure too before it stops the whole job.
FAILURE_GRACE_S = 5.0
#: The message tag of the failure reports (point-to-point on ``COMM_WORLD``; collectives never match it).
_FAILURE_TAG = 32001
#: Environment variables in which MPI launchers give the number of processes.
_SIZE_VARIABLES = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "SLURM_NTASKS")


def _world():
    """``MPI.COMM_WORLD`` if this process runs under a launcher with more than one rank, else None."""
    import os
    import sys

    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is None:
        sizes = [os.environ.get(name, "") for name in _SIZE_VARIABLES]
        if not any(size.isdigit() and int(size) > 1 for size in sizes):
            return None
        from mpi4py import MPI as mpi  # a rank that failed before MPI was started (e.g. during its imports)
    if not mpi.Is_initialized() or mpi.Is_finalized() or mpi.COMM_WORLD.size == 1:
        return None
    return mpi.COMM_WORLD


def failed_together(code: int, grace_s: float | None = None) -> bool:
    """Whether every rank of ``COMM_WORLD`` is failing too (called by a rank that is failing; not collective).

    The failing rank tells every other rank (a message outside any collective) and waits up to ``grace_s``
    (:data:`FAILURE_GRACE_S`) for the same report from each. An error that every rank raises (bad input checked
    on every rank, an error spread by :func:`on_rank0` or :func:`on_every_rank`) arrives within milliseconds:
    True, and the ranks stop together as usual. A failure on some ranks only leaves the others inside a
    collective call, where they would wait forever: False, and the caller stops the job (:func:`abort`).
    Serially (or without MPI): True.
    """
    import time

    comm = _world()
    if comm is None:
        return True
    from mpi4py import MPI

    others = [r for r in range(comm.size) if r != comm.rank]
    sends = [comm.isend(int(code), dest=r, tag=_FAILURE_TAG) for r in others]
    heard: set[int] = set()
    deadline = time.monotonic() + (FAILURE_GRACE_S if grace_s is None else grace_s)
    status = MPI.Status()
    while len(heard) < len(others) and time.monotonic() < deadline:
        if comm.iprobe(source=MPI.ANY_SOURCE, tag=_FAILURE_TAG, status=status):
            source = status.Get_source()
            comm.recv(source=source, tag=_FAILURE_TAG)
            heard.add(source)
        else:
            time.sleep(0.01)
    if len(heard) < len(others):
        return False
    while not MPI.Request.Testall(sends) and time.monotonic() < deadline + 1.0:  # every report was received
        time.sleep(0.01)
    return True


def abort(code: int) -> None:
    """Stop every rank of ``COMM_WORLD`` with exit status ``code`` (``MPI_Abort``); does not return under MPI."""
    comm = _world()
    if comm is not None:
        comm.Abort(int(code))
