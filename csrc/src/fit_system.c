// SPDX-License-Identifier: GPL-3.0-or-later
/* A least-squares round of the SURFACE fit (the system fit.c describes):
 * the fairness term's umbrella Laplacian, the normal-equation operator,
 * the 3x3 block-Jacobi preconditioner and conjugate gradients.  The
 * products over the samples are fit_blocks.c's. */
#include "fit.h"

#include <math.h>
#include <string.h>

/* Conjugate gradients stop early only when the residual has fallen this far:
 * in practice every round takes solver_iterations steps, which measured
 * better (for the same time) than looser tolerances with more rounds. */
#define CG_TOLERANCE 1e-10

static void laplacian(const fit_system *f, const double *x, double *y) {
    for (int32_t v = 0; v < f->n; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        double *out = y + 3 * (int64_t)v;
        if (a == b) {
            out[0] = out[1] = out[2] = 0.0;
            continue;
        }
        double m[3] = {0.0, 0.0, 0.0};
        for (int64_t k = a; k < b; ++k)
            for (int c = 0; c < 3; ++c) m[c] += x[3 * (int64_t)f->nb[k] + c];
        for (int c = 0; c < 3; ++c) out[c] = x[3 * (int64_t)v + c] - m[c] / (double)(b - a);
    }
}

/* z += scale * Lap^T y (the neighbour relation is symmetric). */
static void laplacian_transpose_add(const fit_system *f, const double *y, double scale, double *z) {
    for (int32_t v = 0; v < f->n; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        if (a == b) continue;
        double acc[3] = {y[3 * (int64_t)v], y[3 * (int64_t)v + 1], y[3 * (int64_t)v + 2]};
        for (int64_t k = a; k < b; ++k) {
            const int32_t j = f->nb[k];
            const double inv = 1.0 / (double)(f->nb_start[j + 1] - f->nb_start[j]);
            for (int c = 0; c < 3; ++c) acc[c] -= y[3 * (int64_t)j + c] * inv;
        }
        for (int c = 0; c < 3; ++c) z[3 * (int64_t)v + c] += scale * acc[c];
    }
}

static inline double stiffness(const fit_system *f, int32_t v) { return f->hold[v] + f->smooth[v] - 1.0; }

/* z += lambda Lap^T C Lap x (the operator's share), or with `held` the
 * right-hand side's lambda Lap^T H Lap x. */
static void fairness_add(const fit_system *f, const double *x, int held, double *z) {
    laplacian(f, x, f->tmp_n);
    for (int32_t v = 0; v < f->n; ++v) {
        const double k = held ? f->hold[v] : stiffness(f, v);
        for (int c = 0; c < 3; ++c) f->tmp_n[3 * (int64_t)v + c] *= k;
    }
    laplacian_transpose_add(f, f->tmp_n, f->lambda, z);
}

/* y = A x, the normal-equation matrix: M^T B M x block by block, then the
 * fairness and the damping. */
static void system_apply(const fit_system *f, const double *x, double *y) {
    memset(y, 0, sizeof(double) * 3 * (size_t)f->n);
    spia__fit_blocks_normal(f, x, NULL, y);
    if (f->lambda > 0.0) {
        fairness_add(f, x, 0, y);
    }
    for (int32_t v = 0; v < f->n; ++v)
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            y[i] = f->free_vertex[v] ? y[i] + f->damping * x[i] : 0.0;
        }
}

/* Inverse of a symmetric 3x3 matrix (xx, xy, xz, yy, yz, zz), as 9 entries;
 * falls back to the inverse diagonal when it is near singular. */
static void invert_sym3(const double a[6], double inv[9]) {
    const double c00 = a[3] * a[5] - a[4] * a[4], c01 = a[2] * a[4] - a[1] * a[5], c02 = a[1] * a[4] - a[2] * a[3];
    const double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
    const double scale = fabs(a[0]) + fabs(a[3]) + fabs(a[5]);
    memset(inv, 0, 9 * sizeof(double));
    if (!(fabs(det) > 1e-12 * scale * scale * scale)) {
        if (a[0] > 0.0) inv[0] = 1.0 / a[0];
        if (a[3] > 0.0) inv[4] = 1.0 / a[3];
        if (a[5] > 0.0) inv[8] = 1.0 / a[5];
        return;
    }
    const double c11 = a[0] * a[5] - a[2] * a[2], c12 = a[1] * a[2] - a[0] * a[4], c22 = a[0] * a[3] - a[1] * a[1];
    inv[0] = c00 / det, inv[1] = c01 / det, inv[2] = c02 / det;
    inv[3] = c01 / det, inv[4] = c11 / det, inv[5] = c12 / det;
    inv[6] = c02 / det, inv[7] = c12 / det, inv[8] = c22 / det;
}

