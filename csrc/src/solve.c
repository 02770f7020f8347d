/* Solvers on a limit stencil table L: find V with L V = P.
 *
 * PIA (the papers' progressive iterative approximation) is the Richardson
 * iteration V += P - L V: every control point moves by the gap between its
 * target and its current limit point.  It converges when the eigenvalues of L
 * lie in (0, 1], as they do for the limit matrices of the schemes here.
 *
 * GS-PIA (Gauss-Seidel PIA) visits the vertices in order and moves each one,
 * in place, so that its own limit point lands on its target given the
 * current positions of the others: V_i += (P_i - (L V)_i) / L_ii.  For a
 * limit matrix that is a positive diagonal times a symmetric positive
 * definite matrix (closed Loop meshes) this is Gauss-Seidel on the SPD
 * matrix and converges; on Catmull-Clark cages it converges faster than PIA
 * in practice, which the tests check on every mesh they use.
 *
 * AUTO is Chebyshev-accelerated PIA (see step_chebyshev), after a few PIA
 * steps that estimate the spectrum.
 *
 * All stop when max_i |P_i - (L V)_i| <= tolerance * diagonal, at
 * max_iterations, when the error has not fallen for STAGNATION_WINDOW
 * iterations, or (as a failure) when it blows up.
 */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum {
    STAGNATION_WINDOW = 50, /* iterations without a 0.1% improvement */
    ESTIMATE_STEPS = 4      /* PIA steps before Chebyshev, to estimate the spectrum */
};
/* Bounds on the assumed smallest eigenvalue for Chebyshev: Catmull-Clark
 * limit matrices of real meshes measured between 0.07 and 0.36 (singular
 * modes aside, which no method can reduce). */
#define CHEB_A_MIN 0.05
#define CHEB_A_MAX 0.25
#define DIVERGENCE_FACTOR 1e4 /* error this many times the initial one */

typedef struct solver_state {
    const spia_stencils *L;
    int32_t n;
    double *P; /* targets              */
    double *V; /* current cage         */
    double *R; /* residual P - L V     */
    double *diag;
    double *initial; /* |P_i - (L P)_i|, to tell stuck vertices from slow ones */
    unsigned char *stuck; /* rows no longer updated (see spia_solve)  */
    double norm2;         /* squared 2-norm of R over active rows, from residual() */
    /* Chebyshev state (AUTO): search direction and recurrence scalars. */
    double *D;
    double cheb_a, cheb_rho;
    int32_t cheb_steps;
} solver_state;

/* R = P - L V; returns the max distance over all rows and writes the mean
 * and the max over rows that are not stuck. */
static double residual(solver_state *s, double *mean, double *max_active) {
    const spia_stencils *L = s->L;
    double maxd = 0.0, maxa = 0.0, sum = 0.0, norm2 = 0.0;
    for (int32_t r = 0; r < s->n; ++r) {
        double x = 0.0, y = 0.0, z = 0.0;
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
            const double w = L->weights[k];
            const double *p = s->V + 3 * (int64_t)L->indices[k];
            x += w * p[0];
            y += w * p[1];
            z += w * p[2];
        }
        double *q = s->R + 3 * (int64_t)r;
        const double *t = s->P + 3 * (int64_t)r;
        q[0] = t[0] - x;
        q[1] = t[1] - y;
        q[2] = t[2] - z;
        double d = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        if (d > maxd || d != d) maxd = d != d ? NAN : d;
        if (!s->stuck[r]) {
            if (d > maxa || d != d) maxa = d != d ? NAN : d;
            norm2 += d * d;
        }
        sum += d;
    }
    *mean = s->n ? sum / s->n : 0.0;
    *max_active = maxa;
    s->norm2 = norm2;
    return maxd;
}

static void step_pia(solver_state *s) {
    const int64_t m = 3 * (int64_t)s->n;
    for (int64_t k = 0; k < m; ++k)
        if (!s->stuck[k / 3]) s->V[k] += s->R[k];
}

