"""The FFT solver's fused C kernels (``_kernels.c``): compiled once per machine, loaded with cffi.

Built by :func:`foambase.native.load_library` with ``cc -O3 -march=native`` (cached per source, flags and CPU).
If no compiler works, :func:`load` returns ``None`` and the solver falls back to its numpy kernels (same algebra,
a few times more memory traffic), with a warning in the log.
"""

from __future__ import annotations

import functools
from pathlib import Path

from foambase.native import load_library

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


@functools.cache
def load():
    """``(ffi, lib)`` of the compiled kernels, or ``None`` if they cannot be built on this machine."""
    return load_library(SOURCE, FLAGS, DECLARATIONS, "fft_kernels", disable="FENICSFOAM_FFT_KERNELS",
                        what="FFT solver")
