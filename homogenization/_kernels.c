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
#include <string.h>

/* Voxels are processed in tiles: each tile's six components are copied to (or from) local buffers one
 * component at a time, so that memory is streamed component by component. Touching the six components of one
 * voxel directly would stride by N1 N2 N3 doubles, a power of two on the usual grids, and the 12-18 streams
 * would then evict each other from the same cache sets. Sums use `omp simd` reductions (-fopenmp-simd: no
 * OpenMP runtime), so that they vectorize; their rounding differs from a sequential sum at the 1e-16 level. */
#define TILE 2048
/* row r of the 6x6 matrix T times the strain (e0 ... e5) */
#define ROW6(T, r) \
    (T[6 * (r)] * e0 + T[6 * (r) + 1] * e1 + T[6 * (r) + 2] * e2 + T[6 * (r) + 3] * e3 + T[6 * (r) + 4] * e4 \
     + T[6 * (r) + 5] * e5)

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

/* ------------------------------------------------------------------------------------------------------------
 * Displacement form of the rotated scheme (scheme "pcg"): trilinear hexahedra with one-point quadrature.
 *
 * Nodal displacements u (3 components) live at the voxel corners: node (i, j, k) is the lower corner of voxel
 * (i, j, k). The strain of voxel v is e = E + B u (Mandel), from the one-point gradient of the shape functions,
 * dN/dx_d = s_d / (4 h_d) with s_d = +1 for the voxel's 4 nodes on its upper side along d, -1 on the lower side.
 * Arrays are blocks of whole planes along axis 0, periodic along axes 1 and 2 (wrapped here) and along axis 0
 * through ghost planes filled by the caller: p has plane l + 1 = node plane l (ghosts 0 and n + 1), phase has
 * plane l + 1 = voxel plane l (ghost 0). Voxel plane v uses node planes v and v + 1; node plane l gathers from
 * voxel planes l - 1 and l.
 * ------------------------------------------------------------------------------------------------------------ */

/* Tensor stress (11 22 33 23 13 12) of voxel plane v into tau, stored with one leading wrap row and column:
 * tau[c][(j + 1) * (n3 + 1) + k + 1] = voxel (j, k), row 0 = voxel row n2 - 1, column 0 = voxel column n3 - 1.
 * Adds sum_x w.e tau (energy) and sum_x tau_c (mean[c]) to acc[0..6] if count != 0. s, d: 3 * n2 * (n3 + 1)
 * scratch (plane average and difference of p along axis 0, with one trailing wrap column); ebuf: 6 * n3. */
