// SPDX-License-Identifier: GPL-3.0-or-later
/* Solvers on a limit stencil table L: find V with L V = P.
 *
 * PIA (the papers' progressive iterative approximation) is the Richardson
 * iteration V += P - L V: every control point moves by the gap between its
 * target and its current limit point.  It converges when the eigenvalues of L
 * lie in (0, 1], as they do for the limit matrices of the schemes here.
 *
 * WPIA (weighted PIA) is V += w (P - L V); with the spectrum in
 * [lambda_min, lambda_max] the best weight is 2 / (lambda_min + lambda_max).
 *
 * GS-PIA (Gauss-Seidel PIA) visits the vertices in order and moves each one,
 * in place, so that its own limit point lands on its target given the
 * current positions of the others: V_i += (P_i - (L V)_i) / L_ii.  For a
 * limit matrix that is a positive diagonal times a symmetric positive
 * definite matrix (closed Loop meshes: L = D S) this is Gauss-Seidel on the
 * SPD matrix S, since scaling rows by D^-1 changes neither the sweep nor the
 * iterates, and so it converges.
 *
 * CG is conjugate gradients on the symmetrized system where the limit
 * matrix allows it (closed meshes, see step_cg).  GS_PIA_FAST is GS-PIA on
 * the table's sweep layout, in fast.c; spia_solve hands it the solve.
 * AUTO takes GS_PIA_FAST on tables of AUTO_FAST_ROWS rows or more and on
 * rough targets; on smaller smooth ones CG or Chebyshev-accelerated PIA
 * (see step_chebyshev, choose_auto).
 *
 * Products with L are shared among threads by rows; sums over rows are
 * taken per block of BLOCK rows and the blocks added in order, so results
 * do not depend on the thread count.  GS-PIA's sweep is serial; with
 * SPIA_SOLVE_MULTICOLOUR it goes colour after colour, each on the
 * threads.
 *
 * All stop when max_i |P_i - (L V)_i| <= tolerance * diagonal, at
 * max_iterations, when the error has not fallen for STAGNATION_WINDOW
 * iterations, or (as a failure) when it blows up.  With `staged` the rows of
 * boundary vertices are solved first and then frozen.
 */
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum {
    STAGNATION_WINDOW = 50, /* iterations without a 0.1% improvement */
    ESTIMATE_STEPS = 4,     /* PIA steps before Chebyshev, to estimate the spectrum */
    POWER_STEPS = 30        /* power iterations for WPIA's weight */
};
/* Bounds on the assumed smallest eigenvalue for Chebyshev: Catmull-Clark
 * limit matrices of real meshes measured between 0.07 and 0.36 (singular
 * modes aside, which no method can reduce). */
#define CHEB_A_MIN 0.05
#define CHEB_A_MAX 0.25
#define DIVERGENCE_FACTOR 1e4 /* error this many times the initial one */
/* See choose_auto. */
#define AUTO_SMOOTH 0.15
enum { AUTO_PROBE_ROWS = 4096 };
/* See mark_stuck. */
#define DRIFT_FACTOR 50.0
/* See multicolour_order: colours at most, the last for the rows left. */
enum { MULTICOLOURS = 64 };
/* See first_step. */
#define FIRST_STEP_SCALE 1.28
/* From this many rows on, AUTO takes GS_PIA_FAST whatever the probe says
 * (below, its iterations, cheap as they are, are too many beside CG's on
 * the smallest smooth meshes). */
enum { AUTO_FAST_ROWS = 10000 };
/* SPIA_SOLVE_* flags AUTO adds when it takes GS_PIA_FAST: the first step
 * saved more sweeps than it cost on the rough sphere and the scans
 * measured (bench/bench_solve.py). */
#define AUTO_FAST_FLAGS SPIA_SOLVE_FIRST_STEP

typedef struct solver_state {
    const spia_stencils *L;
    int32_t n;
    spia_method method;
    const float *P; /* targets (the caller's) */
    const float *start; /* first iterate: options' initial_cage, else P */
    double *V; /* current cage         */
    double *R; /* residual P - L V     */
    double *diag;
    double *initial;       /* the first iterate's residual, to tell stuck vertices from slow ones */
    unsigned char *stuck;  /* rows that cannot be reached: left on their targets */
    unsigned char *frozen; /* rows of the other stage (staged solves)            */
    double norm2;          /* squared 2-norm of R over active rows, from residual() */
    double weight;         /* WPIA */
    /* Chebyshev and CG state: search direction and recurrence scalars. */
    double *D;
    double cheb_a, cheb_rho;
    int32_t cheb_steps;
    /* CG on the symmetric S = diag(scale)^-1 L (see step_cg). */
    double *scale; /* per row, or NULL when L has no such scaling */
    double *T;     /* L p */
    double cg_rr[3];
    int32_t cg_steps;
    int threads;
    int diag_positive; /* every L_ii > 0 (GS-PIA applies) */
    /* Per block of BLOCK rows: partial sums, added up in block order so that
     * the result does not depend on the number of threads. */
    int64_t blocks;
    double *partial; /* blocks * PARTS */
    /* SPIA_SOLVE_MULTICOLOUR: the rows colour after colour; colour_start
     * has colours + 1 entries, the last colour's rows swept one by one. */
    int32_t *colour_rows;
    int32_t colour_start[MULTICOLOURS + 1];
    int colours;
} solver_state;

enum { BLOCK = 2048, PARTS = 4, PARALLEL_ROWS = SPIA_PARALLEL_ROWS };

/* Sums column `part` of the per-block partials in block order. */
static double block_sum(const solver_state *s, int part) {
    double t = 0.0;
    for (int64_t b = 0; b < s->blocks; ++b) t += s->partial[PARTS * b + part];
    return t;
}
static double block_max(const solver_state *s, int part) {
    double t = 0.0;
    for (int64_t b = 0; b < s->blocks; ++b) {
        const double x = s->partial[PARTS * b + part];
        if (x > t || x != x) t = x != x ? NAN : x;
    }
    return t;
}

static inline int active(const solver_state *s, int32_t r) { return !s->stuck[r] && !s->frozen[r]; }

/* Statistics of R: returns the max distance over all rows and writes the
 * mean over all rows and the max over active rows.  With `product`, first
 * R = P - L V. */
typedef struct residual_task {
    solver_state *s;
    int product;
} residual_task;

static void residual_blocks(void *context, int64_t b0, int64_t b1, int thread) {
    (void)thread;
    const residual_task *task = (const residual_task *)context;
    solver_state *s = task->s;
    const int32_t n = s->n;
    for (int64_t b = b0; b < b1; ++b) {
        double maxd = 0.0, maxa = 0.0, sum = 0.0, norm2 = 0.0;
        const int32_t end = (int32_t)((b + 1) * BLOCK < n ? (b + 1) * BLOCK : n);
        for (int32_t r = (int32_t)(b * BLOCK); r < end; ++r) {
            double *q = s->R + 3 * (int64_t)r;
            if (task->product) {
                double lv[3];
                spia__row_product(s->L, r, s->V, lv);
                for (int a = 0; a < 3; ++a) q[a] = s->P[3 * (int64_t)r + a] - lv[a];
            }
            double d = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
            if (d > maxd || d != d) maxd = d != d ? NAN : d;
            if (active(s, r)) {
                if (d > maxa || d != d) maxa = d != d ? NAN : d;
                norm2 += d * d;
            }
            sum += d;
        }
        double *p = s->partial + PARTS * b;
        p[0] = maxd;
        p[1] = maxa;
        p[2] = sum;
        p[3] = norm2;
    }
}

