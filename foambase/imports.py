"""Objects named ``"module:name"`` (a scene's field or orientation function, a sub-command)."""

from __future__ import annotations

import importlib
from typing import Any

from foambase.errors import InputError

__all__ = ["import_callable"]


def import_callable(spec: str, what: str = "") -> Any:
    """The callable named ``"module:name"``.

    Any failure (the module or the name missing, or whatever the module raises when imported), and an object
    that is not callable, is an :class:`InputError` prefixed with ``what`` (e.g. ``"orientation.function: "``).
    """
    module, _, name = spec.partition(":")
    try:
        function = getattr(importlib.import_module(module), name)
    except Exception as exc:  # ImportError, AttributeError, or whatever the module raises when imported
        raise InputError(f"{what}cannot import {spec!r}: {type(exc).__name__}: {exc}") from exc
    if not callable(function):
        raise InputError(f"{what}{spec!r} is a {type(function).__name__}, not a function")
    return function