static void hex_voxel_plane(int64_t v, int64_t n2, int64_t n3, const double *p, int64_t pstride,
                            const int32_t *phase, int nphase, const double *tables, const double *w,
                            const double *E, const double *h, double *restrict s, double *restrict d,
                            double *restrict tau, double *restrict ebuf, int count, double *acc)
{
    const int64_t plane = n2 * n3, row = n3 + 1, tplane = (n2 + 1) * (n3 + 1);
    const double inv0 = 1.0 / h[0], q1 = 0.5 / h[1], q2 = 0.5 / h[2];
    const double SQ = 0.70710678118654752440; /* 1/sqrt(2) */
    for (int c = 0; c < 3; ++c) {
        double *sc = s + c * n2 * row, *dc = d + c * n2 * row;
        if (p == NULL) {
            for (int64_t a = 0; a < n2 * row; ++a)
                sc[a] = dc[a] = 0.0;
            continue;
        }
        const double *P0 = p + c * pstride + (v + 1) * plane, *P1 = P0 + plane;
        for (int64_t j = 0; j < n2; ++j) {
#pragma omp simd
            for (int64_t k = 0; k < n3; ++k) {
                sc[j * row + k] = 0.5 * (P0[j * n3 + k] + P1[j * n3 + k]);
                dc[j * row + k] = inv0 * (P1[j * n3 + k] - P0[j * n3 + k]);
            }
            sc[j * row + n3] = sc[j * row];
            dc[j * row + n3] = dc[j * row];
        }
    }
    const int32_t *id = phase + (v + 1) * plane;
    int empty[64];
    for (int ph = 0; ph < nphase && ph < 64; ++ph) {
        empty[ph] = 1;
        for (int a = 0; a < 36; ++a)
            empty[ph] &= (tables[36 * ph + a] == 0.0);
    }
    double *tr[6];
    for (int c = 0; c < 6; ++c)
        tr[c] = tau + c * tplane;
    int nonvoid[64], nnv = 0;
    for (int ph = 0; ph < nphase && ph < 64; ++ph)
        if (!empty[ph])
            nonvoid[nnv++] = ph;
    double energy = 0.0, mean[6] = {0, 0, 0, 0, 0, 0};
    /* Mandel strain of one voxel row */
    double *restrict ev0 = ebuf, *restrict ev1 = ebuf + n3, *restrict ev2 = ebuf + 2 * n3;
    double *restrict ev3 = ebuf + 3 * n3, *restrict ev4 = ebuf + 4 * n3, *restrict ev5 = ebuf + 5 * n3;
    const double E0 = E ? E[0] : 0.0, E1 = E ? E[1] : 0.0, E2 = E ? E[2] : 0.0, E3 = E ? E[3] : 0.0,
                 E4 = E ? E[4] : 0.0, E5 = E ? E[5] : 0.0;
    for (int64_t j = 0; j < n2; ++j) {
        const int64_t jp = (j + 1 == n2) ? 0 : j + 1;
        const double *s0 = s + j * row, *s1 = s0 + n2 * row, *s2 = s1 + n2 * row;
        const double *t0 = s + jp * row, *t1 = t0 + n2 * row, *t2 = t1 + n2 * row; /* s at row jp */
        const double *d0 = d + j * row, *d1 = d0 + n2 * row, *d2 = d1 + n2 * row;
        const double *b0 = d + jp * row, *b1 = b0 + n2 * row, *b2 = b1 + n2 * row; /* d at row jp */
        const int32_t *idr = id + j * n3;
        double *restrict o0 = tr[0] + (j + 1) * row + 1, *restrict o1 = tr[1] + (j + 1) * row + 1,
                         *restrict o2 = tr[2] + (j + 1) * row + 1, *restrict o3 = tr[3] + (j + 1) * row + 1,
                         *restrict o4 = tr[4] + (j + 1) * row + 1, *restrict o5 = tr[5] + (j + 1) * row + 1;
#pragma omp simd
        for (int64_t k = 0; k < n3; ++k) {
            /* one-point gradients: along 0 from the plane differences d, along 1 and 2 from the plane means s */
            const double a00 = 0.25 * (d0[k] + d0[k + 1] + b0[k] + b0[k + 1]);
            const double a10 = 0.25 * (d1[k] + d1[k + 1] + b1[k] + b1[k + 1]);
            const double a20 = 0.25 * (d2[k] + d2[k + 1] + b2[k] + b2[k + 1]);
            const double a01 = q1 * (t0[k] + t0[k + 1] - s0[k] - s0[k + 1]);
            const double a11 = q1 * (t1[k] + t1[k + 1] - s1[k] - s1[k + 1]);
            const double a21 = q1 * (t2[k] + t2[k + 1] - s2[k] - s2[k + 1]);
            const double a02 = q2 * (s0[k + 1] + t0[k + 1] - s0[k] - t0[k]);
            const double a12 = q2 * (s1[k + 1] + t1[k + 1] - s1[k] - t1[k]);
            const double a22 = q2 * (s2[k + 1] + t2[k + 1] - s2[k] - t2[k]);
            ev0[k] = a00 + E0;
            ev1[k] = a11 + E1;
            ev2[k] = a22 + E2;
            ev3[k] = SQ * (a12 + a21) + E3;
            ev4[k] = SQ * (a02 + a20) + E4;
            ev5[k] = SQ * (a01 + a10) + E5;
        }
        if (nnv == 0)
            for (int64_t k = 0; k < n3; ++k)
                o0[k] = o1[k] = o2[k] = o3[k] = o4[k] = o5[k] = 0.0;
        /* one vectorizable sweep per non-void phase, its matrix held in registers; each voxel has one phase, so
         * the energy and the stress sums add the masked contributions of every sweep */
        double en = 0.0, m0 = 0.0, m1 = 0.0, m2 = 0.0, m3 = 0.0, m4 = 0.0, m5 = 0.0;
        for (int qn = 0; qn < nnv; ++qn) {
            const int ph = nonvoid[qn];
            double T[36];
            for (int a = 0; a < 36; ++a)
                T[a] = tables[36 * ph + a];
            if (qn == 0) { /* the first sweep writes (never reads the previous plane's values), the others add */
#pragma omp simd reduction(+ : en, m0, m1, m2, m3, m4, m5)
                for (int64_t k = 0; k < n3; ++k) {
                    const double mask = (idr[k] == ph) ? 1.0 : 0.0;
                    const double e0 = ev0[k], e1 = ev1[k], e2 = ev2[k], e3 = ev3[k], e4 = ev4[k], e5 = ev5[k];
                    const double y0 = mask * ROW6(T, 0);
                    const double y1 = mask * ROW6(T, 1);
                    const double y2 = mask * ROW6(T, 2);
                    const double y3 = mask * ROW6(T, 3);
                    const double y4 = mask * ROW6(T, 4);
                    const double y5 = mask * ROW6(T, 5);
                    o0[k] = y0;
                    o1[k] = y1;
                    o2[k] = y2;
                    o3[k] = y3;
                    o4[k] = y4;
                    o5[k] = y5;
                    en += w[0] * e0 * y0 + w[1] * e1 * y1 + w[2] * e2 * y2 + w[3] * e3 * y3 + w[4] * e4 * y4
                          + w[5] * e5 * y5;
                    m0 += y0;
                    m1 += y1;
                    m2 += y2;
                    m3 += y3;
                    m4 += y4;
                    m5 += y5;
                }
            } else {
#pragma omp simd reduction(+ : en, m0, m1, m2, m3, m4, m5)
                for (int64_t k = 0; k < n3; ++k) {
                    const double mask = (idr[k] == ph) ? 1.0 : 0.0;
                    const double e0 = ev0[k], e1 = ev1[k], e2 = ev2[k], e3 = ev3[k], e4 = ev4[k], e5 = ev5[k];
                    const double y0 = mask * ROW6(T, 0);
                    const double y1 = mask * ROW6(T, 1);
                    const double y2 = mask * ROW6(T, 2);
                    const double y3 = mask * ROW6(T, 3);
                    const double y4 = mask * ROW6(T, 4);
                    const double y5 = mask * ROW6(T, 5);
                    o0[k] += y0;
                    o1[k] += y1;
                    o2[k] += y2;
                    o3[k] += y3;
                    o4[k] += y4;
                    o5[k] += y5;
                    en += w[0] * e0 * y0 + w[1] * e1 * y1 + w[2] * e2 * y2 + w[3] * e3 * y3 + w[4] * e4 * y4
                          + w[5] * e5 * y5;
                    m0 += y0;
                    m1 += y1;
                    m2 += y2;
                    m3 += y3;
                    m4 += y4;
                    m5 += y5;
                }
            }
        }
        energy += en;
        mean[0] += m0;
        mean[1] += m1;
        mean[2] += m2;
        mean[3] += m3;
        mean[4] += m4;
        mean[5] += m5;
    }
    /* wrap row 0 and column 0 */
    for (int c = 0; c < 6; ++c) {
        double *T = tr[c];
        for (int64_t k = 0; k < n3; ++k)
            T[k + 1] = T[n2 * row + k + 1];
        for (int64_t j = 0; j <= n2; ++j)
            T[j * row] = T[j * row + n3];
    }
    if (count) {
        acc[0] += energy;
        for (int c = 0; c < 6; ++c)
            acc[1 + c] += mean[c];
    }
}

