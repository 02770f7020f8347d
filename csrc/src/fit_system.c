// SPDX-License-Identifier: GPL-3.0-or-later
/* A least-squares round of the SURFACE fit (the system fit.c describes):
 * the fairness term's umbrella Laplacian, the normal-equation operator,
 * the 3x3 block-Jacobi preconditioner and conjugate gradients.  The
 * products over the samples are fit_blocks.c's. */
#include "fit.h"
#include "threads.h"

#include <math.h>
#include <string.h>

/* Conjugate gradients stop early only when the residual has fallen this far:
 * in practice every round takes solver_iterations steps, which measured
 * better (for the same time) than looser tolerances with more rounds. */
#define CG_TOLERANCE 1e-10

/* The per-vertex passes run over the vertices in chunks of VERTEX_CHUNK or
 * more on the fit's threads (spia__parallel_sum: a sum over the vertices is
 * the same whatever the threads).  On one thread these passes took about
 * 4 s of the 50k-vertex dragon cage's detail levels (profiled; 3.2M
 * vertices at the finest); on two the levels took 48 s instead of 51.5. */
#define VERTEX_CHUNK 16384

typedef struct vertex_pass vertex_pass;
typedef double (*vertex_fn)(const vertex_pass *p, int32_t begin, int32_t end);

struct vertex_pass {
    const fit_system *f;
    vertex_fn fn;
    const double *x, *y, *P; /* what each pass reads */
    double *z, *w, *r, *V;   /* and writes */
    double a;                /* a scalar of the pass */
    int held;
};

static double vertex_chunk(void *context, int64_t begin, int64_t end) {
    const vertex_pass *p = context;
    return p->fn(p, (int32_t)begin, (int32_t)end);
}

/* Runs fn over every vertex; returns the sum of what it returns. */
static double vertex_run(vertex_pass *p, vertex_fn fn) {
    p->fn = fn;
    return spia__parallel_sum(p->f->threads, p->f->n, VERTEX_CHUNK, vertex_chunk, p);
}

static inline double stiffness(const fit_system *f, int32_t v) { return f->hold[v] + f->smooth[v] - 1.0; }

/* w = C Lap x (with `held`, H Lap x): the umbrella Laplacian scaled by
 * each vertex's stiffness (or hold). */
static double laplacian_scaled(const vertex_pass *p, int32_t begin, int32_t end) {
    const fit_system *f = p->f;
    const double *x = p->x;
    for (int32_t v = begin; v < end; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        double *out = p->w + 3 * (int64_t)v;
        if (a == b) {
            out[0] = out[1] = out[2] = 0.0;
            continue;
        }
        double m[3] = {0.0, 0.0, 0.0};
        for (int64_t k = a; k < b; ++k)
            for (int c = 0; c < 3; ++c) m[c] += x[3 * (int64_t)f->nb[k] + c];
        const double s = p->held ? f->hold[v] : stiffness(f, v);
        for (int c = 0; c < 3; ++c) out[c] = (x[3 * (int64_t)v + c] - m[c] / (double)(b - a)) * s;
    }
    return 0.0;
}

/* z += a * Lap^T w (the neighbour relation is symmetric). */
static double laplacian_transpose_add(const vertex_pass *p, int32_t begin, int32_t end) {
    const fit_system *f = p->f;
    const double *y = p->w;
    for (int32_t v = begin; v < end; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        if (a == b) continue;
        double acc[3] = {y[3 * (int64_t)v], y[3 * (int64_t)v + 1], y[3 * (int64_t)v + 2]};
        for (int64_t k = a; k < b; ++k) {
            const int32_t j = f->nb[k];
            const double inv = 1.0 / (double)(f->nb_start[j + 1] - f->nb_start[j]);
            for (int c = 0; c < 3; ++c) acc[c] -= y[3 * (int64_t)j + c] * inv;
        }
        for (int c = 0; c < 3; ++c) p->z[3 * (int64_t)v + c] += p->a * acc[c];
    }
    return 0.0;
}

/* z += lambda Lap^T C Lap x (the operator's share), or with `held` the
 * right-hand side's lambda Lap^T H Lap x. */
static void fairness_add(const fit_system *f, const double *x, int held, double *z) {
    vertex_pass p;
    p.f = f, p.x = x, p.w = f->tmp_n, p.z = z, p.a = f->lambda, p.held = held;
    vertex_run(&p, laplacian_scaled);
    vertex_run(&p, laplacian_transpose_add);
}

/* z = z + damping x at free vertices, 0 at the others. */
static double damp(const vertex_pass *p, int32_t begin, int32_t end) {
    const fit_system *f = p->f;
    for (int32_t v = begin; v < end; ++v)
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            p->z[i] = f->free_vertex[v] ? p->z[i] + f->damping * p->x[i] : 0.0;
        }
    return 0.0;
}

/* y = A x, the normal-equation matrix: M^T B M x block by block, then the
 * fairness and the damping. */