static double residual_pass(solver_state *s, int product, double *mean, double *max_active) {
    const int32_t n = s->n;
    residual_task task = {s, product};
    spia__parallel_for(s->threads, s->blocks, 0, residual_blocks, &task);
    *mean = n ? block_sum(s, 2) / n : 0.0;
    *max_active = block_max(s, 1);
    s->norm2 = block_sum(s, 3);
    return block_max(s, 0);
}

static double residual_stats(solver_state *s, double *mean, double *max_active) {
    return residual_pass(s, 0, mean, max_active);
}

/* R = P - L V, then its statistics as residual_stats. */
static double residual(solver_state *s, double *mean, double *max_active) {
    return residual_pass(s, 1, mean, max_active);
}

typedef struct richardson_task {
    solver_state *s;
    double w;
} richardson_task;

static void richardson_rows(void *context, int64_t r0, int64_t r1, int thread) {
    (void)thread;
    const richardson_task *task = (const richardson_task *)context;
    solver_state *s = task->s;
    for (int64_t r = r0; r < r1; ++r)
        if (active(s, (int32_t)r))
            for (int a = 0; a < 3; ++a) s->V[3 * r + a] += task->w * s->R[3 * r + a];
}

static void step_richardson(solver_state *s, double w) {
    richardson_task task = {s, w};
    spia__parallel_for(s->threads, s->n, 0, richardson_rows, &task);
}

/* One Gauss-Seidel sweep, in vertex order (inherently serial).  Returns the
 * largest residual met on the way, |P_i - (L V)_i| over active rows just
 * before row i moves: the error as the sweep found it, which costs no extra
 * product (the residual after the sweep is smaller where the sweep
 * converges, and is computed when this says the tolerance is reached). */
static double step_gs_pia(solver_state *s) {
    double worst = 0.0;
    for (int32_t r = 0; r < s->n; ++r) {
        if (!active(s, r)) continue;
        double lv[3];
        spia__row_product(s->L, r, s->V, lv);
        const float *t = s->P + 3 * (int64_t)r;
        double *v = s->V + 3 * (int64_t)r;
        const double inv = 1.0 / s->diag[r];
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double g = t[a] - lv[a];
            d2 += g * g;
            v[a] += g * inv;
        }
        const double d = sqrt(d2);
        if (d > worst || d != d) worst = d != d ? NAN : d;
    }
    return worst;
}

/* SPIA_SOLVE_MULTICOLOUR: a greedy colouring in row order, each row taking
 * the first colour that no row of its stencil has and that no earlier row
 * holding it in its stencil has (the table need not be symmetric), so that
 * the rows of one colour neither read nor write each other; rows that find
 * all MULTICOLOURS - 1 colours taken get the last, swept one by one.
 * Returns 0 when out of memory. */
static int multicolour_order(solver_state *s) {
    const spia_stencils *L = s->L;
    const int32_t n = s->n;
    uint64_t *taken = (uint64_t *)calloc((size_t)n, sizeof(uint64_t));
    unsigned char *colour = (unsigned char *)malloc((size_t)n);
    s->colour_rows = (int32_t *)malloc(sizeof(int32_t) * (size_t)n);
    if (!taken || !colour || !s->colour_rows) {
        free(taken);
        free(colour);
        return 0;
    }
    int32_t count[MULTICOLOURS + 1] = {0};
    for (int32_t r = 0; r < n; ++r) {
        uint64_t used = taken[r];
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k)
            if (L->indices[k] < r) used |= (uint64_t)1 << colour[L->indices[k]];
        int c = 0;
        while (c < MULTICOLOURS - 1 && (used >> c & 1u)) ++c;
        colour[r] = (unsigned char)c;
        count[c + 1]++;
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k)
            if (L->indices[k] > r) taken[L->indices[k]] |= (uint64_t)1 << c;
    }
    for (int c = 0; c < MULTICOLOURS; ++c) count[c + 1] += count[c];
    s->colours = 0;
    for (int c = 0; c <= MULTICOLOURS; ++c) s->colour_start[c] = count[c];
    for (int c = 0; c < MULTICOLOURS; ++c)
        if (count[c + 1] > count[c]) s->colours = c + 1;
    for (int32_t r = 0; r < n; ++r) s->colour_rows[count[colour[r]]++] = r;
    free(taken);
    free(colour);
    return 1;
}

/* One Gauss-Seidel update of row r; returns |P_r - (L V)_r| before it. */
static inline double gs_row(solver_state *s, int32_t r) {
    double lv[3];
    spia__row_product(s->L, r, s->V, lv);
    const float *t = s->P + 3 * (int64_t)r;
    double *v = s->V + 3 * (int64_t)r;
    const double inv = 1.0 / s->diag[r];
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) {
        const double g = t[a] - lv[a];
        d2 += g * g;
        v[a] += g * inv;
    }
    return sqrt(d2);
}

typedef struct colour_task {
    solver_state *s;
    int32_t base;      /* the colour's first entry in colour_rows */
    double worst[256]; /* per thread */
} colour_task;

static void colour_rows(void *context, int64_t q0, int64_t q1, int thread) {
    colour_task *task = (colour_task *)context;
    solver_state *s = task->s;
    double worst = task->worst[thread];
    for (int64_t q = q0; q < q1; ++q) {
        const int32_t r = s->colour_rows[task->base + q];
        if (!active(s, r)) continue;
        const double d = gs_row(s, r);
        if (d > worst || d != d) worst = d != d ? NAN : d;
    }
    task->worst[thread] = worst;
}

/* step_gs_pia in the multicolour order: the rows of a colour at once, on
 * the threads; the same result whatever their number (the largest is
 * exact in any order). */
static double step_gs_pia_multicolour(solver_state *s) {
    colour_task task;
    memset(&task, 0, sizeof task);
    task.s = s;
    const int threads = s->threads < 256 ? s->threads : 256;
    for (int c = 0; c < s->colours; ++c) {
        task.base = s->colour_start[c];
        const int32_t count = s->colour_start[c + 1] - s->colour_start[c];
        if (c == MULTICOLOURS - 1)
            colour_rows(&task, 0, count, 0);
        else
            spia__parallel_for(threads, count, 0, colour_rows, &task);
    }
    double worst = 0.0;
    for (int t = 0; t < threads; ++t)
        if (task.worst[t] > worst || task.worst[t] != task.worst[t])
            worst = task.worst[t] != task.worst[t] ? NAN : task.worst[t];
    return worst;
}

/* SPIA_SOLVE_FIRST_STEP: V += M R, R = P - L V (s->R, active rows), M the
 * local approximate inverse of the header: row i of L with the signs of
 * its larger off-diagonal weights flipped, times 1.28 / L_ii^2. */
typedef struct first_task {
    solver_state *s;
} first_task;

static void first_step_rows(void *context, int64_t r0, int64_t r1, int thread) {
    (void)thread;
    solver_state *s = ((first_task *)context)->s;
    const spia_stencils *L = s->L;
    for (int64_t r = r0; r < r1; ++r) {
        if (!active(s, (int32_t)r) || !(s->diag[r] > 0.0)) continue;
        double largest = 0.0, sum[3] = {0.0, 0.0, 0.0};
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k)
            if (L->indices[k] != r && L->weights[k] > largest) largest = L->weights[k];
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
            const double w = L->weights[k];
            const double sw = L->indices[k] != r && w >= 0.5 * largest ? -w : w;
            const double *q = s->R + 3 * (int64_t)L->indices[k];
            for (int a = 0; a < 3; ++a) sum[a] += sw * q[a];
        }
        const double scale = FIRST_STEP_SCALE / (s->diag[r] * s->diag[r]);
        for (int a = 0; a < 3; ++a) s->V[3 * r + a] += scale * sum[a];
    }
}