/* q = B^T sigma(E + B p) on node planes [a, b) (local; q unpadded, plane l at q + l * plane). p == NULL means
 * p = 0, E == NULL means E = 0. tables: per phase the 6x6 map from Mandel strain to tensor stress (row-major),
 * w: Mandel weights (1, 1, 1, sqrt2, sqrt2, sqrt2). sums[0] += sum over voxel planes [a, b) of e.sigma (Mandel;
 * = p.Kp when E == NULL), sums[1..6] += sum of the tensor stress components. */
void ff_hex_apply(int64_t n2, int64_t n3, int64_t a, int64_t b, const double *p, int64_t pstride,
                  const int32_t *phase, int nphase, const double *tables, const double *w, const double *E,
                  const double *h, double *q, int64_t qstride, double *sums)
{
    const int64_t plane = n2 * n3, row = n3 + 1, tplane = (n2 + 1) * (n3 + 1);
    double *s = malloc(3 * n2 * row * sizeof(double));
    double *d = malloc(3 * n2 * row * sizeof(double));
    double *tauA = malloc(6 * tplane * sizeof(double)); /* voxel plane l - 1 */
    double *tauB = malloc(6 * tplane * sizeof(double)); /* voxel plane l */
    double *pqrs = malloc(8 * row * sizeof(double));    /* P, Q, R, S of two padded rows */
    double *ebuf = malloc(6 * n3 * sizeof(double));     /* strain of one voxel row */
    double acc[7] = {0, 0, 0, 0, 0, 0, 0};
    const double f0 = 0.25 / h[0], f1 = 0.25 / h[1], f2 = 0.25 / h[2];
    /* tau_cd as Voigt index: row c, column d */
    static const int V[3][3] = {{0, 5, 4}, {5, 1, 3}, {4, 3, 2}};
    hex_voxel_plane(a - 1, n2, n3, p, pstride, phase, nphase, tables, w, E, h, s, d, tauA, ebuf, 0, acc);
    for (int64_t l = a; l < b; ++l) {
        hex_voxel_plane(l, n2, n3, p, pstride, phase, nphase, tables, w, E, h, s, d, tauB, ebuf, 1, acc);
        for (int c = 0; c < 3; ++c) {
            /* f = f0 sum4 (A - B)_c0 + f1 sum_cols (U_c1[row j] - U_c1[row j+1]) + f2 sum_rows (U_c2[col k] -
             * U_c2[col k+1]) with U = A + B, written as P[j][k] + Q[j][k+1] + R[j+1][k] + S[j+1][k+1] */
            const double *A0 = tauA + V[c][0] * tplane, *B0 = tauB + V[c][0] * tplane;
            const double *A1 = tauA + V[c][1] * tplane, *B1 = tauB + V[c][1] * tplane;
            const double *A2 = tauA + V[c][2] * tplane, *B2 = tauB + V[c][2] * tplane;
            double *out = q + c * qstride + l * plane;
            for (int64_t rr = 0; rr <= n2; ++rr) {
                double *restrict P = pqrs + (rr & 1) * 4 * row, *restrict Q = P + row, *restrict R = Q + row,
                                 *restrict S = R + row;
                const int64_t o = rr * row;
#pragma omp simd
                for (int64_t k = 0; k <= n3; ++k) {
                    const double x = f0 * (A0[o + k] - B0[o + k]), u = f1 * (A1[o + k] + B1[o + k]),
                                 z = f2 * (A2[o + k] + B2[o + k]);
                    P[k] = x + u + z;
                    Q[k] = x + u - z;
                    R[k] = x - u + z;
                    S[k] = x - u - z;
                }
                if (rr == 0)
                    continue;
                const int64_t j = rr - 1;
                const double *Pj = pqrs + (j & 1) * 4 * row, *Qj = Pj + row; /* row j */
                const double *Rj = P + 2 * row, *Sj = P + 3 * row;            /* row j + 1 */
                double *restrict oj = out + j * n3;
#pragma omp simd
                for (int64_t k = 0; k < n3; ++k)
                    oj[k] = Pj[k] + Qj[k + 1] + Rj[k] + Sj[k + 1];
            }
        }
        double *t = tauA;
        tauA = tauB;
        tauB = t;
    }
    for (int c = 0; c < 7; ++c)
        sums[c] += acc[c];
    free(s);
    free(d);
    free(tauA);
    free(tauB);
    free(pqrs);
    free(ebuf);
}

