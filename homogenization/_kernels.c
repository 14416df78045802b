/* Fused per-voxel kernels of the FFT solver (homogenization/fft.py), compiled on first use by
 * homogenization/_native.py and called through cffi on blocks of whole planes.
 *
 * Fields are (6, N1, N2, N3) C arrays passed as a pointer to the block's first voxel of component 0 and the
 * component stride (N1 N2 N3 doubles, or 2 N1 N2 (N3/2+1) doubles for the half spectrum seen as doubles).
 * Each kernel reads and writes every array once; the numpy fallback in fft.py does the same algebra in
 * several passes.
 */
#include <stdint.h>
#include <stdlib.h>

/* Voxels are processed in tiles: each tile's six components are copied to (or from) local buffers one
 * component at a time, so that memory is streamed component by component. Touching the six components of one
 * voxel directly would stride by N1 N2 N3 doubles, a power of two on the usual grids, and the 12-18 streams
 * would then evict each other from the same cache sets. Sums use `omp simd` reductions (-fopenmp-simd: no
 * OpenMP runtime), so that they vectorize; their rounding differs from a sequential sum at the 1e-16 level. */
#define TILE 2048

/* Optionally p <- r + beta p (the CG search direction, update != 0), then sig = T[phase] p with T the
 * per-phase 6x6 matrix from Mandel strain to tensor stress (nphase of them, row-major); returns
 * sum_x sum_c w_c p_c sig_c, the Mandel energy product <p, C:p>. */
double ff_constitutive(int64_t n, int64_t stride, double *p, const double *r, double beta, int update,
                       const int32_t *phase, int nphase, const double *tables, const double *w, double *sig)
{
    double energy = 0.0;
    double (*restrict e)[TILE] = malloc(6 * TILE * sizeof(double));
    double (*restrict s)[TILE] = malloc(6 * TILE * sizeof(double));
    for (int64_t i0 = 0; i0 < n; i0 += TILE) {
        const int64_t m = (n - i0 < TILE) ? n - i0 : TILE;
        for (int c = 0; c < 6; ++c) {
            double *pc = p + c * stride + i0;
            if (update) {
                const double *rc = r + c * stride + i0;
                for (int64_t i = 0; i < m; ++i) {
                    pc[i] = rc[i] + beta * pc[i];
                    e[c][i] = pc[i];
                }
            } else {
                for (int64_t i = 0; i < m; ++i)
                    e[c][i] = pc[i];
            }
        }
        for (int c = 0; c < 6; ++c)
            for (int64_t i = 0; i < m; ++i)
                s[c][i] = 0.0;
        /* one vectorizable sweep per non-void phase, its matrix held in registers */
        for (int ph = 0; ph < nphase; ++ph) {
            double t[36]; /* a local copy: the compiler may keep it in registers (no aliasing with s) */
            int empty = 1;
            for (int a = 0; a < 36; ++a) {
                t[a] = tables[36 * ph + a];
                empty &= (t[a] == 0.0);
            }
            if (empty)
                continue;
            const int32_t *id = phase + i0;
            for (int64_t i = 0; i < m; ++i) {
                const double mask = (id[i] == ph) ? 1.0 : 0.0;
                const double e0 = mask * e[0][i], e1 = mask * e[1][i], e2 = mask * e[2][i], e3 = mask * e[3][i],
                             e4 = mask * e[4][i], e5 = mask * e[5][i];
                for (int c = 0; c < 6; ++c)
                    s[c][i] += t[6 * c] * e0 + t[6 * c + 1] * e1 + t[6 * c + 2] * e2 + t[6 * c + 3] * e3
                               + t[6 * c + 4] * e4 + t[6 * c + 5] * e5;
            }
        }
        for (int c = 0; c < 6; ++c) {
            double *sc = sig + c * stride + i0;
            double acc = 0.0;
#pragma omp simd reduction(+ : acc)
            for (int64_t i = 0; i < m; ++i) {
                sc[i] = s[c][i];
                acc += e[c][i] * s[c][i];
            }
            energy += w[c] * acc;
        }
    }
    free(e);
    free(s);
    return energy;
}