static void first_step(solver_state *s) {
    first_task task = {s};
    spia__parallel_for(s->threads, s->n, 0, first_step_rows, &task);
}

/* Chebyshev semi-iteration for L V = P with the spectrum of L taken as
 * [a, 1] (Saad, Iterative Methods for Sparse Linear Systems, Alg. 12.1), on
 * the residual R = P - L V that residual() leaves: one product with L per
 * step, like PIA, but the error falls like ((sqrt(k) - 1) / (sqrt(k) + 1))^n
 * with k = 1 / a instead of (1 - a)^n.  The limit matrices here have real
 * eigenvalues in (0, 1] (L 1 = 1 as the weights of a row add up to 1); for
 * eigenvalues below the assumed a the polynomial still has modulus below 1,
 * so a too large a slows those modes down but never makes them grow. */
typedef struct chebyshev_task {
    solver_state *s;
    double c1, c2;
} chebyshev_task;

static void chebyshev_rows(void *context, int64_t r0, int64_t r1, int thread) {
    (void)thread;
    const chebyshev_task *task = (const chebyshev_task *)context;
    solver_state *s = task->s;
    for (int64_t r = r0; r < r1; ++r)
        for (int a = 0; a < 3; ++a) {
            const int64_t k = 3 * r + a;
            const double previous = s->cheb_steps > 0 ? task->c1 * s->D[k] : 0.0; /* D starts unset */
            s->D[k] = active(s, (int32_t)r) ? previous + task->c2 * s->R[k] : 0.0;
            s->V[k] += s->D[k];
        }
}

static void step_chebyshev(solver_state *s) {
    const double theta = 0.5 * (1.0 + s->cheb_a), delta = 0.5 * (1.0 - s->cheb_a);
    const double sigma = theta / delta;
    double c1 = 0.0, c2 = 1.0 / theta;
    if (s->cheb_steps > 0) {
        const double rho = 1.0 / (2.0 * sigma - s->cheb_rho);
        c1 = rho * s->cheb_rho;
        c2 = 2.0 * rho / delta;
        s->cheb_rho = rho;
    } else {
        s->cheb_rho = 1.0 / sigma;
    }
    chebyshev_task task = {s, c1, c2};
    spia__parallel_for(s->threads, s->n, 0, chebyshev_rows, &task);
    ++s->cheb_steps;
}

/* The weight L_jr (0 if absent), by binary search: columns are sorted. */
static double entry(const spia_stencils *L, int32_t j, int32_t r) {
    int64_t lo = L->offsets[j], hi = L->offsets[j + 1];
    while (lo < hi) {
        int64_t mid = (lo + hi) / 2;
        if (L->indices[mid] < r) lo = mid + 1; else hi = mid;
    }
    return lo < L->offsets[j + 1] && L->indices[lo] == r ? L->weights[lo] : 0.0;
}

/* A positive diagonal c with S = c^-1 L symmetric, as the closed Loop limit
 * matrix (the papers' B = D S, c_i = (1 - beta_i) / n_i) and the two-phase
 * Doo-Sabin one (c_i = 1 / n_i) have.  Symmetry asks c_j = c_i L_ji / L_ij
 * along every stencil entry, so c is propagated from 1 at one vertex of
 * each connected part (breadth first) and then every entry is checked.
 * work holds rows ints.  Returns 0 if there is no such scaling. */
typedef struct symmetry_task {
    const spia_stencils *L;
    const double *c;
    unsigned char asymmetric[256]; /* per thread: an entry breaks the symmetry */
} symmetry_task;

static void symmetry_rows(void *context, int64_t r0, int64_t r1, int thread) {
    symmetry_task *task = (symmetry_task *)context;
    const spia_stencils *L = task->L;
    const double *c = task->c;
    for (int64_t r = r0; r < r1 && !task->asymmetric[thread]; ++r)
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
            const int32_t j = L->indices[k];
            if (j == r) continue;
            const double a = L->weights[k] / c[r], b = entry(L, j, (int32_t)r) / c[j];
            if (!(fabs(a - b) <= 1e-12 * fabs(a))) {
                task->asymmetric[thread] = 1;
                break;
            }
        }
}

static int symmetric_scaling(const spia_stencils *L, double *c, int32_t *queue, int threads) {
    for (int32_t r = 0; r < L->rows; ++r) c[r] = 0.0;
    for (int32_t root = 0; root < L->rows; ++root) {
        if (c[root] != 0.0) continue;
        c[root] = 1.0;
        int32_t head = 0, tail = 0;
        queue[tail++] = root;
        while (head < tail) {
            const int32_t r = queue[head++];
            for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
                const int32_t j = L->indices[k];
                if (j == r || c[j] != 0.0) continue;
                const double ljr = entry(L, j, r);
                if (!(ljr > 0.0) || !(L->weights[k] > 0.0)) return 0;
                c[j] = c[r] * ljr / L->weights[k];
                queue[tail++] = j;
            }
        }
    }
    symmetry_task task = {L, c, {0}};
    const int pieces = threads > 1 ? threads : 1;
    spia__parallel_for(pieces, L->rows, 0, symmetry_rows, &task);
    for (int t = 0; t < pieces; ++t)
        if (task.asymmetric[t]) return 0;
    return 1;
}

/* Conjugate gradients on S V = c^-1 P, S = c^-1 L symmetric (positive
 * definite for closed Loop meshes, as the papers prove), one coordinate at
 * a time, on the active rows (a principal submatrix, still SPD).  Its
 * residual is c^-1 R, so R is kept by the recurrence R -= alpha L p: one
 * product with L per step.  Returns 0 on a breakdown (p.Sp <= 0: S is not
 * positive definite), leaving V unchanged. */
/* The four row passes of one CG step, by block (see step_cg). */
typedef struct cg_task {
    solver_state *s;
    int phase;
    double alpha[3], beta[3];
} cg_task;

static void cg_blocks(void *context, int64_t b0, int64_t b1, int thread) {
    (void)thread;
    const cg_task *task = (const cg_task *)context;
    solver_state *s = task->s;
    const int32_t n = s->n;
    const double *c = s->scale;
    for (int64_t b = b0; b < b1; ++b) {
        double part[3] = {0.0, 0.0, 0.0};
        const int32_t end = (int32_t)((b + 1) * BLOCK < n ? (b + 1) * BLOCK : n);
        for (int32_t r = (int32_t)(b * BLOCK); r < end; ++r) {
            const int on = active(s, r);
            double *D = s->D + 3 * (int64_t)r, *R = s->R + 3 * (int64_t)r, *T = s->T + 3 * (int64_t)r;
            switch (task->phase) {
            case 0: /* the first direction: p = c^-1 R */
                for (int a = 0; a < 3; ++a) {
                    D[a] = on ? R[a] / c[r] : 0.0;
                    part[a] += D[a] * D[a];
                }
                break;
            case 1: /* T = L p, and p.Sp */
                spia__row_product(s->L, r, s->D, T);
                if (on)
                    for (int a = 0; a < 3; ++a) part[a] += D[a] * T[a] / c[r];
                break;
            case 2: /* V += alpha p, R -= alpha L p, and |c^-1 R|^2 */
                for (int a = 0; a < 3; ++a) {
                    s->V[3 * (int64_t)r + a] += task->alpha[a] * D[a];
                    R[a] -= task->alpha[a] * T[a];
                    if (on) part[a] += (R[a] / c[r]) * (R[a] / c[r]);
                }
                break;
            default: /* the next direction */
                for (int a = 0; a < 3; ++a) D[a] = on ? R[a] / c[r] + task->beta[a] * D[a] : 0.0;
                break;
            }
        }
        if (task->phase != 3)
            for (int a = 0; a < 3; ++a) s->partial[PARTS * b + a] = part[a];
    }
}

