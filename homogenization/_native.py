"""The FFT solver's fused C kernels (``_kernels.c``): compiled once per machine, loaded with cffi.

The C compiler is already a requirement of the stack (FFCx compiles every dolfinx form with it). The shared
library is built with ``cc -O3 -march=native`` into ``$XDG_CACHE_HOME/fenicsfoam`` (default ``~/.cache``),
named after a hash of the source, the flags and the CPU, written to a temporary file and renamed (safe when
several MPI ranks compile at once). If no compiler works, :func:`load` returns ``None`` and the solver falls
back to its numpy kernels (same algebra, a few times more memory traffic), with a warning in the log.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import platform
import shutil
import subprocess
from pathlib import Path

import cffi

from foambase.files import atomic_path

logger = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("_kernels.c")
FLAGS = ["-O3", "-march=native", "-fopenmp-simd", "-fPIC", "-shared", "-fno-math-errno"]
DECLARATIONS = """
double ff_constitutive(int64_t n, int64_t stride, double *p, const double *r, double beta, int update,
                       const int32_t *phase, int nphase, const double *tables, const double *w, double *sig);
double ff_green(int64_t n, int64_t stride, double *hat, int64_t nstride, const double *nvec, double c,
                int residual, int64_t h, int nyquist);
double ff_axpy(int64_t n, int64_t stride, const double *alpha, const double *x, double *y, int norm);
void ff_hex_apply(int64_t n2, int64_t n3, int64_t a, int64_t b, const double *p, int64_t pstride,
                  const int32_t *phase, int nphase, const double *tables, const double *w, const double *E,
                  const double *h, double *q, int64_t qstride, double *sums);
double ff_hex_green(int64_t ni, int64_t n2, int64_t h3, double *hat, int64_t stride, const double *K0,
                    const double *C0, const double *K1, const double *C1, const double *K2, const double *C2,
                    double kmin, double scale, int nyquist, int64_t k_lo, int64_t h_global);
void ff_hex8_apply(int64_t n2, int64_t n3, int64_t a, int64_t b, const double *p, int64_t pstride,
                   const int32_t *phase, const double *Ke, const int32_t *active, const double *tables,
                   const double *h, double *q, int64_t qstride, double *sums);
double ff_hex8_green(int64_t ni, int64_t n2, int64_t h3, double *hat, int64_t stride, const double *K0,
                     const double *C0, const double *W0, const double *K1, const double *C1, const double *W1,
                     const double *K2, const double *C2, const double *W2, double kmin, double scale, int nyquist,
                     int64_t k_lo, int64_t h_global);
double ff_axpby(int64_t n, int ncomp, const double *alpha, const double *x, int64_t xstride, double beta,
                double *y, int64_t ystride, int norm);
"""


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "flags")):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _library_path() -> Path:
    key = hashlib.sha256("\0".join([SOURCE.read_text(), *FLAGS, _cpu()]).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "fenicsfoam"
    return cache / f"fft_kernels_{key}.so"


def _compile(target: Path) -> None:
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise OSError("no C compiler found (cc, gcc or $CC)")
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(target) as tmp:
            subprocess.run([compiler, *FLAGS, str(SOURCE), "-o", str(tmp)], check=True, capture_output=True,
                           text=True)
    except subprocess.CalledProcessError as exc:
        raise OSError(f"compiling {SOURCE.name} failed: {exc.stderr.strip()}") from exc


@functools.cache
def load():
    """``(ffi, lib)`` of the compiled kernels, or ``None`` if they cannot be built on this machine."""
    if os.environ.get("FENICSFOAM_FFT_KERNELS", "").lower() == "numpy":
        return None
    try:
        path = _library_path()
        if not path.exists():
            _compile(path)
        ffi = cffi.FFI()
        ffi.cdef(DECLARATIONS)
        return ffi, ffi.dlopen(str(path))
    except OSError as exc:
        logger.warning("FFT solver: native kernels unavailable (%s); using the numpy kernels", exc)
        return None
