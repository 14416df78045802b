"""The error family of fenicsfoam (re-exported from :mod:`foambase.errors`; importing it imports no dolfinx).

``except fenicsfoam.errors.FenicsfoamError`` catches every error the public API raises; the categories keep their
builtin parents (``InputError`` is a ``ValueError``, ``NotConvergedError`` a ``RuntimeError``) and carry the
command-line exit status (``exit_code``: 1 other failure, 2 bad input, 3 did not converge).
"""

from foambase.errors import *  # noqa: F403 - the whole family, re-exported
from foambase.errors import __all__  # noqa: F401