static void step_gs_pia(solver_state *s) {
    const spia_stencils *L = s->L;
    for (int32_t r = 0; r < s->n; ++r) {
        if (s->stuck[r]) continue;
        double x = 0.0, y = 0.0, z = 0.0;
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k) {
            const double w = L->weights[k];
            const double *p = s->V + 3 * (int64_t)L->indices[k];
            x += w * p[0];
            y += w * p[1];
            z += w * p[2];
        }
        const double *t = s->P + 3 * (int64_t)r;
        double *v = s->V + 3 * (int64_t)r;
        const double inv = 1.0 / s->diag[r];
        v[0] += (t[0] - x) * inv;
        v[1] += (t[1] - y) * inv;
        v[2] += (t[2] - z) * inv;
    }
}

/* Chebyshev semi-iteration for L V = P with the spectrum of L taken as
 * [a, 1] (Saad, Iterative Methods for Sparse Linear Systems, Alg. 12.1), on
 * the residual R = P - L V that residual() leaves: one product with L per
 * step, like PIA, but the error falls like ((sqrt(k) - 1) / (sqrt(k) + 1))^n
 * with k = 1 / a instead of (1 - a)^n.  The limit matrices here have real
 * eigenvalues in (0, 1] (L 1 = 1 as the weights of a row add up to 1); for
 * eigenvalues below the assumed a the polynomial still has modulus below 1,
 * so a too large a slows those modes down but never makes them grow. */
static void step_chebyshev(solver_state *s) {
    const double theta = 0.5 * (1.0 + s->cheb_a), delta = 0.5 * (1.0 - s->cheb_a);
    const double sigma = theta / delta;
    const int64_t m = 3 * (int64_t)s->n;
    if (s->cheb_steps == 0) {
        s->cheb_rho = 1.0 / sigma;
        for (int64_t k = 0; k < m; ++k) s->D[k] = s->stuck[k / 3] ? 0.0 : s->R[k] / theta;
    } else {
        const double rho = 1.0 / (2.0 * sigma - s->cheb_rho);
        const double c1 = rho * s->cheb_rho, c2 = 2.0 * rho / delta;
        for (int64_t k = 0; k < m; ++k) s->D[k] = s->stuck[k / 3] ? 0.0 : c1 * s->D[k] + c2 * s->R[k];
        s->cheb_rho = rho;
    }
    for (int64_t k = 0; k < m; ++k) s->V[k] += s->D[k];
    ++s->cheb_steps;
}

static double bbox_diagonal(const double *P, int32_t n) {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int32_t i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) {
            double x = P[3 * (int64_t)i + a];
            if (x < lo[a]) lo[a] = x;
            if (x > hi[a]) hi[a] = x;
        }
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) d2 += (hi[a] - lo[a]) * (hi[a] - lo[a]);
    return sqrt(d2);
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

/* Rows whose residual has not fallen below half its initial value when the
 * iteration stagnates cannot be reached: their limit points are tied to
 * others' (a double-sided face, whose three vertices all have the centroid
 * as limit point, is the common case in scans).  Every update would only
 * push them along the null space of L, so they are put back on their
 * targets and left there, and the rest is solved without them.  GS-PIA
 * zeroes the residual of the last vertex it visits in such a group, which
 * then shows only by its drift: a cage vertex that has moved DRIFT_FACTOR
 * times farther than the largest initial distance of any vertex to its
 * limit point (a solvable cage moves by far less). */
#define DRIFT_FACTOR 50.0
static int32_t mark_stuck(solver_state *s, double threshold) {
    int32_t count = 0;
    double initial_max = threshold;
    for (int32_t r = 0; r < s->n; ++r)
        if (s->initial[r] > initial_max) initial_max = s->initial[r];
    for (int32_t r = 0; r < s->n; ++r) {
        const double *q = s->R + 3 * (int64_t)r;
        const double *v = s->V + 3 * (int64_t)r, *p = s->P + 3 * (int64_t)r;
        double d = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        double moved = sqrt((v[0] - p[0]) * (v[0] - p[0]) + (v[1] - p[1]) * (v[1] - p[1]) + (v[2] - p[2]) * (v[2] - p[2]));
        if ((d > threshold && d > 0.5 * s->initial[r]) || moved > DRIFT_FACTOR * initial_max) {
            s->stuck[r] = 1;
            for (int a = 0; a < 3; ++a) s->V[3 * (int64_t)r + a] = s->P[3 * (int64_t)r + a];
            ++count;
        }
    }
    return count;
}