/* In place on the half spectrum of r (3 components, complex as (re, im) doubles, lines of h3 entries along the
 * last axis, ni * n2 lines from the block's first plane; the last axis holds the global indices k_lo ...
 * k_lo + h3 - 1 of 0 ... h_global - 1): hat <- scale K_I(xi)^-1 hat with the reference
 * operator K_I = B^T B (Mandel identity), K_I(xi) = (|k|^2 I + k k^T) / 2, so
 * K_I^-1 r = (2 / |k|^2) (r - (k.r) k / (2 |k|^2)); zero where |k|^2 <= kmin (k = 0: the mean and the hourglass
 * modes). The rotated wave vector k = (K0 C1 C2, C0 K1 C2, C0 C1 K2) is built from the per-axis tables
 * K_d = (2 / h_d) sin(pi m_d / N_d), C_d = cos(pi m_d / N_d) of the block's indices. Returns
 * sum w conj(r).z over the block, w = 1 on the single planes (global last index 0, and h_global - 1 if
 * nyquist), else 2:
 * with scale = 1/N^3 this is sum_x r.z of the transformed-back z (Parseval). */
double ff_hex_green(int64_t ni, int64_t n2, int64_t h3, double *hat, int64_t stride, const double *K0,
                    const double *C0, const double *K1, const double *C1, const double *K2, const double *C2,
                    double kmin, double scale, int nyquist, int64_t k_lo, int64_t h_global)
{
    double total = 0.0, single = 0.0;
    double *buf = malloc(5 * h3 * sizeof(double));
    double *k0 = buf, *k1 = buf + h3, *k2 = buf + 2 * h3, *amp = buf + 3 * h3, *half = buf + 4 * h3;
    for (int64_t i = 0; i < ni; ++i)
        for (int64_t j = 0; j < n2; ++j) {
            const double A = K0[i] * C1[j], Bv = C0[i] * K1[j], Cc = C0[i] * C1[j];
            double *x = hat + 2 * ((i * n2 + j) * h3), *y = x + stride, *z = y + stride;
#pragma omp simd
            for (int64_t k = 0; k < h3; ++k) {
                k0[k] = A * C2[k];
                k1[k] = Bv * C2[k];
                k2[k] = Cc * K2[k];
                const double kk = k0[k] * k0[k] + k1[k] * k1[k] + k2[k] * k2[k];
                const double safe = (kk > kmin) ? kk : 1.0;
                amp[k] = (kk > kmin) ? 2.0 * scale / safe : 0.0;
                half[k] = 0.5 / safe;
            }
            /* the single planes (last index 0, and h3 - 1 on an even axis) count once in Parseval's sum: their
             * r.z (from the untransformed r) is subtracted once from the doubled total */
            for (int e = 0; e < 2; ++e) {
                const int64_t k = e ? h_global - 1 - k_lo : -k_lo; /* global last index 0 and h_global - 1 */
                if (k < 0 || k >= h3 || (e && (!nyquist || h_global < 2)))
                    continue;
                for (int part = 0; part < 2; ++part) {
                    const double r0 = x[2 * k + part], r1 = y[2 * k + part], r2 = z[2 * k + part];
                    const double kr = half[k] * (k0[k] * r0 + k1[k] * r1 + k2[k] * r2);
                    single += amp[k] * (r0 * (r0 - kr * k0[k]) + r1 * (r1 - kr * k1[k]) + r2 * (r2 - kr * k2[k]));
                }
            }
            double line = 0.0;
#pragma omp simd reduction(+ : line)
            for (int64_t k = 0; k < h3; ++k) {
                const double a = amp[k], c = half[k], q0 = k0[k], q1 = k1[k], q2 = k2[k];
                const double xr = x[2 * k], xi = x[2 * k + 1], yr = y[2 * k], yi = y[2 * k + 1], zr = z[2 * k],
                             zi = z[2 * k + 1];
                const double kr = c * (q0 * xr + q1 * yr + q2 * zr), ki = c * (q0 * xi + q1 * yi + q2 * zi);
                const double ar0 = a * (xr - kr * q0), ar1 = a * (yr - kr * q1), ar2 = a * (zr - kr * q2);
                const double ai0 = a * (xi - ki * q0), ai1 = a * (yi - ki * q1), ai2 = a * (zi - ki * q2);
                line += xr * ar0 + yr * ar1 + zr * ar2 + xi * ai0 + yi * ai1 + zi * ai2;
                x[2 * k] = ar0;
                x[2 * k + 1] = ai0;
                y[2 * k] = ar1;
                y[2 * k + 1] = ai1;
                z[2 * k] = ar2;
                z[2 * k + 1] = ai2;
            }
            total += line;
        }
    free(buf);
    return 2.0 * total - single;
}

