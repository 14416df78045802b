"""The gauge-wall kernel (``_gauge_kernel.c``): compiled once per machine, loaded with cffi.

Built like the FFT solver's kernels, by :func:`foambase.native.load_library` (``cc -O3 -march=native``, cached per
source, flags and CPU). Without a working compiler :func:`load` returns ``None`` and
:class:`meshes.gauge.GaugeWalls` uses its numpy implementation (same algebra, slower).
"""

from __future__ import annotations

import functools
from pathlib import Path

from foambase.native import load_library

SOURCE = Path(__file__).with_name("_gauge_kernel.c")
FLAGS = ["-O3", "-march=native", "-fPIC", "-shared", "-fno-math-errno"]
DECLARATIONS = """
int64_t gw_evaluate(int64_t M, const double *x, int K, const int64_t *idx, const double *e, const double *images,
                    int F, const double *nu, int P, const int *pa, const int *pb, const double *dn, const double *nn,
                    const double *t, const double *D1, const double *r1, const double *Dn1, const double *D2,
                    const double *r2, const double *Dn2, double R, double G, double upper, int last,
                    double *psi, double *foot, int *piece, int64_t *first, int *done);
"""


@functools.cache
def load():
    """``(ffi, lib)`` of the compiled kernel, or ``None`` if it cannot be built on this machine."""
    return load_library(SOURCE, FLAGS, DECLARATIONS, "gauge_kernel", disable="FENICSFOAM_GAUGE_KERNEL",
                        what="gauge walls", libraries=["-lm"])
