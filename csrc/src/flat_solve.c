// SPDX-License-Identifier: GPL-3.0-or-later
/* The flat positions' least squares (spia__flat_solve), from a grid of
 * limit points: spia_flat_positions' own, or the one a fit measured the
 * scan's distances with (spia_fit_report.flat_positions). */
#include "fit.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* spia_flat_positions: each quad's 3 x 3 grid of limit points (corners, edge
 * midpoints, centre) against the bilinear quad through its corners' new
 * positions, in least squares, the corner points weighted FLAT_CORNER_WEIGHT
 * (measured on the bunny's level 3: 0, 1/16, 1/4 and 1 left the scan's
 * vertices a median 2.5, 2.6, 2.9 and 3.5e-5 of the diagonal from the flat
 * faces, against 4.4e-5 from those through the limit points; with none a
 * checkerboard of the vertices would not be determined); conjugate
 * gradients with a Jacobi preconditioner, from the limit points. */
#define FLAT_CORNER_WEIGHT 0.0625
#define FLAT_MAX_ITERATIONS 200
#define FLAT_TOLERANCE 1e-8

/* Bilinear weights of grid point (i, j), i along the first edge, at (i / 2, j / 2). */
static void flat_weights(int i, int j, double w[4]) {
    const double s = 0.5 * i, t = 0.5 * j;
    w[0] = (1 - s) * (1 - t), w[1] = s * (1 - t), w[2] = s * t, w[3] = (1 - s) * t;
}

/* y = A x: the quads' 4 x 4 normal block M (the same for every quad), and
 * an identity row for each vertex no quad uses (extra 1). */
static void flat_apply(const spia_mesh *m, const double M[16], const double *extra, const double *x, double *y) {
    memset(y, 0, sizeof(double) * 3 * (size_t)m->vertex_count);
    for (int32_t f = 0; f < m->face_count; ++f) {
        const int32_t *q = m->face_vertices + 4 * (int64_t)f;
        for (int c = 0; c < 4; ++c)
            for (int a = 0; a < 3; ++a) {
                double sum = 0.0;
                for (int d = 0; d < 4; ++d) sum += M[4 * c + d] * x[3 * (int64_t)q[d] + a];
                y[3 * (int64_t)q[c] + a] += sum;
            }
    }
    for (int64_t i = 0; i < 3 * (int64_t)m->vertex_count; ++i) y[i] += extra[i / 3] * x[i];
}

static spia_result flat_oom(spia_status *status) {
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the flat positions");
}

spia_result spia__flat_solve(const spia_mesh *m, const float *X, int32_t side, float *out, fit_clock *clock,
                             spia_status *status) {
    const int32_t n = m->vertex_count;
    /* Grid point (i, j) of the 3 x 3 is point (step i, step j) of a face's side x side. */
    const int64_t step = (side - 1) / 2, per_face = 3 * (int64_t)side * side;
    const int64_t N3 = 3 * (int64_t)n;
    double M[16] = {0}, w[4];
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) {
            const double k = ((i == 1) || (j == 1)) ? 1.0 : FLAT_CORNER_WEIGHT;
            flat_weights(i, j, w);
            for (int c = 0; c < 4; ++c)
                for (int d = 0; d < 4; ++d) M[4 * c + d] += k * w[c] * w[d];
        }
    double *buf = malloc(sizeof(double) * (6 * (size_t)N3 + 2 * (size_t)n + 1));
    unsigned char *seen = calloc((size_t)n + 1, 1);
    if (!buf || !seen) {
        free(buf), free(seen);
        return flat_oom(status);
    }
    double *x = buf, *b = buf + N3, *r = buf + 2 * N3, *z = buf + 3 * N3, *p = buf + 4 * N3, *Ap = buf + 5 * N3;
    double *extra = buf + 6 * N3, *pre = extra + n;
    memset(b, 0, sizeof(double) * (size_t)N3);
    memset(extra, 0, sizeof(double) * 2 * (size_t)n);
    /* The right-hand side, the preconditioner, and the start: each vertex at
     * its limit point (its corner point in its first quad's grid). */
    static const int corner_i[4] = {0, 2, 2, 0}, corner_j[4] = {0, 0, 2, 2};
    for (int32_t f = 0; f < m->face_count; ++f) {
        const int32_t *q = m->face_vertices + 4 * (int64_t)f;
        const float *G = X + per_face * f;
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) {
                const double k = ((i == 1) || (j == 1)) ? 1.0 : FLAT_CORNER_WEIGHT;
                const float *g = G + 3 * (step * j * side + step * i);
                flat_weights(i, j, w);
                for (int c = 0; c < 4; ++c)
                    for (int a = 0; a < 3; ++a) b[3 * (int64_t)q[c] + a] += k * w[c] * g[a];
            }
        for (int c = 0; c < 4; ++c) {
            pre[q[c]] += M[5 * c];
            if (!seen[q[c]]) {
                seen[q[c]] = 1;
                const float *g = G + 3 * (step * corner_j[c] * side + step * corner_i[c]);
                for (int a = 0; a < 3; ++a) x[3 * (int64_t)q[c] + a] = g[a];
            }
        }
    }
    for (int32_t v = 0; v < n; ++v)
        if (!seen[v]) {
            extra[v] = 1.0, pre[v] = 1.0;
            for (int a = 0; a < 3; ++a) b[3 * (int64_t)v + a] = x[3 * (int64_t)v + a] = m->positions[3 * (int64_t)v + a];
        }
    free(seen);
    flat_apply(m, M, extra, x, Ap);
    double rz = 0.0, bb = 0.0;
    for (int64_t i = 0; i < N3; ++i) {
        r[i] = b[i] - Ap[i];
        z[i] = r[i] / pre[i / 3];
        p[i] = z[i];
        rz += r[i] * z[i];
        bb += b[i] * b[i];
    }
    for (int it = 0; it < FLAT_MAX_ITERATIONS && rz > FLAT_TOLERANCE * FLAT_TOLERANCE * bb; ++it) {
        if (spia__fit_clock_tick(clock)) {
            free(buf);
            return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the flat positions");
        }
        flat_apply(m, M, extra, p, Ap);
        double pAp = 0.0;
        for (int64_t i = 0; i < N3; ++i) pAp += p[i] * Ap[i];
        if (!(pAp > 0.0)) break;
        const double alpha = rz / pAp;
        double rz_new = 0.0;
        for (int64_t i = 0; i < N3; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * Ap[i];
            z[i] = r[i] / pre[i / 3];
            rz_new += r[i] * z[i];
        }
        const double beta = rz_new / rz;
        rz = rz_new;
        for (int64_t i = 0; i < N3; ++i) p[i] = z[i] + beta * p[i];
    }
    for (int64_t i = 0; i < N3; ++i)
        if (!isfinite(x[i])) {
            free(buf);
            return spia__fail(status, SPIA_ERROR_DIVERGED, -1, "the flat positions are not finite");
        }
    for (int64_t i = 0; i < N3; ++i) out[i] = (float)x[i];
    free(buf);
    return SPIA_OK;
}