/* y_c <- alpha_c x_c + beta y_c for c < ncomp (x, y with their own component strides; beta = 0 does not read
 * y); returns sum y.y if norm != 0, else 0. */
double ff_axpby(int64_t n, int ncomp, const double *alpha, const double *x, int64_t xstride, double beta,
                double *y, int64_t ystride, int norm)
{
    double total = 0.0;
    for (int c = 0; c < ncomp; ++c) {
        const double a = alpha[c];
        const double *xc = x + c * xstride;
        double *yc = y + c * ystride;
        if (beta == 0.0) /* y may hold garbage (NaN): never read it */
            for (int64_t i = 0; i < n; ++i)
                yc[i] = a * xc[i];
        else
            for (int64_t i = 0; i < n; ++i)
                yc[i] = a * xc[i] + beta * yc[i];
        if (norm) {
#pragma omp simd reduction(+ : total)
            for (int64_t i = 0; i < n; ++i)
                total += yc[i] * yc[i];
        }
    }
    return total;
}

/* ---------------------------------------------------------------------------------------------------------------
 * Fully integrated trilinear voxels (hex8, 2 x 2 x 2 Gauss points): K p = sum over voxels of Ke(phase) p_e with the
 * 24 x 24 element matrices Ke (node n = 4 da + 2 db + dc of the voxel, dof 3 n + component; built in _nodal.py).
 * --------------------------------------------------------------------------------------------------------------- */

