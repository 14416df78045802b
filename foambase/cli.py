"""Command lines made of sub-commands, with one table of exit codes.

A :class:`Command` is a name, a help line, a function that adds its arguments to an ``argparse`` parser, an
optional usage check and the function that runs it. :func:`main` builds ``PROG COMMAND [options]`` from a
registry of ``"module:ATTRIBUTE"`` strings (a new sub-command is one line in the registry; its module is imported
when the parser is built) and :func:`main_single` runs one command as a program of its own (an alias such as
``homogenize``); both go through :func:`dispatch`, the one place that maps outcomes to exit statuses:

====  ======================================================================================
code  meaning
====  ======================================================================================
0     success
1     any other failure (a :class:`~foambase.errors.FenicsfoamError` with code 1; an unexpected exception,
      which prints its traceback)
2     bad input, detected before any work: argparse usage errors, a command's usage check, and
      :class:`~foambase.errors.InputError` (e.g. an invalid scene)
3     a solver did not converge (:class:`~foambase.errors.NotConvergedError`)
130   interrupted by SIGINT (Ctrl-C); 143: by SIGTERM (``128 +`` the signal number,
      :mod:`foambase.signals`)
====  ======================================================================================

Before anything else, the entry points keep OpenBLAS single-threaded unless the user said otherwise
(:func:`foambase.threads.single_threaded_blas_by_default`; it must happen before numpy is imported, which is why the
registry is imported lazily), then set up logging on rank 0 (:func:`foambase.logs.setup_logging`: ``-v`` INFO,
``-vv`` DEBUG). Errors of the family are printed once, on rank 0, as ``PROG COMMAND: error: message``. The command
runs inside :func:`foambase.signals.interruptible`: a SIGTERM unwinds like a Ctrl-C (clean-up code runs, temporary
files are removed) and either is reported as ``PROG COMMAND: interrupted by SIGNAL``.

Under ``mpirun`` no rank is left waiting for one that failed: a failing rank checks that every other rank is
failing too (:func:`foambase.mpi.failed_together`, within :data:`foambase.mpi.FAILURE_GRACE_S`); if one is not
(an error that only some ranks met, outside the collective checks of :mod:`foambase.mpi`), the failing rank prints
``PROG COMMAND: error on rank R only: message`` and stops the job with the error's exit status (``MPI_Abort``).
A ``sys.exit`` called inside a command (e.g. by a user's function) is a failure (status 1), never a silent success.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from foambase import signals
from foambase.errors import EXIT_FAILURE, EXIT_OK, FenicsfoamError, exit_code
from foambase.files import UNCLOSABLE
from foambase.logs import launcher_rank, setup_logging
from foambase.mpi import abort, exited, failed_together
from foambase.signals import interruptible
from foambase.threads import single_threaded_blas_by_default

__all__ = ["EPILOG", "Command", "build_parser", "dispatch", "main", "main_single", "nonempty_path", "report_checks",
           "resolve", "shorten"]

#: The exit status of a Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130
#: The exit-code table, shown under every ``--help``.
EPILOG = ("exit status: 0 ok, 1 other failure, 2 bad input (before any work), 3 a solver did not converge, "
          "130/143 interrupted (SIGINT/SIGTERM)")


@dataclass(frozen=True)
class Command:
    """A sub-command.

    Attributes
    ----------
    name
        The sub-command's name (``fenicsfoam NAME``).
    help
        One line for ``PROG --help``.
    add_arguments
        Adds the command's arguments to its parser.
    run
        Runs the command; returns the exit status (0) or raises an error of the family.
    description
        Longer text for ``PROG NAME --help`` (default: ``help``).
    check
        ``check(parser, args)`` validates the arguments before any work and reports a usage error with
        ``parser.error`` (exit status 2).
    passthrough
        Arguments after ``--`` are not parsed but handed to the command as ``args.passthrough`` (e.g. PETSc options).

    """

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str = ""
    check: Callable[[argparse.ArgumentParser, argparse.Namespace], None] | None = None
    passthrough: bool = False


def nonempty_path(text: str) -> Path:
    """An ``argparse`` type: a path, refusing the empty string (which ``Path`` would read as ``.``)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


def resolve(spec: str) -> Command:
    """The :class:`Command` named by ``"module:ATTRIBUTE"``."""
    from foambase.imports import import_object

    return import_object(spec)


def _verbosity(parser: argparse.ArgumentParser, dest: str = "verbose") -> None:
    parser.add_argument("-v", "--verbose", dest=dest, action="count", default=0,
                        help="more log output: -v INFO (with FFCx's compiler lines), -vv DEBUG")


def _command_parser(parser: argparse.ArgumentParser, command: Command) -> None:
    command.add_arguments(parser)
    _verbosity(parser)
    parser.set_defaults(command=command, command_parser=parser)


def build_parser(prog: str, description: str, commands: Sequence[Command]) -> argparse.ArgumentParser:
    """The parser of ``PROG [-v] COMMAND [options]``."""
    parser = argparse.ArgumentParser(prog=prog, description=description, epilog=EPILOG)
    _verbosity(parser, dest="verbose_global")
    sub = parser.add_subparsers(dest="command_name", required=True, metavar="COMMAND")
    for command in commands:
        _command_parser(sub.add_parser(command.name, help=command.help, epilog=EPILOG,
                                       description=command.description or command.help,
                                       formatter_class=argparse.ArgumentDefaultsHelpFormatter), command)
    return parser


