/* The in-layer distance to the walls of a gauge-Voronoi diagram (meshes.gauge.GaugeWalls), one point at a time.
 *
 * Same algebra as GaugeWalls._evaluate_numpy: for each point, its K candidate site images (the Euclidean nearest
 * in the undeformed coordinates, found by the caller's KD-tree), their gauge distances d_k = max_f nu_f.(x - p_k),
 * the nearest site (k1), then the bisector polylines of (k1, k) in order of the lower bound (d_k - d_1)/(2G),
 * until that bound exceeds min(psi, upper). Each bisector piece (a, b) is the interval of the line
 * (nu_a - nu_b).y = nu_a.p1 - nu_b.pk (in the layer z = x_z) where face a is active for p1 and face b for pk. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#define MAXF 64

static double piece_distance(const double *x, const double *p1, const double *pk, int P, int F, const int *pa,
                             const int *pb, const double *nu, const double *dn, const double *nn, const double *t,
                             const double *D1, const double *r1, const double *Dn1, const double *D2,
                             const double *r2, const double *Dn2, double *foot, int *piece)
{
    double best = INFINITY;
    double a1[MAXF], a2[MAXF];  /* nu_f . (x - p) for both sites */
    for (int f = 0; f < F; ++f) {
        a1[f] = nu[3 * f] * (x[0] - p1[0]) + nu[3 * f + 1] * (x[1] - p1[1]) + nu[3 * f + 2] * (x[2] - p1[2]);
        a2[f] = nu[3 * f] * (x[0] - pk[0]) + nu[3 * f + 1] * (x[1] - pk[1]) + nu[3 * f + 2] * (x[2] - pk[2]);
    }
    for (int q = 0; q < P; ++q) {
        const int a = pa[q], b = pb[q];
        /* signed offset of x from the line along dn (in units of nn): foot y0 = x - s_perp dn */
        const double g = (a1[a] - a2[b]);     /* = dn.x - c with the layer's z */
        const double s_perp = g / nn[q];
        const double dperp2 = s_perp * s_perp * nn[q];
        if (dperp2 >= best * best)
            continue;                          /* the line itself is farther than the best piece */
        double lo = -INFINITY, hi = INFINITY;
        int ok = 1;
        for (int f = 0; f < F && ok; ++f) {
            /* (nu_a - nu_f).(y - p1) >= 0 at y = y0 + s t:  val0 + s rate >= 0 */
            const double v0 = (a1[a] - a1[f]) - s_perp * Dn1[q * F + f];
            const double r = r1[q * F + f];
            if (r > 1e-14)
                lo = fmax(lo, -v0 / r);
            else if (r < -1e-14)
                hi = fmin(hi, -v0 / r);
            else if (v0 < -1e-12)
                ok = 0;
        }
        for (int f = 0; f < F && ok; ++f) {
            const double v0 = (a2[b] - a2[f]) - s_perp * Dn2[q * F + f];
            const double r = r2[q * F + f];
            if (r > 1e-14)
                lo = fmax(lo, -v0 / r);
            else if (r < -1e-14)
                hi = fmin(hi, -v0 / r);
            else if (v0 < -1e-12)
                ok = 0;
        }
        if (!ok || lo > hi)
            continue;
        const double s = fmin(fmax(0.0, lo), hi);
        const double d = sqrt(dperp2 + s * s);
        if (d < best) {
            best = d;
            *piece = q;
            foot[0] = x[0] - s_perp * dn[3 * q] + s * t[2 * q];
            foot[1] = x[1] - s_perp * dn[3 * q + 1] + s * t[2 * q + 1];
            foot[2] = x[2];
        }
    }
    (void)D1; (void)D2;
    return best;
}

/* Returns the number of points not yet exact (done[i] = 0: more candidates needed). */
int64_t gw_evaluate(int64_t M, const double *x, int K, const int64_t *idx, const double *e, const double *images,
                    int F, const double *nu, int P, const int *pa, const int *pb, const double *dn, const double *nn,
                    const double *t, const double *D1, const double *r1, const double *Dn1, const double *D2,
                    const double *r2, const double *Dn2, double R, double G, double upper, int last,
                    double *psi, double *foot, int *piece, int64_t *first, int *done)
{
    int64_t pending = 0;
    double *d = malloc(sizeof(double) * K);
    double *lower = malloc(sizeof(double) * K);
    int *order = malloc(sizeof(int) * K);
    for (int64_t i = 0; i < M; ++i) {
        const double *xi = x + 3 * i;
        const int64_t *ci = idx + (int64_t)K * i;
        int k1 = 0;
        for (int k = 0; k < K; ++k) {
            const double *p = images + 3 * ci[k];
            double m = -INFINITY;
            for (int f = 0; f < F; ++f) {
                const double v = nu[3 * f] * (xi[0] - p[0]) + nu[3 * f + 1] * (xi[1] - p[1])
                                 + nu[3 * f + 2] * (xi[2] - p[2]);
                m = v > m ? v : m;
            }
            d[k] = m;
            if (m < d[k1])
                k1 = k;
        }
        const double d1 = d[k1];
        first[i] = ci[k1];
        int n = 0;
        for (int k = 0; k < K; ++k)
            if (k != k1) {
                lower[k] = (d[k] - d1) / (2.0 * G);
                /* insertion sort of the candidates by their lower bound */
                int j = n++;
                while (j > 0 && lower[order[j - 1]] > lower[k]) {
                    order[j] = order[j - 1];
                    --j;
                }
                order[j] = k;
            }
        double best = INFINITY;
        double f3[3] = {xi[0], xi[1], xi[2]};
        int pc = -1;
        for (int j = 0; j < n; ++j) {
            const int k = order[j];
            const double cap = best < upper ? best : upper;
            if (lower[k] > cap)
                break;
            double ft[3];
            int q = -1;
            const double dist = piece_distance(xi, images + 3 * ci[k1], images + 3 * ci[k], P, F, pa, pb, nu, dn,
                                               nn, t, D1, r1, Dn1, D2, r2, Dn2, ft, &q);
            if (dist < best) {
                best = dist;
                f3[0] = ft[0]; f3[1] = ft[1]; f3[2] = ft[2];
                pc = q;
            }
        }
        const double outside = (e[(int64_t)K * i + K - 1] / R - d1) / (2.0 * G);
        const double cap = best < upper ? best : upper;
        done[i] = last || outside >= cap;
        if (!done[i])
            ++pending;
        psi[i] = best;
        foot[3 * i] = f3[0]; foot[3 * i + 1] = f3[1]; foot[3 * i + 2] = f3[2];
        piece[i] = pc;
    }
    free(d);
    free(lower);
    free(order);
    return pending;
}