/* One voxel plane v (local; phase plane v + 1, padded node planes v + 1 and v + 2 of p): Ke p_e of every voxel whose
 * phase is active, scattered to the voxel's lower node plane (lo, may be NULL) and upper node plane (up). If acc is
 * not NULL, acc[0] += sum p_e.Ke p_e and acc[1..6] += the tensor stress of the centre strain (tables). */
static void hex8_voxel_plane(int64_t v, int64_t n2, int64_t n3, const double *p, int64_t pstride,
                             const int32_t *phase, const double *Ke, const int32_t *active, const double *tables,
                             const double *h, double *lo, double *up, double *acc)
{
    const int64_t plane = n2 * n3;
    const int32_t *ids = phase + (v + 1) * plane;
    const double g0 = 0.25 / h[0], g1 = 0.25 / h[1], g2 = 0.25 / h[2];
    static const double r2 = 0.70710678118654752440; /* 1/sqrt2 */
    if (lo)
        memset(lo, 0, 3 * plane * sizeof(double));
    memset(up, 0, 3 * plane * sizeof(double));
    double energy = 0.0, mean[6] = {0, 0, 0, 0, 0, 0};
    for (int64_t j = 0; j < n2; ++j) {
        const int64_t jj[2] = {j, (j + 1 == n2) ? 0 : j + 1};
        for (int64_t k = 0; k < n3; ++k) {
            const int32_t ph = ids[j * n3 + k];
            if (!active[ph])
                continue;
            const int64_t kk[2] = {k, (k + 1 == n3) ? 0 : k + 1};
            int64_t at[8];
            double u[24], f[24];
            for (int da = 0; da < 2; ++da)
                for (int db = 0; db < 2; ++db)
                    for (int dc = 0; dc < 2; ++dc) {
                        const int n = 4 * da + 2 * db + dc;
                        at[n] = jj[db] * n3 + kk[dc];
                        const double *src = p + (v + 1 + da) * plane + at[n];
                        u[3 * n] = src[0];
                        u[3 * n + 1] = src[pstride];
                        u[3 * n + 2] = src[2 * pstride];
                    }
            const double *A = Ke + 576 * (int64_t)ph;
            for (int r = 0; r < 24; ++r) {
                double s = 0.0;
#pragma omp simd reduction(+ : s)
                for (int c = 0; c < 24; ++c)
                    s += A[24 * r + c] * u[c];
                f[r] = s;
            }
            for (int n = 0; n < 8; ++n) {
                double *dst = (n < 4) ? lo : up;
                if (!dst)
                    continue;
                dst[at[n]] += f[3 * n];
                dst[plane + at[n]] += f[3 * n + 1];
                dst[2 * plane + at[n]] += f[3 * n + 2];
            }
            if (acc) {
                double e = 0.0;
                for (int r = 0; r < 24; ++r)
                    e += u[r] * f[r];
                energy += e;
                /* centre gradient: G[c][d] = sum_n u_c(n) s_d(n) / (4 h_d) */
                double G[3][3];
                for (int c = 0; c < 3; ++c) {
                    double x0 = 0.0, x1 = 0.0, x2 = 0.0;
                    for (int n = 0; n < 8; ++n) {
                        const double val = u[3 * n + c];
                        x0 += (n & 4) ? val : -val;
                        x1 += (n & 2) ? val : -val;
                        x2 += (n & 1) ? val : -val;
                    }
                    G[c][0] = g0 * x0;
                    G[c][1] = g1 * x1;
                    G[c][2] = g2 * x2;
                }
                const double em[6] = {G[0][0], G[1][1], G[2][2], r2 * (G[1][2] + G[2][1]), r2 * (G[0][2] + G[2][0]),
                                      r2 * (G[0][1] + G[1][0])};
                const double *T = tables + 36 * (int64_t)ph;
                for (int a = 0; a < 6; ++a)
                    mean[a] += T[6 * a] * em[0] + T[6 * a + 1] * em[1] + T[6 * a + 2] * em[2] + T[6 * a + 3] * em[3]
                               + T[6 * a + 4] * em[4] + T[6 * a + 5] * em[5];
            }
        }
    }
    if (acc) {
        acc[0] += energy;
        for (int a = 0; a < 6; ++a)
            acc[1 + a] += mean[a];
    }
}