static int step_cg(solver_state *s) {
    cg_task task;
    memset(&task, 0, sizeof task);
    task.s = s;
    if (s->cg_steps == 0) {
        task.phase = 0;
        spia__parallel_for(s->threads, s->blocks, 0, cg_blocks, &task);
        for (int a = 0; a < 3; ++a) s->cg_rr[a] = block_sum(s, a);
    }
    task.phase = 1;
    spia__parallel_for(s->threads, s->blocks, 0, cg_blocks, &task);
    for (int a = 0; a < 3; ++a) {
        const double pq = block_sum(s, a);
        if (s->cg_rr[a] == 0.0) {
            task.alpha[a] = 0.0; /* this coordinate is solved */
            continue;
        }
        if (!(pq > 0.0)) return 0;
        task.alpha[a] = s->cg_rr[a] / pq;
    }
    task.phase = 2;
    spia__parallel_for(s->threads, s->blocks, 0, cg_blocks, &task);
    for (int a = 0; a < 3; ++a) {
        const double rr = block_sum(s, a);
        task.beta[a] = s->cg_rr[a] > 0.0 ? rr / s->cg_rr[a] : 0.0;
        s->cg_rr[a] = rr;
    }
    task.phase = 3;
    spia__parallel_for(s->threads, s->blocks, 0, cg_blocks, &task);
    ++s->cg_steps;
    return 1;
}

/* A deterministic start vector for power iterations. */
static double pseudo_random(uint64_t *state) {
    *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(*state >> 11) / 9007199254740992.0 - 0.5;
}

/* Largest |eigenvalue| of (shift I - L) by power iterations (scalar field,
 * one coordinate). */
static double power_estimate(const spia_stencils *L, double shift, double *x, double *y) {
    uint64_t seed = 12345;
    for (int32_t i = 0; i < L->rows; ++i) x[i] = pseudo_random(&seed);
    double estimate = 0.0;
    for (int it = 0; it < POWER_STEPS; ++it) {
        double nx = 0.0, ny = 0.0;
        for (int32_t r = 0; r < L->rows; ++r) {
            double lx = 0.0;
            for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) lx += L->weights[k] * x[L->indices[k]];
            y[r] = shift * x[r] - lx;
            nx += x[r] * x[r];
            ny += y[r] * y[r];
        }
        if (!(ny > 0.0)) return 0.0;
        estimate = sqrt(ny / nx);
        const double inv = 1.0 / sqrt(ny);
        for (int32_t r = 0; r < L->rows; ++r) x[r] = y[r] * inv;
    }
    return estimate;
}

/* WPIA's weight 2 / (lambda_min + lambda_max).  With no negative weight,
 * every eigenvalue has modulus at most 1 (a row's weights add up to 1) and
 * 1 is one (L 1 = 1), so lambda_max = 1; else it is estimated too.
 * lambda_min = lambda_max - (largest eigenvalue of lambda_max I - L).  Power
 * iterations approach that from below, so the weight errs small: safe. */
static double best_weight(const spia_stencils *L, double *work) {
    int negative = 0;
    for (int64_t k = 0; k < L->nnz && !negative; ++k) negative = L->weights[k] < 0.0;
    double lambda_max = negative ? power_estimate(L, 0.0, work, work + L->rows) : 1.0;
    double lambda_min = lambda_max - power_estimate(L, lambda_max, work, work + L->rows);
    if (!(lambda_min > 0.0)) lambda_min = 0.0;
    return 2.0 / (lambda_min + lambda_max);
}

/* Rows whose residual has not fallen below half its initial value when the
 * iteration stagnates cannot be reached: their limit points are tied to
 * others' (a double-sided face, whose three vertices all have the centroid
 * as limit point, is the common case in scans).  Every update would only
 * push them along the null space of L, so they are put back on their
 * targets and left there, and the rest is solved without them.  GS-PIA
 * zeroes the residual of the last vertex it visits in such a group, which
 * then shows only by its drift: a cage vertex that has moved from the
 * first iterate DRIFT_FACTOR times farther than the largest initial
 * distance of any vertex to its limit point (a solvable cage moves by far
 * less). */
static int32_t mark_stuck(solver_state *s, double threshold) {
    int32_t count = 0;
    double initial_max = threshold;
    for (int32_t r = 0; r < s->n; ++r)
        if (active(s, r) && s->initial[r] > initial_max) initial_max = s->initial[r];
    for (int32_t r = 0; r < s->n; ++r) {
        if (!active(s, r)) continue;
        const double *q = s->R + 3 * (int64_t)r;
        double *v = s->V + 3 * (int64_t)r;
        const float *p = s->P + 3 * (int64_t)r, *v0 = s->start + 3 * (int64_t)r;
        double d = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        double moved = sqrt((v[0] - v0[0]) * (v[0] - v0[0]) + (v[1] - v0[1]) * (v[1] - v0[1]) +
                            (v[2] - v0[2]) * (v[2] - v0[2]));
        if ((d > threshold && d > 0.5 * s->initial[r]) || moved > DRIFT_FACTOR * initial_max) {
            s->stuck[r] = 1;
            for (int a = 0; a < 3; ++a) v[a] = p[a];
            ++count;
        }
    }
    return count;
}

/* The targets looked over once, on the threads, in pieces of SCAN_ROWS rows:
 * the first row with a NaN or infinite coordinate (-1 if none), and the
 * bounding box.  (Smallest index and extremes: the same for any count.) */
enum { SCAN_ROWS = 65536 };
typedef struct scan_task {
    const float *P;
    int32_t n;
    int64_t *bad;  /* per piece */
    double *box;   /* per piece: 3 lows, 3 highs */
} scan_task;

static void scan_rows(void *context, int64_t p0, int64_t p1, int thread) {
    (void)thread;
    scan_task *t = (scan_task *)context;
    for (int64_t piece = p0; piece < p1; ++piece) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        int64_t bad = -1;
        const int64_t end = (piece + 1) * SCAN_ROWS < t->n ? (piece + 1) * SCAN_ROWS : t->n;
        for (int64_t i = piece * SCAN_ROWS; i < end; ++i)
            for (int a = 0; a < 3; ++a) {
                const double x = t->P[3 * i + a];
                if (!isfinite(x) && bad < 0) bad = i;
                if (x < lo[a]) lo[a] = x;
                if (x > hi[a]) hi[a] = x;
            }
        t->bad[piece] = bad;
        for (int a = 0; a < 3; ++a) {
            t->box[6 * piece + a] = lo[a];
            t->box[6 * piece + 3 + a] = hi[a];
        }
    }
}

/* Returns the first row with a non-finite coordinate, -1 if there is none
 * (and the diagonal of the bounding box into *diagonal), -2 when out of
 * memory. */
