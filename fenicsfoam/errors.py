"""The error family of fenicsfoam (re-exported from :mod:`foambase.errors`; importing it imports no dolfinx).

``except fenicsfoam.errors.FenicsfoamError`` catches every error the public API raises; the categories keep their
builtin parents (:class:`InputError` is a ``ValueError``, :class:`NotConvergedError` a ``RuntimeError``) and carry
the command-line exit status (``exit_code``: 1 other failure, 2 bad input, 3 did not converge).
"""

from foambase.errors import (
    EXIT_FAILURE,
    EXIT_INPUT,
    EXIT_NOT_CONVERGED,
    EXIT_OK,
    ComputationError,
    FenicsfoamError,
    InputError,
    NotConvergedError,
    exit_code,
)

__all__ = [
    "EXIT_FAILURE",
    "EXIT_INPUT",
    "EXIT_NOT_CONVERGED",
    "EXIT_OK",
    "ComputationError",
    "FenicsfoamError",
    "InputError",
    "NotConvergedError",
    "exit_code",
]