def _split_passthrough(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    argv = list(argv)
    if "--" not in argv:
        return argv, []
    i = argv.index("--")
    return argv[:i], argv[i + 1:]


def dispatch(parser: argparse.ArgumentParser, argv: Sequence[str]) -> int:
    """Parse ``argv``, set up logging, run the chosen command and map its outcome to an exit status."""
    own, passthrough = _split_passthrough(argv)
    args = parser.parse_args(own)  # usage errors: SystemExit(2); --help: SystemExit(0)
    command: Command = args.command
    own_parser: argparse.ArgumentParser = args.command_parser
    if passthrough and not command.passthrough:
        own_parser.error(f"unrecognized arguments after '--': {' '.join(passthrough)}")
    args.passthrough = passthrough
    setup_logging(args.verbose + getattr(args, "verbose_global", 0))
    code = _dispatch(own_parser, command, args)
    if UNCLOSABLE:  # a native file that failed to write: the exit-time clean-up of its library would crash
        _exit_without_cleanup(code)
    return code


#: The longest error message printed whole (a message quoting a huge value is cut in its middle).
MAX_MESSAGE = 2000


def shorten(text: str, limit: int = MAX_MESSAGE) -> str:
    """``text``, or its first and last ``limit // 2`` characters around a note of how many were left out."""
    if len(text) <= limit:
        return text
    half = limit // 2
    return f"{text[:half]} … ({len(text) - 2 * half} characters left out) … {text[-half:]}"


def _exit_without_cleanup(code: int) -> None:
    """End the process now with ``code``: output flushed, no exit-time handlers of native libraries.

    Not even ``MPI_Finalize``: parallel HDF5 closes its files from it and crashes on the one that failed.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _dispatch(own_parser: argparse.ArgumentParser, command: Command, args: argparse.Namespace) -> int:
    def interrupted_line(signal_name: str) -> None:  # the signal backstop ended a main thread stuck in compiled code
        sys.stdout.flush()  # what the command printed (a run's table of the steps done) comes first
        if launcher_rank() == 0:
            print(f"{own_parser.prog}: interrupted by {signal_name} (the main thread was inside a compiled call and "
                  f"was stopped {signals.FORCE_S:g} s after the signal)", file=sys.stderr, flush=True)

    try:
        with interruptible():
            signals.register_last_resort(interrupted_line)  # the first registered: it runs last
            try:
                if command.check is not None:
                    command.check(own_parser, args)
                try:
                    status = command.run(args)
                except SystemExit as exc:  # sys.exit inside the work (e.g. a user's function): not a success
                    raise exited(exc, "the command did not finish") from exc
            finally:
                signals.discard_last_resort(interrupted_line)
    except FenicsfoamError as error:
        code = exit_code(error)
        if not failed_together(code):  # the other ranks wait in a collective call: stop them, say why here
            print(f"{own_parser.prog}: error on rank {launcher_rank()} only: {shorten(str(error))}", file=sys.stderr,
                  flush=True)
            abort(code)
        if launcher_rank() == 0:
            print(f"{own_parser.prog}: error: {shorten(str(error))}", file=sys.stderr)
        return code
    except KeyboardInterrupt as interruption:  # foambase.signals.Interrupted carries its signal's exit status
        if launcher_rank() == 0:
            print(f"{own_parser.prog}: {interruption or 'interrupted'}", file=sys.stderr)
        return getattr(interruption, "exit_code", EXIT_INTERRUPTED)
    except Exception:  # a bug: its traceback, and under MPI no rank left waiting for this one
        if not failed_together(EXIT_FAILURE):
            traceback.print_exc()
            print(f"{own_parser.prog}: unexpected error on rank {launcher_rank()} only", file=sys.stderr, flush=True)
            abort(EXIT_FAILURE)
        raise
    return EXIT_OK if status is None else int(status)


def main(prog: str, description: str, registry: Sequence[str], argv: Sequence[str] | None = None) -> int:
    """Run ``PROG COMMAND ...`` for the commands of ``registry`` (``"module:ATTRIBUTE"`` strings)."""
    single_threaded_blas_by_default()
    try:  # the command modules import the numerical stack: seconds in which Ctrl-C is a clean stop, no traceback
        parser = build_parser(prog, description, [resolve(spec) for spec in registry])
    except KeyboardInterrupt:
        return _interrupted_while_loading(prog)
    return dispatch(parser, sys.argv[1:] if argv is None else argv)


def report_checks(failures: Sequence[str], comm=None) -> int:
    """The exit status of a script's own checks (demos, studies), the same on every rank: 0 if none failed, else 1.

    Rank 0's ``failures`` are broadcast (a check computed on rank 0 only may pass ``[]`` or ``None`` elsewhere);
    rank 0 prints each as ``CHECK FAILED: ...`` on stderr, then ``all checks passed`` or ``N check(s) failed`` on
    stdout. ``comm`` defaults to ``MPI.COMM_WORLD``.
    """
    if comm is None:
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
    failures = comm.bcast(list(failures) if comm.rank == 0 else None, root=0)
    if comm.rank == 0:
        for failure in failures:
            print(f"CHECK FAILED: {failure}", file=sys.stderr, flush=True)
        print("all checks passed" if not failures else f"{len(failures)} check(s) failed", flush=True)
    return 1 if failures else 0


def main_single(command: Command, prog: str, argv: Sequence[str] | None = None) -> int:
    """Run one command as the program ``prog`` (same arguments, same code path and exit statuses)."""
    single_threaded_blas_by_default()
    parser = argparse.ArgumentParser(prog=prog, description=command.description or command.help, epilog=EPILOG,
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _command_parser(parser, command)
    return dispatch(parser, sys.argv[1:] if argv is None else argv)


def _interrupted_while_loading(prog: str) -> int:
    """Ctrl-C before any work: one line, nothing written, :data:`EXIT_INTERRUPTED`."""
    if launcher_rank() == 0:
        print(f"{prog}: interrupted while loading (nothing was done)", file=sys.stderr)
    return EXIT_INTERRUPTED
