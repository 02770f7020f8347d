// SPDX-License-Identifier: GPL-3.0-or-later
/* GS_PIA_FAST and the solve flags: the tolerance met (checked with the
 * stencils, apart from the solver's report) on small tables (vertex order)
 * and large ones (the level layout, sweeps pipelined on threads); the same
 * cage for any thread count; progress once per iteration, cancelling
 * mid-run; max_iterations; unreachable vertices; staged solves; the hand
 * over to GS_PIA where float32 cannot reach the tolerance; tables with no
 * layout; the solve flags on GS_PIA. */
#include "support.h"

static double diag_of(const float *pos, int32_t nv) {
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    for (int32_t i = 0; i < nv; ++i)
        for (int a = 0; a < 3; ++a) {
            lo[a] = fmin(lo[a], pos[3 * i + a]);
            hi[a] = fmax(hi[a], pos[3 * i + a]);
        }
    return sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2]));
}

/* max_i |(L cage)_i - P_i| / diagonal over rows not flagged in skip. */
static double limit_error(const spia_stencils *s, const float *targets, const float *cage, const uint8_t *skip) {
    const int32_t n = spia_stencils_row_count(s);
    double *c = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    double *l = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) c[k] = cage[k];
    spia_stencils_apply(s, c, l);
    double worst = 0.0;
    for (int32_t i = 0; i < n; ++i) {
        if (skip && skip[i]) continue;
        double d = 0.0;
        for (int a = 0; a < 3; ++a) d += (l[3 * i + a] - targets[3 * i + a]) * (l[3 * i + a] - targets[3 * i + a]);
        worst = fmax(worst, sqrt(d));
    }
    free(c);
    free(l);
    return worst / diag_of(targets, n);
}

/* A torus of nu x nv quads (or twice as many triangles), its radii varied
 * by a fixed pseudo-random amount (0 for a smooth one). */
static tmesh rough_torus(int nu, int nv, int triangles, double roughness) {
    tmesh m;
    memset(&m, 0, sizeof m);
    m.nv = nu * nv;
    m.pos = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
    uint64_t seed = 7;
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
            const double e = roughness * ((double)(seed >> 11) / 9007199254740992.0 - 0.5);
            const double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv, r = 0.7 * (1.0 + e);
            float *p = m.pos + 3 * (size_t)(j * nu + i);
            p[0] = (float)((2 + r * cos(v)) * cos(u));
            p[1] = (float)((2 + r * cos(v)) * sin(u));
            p[2] = (float)(r * sin(v));
        }
    m.nf = nu * nv * (triangles ? 2 : 1);
    m.nfv = (int64_t)nu * nv * (triangles ? 6 : 4);
    m.sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)m.nf);
    m.fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)m.nfv);
    int64_t k = 0;
    int32_t f = 0;
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            const int32_t a = j * nu + i, b = j * nu + (i + 1) % nu, c = ((j + 1) % nv) * nu + (i + 1) % nu,
                          d = ((j + 1) % nv) * nu + i;
            if (triangles) {
                const int32_t t[6] = {a, b, c, a, c, d};
                for (int q = 0; q < 6; ++q) m.fv[k++] = t[q];
                m.sizes[f++] = 3;
                m.sizes[f++] = 3;
            } else {
                const int32_t t[4] = {a, b, c, d};
                for (int q = 0; q < 4; ++q) m.fv[k++] = t[q];
                m.sizes[f++] = 4;
            }
        }
    return m;
}

typedef struct calls {
    int count, last, ordered;
    int cancel_at;
    double values[64];
} calls;

static int record(void *user, int32_t iteration, double err) {
    calls *c = (calls *)user;
    if (iteration != c->last + 1) c->ordered = 0;
    c->last = iteration;
    if (c->count < 64) c->values[c->count] = err;
    ++c->count;
    return c->cancel_at > 0 && iteration >= c->cancel_at;
}

static spia_result solve(const spia_stencils *s, const float *targets, spia_options o, float *cage, spia_report *rep,
                         double *history, int capacity) {
    memset(rep, 0, sizeof *rep);
    rep->history = history;
    rep->history_capacity = capacity;
    spia_status st;
    const spia_result r = spia_solve(s, targets, &o, cage, rep, &st);
    if (r < 0 && r != SPIA_ERROR_CANCELLED) fprintf(stderr, "solve: %s\n", st.message);
    return r;
}

