"""Atomic file writes: a file is either absent, its previous version, or complete — never half-written.

Every writer goes through :func:`atomic_path`: the content is written to a temporary file in the target's own
directory (so that the final rename stays within one file system) and moved onto the target by ``os.replace``,
which POSIX makes atomic. A system error while writing (disk full, file-size limit, quota) is raised as a
:class:`~foambase.errors.WriteError` naming the target and the error. On an exception (or a SIGINT/SIGTERM,
:mod:`foambase.signals`) the temporary file is removed and the target is left untouched. The temporary name
(``.NAME.PID.TOKEN.tmp.SUFFIX``, :data:`TEMPORARY`) keeps the target's suffix, so writers that choose a format by
the file name (PNG screenshots, STL, a compiler's output) work unchanged. Files are created with the usual
permissions (``0o666`` less the umask).

Inputs are checked before they are opened (:func:`check_input_file`: only ``os.stat``, so a FIFO never blocks
and /dev/zero is never read). Outputs are checked before any work: :func:`check_output_file` and
:func:`check_output_dir` raise an :class:`~foambase.errors.InputError` naming the argument when a file or directory
cannot be written there (an empty path, a directory where a file is expected or the reverse, a missing or read-only
directory).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from foambase.errors import InputError, WriteError
from foambase.signals import discard_temporary, register_temporary

__all__ = ["TEMPORARY", "atomic_open", "atomic_path", "check_input_file", "check_output_dir", "check_output_file",
           "keep_unclosable", "write_error",
           "write_json_atomic", "write_text_atomic"]

#: The names of :func:`atomic_path`'s temporary files (left behind only by a process that was killed).
TEMPORARY = re.compile(r"^\..*\.\d+\.[0-9a-f]{8}\.tmp(\.[^.]*)?$")


#: Native file handles a failed write left open: never destroyed (:func:`keep_unclosable`).
UNCLOSABLE: list = []


def keep_unclosable(handle: Any) -> None:
    """Keep a native file handle that failed to write (e.g. an HDF5 file) from ever being destroyed.

    Its destructor would try to close the file again and abort the process; the handle is leaked instead, and
    the command lines end such a process without the library's exit-time clean-up (:func:`foambase.cli.dispatch`).
    """
    import ctypes

    ctypes.pythonapi.Py_IncRef(ctypes.py_object(handle))
    UNCLOSABLE.append(handle)


def write_error(path: str | os.PathLike, exc: OSError) -> WriteError:
    """The :class:`~foambase.errors.WriteError` for ``path``: the file and the system's error (``strerror``, errno)."""
    name = errno.errorcode.get(exc.errno, str(exc.errno)) if exc.errno is not None else type(exc).__name__
    return WriteError(f"cannot write {path}: {exc.strerror or exc} ({name}); the file was not written (a previous "
                      "version, if any, is kept)")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block ends without an exception.

    The temporary file exists (empty) when the block starts; it is removed if the block raises.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")
    register_temporary(tmp)
    try:
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            yield tmp
            os.replace(tmp, path)
        except OSError as exc:
            if exc.errno is None:
                raise
            raise write_error(path, exc) from exc
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        discard_temporary(tmp)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[IO]:
    """``open`` a temporary file beside ``path`` (``mode`` ``"w"`` or ``"wb"``); it replaces ``path`` on success.

    Text mode defaults to ``newline=""`` (the caller's line endings are written as given, e.g. by ``csv``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes a new file: mode must be 'w' or 'wb', got {mode!r}")
    if mode == "w":
        kwargs.setdefault("newline", "")
        kwargs.setdefault("encoding", "utf-8")
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as f:
        yield f


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8, line endings as given) to ``path`` atomically; returns the path."""
    with atomic_open(path) as f:
        f.write(text)
    return Path(path)


def write_json_atomic(path: str | os.PathLike, data: Any, indent: int = 2) -> Path:
    """Write ``data`` as JSON (``indent``, a final newline) to ``path`` atomically; returns the path."""
    return write_text_atomic(path, json.dumps(data, indent=indent) + "\n")


_SPECIAL = ((stat.S_ISDIR, "is a directory, not a file"), (stat.S_ISFIFO, "is a named pipe (FIFO), not a regular file"),
            (stat.S_ISCHR, "is a character device (such as /dev/zero), not a regular file"),
            (stat.S_ISBLK, "is a block device, not a regular file"), (stat.S_ISSOCK, "is a socket, not a regular file"))


