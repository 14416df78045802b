"""The error family: every error that fenicsfoam's public API raises derives from :class:`FenicsfoamError`.

Each error keeps the builtin parent a caller may already catch (bad input is still a ``ValueError``, a solver that
did not converge still a ``RuntimeError``) and carries the exit status that the command lines return for it,
``exit_code``; :func:`exit_code` reads it in the one place that maps errors to exit statuses:

====  =================================================================================
code  meaning
====  =================================================================================
0     success
1     any other failure (:class:`FenicsfoamError`, :class:`ComputationError`, an unexpected exception)
2     bad input, detected before any work (:class:`InputError`; argparse's usage errors too)
3     a solver did not converge (:class:`NotConvergedError`)
====  =================================================================================

A :class:`WriteError` (a :class:`ComputationError`) names an output file that could not be written and the
system's error. The named errors of the packages derive from these categories, e.g. ``fenicsfoam.scene.SceneError`` and
``meshes.foam.FoamParameterError`` from :class:`InputError`, ``fenicsfoam.solver.ConvergenceError`` and
``homogenization.fft.FFTConvergenceError`` from :class:`NotConvergedError`.
"""

from __future__ import annotations

__all__ = [
    "EXIT_FAILURE",
    "EXIT_INPUT",
    "EXIT_NOT_CONVERGED",
    "EXIT_OK",
    "ComputationError",
    "FenicsfoamError",
    "InputError",
    "NotConvergedError",
    "WriteError",
    "exit_code",
]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_INPUT = 2
EXIT_NOT_CONVERGED = 3


class FenicsfoamError(Exception):
    """Base of every fenicsfoam error; ``exit_code`` is the command-line exit status for it (1 unless overridden).

    An instance may carry its own ``exit_code`` (e.g. an error that reports another rank's failure).
    """

    exit_code: int = EXIT_FAILURE


class InputError(FenicsfoamError, ValueError):
    """A bad input value: the message names it and what would be valid (exit status 2)."""

    exit_code = EXIT_INPUT


class NotConvergedError(FenicsfoamError, RuntimeError):
    """An iterative solver did not reach its tolerance (exit status 3)."""

    exit_code = EXIT_NOT_CONVERGED


class ComputationError(FenicsfoamError, RuntimeError):
    """A computation failed for another reason than bad input or non-convergence (exit status 1)."""


class WriteError(ComputationError):
    """An output file could not be written (disk full, file-size limit, quota…) (exit status 1).

    The message names the file and the system's error; the file is absent or its previous version, never
    half-written.
    """


def exit_code(error: BaseException) -> int:
    """The exit status of a command that stopped on ``error`` (the table of the module docstring)."""
    return int(error.exit_code) if isinstance(error, FenicsfoamError) else EXIT_FAILURE