/* The tolerance met, the report right, and the same cage with 1 to 4
 * threads. */
static void check_converges(const tmesh *m, const char *name, spia_scheme scheme, int flags, int staged) {
    spia_mesh mesh = tmesh_view(m);
    spia_options o = spia_options_default();
    o.scheme = scheme;
    o.method = SPIA_METHOD_GS_PIA_FAST;
    o.solve_flags = flags;
    o.staged = staged;
    spia_status st;
    spia_stencils *s = NULL;
    CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "%s: %s", name, st.message);
    if (!s) return;
    const size_t bytes = sizeof(float) * 3 * (size_t)m->nv;
    float *cage = (float *)malloc(bytes), *other = (float *)malloc(bytes);
    double history[1000];
    spia_report rep, rep2;
    o.threads = 1;
    CHECK(solve(s, m->pos, o, cage, &rep, history, 1000) == SPIA_OK, "%s flags %d: not converged", name, flags);
    const double err = limit_error(s, m->pos, cage, NULL);
    CHECK(err <= 1e-6 + 4e-7, "%s flags %d: limit error %g", name, flags, err);
    CHECK(fabs(rep.max_error_relative - err) <= 1e-9 + 1e-6 * err, "%s: report %g, measured %g", name,
          rep.max_error_relative, err);
    CHECK(rep.method == SPIA_METHOD_GS_PIA_FAST, "%s: method %d", name, (int)rep.method);
    CHECK(rep.history_count == rep.iterations, "%s: history %d of %d", name, (int)rep.history_count,
          (int)rep.iterations);
    CHECK(rep.iterations > 0 && rep.history[rep.iterations - 1] <= 1e-6, "%s: last history entry %g", name,
          rep.iterations > 0 ? rep.history[rep.iterations - 1] : -1.0);
    if (staged)
        CHECK(rep.stage_iterations[0] > 0 && rep.stage_iterations[0] + rep.stage_iterations[1] == rep.iterations,
              "%s: stages %d + %d of %d", name, (int)rep.stage_iterations[0], (int)rep.stage_iterations[1],
              (int)rep.iterations);
    for (int threads = 2; threads <= 4; ++threads) {
        o.threads = threads;
        double history2[1000];
        CHECK(solve(s, m->pos, o, other, &rep2, history2, 1000) == SPIA_OK, "%s: %d threads", name, threads);
        CHECK(memcmp(cage, other, bytes) == 0, "%s flags %d: cages differ between 1 and %d threads", name, flags,
              threads);
        CHECK(rep2.iterations == rep.iterations && rep2.max_error == rep.max_error &&
                  memcmp(history, history2, sizeof(double) * (size_t)rep.iterations) == 0,
              "%s: %d threads report otherwise", name, threads);
    }
    printf("%-34s %7d vertices, flags %d%s: %3d iterations, error %.2g\n", name, (int)m->nv, flags,
           staged ? " staged" : "", (int)rep.iterations, err);
    free(cage);
    free(other);
    spia_stencils_free(s);
}