/* In place on the half spectrum of a symmetric tau (tensor components 11 22 33 23 13 12, complex numbers as
 * (re, im) doubles): hat <- n (x) w + w (x) n with w = tau n - c (n . tau n) n, stored as n_i w_i (diagonal) and
 * n_i w_j + n_j w_i (shear). nvec holds the unit wave vector per complex entry (3 components, stride nstride).
 * The block starts at a line of h complex entries along the last axis. With residual != 0, returns
 * sum (2 |tau n|^2 - (n . tau n)^2) weighted 1 on the single planes (k3 = 0, and k3 = h - 1 if nyquist) and
 * 2 elsewhere (Parseval on the half spectrum); else 0. */
double ff_green(int64_t n, int64_t stride, double *hat, int64_t nstride, const double *nvec, double c,
                int residual, int64_t h, int nyquist)
{
    double total = 0.0;
    /* the tile's real and imaginary parts, de-interleaved so that the loop below runs at unit stride */
    double (*restrict re)[TILE] = malloc(6 * TILE * sizeof(double));
    double (*restrict im)[TILE] = malloc(6 * TILE * sizeof(double));
    double (*restrict q)[TILE] = malloc(4 * TILE * sizeof(double)); /* n0, n1, n2, Parseval weight */
    for (int64_t k0 = 0; k0 < n; k0 += TILE) {
        const int64_t m = (n - k0 < TILE) ? n - k0 : TILE;
        for (int a = 0; a < 6; ++a) {
            const double *src = hat + a * stride + 2 * k0;
            for (int64_t k = 0; k < m; ++k) {
                re[a][k] = src[2 * k];
                im[a][k] = src[2 * k + 1];
            }
        }
        for (int a = 0; a < 3; ++a) {
            const double *src = nvec + a * nstride + k0;
            for (int64_t k = 0; k < m; ++k)
                q[a][k] = src[k];
        }
        if (residual)
            for (int64_t k = 0; k < m; ++k) {
                const int64_t line = (k0 + k) % h;
                q[3][k] = (line == 0 || (nyquist && line == h - 1)) ? 1.0 : 2.0;
            }
        for (int part = 0; part < 2; ++part) {
            double (*restrict T)[TILE] = part ? im : re;
            double sum = 0.0;
#pragma omp simd reduction(+ : sum)
            for (int64_t k = 0; k < m; ++k) {
                const double n0 = q[0][k], n1 = q[1][k], n2 = q[2][k];
                const double v0 = T[0][k] * n0 + T[5][k] * n1 + T[4][k] * n2;
                const double v1 = T[5][k] * n0 + T[1][k] * n1 + T[3][k] * n2;
                const double v2 = T[4][k] * n0 + T[3][k] * n1 + T[2][k] * n2;
                const double sv = v0 * n0 + v1 * n1 + v2 * n2;
                if (residual)
                    sum += q[3][k] * (2.0 * (v0 * v0 + v1 * v1 + v2 * v2) - sv * sv);
                const double cs = c * sv;
                const double w0 = v0 - cs * n0, w1 = v1 - cs * n1, w2 = v2 - cs * n2;
                T[0][k] = n0 * w0;
                T[1][k] = n1 * w1;
                T[2][k] = n2 * w2;
                T[3][k] = n1 * w2 + n2 * w1;
                T[4][k] = n0 * w2 + n2 * w0;
                T[5][k] = n0 * w1 + n1 * w0;
            }
            total += sum;
        }
        for (int a = 0; a < 6; ++a) {
            double *dst = hat + a * stride + 2 * k0;
            for (int64_t k = 0; k < m; ++k) {
                dst[2 * k] = re[a][k];
                dst[2 * k + 1] = im[a][k];
            }
        }
    }
    free(re);
    free(im);
    free(q);
    return total;
}

/* y_c <- y_c + alpha_c x_c; returns sum y.y if norm != 0, else 0. */
double ff_axpy(int64_t n, int64_t stride, const double *alpha, const double *x, double *y, int norm)
{
    double total = 0.0;
    for (int c = 0; c < 6; ++c) {
        const double a = alpha[c];
        const double *xc = x + c * stride;
        double *yc = y + c * stride;
        if (norm) {
#pragma omp simd reduction(+ : total)
            for (int64_t i = 0; i < n; ++i) {
                double v = yc[i] + a * xc[i];
                yc[i] = v;
                total += v * v;
            }
        } else {
            for (int64_t i = 0; i < n; ++i)
                yc[i] += a * xc[i];
        }
    }
    return total;
}