static int64_t scan_targets(const float *P, int32_t n, int threads, double *diagonal) {
    const int64_t pieces = ((int64_t)n + SCAN_ROWS - 1) / SCAN_ROWS;
    scan_task t = {P, n, (int64_t *)malloc(sizeof(int64_t) * (size_t)pieces),
                   (double *)malloc(sizeof(double) * 6 * (size_t)pieces)};
    if (!t.bad || !t.box) {
        free(t.bad);
        free(t.box);
        return -2;
    }
    spia__parallel_for(threads, pieces, 1, scan_rows, &t);
    int64_t bad = -1;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int64_t piece = 0; piece < pieces; ++piece) {
        if (bad < 0 && t.bad[piece] >= 0) bad = t.bad[piece];
        for (int a = 0; a < 3; ++a) {
            if (t.box[6 * piece + a] < lo[a]) lo[a] = t.box[6 * piece + a];
            if (t.box[6 * piece + 3 + a] > hi[a]) hi[a] = t.box[6 * piece + 3 + a];
        }
    }
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) d2 += (hi[a] - lo[a]) * (hi[a] - lo[a]);
    *diagonal = sqrt(d2);
    free(t.bad);
    free(t.box);
    return bad;
}

static void report_reset(spia_report *rep) {
    if (!rep) return;
    double *h = rep->history;
    int32_t cap = rep->history_capacity;
    uint8_t *flags = rep->unreachable;
    memset(rep, 0, sizeof *rep);
    rep->history = h;
    rep->history_capacity = cap;
    rep->unreachable = flags;
}

/* The search direction D of Chebyshev, WPIA and CG; returns 0 when out of
 * memory. */
static int krylov_arrays(solver_state *s) {
    if (!s->D) s->D = (double *)malloc(sizeof(double) * 3 * (size_t)s->n);
    return s->D != NULL;
}

/* CG's arrays and scaling (see symmetric_scaling): 1 if L has the D S
 * form, 0 if not, -1 when out of memory. */
static int cg_scaling(solver_state *s) {
    if (!krylov_arrays(s)) return -1;
    if (!s->scale) s->scale = (double *)malloc(sizeof(double) * (size_t)s->n);
    if (!s->T) s->T = (double *)malloc(sizeof(double) * 3 * (size_t)s->n);
    if (!s->scale || !s->T) return -1;
    return symmetric_scaling(s->L, s->scale, (int32_t *)s->T, s->threads);
}

/* How much a PIA step would shrink the current residual R, without taking
 * it: |R - L R| / |R| in the 2-norm over every stride-th active row, the
 * stride chosen so that some thousands of rows are looked at (a small part
 * of one product with L on large meshes). */
static double pia_contraction_probe(const solver_state *s) {
    const int32_t stride = s->n > 4 * AUTO_PROBE_ROWS ? s->n / AUTO_PROBE_ROWS : 1;
    double num = 0.0, den = 0.0;
    for (int32_t r = 0; r < s->n; r += stride) {
        if (!active(s, r)) continue;
        double lr[3];
        spia__row_product(s->L, r, s->R, lr);
        for (int a = 0; a < 3; ++a) {
            const double q = s->R[3 * (int64_t)r + a];
            num += (q - lr[a]) * (q - lr[a]);
            den += q * q;
        }
    }
    return den > 0.0 ? sqrt(num / den) : 0.0;
}

/* P_r - (L x)_r for x in float, summed as spia__row_product sums. */
static void residual_row(const spia_stencils *L, const float *P, const float *x, int32_t r, double out[3]) {
    double a = 0.0, b = 0.0, c = 0.0;
    for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
        const double w = L->weights[k];
        const float *p = x + 3 * (int64_t)L->indices[k];
        a += w * (double)p[0];
        b += w * (double)p[1];
        c += w * (double)p[2];
    }
    out[0] = P[3 * (int64_t)r] - a;
    out[1] = P[3 * (int64_t)r + 1] - b;
    out[2] = P[3 * (int64_t)r + 2] - c;
}

/* pia_contraction_probe for the first iterate `start`, from the table
 * alone (before any solver state exists): the same rows, the same sums.
 * Returns -1 when out of memory. */
static double first_contraction_probe(const spia_stencils *L, const float *P, const float *start) {
    const int32_t n = L->rows;
    const int32_t stride = n > 4 * AUTO_PROBE_ROWS ? n / AUTO_PROBE_ROWS : 1;
    double num = 0.0, den = 0.0;
    if (stride == 1) {
        /* Every row: the residual once for all. */
        double *R = (double *)malloc(sizeof(double) * 3 * (size_t)n);
        if (!R) return -1.0;
        for (int32_t r = 0; r < n; ++r) residual_row(L, P, start, r, R + 3 * (int64_t)r);
        for (int32_t r = 0; r < n; ++r) {
            double lr[3];
            spia__row_product(L, r, R, lr);
            for (int a = 0; a < 3; ++a) {
                const double q = R[3 * (int64_t)r + a];
                num += (q - lr[a]) * (q - lr[a]);
                den += q * q;
            }
        }
        free(R);
    } else {
        /* Sampled rows: each one's residual and its stencil's. */
        for (int32_t r = 0; r < n; r += stride) {
            double lr[3] = {0.0, 0.0, 0.0}, q[3];
            int own = 0;
            for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
                const int32_t j = L->indices[k];
                double rj[3];
                residual_row(L, P, start, j, rj);
                for (int a = 0; a < 3; ++a) lr[a] += L->weights[k] * rj[a];
                if (j == r) {
                    own = 1;
                    for (int a = 0; a < 3; ++a) q[a] = rj[a];
                }
            }
            if (!own) residual_row(L, P, start, r, q);
            for (int a = 0; a < 3; ++a) {
                num += (q[a] - lr[a]) * (q[a] - lr[a]);
                den += q[a] * q[a];
            }
        }
    }
    return den > 0.0 ? sqrt(num / den) : 0.0;
}

/* AUTO's choice before its first step, from pia_contraction_probe.  A
 * contraction below AUTO_SMOOTH means a smooth
 * target, whose error lies in modes PIA-like methods remove in a few steps
 * and on which Gauss-Seidel overshoots: CG where L = D S, else Chebyshev.
 * Otherwise (rough targets, scans) GS-PIA, which needed the fewest
 * products on every scan measured (bench/bench_perf_dev.py), if every
 * L_ii > 0; else Chebyshev.  Returns 0 when out of memory. */
static int choose_auto(solver_state *s, double contraction) {
    if (contraction < AUTO_SMOOTH) {
        const int cg = cg_scaling(s);
        if (cg < 0) return 0;
        s->method = cg ? SPIA_METHOD_CG : SPIA_METHOD_CHEBYSHEV;
        return 1;
    }
    if (s->diag_positive) {
        s->method = SPIA_METHOD_GS_PIA;
        return 1;
    }
    s->method = SPIA_METHOD_CHEBYSHEV;
    return krylov_arrays(s);
}

/* One step of s->method (GS-PIA's sweep also estimates the error it
 * leaves: *sweep_error, else left alone); returns 1 when the step kept the
 * residual up to date (CG). */
static int take_step(solver_state *s, int32_t steps, double contraction, spia_report *report, double *sweep_error) {
    switch (s->method) {
    case SPIA_METHOD_CG:
        if (step_cg(s)) return 1;
        /* not positive definite after all: Chebyshev from here on */
        s->method = SPIA_METHOD_CHEBYSHEV;
        if (report) report->method = s->method;
        step_richardson(s, 1.0);
        return 0;
    case SPIA_METHOD_GS_PIA:
        *sweep_error = s->colour_rows ? step_gs_pia_multicolour(s) : step_gs_pia(s);
        return 0;
    case SPIA_METHOD_WPIA:
        step_richardson(s, s->weight);
        return 0;
    case SPIA_METHOD_CHEBYSHEV:
        if (steps >= ESTIMATE_STEPS) {
            /* PIA's residual contracts by 1 - lambda_min per step once
             * the slowest mode dominates; after a few steps it has not
             * yet, and the contraction seen then overestimates
             * lambda_min by a factor of three to five on the meshes
             * measured (eigenvalues computed with numpy). */
            if (s->cheb_steps == 0) {
                double a = (1.0 - contraction) / 3.0;
                s->cheb_a = a < CHEB_A_MIN ? CHEB_A_MIN : a > CHEB_A_MAX ? CHEB_A_MAX : a;
            }
            step_chebyshev(s);
            return 0;
        }
        /* the first steps are PIA's */
        step_richardson(s, 1.0);
        return 0;
    default:
        step_richardson(s, 1.0);
        return 0;
    }
}

