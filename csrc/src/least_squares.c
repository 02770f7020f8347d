// SPDX-License-Identifier: GPL-3.0-or-later
/* Least squares on a limit stencil table: min over V of |P - L V|, by
 * conjugate gradients on the normal equations L^T L V = L^T P (CGLS, in the
 * form of Paige and Saunders' LSQR paper, each coordinate its own system).
 *
 * PIA and its relatives need L's eigenvalues in (0, 1].  Some meshes break
 * that: at an interior valence-2 vertex, on a face folded back over its
 * neighbours or on a double-sided face, L is singular (some limit points
 * are tied together and no cage passes through all of them) and may have
 * negative eigenvalues, and the iteration stagnates or diverges.  CGLS
 * converges for any matrix: from a first iterate V0 it reaches the
 * least-squares cage nearest V0 (it only moves V0 within the row space of
 * L, and keeps V0's component in L's null space), whose residual P - L V is
 * the least-squares residual, the same for every least-squares cage.  The
 * vertices that then still miss their targets are the ones no cage can
 * reach.
 *
 * Products with L run on L's rows and products with L^T on the rows of its
 * transpose, built here once; both are shared among threads by rows, and
 * every sum over rows is taken per block and added in block order, so the
 * result does not depend on the thread count. */
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum {
    LSQ_BLOCK = 2048,
    /* The recursively updated residual is replaced by P - L V this often,
     * so that rounding in the recursion cannot pile up. */
    LSQ_REFRESH = 50,
    /* Steps without a 1% fall of |L^T r| before the stop (the rounding
     * floor). */
    LSQ_WINDOW = 100
};
/* Stop when |L^T r| (2-norm over all rows and coordinates) is this small
 * against the tolerance: then r is within LSQ_NORMAL_FACTOR / sigma times
 * the tolerance of the least-squares residual, sigma L's smallest nonzero
 * singular value.  OpenSubdiv's singular regression shapes and the dragon
 * scan matched numpy's lstsq (scipy's lsqr) to 1e-6 of the diagonal with
 * it; 1e-7 cost the dragon 18 more steps (bench/bench_least_squares.py). */
#define LSQ_NORMAL_FACTOR 1e-4

typedef struct lsq_state {
    const spia_stencils *L;
    int32_t n;
    /* L^T in CSR (n rows, the same entries). */
    int64_t *t_offsets;
    int32_t *t_indices;
    double *t_weights;
    const float *P;
    double *V, *R, *S, *Dir, *Q; /* cage, residual, L^T r, direction, L p */
    int threads;
    int64_t blocks;
    double *partial; /* blocks * 4 */
} lsq_state;

/* Transposes L's CSR arrays (counting sort by column: row order kept within
 * each column).  Returns 0 when out of memory. */
static int transpose(lsq_state *q) {
    const spia_stencils *L = q->L;
    const int32_t n = q->n;
    const int64_t nnz = L->offsets[n];
    q->t_offsets = (int64_t *)calloc((size_t)n + 1, sizeof(int64_t));
    q->t_indices = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nnz > 0 ? nnz : 1));
    q->t_weights = (double *)malloc(sizeof(double) * (size_t)(nnz > 0 ? nnz : 1));
    int64_t *fill = (int64_t *)malloc(sizeof(int64_t) * (size_t)n);
    if (!q->t_offsets || !q->t_indices || !q->t_weights || !fill) {
        free(fill);
        return 0;
    }
    for (int64_t k = 0; k < nnz; ++k) ++q->t_offsets[L->indices[k] + 1];
    for (int32_t j = 0; j < n; ++j) q->t_offsets[j + 1] += q->t_offsets[j];
    memcpy(fill, q->t_offsets, sizeof(int64_t) * (size_t)n);
    for (int32_t r = 0; r < n; ++r)
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
            const int64_t at = fill[L->indices[k]]++;
            q->t_indices[at] = r;
            q->t_weights[at] = L->weights[k];
        }
    free(fill);
    return 1;
}