/* z = P r with the 3x3 blocks of P (9 per vertex); returns z . r. */
static double precondition(int32_t n, const double *precond, const double *r, double *z) {
    double rz = 0.0;
    for (int32_t v = 0; v < n; ++v) {
        const double *P = precond + 9 * (int64_t)v, *rv = r + 3 * (int64_t)v;
        double *zv = z + 3 * (int64_t)v;
        for (int c = 0; c < 3; ++c) zv[c] = P[3 * c] * rv[0] + P[3 * c + 1] * rv[1] + P[3 * c + 2] * rv[2];
        rz += zv[0] * rv[0] + zv[1] * rv[1] + zv[2] * rv[2];
    }
    return rz;
}

/* One round: conjugate gradients on A V = b from the current V, with targets
 * T (S * 3 floats).  `work` holds 5 * 3n doubles, `precond` 9n. */
int spia__fit_least_squares_round(fit_system *f, const float *T, const double *V0, double *V, int iterations,
                                  double *work, double *precond, fit_clock *clock) {
    const int64_t N3 = 3 * (int64_t)f->n;
    double *b = work, *r = work + N3, *z = work + 2 * N3, *p = work + 3 * N3, *Ap = work + 4 * N3;
    /* b = M^T B T + lambda Lap^T H Lap V0 + damping V (the damping anchors the
     * current iterate, so it does not bias the fit). */
    memset(b, 0, sizeof(double) * (size_t)N3);
    spia__fit_blocks_normal(f, NULL, T, b);
    if (f->lambda > 0.0) {
        fairness_add(f, V0, 1, b);
    }
    for (int64_t i = 0; i < N3; ++i) b[i] += f->damping * V[i];

    /* Block-Jacobi preconditioner: sum_s m_si^2 B_s + lambda (Lap^T Lap)_ii + damping. */
    double *diag = f->tmp_diag;
    memset(diag, 0, sizeof(double) * 6 * (size_t)f->n);
    spia__fit_blocks_diagonal(f, diag);
    for (int32_t v = 0; v < f->n; ++v) {
        double *a = diag + 6 * (int64_t)v;
        const int64_t na = f->nb_start[v], nb = f->nb_start[v + 1];
        double lap = 0.0; /* (Lap^T C Lap)_vv */
        if (nb > na) {
            lap = stiffness(f, v);
            for (int64_t k = na; k < nb; ++k) {
                const int32_t j = f->nb[k];
                const double deg = (double)(f->nb_start[j + 1] - f->nb_start[j]);
                lap += stiffness(f, j) / (deg * deg);
            }
        }
        const double d = f->lambda * lap + f->damping;
        a[0] += d, a[3] += d, a[5] += d;
        if (f->free_vertex[v])
            invert_sym3(a, precond + 9 * (int64_t)v);
        else
            memset(precond + 9 * (int64_t)v, 0, 9 * sizeof(double));
    }

    system_apply(f, V, Ap);
    for (int64_t i = 0; i < N3; ++i) r[i] = f->free_vertex[i / 3] ? b[i] - Ap[i] : 0.0;
    double rz = precondition(f->n, precond, r, z);
    memcpy(p, z, sizeof(double) * (size_t)N3);
    const double rz0 = rz;
    int it = 0;
    for (; it < iterations && rz > CG_TOLERANCE * CG_TOLERANCE * rz0 && rz > 0.0 && !spia__fit_clock_tick(clock); ++it) {
        system_apply(f, p, Ap);
        double pAp = 0.0;
        for (int64_t i = 0; i < N3; ++i) pAp += p[i] * Ap[i];
        if (!(pAp > 0.0)) break;
        const double alpha = rz / pAp;
        for (int64_t i = 0; i < N3; ++i) {
            V[i] += alpha * p[i];
            r[i] -= alpha * Ap[i];
        }
        const double rz_new = precondition(f->n, precond, r, z);
        const double beta = rz_new / rz;
        rz = rz_new;
        for (int64_t i = 0; i < N3; ++i) p[i] = z[i] + beta * p[i];
    }
    return it;
}