/* q = K p on node planes [a, b) (local; q unpadded), K the hex8 stiffness. sums[0] += p.Kp over voxel planes [a, b),
 * sums[1..6] += the tensor stress of the voxel-centre strain B0 p (the Gauss-point mean) over the same voxels. */
void ff_hex8_apply(int64_t n2, int64_t n3, int64_t a, int64_t b, const double *p, int64_t pstride,
                   const int32_t *phase, const double *Ke, const int32_t *active, const double *tables,
                   const double *h, double *q, int64_t qstride, double *sums)
{
    const int64_t plane = n2 * n3;
    double *up = malloc(3 * plane * sizeof(double));
    double *up2 = malloc(3 * plane * sizeof(double));
    double *lo = malloc(3 * plane * sizeof(double));
    double acc[7] = {0, 0, 0, 0, 0, 0, 0};
    hex8_voxel_plane(a - 1, n2, n3, p, pstride, phase, Ke, active, tables, h, NULL, up, NULL);
    for (int64_t l = a; l < b; ++l) {
        hex8_voxel_plane(l, n2, n3, p, pstride, phase, Ke, active, tables, h, lo, up2, acc);
        for (int c = 0; c < 3; ++c) {
            double *out = q + c * qstride + l * plane;
            const double *x = up + c * plane, *y = lo + c * plane;
#pragma omp simd
            for (int64_t i = 0; i < plane; ++i)
                out[i] = x[i] + y[i];
        }
        double *t = up;
        up = up2;
        up2 = t;
    }
    for (int c = 0; c < 7; ++c)
        sums[c] += acc[c];
    free(up);
    free(up2);
    free(lo);
}

