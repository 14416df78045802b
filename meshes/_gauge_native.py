"""The gauge-wall kernel (``_gauge_kernel.c``): compiled once per machine, loaded with cffi.

Built like the FFT solver's kernels (:mod:`homogenization._native`): ``cc -O3 -march=native`` into
``$XDG_CACHE_HOME/fenicsfoam`` (default ``~/.cache``), named after a hash of the source, the flags and the CPU,
written to a temporary file and renamed. Without a working compiler :func:`load` returns ``None`` and
:class:`meshes.gauge.GaugeWalls` uses its numpy implementation (same algebra, slower).
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import subprocess
from pathlib import Path

import cffi

from foambase.files import atomic_path
from homogenization._native import _cpu

logger = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("_gauge_kernel.c")
FLAGS = ["-O3", "-march=native", "-fPIC", "-shared", "-fno-math-errno"]
DECLARATIONS = """
int64_t gw_evaluate(int64_t M, const double *x, int K, const int64_t *idx, const double *e, const double *images,
                    int F, const double *nu, int P, const int *pa, const int *pb, const double *dn, const double *nn,
                    const double *t, const double *D1, const double *r1, const double *Dn1, const double *D2,
                    const double *r2, const double *Dn2, double R, double G, double upper, int last,
                    double *psi, double *foot, int *piece, int64_t *first, int *done);
"""


def _library_path() -> Path:
    key = hashlib.sha256("\0".join([SOURCE.read_text(), *FLAGS, _cpu()]).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "fenicsfoam"
    return cache / f"gauge_kernel_{key}.so"


@functools.cache
def load():
    """``(ffi, lib)`` of the compiled kernel, or ``None`` if it cannot be built on this machine."""
    if os.environ.get("FENICSFOAM_GAUGE_KERNEL", "").lower() == "numpy":
        return None
    try:
        path = _library_path()
        if not path.exists():
            compiler = os.environ.get("CC") or "cc"
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                subprocess.run([compiler, *FLAGS, str(SOURCE), "-o", str(tmp), "-lm"], check=True,
                               capture_output=True, text=True)
        ffi = cffi.FFI()
        ffi.cdef(DECLARATIONS)
        return ffi, ffi.dlopen(str(path))
    except (OSError, subprocess.CalledProcessError) as exc:
        logger.warning("gauge walls: native kernel unavailable (%s); using numpy", exc)
        return None