/* Iterates on the active rows until their max error is at most threshold.
 * *it counts iterations over all stages (for the history and the limit). */
static spia_result run_stage(solver_state *s, const spia_options *opt, double threshold, double scale, int32_t *it,
                             int32_t *stuck_count, spia_report *report, spia_status *status) {
    double mean, err, best, prev_norm2, contraction = 1.0;
    double err_all = residual(s, &mean, &err);
    const double initial = err;
    int32_t it_best = *it, steps = 0;
    int stuck_checked = 0;
    best = err;
    prev_norm2 = s->norm2;
    s->cheb_steps = 0;
    s->cg_steps = 0;
    while (!(err <= threshold)) {
        if (*it >= opt->max_iterations) return SPIA_MAX_ITERATIONS;
        if (s->method == SPIA_METHOD_AUTO) {
            const double probe = pia_contraction_probe(s);
            if (!choose_auto(s, probe))
                return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver");
            if (report) report->method = s->method;
        }
        double sweep_error = -1.0;
        const int residual_kept = take_step(s, steps, contraction, report, &sweep_error);
        ++*it;
        ++steps;
        if (sweep_error > threshold && *it - it_best < STAGNATION_WINDOW) {
            /* GS-PIA short of the tolerance and not about to look for
             * stuck rows: the sweep's own estimate will do */
            err = err_all = sweep_error;
        } else {
            err_all = residual_kept ? residual_stats(s, &mean, &err) : residual(s, &mean, &err);
        }
        contraction = prev_norm2 > 0.0 ? sqrt(s->norm2 / prev_norm2) : 0.0;
        prev_norm2 = s->norm2;
        if (report && report->history && *it <= report->history_capacity) {
            report->history[*it - 1] = err_all / scale;
            report->history_count = *it;
        }
        if (!isfinite(err) || err > DIVERGENCE_FACTOR * (initial > threshold ? initial : threshold))
            return spia__fail(status, SPIA_ERROR_DIVERGED, -1,
                              "the iteration diverged after %d iterations (max error %g of the diagonal)", (int)*it,
                              err / scale);
        if (err < best * (1.0 - 1e-3)) {
            best = err;
            it_best = *it;
        } else if (*it - it_best >= STAGNATION_WINDOW) {
            if (stuck_checked) return SPIA_STAGNATED;
            stuck_checked = 1;
            int32_t found = mark_stuck(s, threshold);
            if (found == 0) return SPIA_STAGNATED;
            *stuck_count += found;
            err_all = residual(s, &mean, &err);
            prev_norm2 = s->norm2;
            s->cheb_steps = 0;
            s->cg_steps = 0;
            best = err;
            it_best = *it;
        }
        if (opt->progress && opt->progress(opt->progress_user_data, *it, err_all / scale))
            return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after %d iterations", (int)*it);
    }
    return SPIA_OK;
}

/* *L pointed at `table`, given's CSR arrays (spia__stencils_expand), unless
 * it already is; 0 when out of memory. */
static int with_arrays(const spia_stencils *given, const spia_stencils **L, spia_stencils *table, int threads) {
    if (*L == table) return 1;
    if (spia__stencils_expand(given, table, threads) != SPIA_OK) return 0;
    *L = table;
    return 1;
}

/* What the stages of a solve share besides the solver's state. */
typedef struct solve_call {
    const spia_stencils *given; /* the caller's table */
    /* given, or once its CSR arrays are needed (whatever is not
     * GS_PIA_FAST: see spia__stencils_expand) `table`, which holds them */
    const spia_stencils *L;
    spia_stencils table;
    spia_options opt;
    const float *targets;
    float *cage;
    spia_report *report;
    spia_status *status;
    int32_t n;
    double diagonal;
    float *handover;         /* GS_PIA_FAST's cage for GS-PIA to go on from */
    int32_t it0;             /* iterations before the iterative method's */
    double initial_relative; /* the report's initial error, when GS_PIA_FAST measured it; else -1 */
    int least_squares;
    /* Where an iterative method handed the solve to least squares: how it
     * ended (SPIA_STAGNATED or SPIA_ERROR_DIVERGED; SPIA_OK: no hand-over),
     * which method and after how many iterations, for the message. */
    spia_result gave_up;
    spia_method gave_up_method;
    int32_t gave_up_after;
} solve_call;

/* The method's name as spia_method spells it, for messages. */
static const char *method_name(spia_method m) {
    static const char *const names[] = {"AUTO", "PIA",         "GS_PIA",     "CHEBYSHEV",
                                        "WPIA", "CG",          "GS_PIA_FAST", "LEAST_SQUARES"};
    return (int)m >= 0 && (int)m < (int)(sizeof names / sizeof names[0]) ? names[m] : "the iteration";
}

/* Least squares takes over from `method`, which ended with `how` after
 * `iterations`. */
static void hand_to_least_squares(solve_call *c, spia_result how, spia_method method, int32_t iterations) {
    c->least_squares = 1;
    c->gave_up = how;
    c->gave_up_method = method;
    c->gave_up_after = iterations;
}

static spia_result solver_oom(const solve_call *c) {
    return spia__fail(c->status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver (%d vertices)",
                      (int)c->n);
}

/* The targets and the first iterate finite; c->diagonal the targets'. */
static spia_result check_targets(solve_call *c) {
    const int32_t n = c->n;
    const int64_t bad = scan_targets(c->targets, n, n >= PARALLEL_ROWS ? c->opt.threads : 1, &c->diagonal);
    if (bad == -2) return solver_oom(c);
    if (bad >= 0) return spia__fail(c->status, SPIA_ERROR_NONFINITE, bad, "target %lld is NaN or infinite", (long long)bad);
    if (c->opt.initial_cage) {
        for (int64_t k = 0; k < 3 * (int64_t)n; ++k)
            if (!isfinite(c->opt.initial_cage[k]))
                return spia__fail(c->status, SPIA_ERROR_NONFINITE, k / 3,
                                  "initial cage vertex %lld is NaN or infinite", (long long)(k / 3));
    }
    return SPIA_OK;
}

/* Method selection: GS_PIA_FAST, asked for or AUTO's choice on rough
 * targets (where it would take GS_PIA), where the table has a plan for it
 * (*fast; *automatic: chosen by AUTO); else the method asked for. */