def check_input_file(path: str | os.PathLike | None, what: str = "input file", *,
                     max_bytes: int | None = None) -> Path:
    """Check, before opening it, that ``path`` is a regular file that can be read (and at most ``max_bytes`` long).

    Only ``os.stat`` is called, so a named pipe never blocks and a device is never read. Raises
    :class:`~foambase.errors.InputError` naming ``what`` and saying what the path is: missing, a directory, a FIFO,
    a device, unreadable, or too large.
    """
    if path is None or not str(path).strip():
        raise InputError(f"{what}: an empty path; give a file name")
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{what} {path}: does not exist") from None
    except NotADirectoryError:
        raise InputError(f"{what} {path}: a component of the path is a file, not a directory") from None
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot be read ({exc.strerror})") from None
    for test, what_it_is in _SPECIAL:
        if test(info.st_mode):
            raise InputError(f"{what} {path}: {what_it_is}")
    if not os.access(path, os.R_OK):
        raise InputError(f"{what} {path}: cannot be read (no permission)")
    if max_bytes is not None and info.st_size > max_bytes:
        raise InputError(f"{what} {path}: {info.st_size} bytes, more than the {max_bytes} such a file may have")
    return path


def _writable(directory: Path) -> bool:
    """Whether a file can be created in ``directory`` (tried: permissions, read-only file systems, root)."""
    try:
        fd, probe = _probe(directory)
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def _probe(directory: Path) -> tuple[int, Path]:
    probe = directory / f".write-test.{os.getpid()}.{secrets.token_hex(4)}"
    return os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), probe


def _existing_ancestor(path: Path, what: str) -> Path:
    """The nearest existing ancestor of ``path``, which must be a directory (it will hold the new directories)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"{what} {path}: {parent} is a file, not a directory")
            return parent
    return Path.cwd()  # pragma: no cover - a relative path's ancestors end at "."


def _check_lengths(path: Path, what: str) -> None:
    """:class:`InputError` if a component of ``path`` or the whole is longer than the file system allows."""
    name_max, path_max = 255, 4096
    with contextlib.suppress(OSError, ValueError):
        anchor = next((p for p in [path, *path.parents] if p.exists()), Path("."))
        name_max = os.pathconf(anchor, "PC_NAME_MAX")
        path_max = os.pathconf(anchor, "PC_PATH_MAX")
    long = next((part for part in path.parts if len(os.fsencode(part)) > name_max), None)
    if long is not None:
        raise InputError(f"{what} {str(path)[:80]}...: the name {long[:40]}... has {len(os.fsencode(long))} bytes, "
                         f"more than the {name_max} a file name may have here")
    if len(os.fsencode(str(path.absolute()))) >= path_max:
        raise InputError(f"{what} {str(path)[:80]}...: the path has {len(os.fsencode(str(path.absolute())))} bytes, "
                         f"more than the {path_max - 1} a path may have here")


def check_output_file(path: str | os.PathLike | None, what: str = "output file") -> Path:
    """Check, before any work, that a file can be written at ``path`` (in an existing directory).

    Raises :class:`~foambase.errors.InputError` naming ``what`` (e.g. ``--out``): an empty path, a directory
    at ``path``, a missing directory, a file where a directory is needed, or a directory where nothing can be
    created.
    """
    if path is None or not str(path).strip():
        raise InputError(f"{what}: an empty path; give a file name")
    path = Path(path)
    _check_lengths(path, what)
    if path.is_dir():
        raise InputError(f"{what} {path}: is a directory; give a file name")
    if path.exists() and not path.is_file():
        raise InputError(f"{what} {path}: exists and is not a regular file")
    parent = path.parent
    if not parent.exists():
        _existing_ancestor(path, what)  # names a file on the way
        raise InputError(f"{what} {path}: directory {parent} does not exist")
    if not parent.is_dir():
        raise InputError(f"{what} {path}: {parent} is a file, not a directory")
    if not _writable(parent):
        raise InputError(f"{what} {path}: cannot create files in {parent} (read-only or no permission)")
    return path


def check_output_dir(path: str | os.PathLike | None, what: str = "output directory") -> Path:
    """Check, before any work, that ``path`` is a directory (or can be created) in which files can be written.

    Raises :class:`~foambase.errors.InputError` naming ``what``: an empty path, a file at ``path`` or on the
    way to it, or a directory where nothing can be created.
    """
    if path is None or not str(path).strip():
        raise InputError(f"{what}: an empty path; give a directory")
    path = Path(path)
    _check_lengths(path, what)
    if path.exists():
        if not path.is_dir():
            raise InputError(f"{what} {path}: is a file, not a directory")
        target = path
    else:
        target = _existing_ancestor(path, what)
    if not _writable(target):
        raise InputError(f"{what} {path}: cannot create files in {target} (read-only or no permission)")
    return path
