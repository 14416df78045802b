"""Objects named ``"module:name"`` (a scene's field or orientation function, a sub-command)."""

from __future__ import annotations

import importlib
from typing import Any

from foambase.errors import InputError

__all__ = ["import_callable", "import_object"]


def import_object(spec: str, what: str = "") -> Any:
    """The object named ``"module:name"``; any failure to import it is an :class:`InputError` prefixed with ``what``.

    The failures: the module or the name missing, or whatever the module raises when imported.
    """
    module, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except Exception as exc:  # ImportError, AttributeError, or whatever the module raises when imported
        raise InputError(f"{what}cannot import {spec!r}: {type(exc).__name__}: {exc}") from exc


def import_callable(spec: str, what: str = "") -> Any:
    """The callable named ``"module:name"`` (:func:`import_object`); one that is not callable is an InputError."""
    function = import_object(spec, what)
    if not callable(function):
        raise InputError(f"{what}{spec!r} is a {type(function).__name__}, not a function")
    return function
