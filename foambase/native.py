"""Compiled C helpers: built once per machine with the system's C compiler, loaded with cffi.

The C compiler is already a requirement of the stack (FFCx compiles every dolfinx form with it). A helper's shared
library is built with its flags (e.g. ``-O3 -march=native``) into ``$XDG_CACHE_HOME/fenicsfoam`` (default
``~/.cache``), named after a hash of the source, the flags and the CPU, written to a temporary file and renamed
(safe when several MPI ranks compile at once). If no compiler works, :func:`load_library` returns ``None`` and
the caller uses its numpy implementation (same algebra), with a warning in the log. Used by the FFT solver's
kernels (:mod:`homogenization._native`) and the gauge-wall kernel (:mod:`meshes._gauge_native`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

from foambase.files import atomic_path

__all__ = ["cpu_signature", "library_path", "load_library"]

logger = logging.getLogger(__name__)


def cpu_signature() -> str:
    """The CPU's model name or flags line (``-march=native`` builds for it), or the platform's processor."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "flags")):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


def library_path(source: Path, flags: Sequence[str], stem: str) -> Path:
    """The cached library of ``source`` built with ``flags`` on this CPU: ``<cache>/fenicsfoam/<stem>_<hash>.so``."""
    key = hashlib.sha256("\0".join([source.read_text(), *flags, cpu_signature()]).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "fenicsfoam"
    return cache / f"{stem}_{key}.so"


def _compile(source: Path, flags: Sequence[str], libraries: Sequence[str], target: Path) -> None:
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise OSError("no C compiler found (cc, gcc or $CC)")
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(target) as tmp:
            subprocess.run([compiler, *flags, str(source), "-o", str(tmp), *libraries], check=True,
                           capture_output=True, text=True)
    except subprocess.CalledProcessError as exc:
        raise OSError(f"compiling {source.name} failed: {exc.stderr.strip()}") from exc


def load_library(source: Path, flags: Sequence[str], declarations: str, stem: str, *, disable: str, what: str,
                 libraries: Sequence[str] = ()):
    """``(ffi, lib)`` of the compiled ``source``, or ``None`` if it cannot be built here (or is disabled).

    ``disable``: an environment variable that, set to ``numpy``, makes the caller use its numpy implementation;
    ``what``: the caller's name in the warning logged when the library is unavailable; ``libraries``: linker
    arguments (e.g. ``-lm``).
    """
    if os.environ.get(disable, "").lower() == "numpy":
        return None
    try:
        import cffi

        path = library_path(source, flags, stem)
        if not path.exists():
            _compile(source, flags, libraries, path)
        ffi = cffi.FFI()
        ffi.cdef(declarations)
        return ffi, ffi.dlopen(str(path))
    except OSError as exc:
        logger.warning("%s: native kernels unavailable (%s); using the numpy kernels", what, exc)
        return None