/* Green operator of the hex8 discretization for the Mandel identity as material, in place on the spectrum of a
 * 3-component nodal field: hat <- scale M(xi)^-1 hat, M = (tr A I + A) / 2 with A_cc = K_c^2 W_d W_f,
 * A_cd = K_c C_c K_d C_d W_f ({c, d, f} = {0, 1, 2}), per-axis tables K = (2/h) sin(pi m/N), C = cos(pi m/N),
 * W = C^2 + sin^2(pi m/N)/3; zero where tr A <= kmin (xi = 0). Returns sum w conj(r).z as ff_hex_green. */
double ff_hex8_green(int64_t ni, int64_t n2, int64_t h3, double *hat, int64_t stride, const double *K0,
                     const double *C0, const double *W0, const double *K1, const double *C1, const double *W1,
                     const double *K2, const double *C2, const double *W2, double kmin, double scale, int nyquist,
                     int64_t k_lo, int64_t h_global)
{
    double total = 0.0, single = 0.0;
    for (int64_t i = 0; i < ni; ++i)
        for (int64_t j = 0; j < n2; ++j) {
            double *x = hat + 2 * ((i * n2 + j) * h3), *y = x + stride, *z = y + stride;
            const double a0 = K0[i], c0 = C0[i], w0 = W0[i], a1 = K1[j], c1 = C1[j], w1 = W1[j];
            double line = 0.0, once = 0.0;
            for (int64_t k = 0; k < h3; ++k) {
                const double a2 = K2[k], c2 = C2[k], w2 = W2[k];
                const double A00 = a0 * a0 * w1 * w2, A11 = a1 * a1 * w0 * w2, A22 = a2 * a2 * w0 * w1;
                const double tr = A00 + A11 + A22;
                double m00 = 0, m11 = 0, m22 = 0, m01 = 0, m02 = 0, m12 = 0;
                if (tr > kmin) {
                    const double d = 0.5 * tr;
                    const double M00 = d + 0.5 * A00, M11 = d + 0.5 * A11, M22 = d + 0.5 * A22;
                    const double M01 = 0.5 * a0 * c0 * a1 * c1 * w2, M02 = 0.5 * a0 * c0 * a2 * c2 * w1,
                                 M12 = 0.5 * a1 * c1 * a2 * c2 * w0;
                    const double i00 = M11 * M22 - M12 * M12, i01 = M02 * M12 - M01 * M22,
                                 i02 = M01 * M12 - M02 * M11, i11 = M00 * M22 - M02 * M02,
                                 i12 = M01 * M02 - M00 * M12, i22 = M00 * M11 - M01 * M01;
                    const double s = scale / (M00 * i00 + M01 * i01 + M02 * i02);
                    m00 = s * i00;
                    m11 = s * i11;
                    m22 = s * i22;
                    m01 = s * i01;
                    m02 = s * i02;
                    m12 = s * i12;
                }
                double rz = 0.0;
                for (int part = 0; part < 2; ++part) {
                    const double r0 = x[2 * k + part], r1 = y[2 * k + part], r2 = z[2 * k + part];
                    const double z0 = m00 * r0 + m01 * r1 + m02 * r2, z1 = m01 * r0 + m11 * r1 + m12 * r2,
                                 z2 = m02 * r0 + m12 * r1 + m22 * r2;
                    rz += r0 * z0 + r1 * z1 + r2 * z2;
                    x[2 * k + part] = z0;
                    y[2 * k + part] = z1;
                    z[2 * k + part] = z2;
                }
                line += rz;
                const int64_t g = k + k_lo;
                if (g == 0 || (nyquist && h_global > 1 && g == h_global - 1))
                    once += rz;
            }
            total += line;
            single += once;
        }
    return 2.0 * total - single;
}