static spia_result select_method(solve_call *c, int *fast, int *automatic) {
    const spia_stencils *L = c->L;
    const int32_t n = c->n;
    const int fast_fits = L->plan && L->plan->diagonal_first;
    const int staged_solve = c->opt.staged && L->boundary_count > 0 && L->boundary_count < n;
    *fast = 0, *automatic = 0;
    if (c->opt.method == SPIA_METHOD_GS_PIA_FAST) {
        if (fast_fits)
            *fast = 1;
        else
            c->opt.method = SPIA_METHOD_GS_PIA; /* no plan (or a row without its own weight, refused below) */
    } else if (c->opt.method == SPIA_METHOD_AUTO && fast_fits && !staged_solve) {
        /* From AUTO_FAST_ROWS rows on, GS_PIA_FAST on smooth targets too:
         * it was faster there than CG and Chebyshev on every target
         * measured (a smooth 1M torus: 4 sweeps in 0.1 s against CG's one
         * iteration and its setup in 0.35 s; 30k: 3.4 ms against 8 ms);
         * below, the probe decides. */
        if (n < AUTO_FAST_ROWS && !with_arrays(c->given, &c->L, &c->table, c->opt.threads)) return solver_oom(c);
        const double probe =
            n >= AUTO_FAST_ROWS
                ? 1.0
                : first_contraction_probe(c->L, c->targets, c->opt.initial_cage ? c->opt.initial_cage : c->targets);
        if (probe < 0.0) return solver_oom(c);
        if (!(probe < AUTO_SMOOTH)) {
            *fast = 1;
            *automatic = 1;
            c->opt.solve_flags |= AUTO_FAST_FLAGS;
        }
    }
    /* Least squares (see least_squares.c): asked for, or where the
     * iteration stagnates or diverges. */
    c->least_squares = c->opt.method == SPIA_METHOD_LEAST_SQUARES;
    return SPIA_OK;
}

/* GS_PIA_FAST (fast.c): returns 1 when it has finished the solve (*res its
 * result), 0 when another method is to go on: least squares where the
 * sweeps stagnated or diverged, GS-PIA from where they got to where float32
 * cannot reach the tolerance. */
static int solve_fast(solve_call *c, int automatic, spia_result *res) {
    spia_report *report = c->report;
    *res = spia__solve_fast(c->L, c->targets, &c->opt, c->diagonal, automatic, c->cage, &c->handover, &c->it0,
                            report, c->status);
    if (*res == SPIA_STAGNATED || *res == SPIA_ERROR_DIVERGED) {
        /* From the cage the sweeps wrote, or after a blow-up from the
         * first iterate. */
        if (report) c->initial_relative = report->initial_max_error_relative;
        if (*res == SPIA_STAGNATED) c->opt.initial_cage = c->cage;
        hand_to_least_squares(c, *res, SPIA_METHOD_GS_PIA_FAST, c->it0);
        return 0;
    }
    if (*res != SPIA__HAND_OVER) return 1;
    /* Beyond float32: GS-PIA goes on from where the sweeps got to. */
    if (report) c->initial_relative = report->initial_max_error_relative;
    c->opt.method = SPIA_METHOD_GS_PIA;
    c->opt.solve_flags &= ~SPIA_SOLVE_FIRST_STEP;
    if (c->handover) c->opt.initial_cage = c->handover;
    return 0;
}

/* The solver's arrays, and the first iterate in s->V. */
static spia_result state_setup(solve_call *c, solver_state *s) {
    const int32_t n = c->n;
    if (!with_arrays(c->given, &c->L, &c->table, c->opt.threads)) return solver_oom(c);
    s->method = c->least_squares ? SPIA_METHOD_LEAST_SQUARES : c->opt.method;
    s->L = c->L;
    s->n = n;
    s->P = c->targets;
    s->V = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    s->R = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    s->diag = (double *)malloc(sizeof(double) * (size_t)n);
    s->initial = (double *)malloc(sizeof(double) * (size_t)n);
    s->stuck = (unsigned char *)calloc((size_t)n, 1);
    s->frozen = (unsigned char *)calloc((size_t)n, 1);
    /* Threads pay off on large tables only (a parallel region costs
     * microseconds, more on a busy machine); the blocks, and so the
     * results, are the same either way. */
    s->threads = c->opt.threads > 0 && n >= PARALLEL_ROWS ? c->opt.threads : 1;
    s->blocks = ((int64_t)n + BLOCK - 1) / BLOCK;
    s->partial = (double *)malloc(sizeof(double) * PARTS * (size_t)s->blocks);
    if (!s->partial) return solver_oom(c);
    if (!s->V || !s->R || !s->diag || !s->initial || !s->stuck || !s->frozen ||
        (s->method != SPIA_METHOD_PIA && s->method != SPIA_METHOD_GS_PIA && s->method != SPIA_METHOD_AUTO &&
         s->method != SPIA_METHOD_LEAST_SQUARES && !krylov_arrays(s)))
        return solver_oom(c);
    s->start = c->opt.initial_cage ? c->opt.initial_cage : c->targets;
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) s->V[k] = (double)s->start[k];
    return SPIA_OK;
}

/* What the method needs of the table: CG a symmetric scaling, GS-PIA a
 * positive weight of every row on itself (and a colouring), WPIA its
 * weight; s->diag the rows' own weights. */
static spia_result method_setup(solve_call *c, solver_state *s) {
    const spia_stencils *L = c->L;
    if (s->method == SPIA_METHOD_CG) {
        const int cg = cg_scaling(s);
        if (cg < 0) return solver_oom(c);
        if (!cg)
            return spia__fail(c->status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                              "CG needs a limit matrix that is a positive diagonal times a symmetric one, as "
                              "closed meshes have (boundary rules break the symmetry); use AUTO");
    }
    s->diag_positive = 1;
    for (int32_t r = 0; r < c->n; ++r) {
        s->diag[r] = 0.0;
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k)
            if (L->indices[k] == r) s->diag[r] = L->weights[k];
        if (!(s->diag[r] > 0.0)) s->diag_positive = 0;
        if (s->method == SPIA_METHOD_GS_PIA && !(s->diag[r] > 0.0))
            return spia__fail(c->status, SPIA_ERROR_INVALID_ARGUMENT, r,
                              "stencil of vertex %d has weight %g on itself; GS-PIA needs a positive one", (int)r,
                              s->diag[r]);
    }
    if (s->method == SPIA_METHOD_GS_PIA && (c->opt.solve_flags & SPIA_SOLVE_MULTICOLOUR) && !multicolour_order(s))
        return solver_oom(c);
    if (s->method == SPIA_METHOD_WPIA) {
        if (c->opt.weight < 0.0 || c->opt.weight >= 2.0 || !isfinite(c->opt.weight))
            return spia__fail(c->status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                              "the WPIA weight must be in (0, 2), got %g", c->opt.weight);
        s->weight = c->opt.weight > 0.0 ? c->opt.weight : best_weight(L, s->D);
    }
    return SPIA_OK;
}

/* The iterative methods (PIA, GS-PIA, WPIA, Chebyshev, CG, AUTO's choice
 * among them), staged or not, from the first iterate's residual; decides
 * whether least squares is to go on (c->least_squares). */