/* out = x_src - A y over rows of A given as CSR, or out = A y when x_src is
 * NULL; per block: partials[0..2] = sum of out^2 per coordinate, [3] =
 * max row length (Euclidean) of out. */
typedef struct product_task {
    lsq_state *q;
    const int64_t *offsets;
    const int32_t *indices;
    const double *weights;
    const double *y;
    const float *minuend; /* NULL: out = A y */
    double *out;
} product_task;

static void product_blocks(void *context, int64_t b0, int64_t b1, int thread) {
    (void)thread;
    const product_task *t = (const product_task *)context;
    const int32_t n = t->q->n;
    for (int64_t b = b0; b < b1; ++b) {
        double sum[3] = {0.0, 0.0, 0.0}, worst = 0.0;
        const int32_t end = (int32_t)((b + 1) * LSQ_BLOCK < n ? (b + 1) * LSQ_BLOCK : n);
        for (int32_t r = (int32_t)(b * LSQ_BLOCK); r < end; ++r) {
            double acc[3] = {0.0, 0.0, 0.0};
            for (int64_t k = t->offsets[r]; k < t->offsets[r + 1]; ++k) {
                const double w = t->weights[k];
                const double *v = t->y + 3 * (int64_t)t->indices[k];
                acc[0] += w * v[0];
                acc[1] += w * v[1];
                acc[2] += w * v[2];
            }
            double *o = t->out + 3 * (int64_t)r, d2 = 0.0;
            for (int a = 0; a < 3; ++a) {
                o[a] = t->minuend ? (double)t->minuend[3 * (int64_t)r + a] - acc[a] : acc[a];
                sum[a] += o[a] * o[a];
                d2 += o[a] * o[a];
            }
            const double d = sqrt(d2);
            if (d > worst || d != d) worst = d != d ? NAN : d;
        }
        double *p = t->q->partial + 4 * b;
        p[0] = sum[0];
        p[1] = sum[1];
        p[2] = sum[2];
        p[3] = worst;
    }
}

/* Runs product_blocks and adds the blocks in order: norms2[a] = |out_a|^2;
 * returns the largest row length. */
static double product(lsq_state *q, int transposed, const double *y, const float *minuend, double *out,
                      double norms2[3]) {
    product_task t = {q,
                      transposed ? q->t_offsets : q->L->offsets,
                      transposed ? q->t_indices : q->L->indices,
                      transposed ? q->t_weights : q->L->weights,
                      y,
                      minuend,
                      out};
    spia__parallel_for(q->threads, q->blocks, 0, product_blocks, &t);
    double worst = 0.0;
    norms2[0] = norms2[1] = norms2[2] = 0.0;
    for (int64_t b = 0; b < q->blocks; ++b) {
        const double *p = q->partial + 4 * b;
        for (int a = 0; a < 3; ++a) norms2[a] += p[a];
        if (p[3] > worst || p[3] != p[3]) worst = p[3] != p[3] ? NAN : p[3];
    }
    return worst;
}

/* x += alpha * d and y -= alpha * e, per coordinate. */
typedef struct update_task {
    lsq_state *q;
    const double *alpha;
} update_task;

static void update_rows(void *context, int64_t r0, int64_t r1, int thread) {
    (void)thread;
    const update_task *t = (const update_task *)context;
    lsq_state *q = t->q;
    for (int64_t r = r0; r < r1; ++r)
        for (int a = 0; a < 3; ++a) {
            q->V[3 * r + a] += t->alpha[a] * q->Dir[3 * r + a];
            q->R[3 * r + a] -= t->alpha[a] * q->Q[3 * r + a];
        }
}

/* Dir = S + beta * Dir, per coordinate. */
static void direction_rows(void *context, int64_t r0, int64_t r1, int thread) {
    (void)thread;
    const update_task *t = (const update_task *)context;
    lsq_state *q = t->q;
    for (int64_t r = r0; r < r1; ++r)
        for (int a = 0; a < 3; ++a) q->Dir[3 * r + a] = q->S[3 * r + a] + t->alpha[a] * q->Dir[3 * r + a];
}