static void system_apply(const fit_system *f, const double *x, double *y) {
    memset(y, 0, sizeof(double) * 3 * (size_t)f->n);
    spia__fit_blocks_normal(f, x, NULL, y);
    if (f->lambda > 0.0) {
        fairness_add(f, x, 0, y);
    }
    vertex_pass p;
    p.f = f, p.x = x, p.z = y;
    vertex_run(&p, damp);
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

/* z_v = P_v r_v with the 3x3 block P_v (9 per vertex); returns z_v . r_v. */
static inline double precondition_one(const double *P, const double *rv, double *zv) {
    for (int c = 0; c < 3; ++c) zv[c] = P[3 * c] * rv[0] + P[3 * c + 1] * rv[1] + P[3 * c + 2] * rv[2];
    return zv[0] * rv[0] + zv[1] * rv[1] + zv[2] * rv[2];
}

/* z += damping V (the right-hand side's anchor at the current iterate). */
static double anchor(const vertex_pass *p, int32_t begin, int32_t end) {
    const double damping = p->f->damping;
    for (int64_t i = 3 * (int64_t)begin; i < 3 * (int64_t)end; ++i) p->z[i] += damping * p->V[i];
    return 0.0;
}

/* The block-Jacobi preconditioner into w (9 per vertex): the inverse of
 * sum_s m_si^2 B_s (tmp_diag, 6 per vertex) + lambda (Lap^T C Lap)_ii +
 * damping, zero at vertices held in place. */
static double preconditioner(const vertex_pass *p, int32_t begin, int32_t end) {
    const fit_system *f = p->f;
    for (int32_t v = begin; v < end; ++v) {
        double *a = f->tmp_diag + 6 * (int64_t)v;
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
            invert_sym3(a, p->w + 9 * (int64_t)v);
        else
            memset(p->w + 9 * (int64_t)v, 0, 9 * sizeof(double));
    }
    return 0.0;
}

/* The first residual r = x - y (b - A V) at free vertices, z = P r;
 * returns z . r. */
static double residual(const vertex_pass *p, int32_t begin, int32_t end) {
    const unsigned char *free_vertex = p->f->free_vertex;
    double rz = 0.0;
    for (int32_t v = begin; v < end; ++v) {
        double *rv = p->r + 3 * (int64_t)v;
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            rv[c] = free_vertex[v] ? p->x[i] - p->y[i] : 0.0;
        }
        rz += precondition_one(p->P + 9 * (int64_t)v, rv, p->z + 3 * (int64_t)v);
    }
    return rz;
}

/* x . y */
static double dot(const vertex_pass *p, int32_t begin, int32_t end) {
    double sum = 0.0;
    for (int64_t i = 3 * (int64_t)begin; i < 3 * (int64_t)end; ++i) sum += p->x[i] * p->y[i];
    return sum;
}

/* A step of a along x (y = A x): V += a x, r -= a y, z = P r; returns
 * z . r. */
static double step(const vertex_pass *p, int32_t begin, int32_t end) {
    double rz = 0.0;
    for (int32_t v = begin; v < end; ++v) {
        double *rv = p->r + 3 * (int64_t)v;
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            p->V[i] += p->a * p->x[i];
            rv[c] -= p->a * p->y[i];
        }
        rz += precondition_one(p->P + 9 * (int64_t)v, rv, p->z + 3 * (int64_t)v);
    }
    return rz;
}

/* The next direction w = x + a w (x: z). */
static double direction(const vertex_pass *p, int32_t begin, int32_t end) {
    for (int64_t i = 3 * (int64_t)begin; i < 3 * (int64_t)end; ++i) p->w[i] = p->x[i] + p->a * p->w[i];
    return 0.0;
}

/* One round: conjugate gradients on A V = b from the current V, with targets
 * T (S * 3 floats).  `work` holds 5 * 3n doubles, `precond` 9n. */
int spia__fit_least_squares_round(fit_system *f, const float *T, const double *V0, double *V, int iterations,
                                  double *work, double *precond, fit_clock *clock) {
    const int64_t N3 = 3 * (int64_t)f->n;
    double *b = work, *r = work + N3, *z = work + 2 * N3, *p = work + 3 * N3, *Ap = work + 4 * N3;
    vertex_pass pass;
    pass.f = f;
    /* b = M^T B T + lambda Lap^T H Lap V0 + damping V (the damping anchors the
     * current iterate, so it does not bias the fit). */
    memset(b, 0, sizeof(double) * (size_t)N3);
    spia__fit_blocks_normal(f, NULL, T, b);
    if (f->lambda > 0.0) {
        fairness_add(f, V0, 1, b);
    }
    pass.z = b, pass.V = V;
    vertex_run(&pass, anchor);

    memset(f->tmp_diag, 0, sizeof(double) * 6 * (size_t)f->n);
    spia__fit_blocks_diagonal(f, f->tmp_diag);
    pass.w = precond;
    vertex_run(&pass, preconditioner);

    system_apply(f, V, Ap);
    pass.x = b, pass.y = Ap, pass.r = r, pass.z = z, pass.P = precond;
    double rz = vertex_run(&pass, residual);
    memcpy(p, z, sizeof(double) * (size_t)N3);
    const double rz0 = rz;
    int it = 0;
    for (; it < iterations && rz > CG_TOLERANCE * CG_TOLERANCE * rz0 && rz > 0.0 && !spia__fit_clock_tick(clock); ++it) {
        system_apply(f, p, Ap);
        pass.x = p, pass.y = Ap;
        const double pAp = vertex_run(&pass, dot);
        if (!(pAp > 0.0)) break;
        pass.a = rz / pAp, pass.V = V, pass.r = r, pass.z = z, pass.P = precond;
        const double rz_new = vertex_run(&pass, step);
        pass.a = rz_new / rz, pass.x = z, pass.w = p;
        rz = rz_new;
        vertex_run(&pass, direction);
    }
    return it;
}