int main(void) {
    /* Small tables (vertex order) and large ones (the level layout). */
    static const char *names[] = {"mushroom.obj", "double-torus.obj", "teapot.obj", "catmark_car.obj"};
    for (int i = 0; i < 4; ++i) {
        char path[1024];
        tmesh m;
        snprintf(path, sizeof path, "%s/%s", SPIA_TEST_DATA_DIR, names[i]);
        CHECK(read_obj(path, &m), "cannot read %s", path);
        check_converges(&m, names[i], SPIA_SCHEME_CATMULL_CLARK, 0, 0);
        check_converges(&m, names[i], SPIA_SCHEME_CATMULL_CLARK, SPIA_SOLVE_FIRST_STEP, 0);
        tmesh_free(&m);
    }
    tmesh big = rough_torus(320, 170, 0, 0.004);
    check_converges(&big, "rough quad torus", SPIA_SCHEME_CATMULL_CLARK, 0, 0);
    check_converges(&big, "rough quad torus", SPIA_SCHEME_CATMULL_CLARK, SPIA_SOLVE_FIRST_STEP, 0);
    check_converges(&big, "rough quad torus", SPIA_SCHEME_CATMULL_CLARK, SPIA_SOLVE_DOUBLE_SWEEPS, 0);
    {
        /* An open one (boundaries: a stencil table that is not symmetric),
         * triangles under Loop, at once and staged. */
        tmesh tri = rough_torus(300, 180, 1, 0.004);
        tri.nf -= 2 * 300; /* the last ring of faces left out: a tube, two boundary loops */
        tri.nfv = 3 * (int64_t)tri.nf;
        check_converges(&tri, "open rough triangle torus (Loop)", SPIA_SCHEME_LOOP, 0, 0);
        check_converges(&tri, "open rough triangle torus (Loop)", SPIA_SCHEME_LOOP, 0, 1);
        tmesh_free(&tri);
    }

    spia_mesh mesh = tmesh_view(&big);
    spia_options o = spia_options_default();
    spia_status st;
    spia_stencils *s = NULL;
    CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "big torus: %s", st.message);
    const size_t bytes = sizeof(float) * 3 * (size_t)big.nv;
    float *cage = (float *)malloc(bytes), *sentinel = (float *)malloc(bytes);
    double history[1000];
    spia_report rep;

    /* AUTO takes GS_PIA_FAST on the rough torus. */
    o.method = SPIA_METHOD_AUTO;
    CHECK(solve(s, big.pos, o, cage, &rep, history, 1000) == SPIA_OK && rep.method == SPIA_METHOD_GS_PIA_FAST,
          "AUTO on the rough torus took method %d", (int)rep.method);

    /* Progress once per iteration, in order, with the history's values;
     * cancelling in the middle of a run of sweeps on two threads. */
    for (int threads = 1; threads <= 2; ++threads) {
        calls c;
        memset(&c, 0, sizeof c);
        c.ordered = 1;
        o = spia_options_default();
        o.method = SPIA_METHOD_GS_PIA_FAST;
        o.threads = threads;
        o.progress = record;
        o.progress_user_data = &c;
        CHECK(solve(s, big.pos, o, cage, &rep, history, 1000) == SPIA_OK, "with progress");
        CHECK(c.ordered && c.count == rep.iterations, "%d progress calls for %d iterations (in order: %d)", c.count,
              (int)rep.iterations, c.ordered);
        for (int i = 0; i < c.count && i < 64; ++i)
            CHECK(c.values[i] == history[i], "progress %d: %g, history %g", i + 1, c.values[i], history[i]);
        memset(&c, 0, sizeof c);
        c.ordered = 1;
        c.cancel_at = 2;
        for (size_t k = 0; k < 3 * (size_t)big.nv; ++k) cage[k] = sentinel[k] = -7.0f;
        CHECK(solve(s, big.pos, o, cage, &rep, history, 1000) == SPIA_ERROR_CANCELLED, "cancel at 2");
        CHECK(rep.iterations == 2 && c.count == 2, "cancelled after %d iterations, %d calls", (int)rep.iterations,
              c.count);
        CHECK(memcmp(cage, sentinel, bytes) == 0, "cage written after cancel");
    }

    /* max_iterations: a usable cage, that many iterations. */
    o = spia_options_default();
    o.method = SPIA_METHOD_GS_PIA_FAST;
    o.max_iterations = 3;
    o.threads = 2;
    CHECK(solve(s, big.pos, o, cage, &rep, history, 1000) == SPIA_MAX_ITERATIONS && rep.iterations == 3,
          "max_iterations 3: %d iterations", (int)rep.iterations);
    CHECK(rep.max_error_relative < rep.initial_max_error_relative, "no progress in 3 iterations");
    CHECK(fabs(limit_error(s, big.pos, cage, NULL) - rep.max_error_relative) <= 1e-6 * rep.max_error_relative,
          "max_iterations: report %g, measured %g", rep.max_error_relative, limit_error(s, big.pos, cage, NULL));

    /* A tolerance float32 sweeps cannot reach: GS_PIA's double sweeps do
     * the work, as GS_PIA alone would (the same cage). */
    {
        float *gs = (float *)malloc(bytes);
        o = spia_options_default();
        o.tolerance = 1e-12;
        o.method = SPIA_METHOD_GS_PIA;
        spia_result a = solve(s, big.pos, o, gs, &rep, history, 1000);
        o.method = SPIA_METHOD_GS_PIA_FAST;
        spia_report rf;
        spia_result b = solve(s, big.pos, o, cage, &rf, history, 1000);
        CHECK(a == b && rf.method == SPIA_METHOD_GS_PIA && rf.iterations == rep.iterations &&
                  memcmp(gs, cage, bytes) == 0,
              "tolerance 1e-12: GS_PIA_FAST %s in %d iterations (method %d), GS_PIA %s in %d", spia_result_name(b),
              (int)rf.iterations, (int)rf.method, spia_result_name(a), (int)rep.iterations);
        free(gs);
    }
    spia_stencils_free(s);

    /* Coordinates far from the origin: the cage's own float rounding is
     * near the tolerance; the double sweeps finish where float32 cannot. */
    {
        tmesh far = rough_torus(320, 170, 0, 0.004);
        for (int64_t k = 0; k < 3 * (int64_t)far.nv; ++k) far.pos[k] += 3000.0f;
        spia_mesh fm = tmesh_view(&far);
        o = spia_options_default();
        o.method = SPIA_METHOD_GS_PIA_FAST;
        CHECK(spia_limit_stencils_create(&fm, &o, &s, &st) == SPIA_OK, "%s", st.message);
        spia_result r = solve(s, far.pos, o, cage, &rep, history, 1000);
        CHECK(r == SPIA_OK, "far torus: %s", spia_result_name(r));
        CHECK(rep.history_count == rep.iterations, "far torus: history %d of %d", (int)rep.history_count,
              (int)rep.iterations);
        printf("%-34s %7d vertices: %s in %d iterations, method %d, error %.2g\n", "rough torus 3000 away",
               (int)far.nv, spia_result_name(r), (int)rep.iterations, (int)rep.method, rep.max_error_relative);
        spia_stencils_free(s);
        tmesh_free(&far);
    }

    /* Double-sided triangles beside the large torus: the level layout's
     * sweeps leave them on their targets and solve the rest. */
    {
        tmesh m = rough_torus(320, 170, 0, 0.004);
        int32_t tri[3][3];
        for (int t = 0; t < 3; ++t) {
            m.pos = (float *)realloc(m.pos, sizeof(float) * 3 * (size_t)(m.nv + 3));
            for (int c = 0; c < 3; ++c) {
                float *p = m.pos + 3 * (size_t)m.nv;
                p[0] = 5.0f + (float)t;
                p[1] = (float)(c == 1);
                p[2] = 0.5f * (float)(c == 2);
                tri[t][c] = m.nv++;
            }
            m.sizes = (int32_t *)realloc(m.sizes, sizeof(int32_t) * (size_t)(m.nf + 2));
            m.fv = (int32_t *)realloc(m.fv, sizeof(int32_t) * (size_t)(m.nfv + 6));
            const int32_t f[6] = {tri[t][0], tri[t][1], tri[t][2], tri[t][1], tri[t][0], tri[t][2]};
            for (int q = 0; q < 6; ++q) m.fv[m.nfv++] = f[q];
            m.sizes[m.nf++] = 3;
            m.sizes[m.nf++] = 3;
        }
        spia_mesh dm = tmesh_view(&m);
        o = spia_options_default();
        CHECK(spia_limit_stencils_create(&dm, &o, &s, &st) == SPIA_OK, "%s", st.message);
        uint8_t *flags = (uint8_t *)calloc((size_t)m.nv, 1);
        float *c2 = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
        for (int threads = 1; threads <= 2; ++threads) {
            o.method = SPIA_METHOD_GS_PIA_FAST;
            o.threads = threads;
            memset(&rep, 0, sizeof rep);
            rep.unreachable = flags;
            spia_result r = spia_solve(s, m.pos, &o, c2, &rep, &st);
            CHECK(r == SPIA_STAGNATED && rep.unreachable_count == 9, "double-sided triangles: %s, %d unreachable",
                  spia_result_name(r), (int)rep.unreachable_count);
            for (int t = 0; t < 3; ++t)
                for (int c = 0; c < 3; ++c) {
                    const int32_t v = tri[t][c];
                    CHECK(flags[v], "vertex %d not flagged", (int)v);
                }
            /* the least-squares cage: each triangle's limit point on its targets' centroid */
            for (int t = 0; t < 3; ++t)
                CHECK(double_sided_miss(s, m.pos, c2, tri[t]) <= 1e-6 * diag_of(m.pos, m.nv),
                      "double-sided triangle %d: limit point %g from the targets' centroid", t,
                      double_sided_miss(s, m.pos, c2, tri[t]));
            CHECK(rep.method == SPIA_METHOD_LEAST_SQUARES, "method %d", (int)rep.method);
            CHECK(limit_error(s, m.pos, c2, flags) <= 1e-6 + 4e-7, "the rest: %g", limit_error(s, m.pos, c2, flags));
        }
        free(flags);
        free(c2);
        spia_stencils_free(s);
        tmesh_free(&m);
    }

    /* More distinct weights than the layout holds (a shape parameter per
     * face, Doo-Sabin): GS_PIA_FAST is GS_PIA. */
    {
        tmesh m = rough_torus(200, 180, 0, 0.0);
        float *shape = (float *)malloc(sizeof(float) * (size_t)m.nf);
        uint64_t seed = 3;
        for (int32_t f = 0; f < m.nf; ++f) {
            seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
            shape[f] = 0.3f + 0.5f * (float)((double)(seed >> 11) / 9007199254740992.0);
        }
        spia_mesh dm = tmesh_view(&m);
        o = spia_options_default();
        o.scheme = SPIA_SCHEME_DOO_SABIN;
        o.face_shape_parameters = shape;
        o.method = SPIA_METHOD_GS_PIA_FAST;
        CHECK(spia_limit_stencils_create(&dm, &o, &s, &st) == SPIA_OK, "%s", st.message);
        float *c2 = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
        spia_result r = solve(s, m.pos, o, c2, &rep, history, 1000);
        CHECK(r == SPIA_OK && rep.method == SPIA_METHOD_GS_PIA, "no layout: %s, method %d", spia_result_name(r),
              (int)rep.method);
        free(c2);
        free(shape);
        spia_stencils_free(s);
        tmesh_free(&m);
    }

    /* The solve flags on GS_PIA, and unknown ones. */
    {
        tmesh m;
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", SPIA_TEST_DATA_DIR, "catmark_car.obj");
        CHECK(read_obj(path, &m), "cannot read %s", path);
        spia_mesh cm = tmesh_view(&m);
        o = spia_options_default();
        CHECK(spia_limit_stencils_create(&cm, &o, &s, &st) == SPIA_OK, "%s", st.message);
        float *c2 = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
        static const int flag_sets[3] = {SPIA_SOLVE_MULTICOLOUR, SPIA_SOLVE_FIRST_STEP,
                                         SPIA_SOLVE_MULTICOLOUR | SPIA_SOLVE_FIRST_STEP};
        for (int k = 0; k < 3; ++k) {
            o.method = SPIA_METHOD_GS_PIA;
            o.solve_flags = flag_sets[k];
            spia_result r = solve(s, m.pos, o, c2, &rep, history, 1000);
            CHECK(r == SPIA_OK && rep.method == SPIA_METHOD_GS_PIA, "GS_PIA flags %d: %s", flag_sets[k],
                  spia_result_name(r));
            CHECK(limit_error(s, m.pos, c2, NULL) <= 1e-6 + 4e-7, "GS_PIA flags %d: error %g", flag_sets[k],
                  limit_error(s, m.pos, c2, NULL));
        }
        o.solve_flags = 64;
        CHECK(spia_solve(s, m.pos, &o, c2, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT, "unknown solve flag");
        free(c2);
        spia_stencils_free(s);
        tmesh_free(&m);
    }

    free(cage);
    free(sentinel);
    tmesh_free(&big);
    TEST_MAIN_END();
}