spia_result spia_solve(const spia_stencils *L, const float *targets, const spia_options *options, float *cage,
                       spia_report *report, spia_status *status) {
    report_reset(report);
    spia_options opt;
    double t0 = spia__now();
    solver_state s;
    memset(&s, 0, sizeof s);
    spia_result res = spia__resolve_options(options, &opt, status);
    if (res != SPIA_OK) goto done;
    if (!L || !targets || !cage) {
        res = spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "stencils, targets and cage must not be NULL");
        goto done;
    }
    const int32_t n = L->rows;
    if (n == 0) {
        res = spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the stencil table has no rows");
        goto done;
    }
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k)
        if (!isfinite(targets[k])) {
            res = spia__fail(status, SPIA_ERROR_NONFINITE, k / 3, "target %lld is NaN or infinite", (long long)(k / 3));
            goto done;
        }

    const spia_method method = opt.method == SPIA_METHOD_AUTO ? SPIA_METHOD_CHEBYSHEV : opt.method;
    s.L = L;
    s.n = n;
    s.P = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    s.V = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    s.R = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    s.diag = (double *)malloc(sizeof(double) * (size_t)n);
    s.initial = (double *)malloc(sizeof(double) * (size_t)n);
    s.stuck = (unsigned char *)calloc((size_t)n, 1);
    if (method == SPIA_METHOD_CHEBYSHEV) s.D = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    if (!s.P || !s.V || !s.R || !s.diag || !s.initial || !s.stuck || (method == SPIA_METHOD_CHEBYSHEV && !s.D)) {
        res = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver (%d vertices)", (int)n);
        goto done;
    }
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) s.P[k] = s.V[k] = (double)targets[k];
    for (int32_t r = 0; r < n; ++r) {
        s.diag[r] = 0.0;
        for (int64_t k = L->offsets[r]; k < L->offsets[r + 1]; ++k)
            if (L->indices[k] == r) s.diag[r] = L->weights[k];
        if (method == SPIA_METHOD_GS_PIA && !(s.diag[r] > 0.0)) {
            res = spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, r,
                             "stencil of vertex %d has weight %g on itself; GS-PIA needs a positive one", (int)r,
                             s.diag[r]);
            goto done;
        }
    }

    const double diagonal = bbox_diagonal(s.P, n);
    const double scale = diagonal > 0.0 ? diagonal : 1.0;
    const double threshold = opt.tolerance * scale;
    double mean, err; /* err: max over rows still solved */
    double err_all = residual(&s, &mean, &err);
    for (int32_t r = 0; r < n; ++r) {
        const double *q = s.R + 3 * (int64_t)r;
        s.initial[r] = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    }
    const double initial = err;
    double best = err, prev_norm2 = s.norm2, contraction = 1.0;
    int32_t it = 0, it_best = 0, stuck_count = 0;
    int stuck_checked = 0;
    res = SPIA_OK;
    if (report) {
        report->initial_max_error_relative = err_all / scale;
        report->method = method;
    }
    while (!(err <= threshold)) {
        if (it >= opt.max_iterations) {
            res = SPIA_MAX_ITERATIONS;
            break;
        }
        if (method == SPIA_METHOD_PIA || (method == SPIA_METHOD_CHEBYSHEV && it < ESTIMATE_STEPS)) {
            step_pia(&s);
        } else if (method == SPIA_METHOD_GS_PIA) {
            step_gs_pia(&s);
        } else {
            /* PIA's residual contracts by 1 - lambda_min per step once the
             * slowest mode dominates; after a few steps it has not yet, and
             * the contraction seen then overestimates lambda_min by a factor
             * of three to five on the meshes measured (eigenvalues computed
             * with numpy), hence the quarter. */
            if (s.cheb_steps == 0) {
                double a = (1.0 - contraction) / 3.0;
                s.cheb_a = a < CHEB_A_MIN ? CHEB_A_MIN : a > CHEB_A_MAX ? CHEB_A_MAX : a;
            }
            step_chebyshev(&s);
        }
        ++it;
        err_all = residual(&s, &mean, &err);
        contraction = prev_norm2 > 0.0 ? sqrt(s.norm2 / prev_norm2) : 0.0;
        prev_norm2 = s.norm2;
        if (report && report->history && it <= report->history_capacity) {
            report->history[it - 1] = err_all / scale;
            report->history_count = it;
        }
        if (!isfinite(err) || err > DIVERGENCE_FACTOR * (initial > threshold ? initial : threshold)) {
            res = spia__fail(status, SPIA_ERROR_DIVERGED, -1,
                             "the iteration diverged after %d iterations (max error %g of the diagonal)", (int)it,
                             err / scale);
            break;
        }
        if (err < best * (1.0 - 1e-3)) {
            best = err;
            it_best = it;
        } else if (it - it_best >= STAGNATION_WINDOW) {
            if (stuck_checked) {
                res = SPIA_STAGNATED;
                break;
            }
            stuck_checked = 1;
            stuck_count = mark_stuck(&s, threshold);
            if (stuck_count == 0) {
                res = SPIA_STAGNATED;
                break;
            }
            err_all = residual(&s, &mean, &err);
            prev_norm2 = s.norm2;
            s.cheb_steps = 0;
            best = err;
            it_best = it;
        }
        if (opt.progress && opt.progress(opt.progress_user_data, it, err_all / scale)) {
            res = spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after %d iterations", (int)it);
            break;
        }
    }
    if (res >= 0) {
        /* Write the cage, then measure it as stored (in float). */
        for (int64_t k = 0; k < 3 * (int64_t)n; ++k) {
            cage[k] = (float)s.V[k];
            s.V[k] = (double)cage[k];
        }
        err_all = residual(&s, &mean, &err);
        if (stuck_count > 0 && res == SPIA_OK) res = SPIA_STAGNATED;
        if (res == SPIA_OK)
            spia__ok(status);
        else if (res == SPIA_MAX_ITERATIONS)
            spia__fail(status, res, -1,
                       "stopped at max_iterations (%d) with max error %.3g of the diagonal, above the tolerance %.3g",
                       (int)it, err_all / scale, opt.tolerance);
        else if (stuck_count > 0)
            spia__fail(status, res, -1,
                       "%d vertices cannot reach their targets: their limit points are tied to other vertices' "
                       "(as on double-sided faces); they keep their positions, with max error %.3g of the diagonal. "
                       "The other vertices reach %.3g",
                       (int)stuck_count, err_all / scale, err / scale);
        else
            spia__fail(status, res, -1,
                       "the error stopped falling after %d iterations at %.3g of the diagonal, above the tolerance %.3g",
                       (int)it, err_all / scale, opt.tolerance);
        if (report) {
            report->iterations = it;
            report->diagonal = diagonal;
            report->max_error = err_all;
            report->mean_error = mean;
            report->max_error_relative = err_all / scale;
            report->mean_error_relative = mean / scale;
            report->reachable_max_error_relative = err / scale;
            report->unreachable_count = stuck_count;
            if (report->unreachable) memcpy(report->unreachable, s.stuck, (size_t)n);
        }
    } else if (report) {
        report->iterations = it;
        report->diagonal = diagonal;
    }
done:
    free(s.P);
    free(s.V);
    free(s.R);
    free(s.diag);
    free(s.initial);
    free(s.stuck);
    free(s.D);
    if (report) {
        report->solve_seconds = spia__now() - t0;
        report->result = res;
    }
    return res;
}