spia_result spia__least_squares(const spia_stencils *L, const float *targets, double *cage, const spia_options *opt,
                                double scale, int32_t *it, int32_t max_steps, spia_report *report,
                                spia_status *status) {
    lsq_state q;
    memset(&q, 0, sizeof q);
    const int32_t n = L->rows;
    q.L = L;
    q.n = n;
    q.P = targets;
    q.V = cage;
    q.threads = opt->threads > 0 && n >= SPIA_PARALLEL_ROWS ? opt->threads : 1;
    q.blocks = ((int64_t)n + LSQ_BLOCK - 1) / LSQ_BLOCK;
    q.R = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    q.S = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    q.Dir = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    q.Q = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    q.partial = (double *)malloc(sizeof(double) * 4 * (size_t)q.blocks);
    spia_result res = SPIA_OK;
    if (!q.R || !q.S || !q.Dir || !q.Q || !q.partial || !transpose(&q)) {
        res = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the least-squares solve (%d vertices)",
                         (int)n);
        goto done;
    }
    const double threshold = opt->tolerance * scale;
    const double normal_goal = LSQ_NORMAL_FACTOR * threshold;
    double r2[3], s2[3], gamma[3], q2[3], alpha[3];
    double worst = product(&q, 0, q.V, q.P, q.R, r2); /* r = P - L V */
    product(&q, 1, q.R, NULL, q.S, s2);                /* s = L^T r */
    memcpy(q.Dir, q.S, sizeof(double) * 3 * (size_t)n);
    memcpy(gamma, s2, sizeof gamma);
    double best_normal = sqrt(s2[0] + s2[1] + s2[2]);
    int32_t best_step = 0;
    for (int32_t step = 1;; ++step) {
        const double normal = sqrt(gamma[0] + gamma[1] + gamma[2]);
        if (!isfinite(worst) || !isfinite(normal)) {
            res = spia__fail(status, SPIA_ERROR_DIVERGED, -1,
                             "the least-squares solve met a NaN or infinite value after %d iterations", (int)*it);
            goto done;
        }
        /* Every row within the tolerance, or the least-squares residual
         * reached, or rounding stops the progress, or the budget is spent. */
        if (worst <= threshold || normal <= normal_goal || step - best_step > LSQ_WINDOW || step > max_steps) break;
        product(&q, 0, q.Dir, NULL, q.Q, q2); /* q = L d */
        for (int a = 0; a < 3; ++a) alpha[a] = q2[a] > 0.0 ? gamma[a] / q2[a] : 0.0;
        update_task u = {&q, alpha};
        spia__parallel_for(q.threads, n, 0, update_rows, &u);
        if (step % LSQ_REFRESH == 0) {
            worst = product(&q, 0, q.V, q.P, q.R, r2);
        } else {
            /* the rows' lengths and norms of the recursive residual */
            worst = 0.0;
            for (int32_t r = 0; r < n; ++r) {
                const double *e = q.R + 3 * (int64_t)r;
                const double d = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
                if (d > worst || d != d) worst = d != d ? NAN : d;
            }
        }
        product(&q, 1, q.R, NULL, q.S, s2);
        double beta[3];
        for (int a = 0; a < 3; ++a) {
            beta[a] = gamma[a] > 0.0 ? s2[a] / gamma[a] : 0.0;
            gamma[a] = s2[a];
        }
        u.alpha = beta;
        spia__parallel_for(q.threads, n, 0, direction_rows, &u);
        ++*it;
        const double now = sqrt(s2[0] + s2[1] + s2[2]);
        if (now < 0.99 * best_normal) {
            best_normal = now;
            best_step = step;
        }
        if (report && report->history && *it <= report->history_capacity) {
            report->history[*it - 1] = worst / scale;
            report->history_count = *it;
        }
        if (opt->progress && opt->progress(opt->progress_user_data, *it, worst / scale)) {
            res = spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after %d iterations", (int)*it);
            goto done;
        }
    }
done:
    free(q.t_offsets);
    free(q.t_indices);
    free(q.t_weights);
    free(q.R);
    free(q.S);
    free(q.Dir);
    free(q.Q);
    free(q.partial);
    return res;
}
