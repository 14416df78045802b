"""PETSc options that nothing reads are reported, never silently ignored: PETSc's own "options left" bookkeeping.

PETSc marks an option of its options database as *used* when an object reads it (``-options_left`` lists the unused
ones when PETSc finalizes). petsc4py does not expose that flag, so :func:`option_used` reads it with
``PetscOptionsUsed`` from the PETSc library that petsc4py has loaded.

When an option is read depends on what it configures:

* the options of the nonlinear solver, its Krylov solver, preconditioner and line search are read when the solver
  is configured (``SNESSetFromOptions``), so :func:`check_options` configures a throwaway solver on
  ``COMM_SELF`` with the given options (under a private prefix) and reports, before any work, a value PETSc refuses
  (``snes_rtol = "abc"``) and an option it does not read (``snes_rtoll``);
* options of the objects made while a solver is set up or run — a direct solver package (``mat_mumps_*``), the
  levels of a multigrid (``mg_levels_*``, ``mg_coarse_*``), sub-solvers (``sub_*``, ``fieldsplit_*``,
  ``redundant_*``) — and the viewers and reports read when a solve ends (``*_view*``, ``*_converged_reason``)
  are *deferred* (:func:`deferred`): they can only be checked after a solve, from the real solver's bookkeeping.

Options given on a command line are checked before any work (:func:`check_tokens`: a value with no option before it,
a NaN or infinite value; :func:`check_options`: a value PETSc refuses, or a missing one) and by
:func:`unused_command_line_options` once the work is done. A NaN or infinite value is refused everywhere: PETSc
would take ``snes_rtol = nan`` as a tolerance that no comparison meets.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import logging
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from foambase.errors import InputError

logger = logging.getLogger(__name__)

__all__ = ["check_options", "check_tokens", "command_line_options", "deferred", "error_message", "option_names",
           "option_used", "unused_command_line_options"]

#: Options read only when a solver is set up or a solve ends (see the module docstring).
DEFERRED = re.compile(r"^(mat_mumps_|mat_superlu|mat_strumpack|mat_mkl_|mat_pastix_|mat_cholmod_|mat_umfpack_|"
                      r"mg_levels_|mg_coarse_|sub_|fieldsplit_|redundant_)|(^|_)view(_|$)|converged_reason")
_CHECK_PREFIX = "fenicsfoam_check_"


@functools.cache
def _library() -> ctypes.CDLL:
    """The PETSc library petsc4py has loaded (found in this process's memory map, else by name)."""
    from petsc4py import PETSc  # noqa: F401 - loads the library

    with contextlib.suppress(OSError):
        with open("/proc/self/maps", encoding="utf-8") as maps:
            for line in maps:
                path = line.split()[-1]
                if "/libpetsc" in path and ".so" in path:
                    return ctypes.CDLL(path)
    name = ctypes.util.find_library("petsc_real") or ctypes.util.find_library("petsc")
    if name is None:  # pragma: no cover - petsc4py without a shared PETSc library
        raise OSError("cannot find the PETSc shared library to read the options' usage")
    return ctypes.CDLL(name)


def option_used(name: str) -> bool:
    """Whether an object has read the option ``name`` (without the leading ``-``) from PETSc's options database."""
    flag = ctypes.c_int(0)
    if _library().PetscOptionsUsed(None, name.lstrip("-").encode(), ctypes.byref(flag)) != 0:
        return False
    return bool(flag.value)


def error_message(code: int) -> str:
    """PETSc's text for an error code (e.g. 63: "Argument out of range")."""
    text = ctypes.c_char_p()
    if _library().PetscErrorMessage(int(code), ctypes.byref(text), None) != 0 or not text.value:
        return f"PETSc error code {code}"
    return text.value.decode(errors="replace")


def deferred(key: str) -> bool:
    """Whether an option (without prefix) is read only when a solver is set up or a solve ends."""
    return bool(DEFERRED.search(key))


def _value(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def check_options(options: Mapping[str, Any], prefix: str, defaults: Mapping[str, Any] = (), *, where: str,
                  own: Iterable[str] = ()) -> None:
    """Check a solver's options before any work: a value PETSc refuses, or an option it would not read.

    A throwaway SNES on ``COMM_SELF`` is configured (``setFromOptions``) with ``defaults``, overridden by
    ``options``, overridden by the options database's ``-PREFIX...`` entries (the command line), exactly as the
    real solver is; nothing is solved.

    Parameters
    ----------
    options
        The options to check, keys without prefix (e.g. a scene's ``[fem.petsc]``).
    prefix
        The real solver's prefix (``scene_``): command-line options under it take part.
    defaults
        The solver's default options (keys without prefix; ``None`` values are not PETSc options).
    where
        How the options are named in messages: ``f"{where}.{key}"`` (e.g. ``fem.petsc``).
    own
        Keys the caller reads itself (not PETSc options; never reported).

    Raises
    ------
    InputError
        Naming the first option whose value PETSc refuses, or that PETSc does not read (unless :func:`deferred`).

    """
    from petsc4py import PETSc

    own = set(own)
    db = PETSc.Options()
    command_line = {name[len(prefix):]: "" if value is None else value for name, value in db.getAll().items()
                    if name.startswith(prefix)}  # a command-line option without a value is a flag: ""
    for key, value in options.items():
        if key not in own:
            _check_finite(f"{where}.{key}", value)
    for key, value in command_line.items():
        _check_finite(f"command-line option -{prefix}{key}", value)
    effective = {k: _value(v) for k, v in {**dict(defaults), **dict(options)}.items() if k not in own}
    effective.update(command_line)
    effective = {k: v for k, v in effective.items() if v is not None}

    def configure(keys: Iterable[str]) -> tuple[PETSc.SNES | None, int]:
        snes = PETSc.SNES().create(PETSc.COMM_SELF)
        snes.setOptionsPrefix(_CHECK_PREFIX)
        names = [_CHECK_PREFIX + k for k in keys]
        for name, key in zip(names, keys):
            db[name] = effective[key]
        PETSc.Sys.pushErrorHandler("ignore")  # PETSc would print its own error stack for a refused value
        try:
            snes.setFromOptions()
            return snes, 0
        except PETSc.Error as exc:
            snes.destroy()
            return None, exc.ierr
        finally:
            PETSc.Sys.popErrorHandler()
            for name in names:
                used = option_used(name)
                db.delValue(name)
                if used:
                    read.add(name[len(_CHECK_PREFIX):])

    read: set[str] = set()
    snes, code = configure(list(effective))
    if snes is None:  # which option? each one alone, over the defaults (which give the solver types)
        for key in [*command_line, *(k for k in options if k not in command_line)]:
            if key in own:
                continue
            keys = [k for k in dict(defaults) if k in effective and k != key] + [key]
            single, single_code = configure(keys)
            if single is None:
                if key in command_line:
                    given = (f"the value {command_line[key]!r}" if command_line[key] != "" else
                             "no value (an option that needs one is followed by it)")
                    raise InputError(f"command-line option -{prefix}{key}: PETSc refuses {given} "
                                     f"({error_message(single_code)})")
                hint = (f"; an option without a value is written {key} = \"\"" if options[key] is True else "")
                raise InputError(f"{where}.{key}: PETSc refuses the value {options[key]!r} "
                                 f"({error_message(single_code)}){hint}")
            single.destroy()
        raise InputError(f"{where}: PETSc refuses these options together ({error_message(code)}): "
                         + ", ".join(f"{k} = {v!r}" for k, v in options.items()))
    try:
        types = f"snes_type {snes.getType()}, ksp_type {snes.getKSP().getType()}, " \
                f"pc_type {snes.getKSP().getPC().getType()}"
    finally:
        snes.destroy()
    for key in options:
        if key in own or key in command_line or key in read or deferred(key):
            continue
        raise InputError(f"{where}.{key}: PETSc does not use this option (misspelt, or not an option of this "
                         f"solver: {types}); PETSc's manual pages list the valid ones")


def _check_finite(name: str, value: Any) -> None:
    """Refuse a NaN or infinite number (PETSc would take it as a tolerance that every comparison fails)."""
    if isinstance(value, bool):
        return
    try:
        number = float(value)
    except (TypeError, ValueError):
        return
    if not math.isfinite(number):
        raise InputError(f"{name}: {value!r} is not a finite number; PETSc options take finite values")


def check_tokens(tokens: Sequence[str]) -> None:
    """Command-line PETSc options (after ``--``): each an ``-option`` followed by at most one value.

    A value with no option before it (``scene_snes_rtol 1e-8``, the dash forgotten) would be dropped by PETSc
    without a word; a NaN or infinite value would be taken. Both are an :class:`InputError` naming the token.
    """
    previous = None
    for token in tokens:
        if option_names([token]):
            previous = token
            continue
        if previous is None:
            hint = f" (did you mean -{token}?)" if re.match(r"^[A-Za-z_]", token) else ""
            raise InputError(f"PETSc options after '--': {token!r} is not an option (options start with '-'){hint}")
        _check_finite(f"command-line option {previous}", token)
        previous = None


def option_names(tokens: Sequence[str]) -> list[str]:
    """The option names (with their ``-``) in command-line tokens such as ``-scene_snes_rtol 1e-8 -snes_monitor``."""
    return [t for t in tokens if re.match(r"^-{1,2}[A-Za-z_]", t)]


def unused_command_line_options(tokens: Sequence[str]) -> list[str]:
    """The options of ``tokens`` (inserted into PETSc's database) that no PETSc object has read."""
    return [name for name in option_names(tokens) if not option_used(name.lstrip("-"))]


@contextlib.contextmanager
def command_line_options(tokens: Sequence[str], prefix: str = "scene_"):
    """PETSc options given on a command line (after ``--``) for the duration of one command.

    Inserts ``tokens`` into PETSc's options database, and on leaving (also after an error) warns about those that no
    PETSc object read and removes them all, so that a later command in the same process (tests, notebooks) starts
    from a clean database. ``prefix`` is the options prefix of the command's solver, named in the warning.
    """
    from petsc4py import PETSc

    check_tokens(tokens)
    db = PETSc.Options()
    if tokens:
        db.insertString(" ".join(tokens))
    try:
        yield
    finally:
        unused = unused_command_line_options(tokens)
        if unused:
            logger.warning("PETSc options after '--' that nothing used: %s (misspelt, or not options of this "
                           "solver; the scene's solver options take the prefix -%s)", " ".join(unused), prefix)
        for name in option_names(tokens):
            db.delValue(name.lstrip("-"))