static spia_result solve_iterative(solve_call *c, solver_state *s, double threshold, double scale, int32_t *it,
                                   int32_t *stuck_count) {
    const spia_stencils *L = c->L;
    spia_report *report = c->report;
    const int32_t n = c->n;
    spia_result res;
    double mean, err;
    double err_all = residual(s, &mean, &err);
    for (int32_t r = 0; r < n; ++r) {
        const double *q = s->R + 3 * (int64_t)r;
        s->initial[r] = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    }
    if (report) {
        report->initial_max_error_relative = c->initial_relative >= 0.0 ? c->initial_relative : err_all / scale;
        report->method = s->method;
        report->weight = s->weight;
    }
    if ((c->opt.solve_flags & SPIA_SOLVE_FIRST_STEP) && s->method == SPIA_METHOD_GS_PIA && !(err <= threshold))
        first_step(s); /* run_stage starts from the residual of the new iterate */

    const int staged = c->opt.staged && L->boundary_count > 0 && L->boundary_count < n;
    if (c->least_squares) {
        res = SPIA_OK;
    } else if (staged) {
        /* Stage 1: the boundary rows, which refer to boundary vertices only. */
        for (int32_t r = 0; r < n; ++r) s->frozen[r] = !L->boundary[r];
        res = run_stage(s, &c->opt, threshold, scale, it, stuck_count, report, c->status);
        if (report) report->stage_iterations[0] = *it;
        if (res == SPIA_OK) {
            for (int32_t r = 0; r < n; ++r) s->frozen[r] = L->boundary[r];
            res = run_stage(s, &c->opt, threshold, scale, it, stuck_count, report, c->status);
            for (int32_t r = 0; r < n; ++r) s->frozen[r] = 0;
        }
        if (report) report->stage_iterations[1] = *it - report->stage_iterations[0];
    } else {
        res = run_stage(s, &c->opt, threshold, scale, it, stuck_count, report, c->status);
    }
    if (s->method == SPIA_METHOD_AUTO) {
        s->method = SPIA_METHOD_PIA; /* done before AUTO had to choose */
        if (report) report->method = s->method;
    }
    if ((res == SPIA_STAGNATED || res == SPIA_ERROR_DIVERGED || (res == SPIA_OK && *stuck_count > 0)) &&
        !c->least_squares) {
        /* Some vertices cannot be reached, or L has eigenvalues outside
         * (0, 1] that PIA-type iterations cannot take: least squares from
         * here, or after a blow-up from the first iterate. */
        hand_to_least_squares(c, res == SPIA_ERROR_DIVERGED ? res : SPIA_STAGNATED, s->method, *it);
        if (res == SPIA_ERROR_DIVERGED)
            for (int64_t k = 0; k < 3 * (int64_t)n; ++k) s->V[k] = (double)s->start[k];
    }
    return res;
}

/* Least squares (least_squares.c) from s->V. */
static spia_result solve_least_squares(solve_call *c, solver_state *s, double scale, int32_t *it) {
    memset(s->stuck, 0, (size_t)c->n);
    s->method = SPIA_METHOD_LEAST_SQUARES;
    if (c->report) c->report->method = s->method;
    return spia__least_squares(c->L, c->targets, s->V, &c->opt, scale, it, c->opt.max_iterations, c->report,
                               c->status);
}

/* Writes the cage, then measures it as stored (in float): the result
 * (least squares: SPIA_STAGNATED where vertices stay beyond the
 * tolerance), its message and the report's errors. */
static spia_result write_cage(solve_call *c, solver_state *s, spia_result res, double threshold, double scale,
                              int32_t it, int32_t stuck_count) {
    spia_report *report = c->report;
    const int32_t n = c->n;
    double mean, err;
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) {
        c->cage[k] = (float)s->V[k];
        s->V[k] = (double)c->cage[k];
    }
    double err_all = residual(s, &mean, &err);
    if (c->least_squares) {
        /* The vertices the least-squares cage leaves beyond the
         * tolerance are the ones no cage reaches. */
        stuck_count = 0;
        for (int32_t r = 0; r < n; ++r) {
            const double *q = s->R + 3 * (int64_t)r;
            s->stuck[r] = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]) > threshold;
            stuck_count += s->stuck[r];
        }
        err_all = residual_stats(s, &mean, &err);
        res = stuck_count > 0 ? SPIA_STAGNATED : SPIA_OK;
    }
    if (res == SPIA_OK)
        spia__ok(c->status);
    else if (res == SPIA_MAX_ITERATIONS)
        spia__fail(c->status, res, -1,
                   "stopped at max_iterations (%d) with max error %.3g of the diagonal, above the tolerance %.3g",
                   (int)it, err_all / scale, c->opt.tolerance);
    else if (c->gave_up != SPIA_OK) /* SPIA_STAGNATED, from least squares after another method */
        spia__fail(c->status, res, -1,
                   "%s %s after %d iterations and least squares took over%s: %d vertices cannot be reached (the "
                   "limit matrix is singular there); it puts them within %.3g of the diagonal, the others "
                   "within %.3g",
                   method_name(c->gave_up_method), c->gave_up == SPIA_ERROR_DIVERGED ? "diverged" : "stagnated",
                   (int)c->gave_up_after, c->gave_up == SPIA_ERROR_DIVERGED ? " from the first iterate" : "",
                   (int)stuck_count, err_all / scale, err / scale);
    else /* SPIA_STAGNATED, from least squares asked for */
        spia__fail(c->status, res, -1,
                   "%d vertices cannot be reached: no cage's limit surface passes through all the points (the "
                   "limit matrix is singular there); the least-squares cage puts them as close as the surface "
                   "allows, within %.3g of the diagonal. The other vertices reach %.3g",
                   (int)stuck_count, err_all / scale, err / scale);
    if (report) {
        report->max_error = err_all;
        report->mean_error = mean;
        report->max_error_relative = err_all / scale;
        report->mean_error_relative = mean / scale;
        report->reachable_max_error_relative = err / scale;
        report->unreachable_count = stuck_count;
        if (report->unreachable) memcpy(report->unreachable, s->stuck, (size_t)n);
    }
    return res;
}

/* The method selected, then GS_PIA_FAST, the iterative methods and least
 * squares, each going on where the one before left off. */
static spia_result solve_stages(solve_call *c, solver_state *s) {
    spia_result res;
    int fast, automatic;
    if ((res = select_method(c, &fast, &automatic)) != SPIA_OK) return res;
    if (fast && solve_fast(c, automatic, &res)) return res;
    if ((res = state_setup(c, s)) != SPIA_OK) return res;
    if ((res = method_setup(c, s)) != SPIA_OK) return res;
    const double scale = c->diagonal > 0.0 ? c->diagonal : 1.0;
    const double threshold = c->opt.tolerance * scale;
    int32_t it = c->it0, stuck_count = 0;
    res = solve_iterative(c, s, threshold, scale, &it, &stuck_count);
    if (c->least_squares) res = solve_least_squares(c, s, scale, &it);
    if (res >= 0) res = write_cage(c, s, res, threshold, scale, it, stuck_count);
    if (c->report) {
        c->report->iterations = it;
        c->report->diagonal = c->diagonal;
    }
    return res;
}

spia_result spia_solve(const spia_stencils *L, const float *targets, const spia_options *options, float *cage,
                       spia_report *report, spia_status *status) {
    report_reset(report);
    const double t0 = spia__now();
    solver_state s;
    memset(&s, 0, sizeof s);
    solve_call c;
    memset(&c, 0, sizeof c);
    c.given = c.L = L;
    c.targets = targets;
    c.cage = cage;
    c.report = report;
    c.status = status;
    c.initial_relative = -1.0;
    spia_result res = spia__resolve_options(options, &c.opt, status);
    if (res != SPIA_OK) goto done;
    if (!L || !targets || !cage) {
        res = spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "stencils, targets and cage must not be NULL");
        goto done;
    }
    c.n = L->rows;
    if (c.n == 0) {
        res = spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the stencil table has no rows");
        goto done;
    }
    if ((res = check_targets(&c)) != SPIA_OK) goto done;
    res = solve_stages(&c, &s);
done:
    if (c.L == &c.table) spia__stencils_expanded_free(c.given, &c.table);
    free(c.handover);
    free(s.colour_rows);
    free(s.V);
    free(s.R);
    free(s.diag);
    free(s.initial);
    free(s.stuck);
    free(s.frozen);
    free(s.D);
    free(s.scale);
    free(s.T);
    free(s.partial);
    if (report) {
        report->solve_seconds = spia__now() - t0;
        report->result = res;
    }
    return res;
}
