"""Reading a TOML table key by key, with errors that name the key path (``regions.arms.density``).

A :class:`_Table` remembers every key taken; :meth:`_Table.done` refuses the keys left over, so a misspelt key is
an error, never silently ignored. Every problem is a :class:`SceneError` (an ``InputError``, so a ``ValueError``)
naming the key path and what would be valid.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from foambase.errors import InputError

__all__ = ["SceneError"]


class SceneError(InputError):
    """A scene is invalid: the message names the key path and what would be valid."""


def _type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


#: Key names the scene schema reads somewhere (the readers add theirs; the schema adds the materials'): a key of
#: a table that is one of them is never taken for a misspelling of another.
KNOWN_KEYS: set[str] = set()


def did_you_mean(word: str, candidates) -> str | None:
    """The candidate equal to ``word`` but for case, else the closest (``difflib``, similarity >= 0.75), or None."""
    candidates = [c for c in candidates if isinstance(c, str)]
    same = [c for c in candidates if c.lower() == word.lower()]
    match = same or difflib.get_close_matches(word, candidates, n=1, cutoff=0.75)
    return match[0] if match else None


class _Table:
    """A TOML table being read: every key taken is remembered; :meth:`done` refuses the keys left over."""

    def __init__(self, data: Any, path: str):
        if not isinstance(data, dict):
            raise SceneError(f"{path or 'scene'}: expected a table, got {_type_name(data)} {data!r}")
        self.data, self.path, self._taken = data, path, set()

    def key(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = None, required: bool = False) -> Any:
        self._taken.add(key)
        KNOWN_KEYS.add(key)
        if key not in self.data:
            if required:
                typo = did_you_mean(key, [k for k in self.data if k not in self._taken and k not in KNOWN_KEYS])
                if typo is not None:  # e.g. gama for gamma: said as the unknown key it is
                    raise SceneError(f"{self.key(typo)}: unknown key; did you mean {key!r}? ({self.key(key)} is "
                                     "required)")
                raise SceneError(f"{self.key(key)}: missing value (required)")
            return default
        return self.data[key]

    def number(self, key: str, *, required: bool = False, default: float | None = None,
               check: Callable[[float], bool] | None = None, valid: str = "") -> float | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise SceneError(f"{self.key(key)}: expected a finite number, got {_type_name(value)} {value!r}")
        if check is not None and not check(value):
            raise SceneError(f"{self.key(key)}: {value!r} is out of range; valid: {valid}")
        return float(value)

    def integer(self, key: str, *, default: int, choices: Sequence[int] | None = None, minimum: int | None = None,
                maximum: int | None = None) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{self.key(key)}: expected an integer, got {_type_name(value)} {value!r}")
        if choices is not None and value not in choices:
            raise SceneError(f"{self.key(key)}: {value!r} is not valid; valid: {', '.join(map(str, choices))}")
        if minimum is not None and value < minimum:
            raise SceneError(f"{self.key(key)}: {value!r} is out of range; valid: an integer >= {minimum}")
        if maximum is not None and value > maximum:
            raise SceneError(f"{self.key(key)}: {value!r} is out of range; valid: an integer <= {maximum}")
        return value

    def string(self, key: str, *, required: bool = False, default: str | None = None,
               choices: Sequence[str] | None = None) -> str | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        if not isinstance(value, str):
            raise SceneError(f"{self.key(key)}: expected a string, got {_type_name(value)} {value!r}")
        if choices is not None and value not in choices:
            raise SceneError(f"{self.key(key)}: {value!r} is not valid; valid: {', '.join(map(repr, choices))}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise SceneError(f"{self.key(key)}: expected true or false, got {_type_name(value)} {value!r}")
        return value

    def vector(self, key: str, size: int, *, required: bool = False, default: Sequence[float] | None = None
               ) -> tuple[float, ...] | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        return _vector(value, size, self.key(key))

    def table(self, key: str, required: bool = False) -> _Table | None:
        value = self.raw(key, None, required)
        return None if value is None else _Table(value, self.key(key))

    def done(self, allowed_extra: Sequence[str] = ()) -> None:
        unknown = sorted(set(self.data) - self._taken - set(allowed_extra))
        if unknown:
            valid = sorted(self._taken | set(allowed_extra))
            hint = did_you_mean(unknown[0], valid)
            raise SceneError(f"{self.key(unknown[0])}: unknown key; {f'did you mean {hint!r}? ' if hint else ''}"
                             f"valid keys here: {', '.join(valid) or 'none'}")


def _vector(value: Any, size: int, path: str) -> tuple[float, ...]:
    if (not isinstance(value, list) or len(value) != size
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise SceneError(f"{path}: expected an array of {size} finite numbers, got {_type_name(value)} {value!r}")
    return tuple(float(v) for v in value)


def _tags(value: Any, path: str, named: Mapping[str, tuple[int, ...]], what: str) -> tuple[int, ...]:
    """An int, a non-empty array of ints, or a name of ``named``, as a tuple of tags."""
    if isinstance(value, str):
        if value not in named:
            raise SceneError(f"{path}: unknown {what} name {value!r}; valid names: {', '.join(sorted(named))} "
                             "(or integer tags)")
        return tuple(named[value])
    if isinstance(value, int) and not isinstance(value, bool):
        return (value,)
    if isinstance(value, list) and value and all(isinstance(t, int) and not isinstance(t, bool) for t in value):
        return tuple(value)
    raise SceneError(f"{path}: expected an integer tag, an array of integer tags or a {what} name, "
                     f"got {_type_name(value)} {value!r}")


def key_error(path: str, keys: Iterable[str], message: str) -> SceneError:
    """A :class:`SceneError` for a library's ``message`` about the values of ``path``'s ``keys``, naming the keys.

    The keys that the message mentions (as words) are named in the order it mentions them, the first one as the key
    path: ``regions.plate.nu_tl (with E_l, E_t): ...``; a message that names none is given as ``path: message``.
    """
    positions = {}
    for key in keys:
        match = re.search(rf"(?<![A-Za-z0-9_.]){re.escape(key)}(?![A-Za-z0-9_])", message)
        if match:
            positions[key] = match.start()
    named = sorted(positions, key=positions.get)
    if not named:
        return SceneError(f"{path}: {message}")
    others = f" (with {', '.join(named[1:])})" if len(named) > 1 else ""
    return SceneError(f"{path}.{named[0]}{others}: {message}")
