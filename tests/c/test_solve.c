// SPDX-License-Identifier: GPL-3.0-or-later
/* Solvers: convergence to the tolerance for every method, L V = P checked
 * with the stencils independently of the solver's own report, GS-PIA
 * faster than PIA, max_iterations, unreachable vertices. */
#include "support.h"

static double diag_of(const tmesh *m) {
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    for (int32_t i = 0; i < m->nv; ++i)
        for (int a = 0; a < 3; ++a) {
            lo[a] = fmin(lo[a], m->pos[3 * i + a]);
            hi[a] = fmax(hi[a], m->pos[3 * i + a]);
        }
    return sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2]));
}

/* max_i |(L cage)_i - P_i| / diagonal, skipping flagged rows. */
static double limit_error(const spia_stencils *s, const tmesh *m, const float *cage, const uint8_t *skip) {
    double *c = (double *)malloc(sizeof(double) * 3 * (size_t)m->nv);
    double *l = (double *)malloc(sizeof(double) * 3 * (size_t)m->nv);
    for (int64_t k = 0; k < 3 * (int64_t)m->nv; ++k) c[k] = cage[k];
    spia_stencils_apply(s, c, l);
    double worst = 0.0;
    for (int32_t i = 0; i < m->nv; ++i) {
        if (skip && skip[i]) continue;
        double d = 0.0;
        for (int a = 0; a < 3; ++a) d += (l[3 * i + a] - m->pos[3 * i + a]) * (l[3 * i + a] - m->pos[3 * i + a]);
        worst = fmax(worst, sqrt(d));
    }
    free(c);
    free(l);
    return worst / diag_of(m);
}

static int32_t solve_and_check(const tmesh *m, const char *name, spia_method method, double tol) {
    spia_mesh mesh = tmesh_view(m);
    spia_options o = spia_options_default();
    o.method = method;
    o.tolerance = tol;
    spia_status st;
    spia_stencils *s = NULL;
    CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "%s: %s", name, st.message);
    float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)m->nv);
    double history[1000];
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    rep.history = history;
    rep.history_capacity = 1000;
    spia_result r = spia_solve(s, m->pos, &o, cage, &rep, &st);
    CHECK(r == SPIA_OK, "%s method %d: %s (%s)", name, (int)method, spia_result_name(r), st.message);
    double err = limit_error(s, m, cage, NULL);
    /* The cage is stored in float, so allow the rounding of the coordinates. */
    CHECK(err <= tol + 4e-7, "%s method %d: limit error %g above %g", name, (int)method, err, tol);
    CHECK(fabs(rep.max_error_relative - err) <= 1e-9 + 1e-6 * err, "%s: report %g, measured %g", name,
          rep.max_error_relative, err);
    CHECK(rep.initial_max_error_relative > 10 * tol, "%s: nothing to solve (%g)", name, rep.initial_max_error_relative);
    CHECK(rep.history_count == rep.iterations, "%s: history %d of %d", name, (int)rep.history_count, (int)rep.iterations);
    CHECK(rep.unreachable_count == 0, "%s: %d unreachable", name, (int)rep.unreachable_count);
    CHECK(rep.method == (method == SPIA_METHOD_AUTO ? rep.method : method), "%s: method", name);
    /* The same through the one-call entry point. */
    float *cage2 = (float *)malloc(sizeof(float) * 3 * (size_t)m->nv);
    CHECK(spia_interpolate(&mesh, &o, cage2, NULL, &st) == SPIA_OK, "%s: %s", name, st.message);
    CHECK(memcmp(cage, cage2, sizeof(float) * 3 * (size_t)m->nv) == 0, "%s: interpolate differs from solve", name);
    free(cage2);
    free(cage);
    spia_stencils_free(s);
    return rep.iterations;
}

static void check_mesh(tmesh *m, const char *name) {
    int32_t pia = solve_and_check(m, name, SPIA_METHOD_PIA, 1e-6);
    int32_t gs = solve_and_check(m, name, SPIA_METHOD_GS_PIA, 1e-6);
    int32_t aut = solve_and_check(m, name, SPIA_METHOD_AUTO, 1e-6);
    solve_and_check(m, name, SPIA_METHOD_CHEBYSHEV, 1e-6);
    solve_and_check(m, name, SPIA_METHOD_GS_PIA_FAST, 1e-6);
    solve_and_check(m, name, SPIA_METHOD_AUTO, 1e-4);
    printf("%-28s %6d vertices: PIA %3d, GS-PIA %3d, AUTO %3d iterations\n", name, (int)m->nv, (int)pia, (int)gs, (int)aut);
    /* An iteration costs one product with the stencils for every method
     * (GS-PIA's sweep gives its own error estimate; the residual is
     * computed only when that reaches the tolerance).  On smooth targets
     * (the tori) PIA needs only a few iterations and GS-PIA overshoots; on
     * rough ones GS-PIA needs fewer iterations than PIA.  AUTO must be
     * behind neither. */
    CHECK(aut <= pia + 1, "%s: AUTO %d iterations, PIA %d", name, (int)aut, (int)pia);
    CHECK(aut <= gs, "%s: AUTO %d iterations, GS-PIA %d", name, (int)aut, (int)gs);
}

/* A warm start: after one vertex of the targets moves by 0.1% of the
 * diagonal, the solve from the cage of the old targets reaches the same
 * tolerance as the solve from the targets, for every method, and GS-PIA
 * needs fewer iterations for it (PIA does not: the error left is one
 * vertex's spike, the slowest kind for PIA, where the targets' error is
 * mostly smooth); from a converged cage none at all.
 * A NaN in the first iterate is refused with the cage untouched, and the
 * first iterate may be the cage buffer itself. */
static void check_warm_start(const tmesh *m0, const char *name) {
    const double tol = 1e-6;
    const size_t bytes = sizeof(float) * 3 * (size_t)m0->nv;
    tmesh m = *m0;
    float *moved = (float *)malloc(bytes), *old_cage = (float *)malloc(bytes);
    float *cold = (float *)malloc(bytes), *warm = (float *)malloc(bytes);
    memcpy(moved, m0->pos, bytes);
    const double d = diag_of(m0);
    moved[3 * 7 + 2] += (float)(0.001 * d);
    spia_mesh mesh = tmesh_view(m0);
    spia_status st;
    spia_stencils *s = NULL;
    spia_options o = spia_options_default();
    CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "%s: %s", name, st.message);
    for (int method = SPIA_METHOD_AUTO; method <= SPIA_METHOD_GS_PIA_FAST; ++method) {
        if (method == SPIA_METHOD_WPIA || method == SPIA_METHOD_CG) continue;
        o = spia_options_default();
        o.method = (spia_method)method;
        o.tolerance = tol;
        spia_report rc, rw;
        memset(&rc, 0, sizeof rc);
        memset(&rw, 0, sizeof rw);
        CHECK(spia_solve(s, m0->pos, &o, old_cage, NULL, &st) == SPIA_OK, "%s: %s", name, st.message);
        CHECK(spia_solve(s, moved, &o, cold, &rc, &st) == SPIA_OK, "%s: %s", name, st.message);
        o.initial_cage = old_cage;
        CHECK(spia_solve(s, moved, &o, warm, &rw, &st) == SPIA_OK, "%s method %d warm: %s", name, method, st.message);
        m.pos = moved;
        CHECK(limit_error(s, &m, warm, NULL) <= tol + 4e-7, "%s method %d: warm start off by %g", name, method,
              limit_error(s, &m, warm, NULL));
        CHECK(rw.initial_max_error_relative < rc.initial_max_error_relative, "%s method %d: start %g, not below %g",
              name, method, rw.initial_max_error_relative, rc.initial_max_error_relative);
        if (method == SPIA_METHOD_GS_PIA || method == SPIA_METHOD_GS_PIA_FAST)
            CHECK(rw.iterations < rc.iterations, "%s method %d: %d iterations warm, %d cold", name, method,
                  (int)rw.iterations, (int)rc.iterations);
        /* From the converged cage: nothing left to do, the same cage. */
        o.initial_cage = cold;
        memcpy(warm, cold, bytes);
        CHECK(spia_solve(s, moved, &o, warm, &rw, &st) == SPIA_OK, "%s: %s", name, st.message);
        CHECK(rw.iterations == 0, "%s method %d: %d iterations from a solved cage", name, method, (int)rw.iterations);
        CHECK(memcmp(warm, cold, bytes) == 0, "%s method %d: a solved cage changed", name, method);
        /* The cage buffer as its own first iterate. */
        memcpy(warm, old_cage, bytes);
        o.initial_cage = warm;
        CHECK(spia_solve(s, moved, &o, warm, &rw, &st) == SPIA_OK, "%s: %s", name, st.message);
        CHECK(limit_error(s, &m, warm, NULL) <= tol + 4e-7, "%s method %d: aliased warm start", name, method);
        /* A NaN in the first iterate. */
        memcpy(warm, old_cage, bytes);
        warm[3 * 5 + 1] = NAN;
        memcpy(cold, warm, bytes);
        o.initial_cage = warm;
        CHECK(spia_solve(s, moved, &o, warm, &rw, &st) == SPIA_ERROR_NONFINITE && st.index == 5,
              "%s method %d: NaN first iterate: %s", name, method, st.message);
        CHECK(memcmp(warm, cold, bytes) == 0, "%s method %d: cage written on failure", name, method);
    }
    spia_stencils_free(s);
    free(moved);
    free(old_cage);
    free(cold);
    free(warm);
}

/* ---- refinement: counts asked for first, progress, cancel ----------------- */

typedef struct refine_calls {
    int count, stop_at, bad;
    int32_t last_level;
    double last_share;
} refine_calls;

static int record_refine(void *user, int32_t iteration, double share) {
    refine_calls *c = (refine_calls *)user;
    if (iteration < c->last_level || share < c->last_share || share > 1.0) ++c->bad;
    c->last_level = iteration, c->last_share = share;
    return ++c->count == c->stop_at;
}

/* spia_refine_size's counts (now in closed form) fill the buffers exactly:
 * a canary after each buffer stays; the corners are the face sizes' sum;
 * every face vertex is in range.  The progress callback sees levels
 * rising and shares rising to 1 at the end; stopping it at its first call
 * gives SPIA_ERROR_CANCELLED and leaves the buffers as they were. */
static void check_refine(const tmesh *m, const char *name, spia_options o) {
    spia_mesh mesh = tmesh_view(m);
    for (int32_t levels = 0; levels <= 3; ++levels) {
        int32_t nv = 0, nf = 0;
        int64_t nc = 0;
        spia_status st;
        spia_result r = spia_refine_size(&mesh, &o, levels, &nv, &nf, &nc, &st);
        CHECK(r == SPIA_OK, "%s level %d size: %s", name, (int)levels, st.message);
        if (r != SPIA_OK) continue;
        const float canary = 12345.0f;
        float *pos = (float *)malloc(sizeof(float) * (3 * (size_t)nv + 1));
        int32_t *fs = (int32_t *)malloc(sizeof(int32_t) * ((size_t)nf + 1));
        int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * ((size_t)nc + 1));
        for (int64_t k = 0; k <= 3 * (int64_t)nv; ++k) pos[k] = canary;
        for (int64_t k = 0; k <= nf; ++k) fs[k] = -7;
        for (int64_t k = 0; k <= nc; ++k) fv[k] = -7;
        refine_calls calls = {0, 0, 0, 0, 0.0};
        spia_options with = o;
        with.progress = record_refine, with.progress_user_data = &calls;
        r = spia_refine(&mesh, &with, levels, pos, fs, fv, &st);
        CHECK(r == SPIA_OK, "%s level %d: %s", name, (int)levels, st.message);
        CHECK(pos[3 * (int64_t)nv] == canary && fs[nf] == -7 && fv[nc] == -7, "%s level %d wrote past the counts",
              name, (int)levels);
        int64_t corners = 0, bad_index = 0, unwritten = 0;
        for (int32_t f = 0; f < nf; ++f) corners += fs[f];
        for (int64_t k = 0; k < nc; ++k) bad_index += fv[k] < 0 || fv[k] >= nv;
        for (int64_t k = 0; k < 3 * (int64_t)nv; ++k) unwritten += pos[k] == canary;
        CHECK(corners == nc && bad_index == 0 && unwritten == 0,
              "%s level %d: corners %lld of %lld, %lld bad indices, %lld positions unwritten", name, (int)levels,
              (long long)corners, (long long)nc, (long long)bad_index, (long long)unwritten);
        CHECK(calls.count >= levels && calls.bad == 0 && calls.last_level == levels && calls.last_share == 1.0,
              "%s level %d: %d progress calls, %d out of order, the last (%d, %g)", name, (int)levels, calls.count,
              calls.bad, (int)calls.last_level, calls.last_share);
        /* Cancelled at the first call: nothing written. */
        for (int64_t k = 0; k < 3 * (int64_t)nv; ++k) pos[k] = canary;
        for (int64_t k = 0; k < nf; ++k) fs[k] = -7;
        for (int64_t k = 0; k < nc; ++k) fv[k] = -7;
        refine_calls stop = {0, 1, 0, 0, 0.0};
        with.progress_user_data = &stop;
        r = spia_refine(&mesh, &with, levels, pos, fs, fv, &st);
        CHECK(r == SPIA_ERROR_CANCELLED && stop.count == 1, "%s level %d: cancel gave %s after %d calls", name,
              (int)levels, spia_result_name(r), stop.count);
        char expected[64];
        snprintf(expected, sizeof expected, "cancelled refining level %d of %d", levels > 0 ? 1 : 0, (int)levels);
        CHECK(strstr(st.message, expected) != NULL, "message: %s (expected %s)", st.message, expected);
        unwritten = 0;
        for (int64_t k = 0; k < 3 * (int64_t)nv; ++k) unwritten += pos[k] == canary;
        for (int64_t k = 0; k < nf; ++k) unwritten += fs[k] == -7;
        for (int64_t k = 0; k < nc; ++k) unwritten += fv[k] == -7;
        CHECK(unwritten == 3 * (int64_t)nv + nf + nc, "%s level %d: a cancelled refinement wrote %lld values", name,
              (int)levels, (long long)(3 * (int64_t)nv + nf + nc - unwritten));
        free(pos);
        free(fs);
        free(fv);
    }
}

static void check_refinements(void) {
    spia_options loop = spia_options_default(), hoppe, ds = spia_options_default();
    loop.scheme = SPIA_SCHEME_LOOP;
    hoppe = loop;
    hoppe.boundary_rule = SPIA_BOUNDARY_RULE_HOPPE;
    ds.scheme = SPIA_SCHEME_DOO_SABIN;
    tmesh torus = make_torus(12, 8, 1), grid = make_grid(5, 4), open, fin;
    /* The grid triangulated (open), and with a vertex no face uses. */
    memset(&open, 0, sizeof open);
    for (int32_t v = 0; v < grid.nv; ++v) tmesh_vertex(&open, grid.pos[3 * v], grid.pos[3 * v + 1], grid.pos[3 * v + 2]);
    for (int32_t f = 0; f < grid.nf; ++f) {
        const int32_t *q = grid.fv + 4 * f;
        tmesh_tri(&open, q[0], q[1], q[2]);
        tmesh_tri(&open, q[0], q[2], q[3]);
    }
    tmesh_vertex(&open, 9.0, 9.0, 9.0);
    /* Three triangles on one edge (non-manifold). */
    memset(&fin, 0, sizeof fin);
    tmesh_vertex(&fin, 0, 0, 0), tmesh_vertex(&fin, 1, 0, 0), tmesh_vertex(&fin, 0.5, 1, 0);
    tmesh_vertex(&fin, 0.5, -1, 0), tmesh_vertex(&fin, 0.5, 0, 1);
    tmesh_tri(&fin, 0, 1, 2), tmesh_tri(&fin, 1, 0, 3), tmesh_tri(&fin, 0, 1, 4);
    check_refine(&torus, "Loop torus", loop);
    check_refine(&open, "Loop open grid", loop);
    check_refine(&open, "Loop open grid, Hoppe", hoppe);
    check_refine(&fin, "Loop fin", loop);
    tmesh quads = make_torus(12, 8, 0), cube = make_cut_cube(3);
    check_refine(&quads, "Doo-Sabin torus", ds);
    check_refine(&cube, "Doo-Sabin cube", ds);
    /* Refused before counting, as the refinement itself would refuse them:
     * Hoppe's rules and a doubled triangle (two triangles on the same three
     * vertices), Doo-Sabin beyond one level and a vertex on two faces (a
     * cube with a vertex in the middle of an edge). */
    tmesh doubled = make_torus(12, 8, 1);
    const int32_t a = tmesh_vertex(&doubled, 5, 0, 0), b = tmesh_vertex(&doubled, 6, 0, 0),
                  c = tmesh_vertex(&doubled, 5, 1, 0);
    tmesh_tri(&doubled, a, b, c), tmesh_tri(&doubled, a, c, b);
    spia_mesh view = tmesh_view(&doubled);
    int32_t nv, nf;
    int64_t nc;
    spia_status st;
    CHECK(spia_refine_size(&view, &hoppe, 2, &nv, &nf, &nc, &st) == SPIA_ERROR_TOPOLOGY &&
              strstr(st.message, "doubled triangle") != NULL && st.index == a,
          "Hoppe, doubled triangle: %s", st.message);
    check_refine(&doubled, "Loop doubled triangle", loop);  /* OpenSubdiv's rules take it */
    tmesh split;
    memset(&split, 0, sizeof split);
    static const double corner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                                        {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
    for (int i = 0; i < 8; ++i) tmesh_vertex(&split, corner[i][0], corner[i][1], corner[i][2]);
    tmesh_vertex(&split, 0.5, 0, 0);
    static const int32_t bottom[5] = {0, 3, 2, 1, 8}, front[5] = {0, 8, 1, 5, 4};
    tmesh_face(&split, 5, bottom), tmesh_face(&split, 5, front);
    tmesh_quad(&split, 4, 5, 6, 7), tmesh_quad(&split, 1, 2, 6, 5), tmesh_quad(&split, 2, 3, 7, 6),
        tmesh_quad(&split, 3, 0, 4, 7);
    view = tmesh_view(&split);
    CHECK(spia_refine_size(&view, &ds, 1, &nv, &nf, &nc, &st) == SPIA_OK, "Doo-Sabin, one level: %s", st.message);
    CHECK(spia_refine_size(&view, &ds, 2, &nv, &nf, &nc, &st) == SPIA_ERROR_TOPOLOGY &&
              strstr(st.message, "on two") != NULL && st.index == 8,
          "Doo-Sabin, a vertex on two faces: %s", st.message);
    tmesh_free(&torus), tmesh_free(&grid), tmesh_free(&open), tmesh_free(&fin), tmesh_free(&quads),
        tmesh_free(&cube), tmesh_free(&doubled), tmesh_free(&split);
}

int main(void) {
    check_refinements();
    tmesh m;
    m = make_torus(12, 8, 0);
    check_mesh(&m, "quad torus");
    check_warm_start(&m, "quad torus");
    tmesh_free(&m);
    m = make_torus(12, 8, 1);
    check_mesh(&m, "triangulated torus");
    tmesh_free(&m);
    m = make_cut_cube(4);
    check_mesh(&m, "cut cube");
    tmesh_free(&m);
    m = make_grid(7, 5);
    check_mesh(&m, "open grid");
    check_warm_start(&m, "open grid");
    tmesh_edge(&m, 9, 10, 0.5f);
    tmesh_edge(&m, 10, 11, 0.9f);
    tmesh_vertex_crease(&m, 20, 0.7f);
    check_mesh(&m, "creased grid");
    tmesh_free(&m);
    static const char *names[] = {"mushroom.obj", "double-torus.obj", "teapot.obj", "catmark_car.obj"};
    for (int i = 0; i < 4; ++i) {
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", SPIA_TEST_DATA_DIR, names[i]);
        CHECK(read_obj(path, &m), "cannot read %s", path);
        check_mesh(&m, names[i]);
        tmesh_free(&m);
    }

    /* Loop, both boundary rules, every method, staged or not (the formulas
     * themselves are checked against numpy in tests/python/test_loop.py). */
    {
        tmesh shapes[2] = {make_torus(12, 8, 1), make_grid(6, 5)};
        /* Triangulate the grid. */
        tmesh tri;
        memset(&tri, 0, sizeof tri);
        for (int32_t v = 0; v < shapes[1].nv; ++v)
            tmesh_vertex(&tri, shapes[1].pos[3 * v], shapes[1].pos[3 * v + 1], shapes[1].pos[3 * v + 2]);
        for (int32_t f = 0; f < shapes[1].nf; ++f) {
            const int32_t *q = shapes[1].fv + 4 * f;
            tmesh_tri(&tri, q[0], q[1], q[2]);
            tmesh_tri(&tri, q[0], q[2], q[3]);
        }
        tmesh_free(&shapes[1]);
        shapes[1] = tri;
        for (int sh = 0; sh < 2; ++sh)
            for (int rule = 0; rule < 2; ++rule)
                for (int method = SPIA_METHOD_AUTO; method <= SPIA_METHOD_GS_PIA_FAST; ++method)
                    for (int staged = 0; staged < 2; ++staged) {
                        spia_mesh mesh = tmesh_view(&shapes[sh]);
                        spia_options o = spia_options_default();
                        o.scheme = SPIA_SCHEME_LOOP;
                        o.boundary_rule = (spia_boundary_rule)rule;
                        o.method = (spia_method)method;
                        o.staged = staged;
                        float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)shapes[sh].nv);
                        spia_report rep;
                        memset(&rep, 0, sizeof rep);
                        spia_status st;
                        spia_result r = spia_interpolate(&mesh, &o, cage, &rep, &st);
                        if (method == SPIA_METHOD_CG && sh == 1) {
                            /* open: no symmetric form */
                            CHECK(r == SPIA_ERROR_INVALID_ARGUMENT, "CG on an open Loop mesh: %s", spia_result_name(r));
                        } else {
                            CHECK(r == SPIA_OK, "Loop shape %d rule %d method %d staged %d: %s", sh, rule, method,
                                  staged, st.message);
                            CHECK(rep.max_error_relative <= 1e-6 + 4e-7, "Loop error %g", rep.max_error_relative);
                            if (staged && sh == 1)
                                CHECK(rep.stage_iterations[0] > 0 && rep.stage_iterations[1] > 0 &&
                                          rep.stage_iterations[0] + rep.stage_iterations[1] == rep.iterations,
                                      "stages %d + %d != %d", (int)rep.stage_iterations[0],
                                      (int)rep.stage_iterations[1], (int)rep.iterations);
                            if (method == SPIA_METHOD_WPIA)
                                CHECK(rep.weight > 1.0 && rep.weight < 2.0, "WPIA weight %g", rep.weight);
                        }
                        /* The refined preview passes through the targets. */
                        if (r == SPIA_OK && method == SPIA_METHOD_AUTO && !staged) {
                            tmesh c = shapes[sh];
                            c.pos = cage;
                            spia_mesh cm = tmesh_view(&c);
                            int32_t nv = 0, nf = 0;
                            int64_t nc = 0;
                            CHECK(spia_refine_size(&cm, &o, 2, &nv, &nf, &nc, &st) == SPIA_OK, "%s", st.message);
                            CHECK(nf == 16 * c.nf && nc == 3 * (int64_t)nf, "refined faces %d", (int)nf);
                            float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)nv);
                            int32_t *fs = (int32_t *)malloc(sizeof(int32_t) * (size_t)nf);
                            int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)nf);
                            CHECK(spia_refine(&cm, &o, 2, pos, fs, fv, &st) == SPIA_OK, "%s", st.message);
                            double worst = 0.0;
                            for (int64_t k = 0; k < 3 * (int64_t)c.nv; ++k)
                                worst = fmax(worst, fabs(pos[k] - shapes[sh].pos[k]));
                            CHECK(worst < 1e-4, "refined limit misses a target by %g", worst);
                            free(pos);
                            free(fs);
                            free(fv);
                        }
                        free(cage);
                    }
        tmesh_free(&shapes[0]);
        tmesh_free(&shapes[1]);
        /* Quads refused, with the count. */
        m = make_grid(3, 3);
        spia_mesh mesh = tmesh_view(&m);
        spia_options o = spia_options_default();
        o.scheme = SPIA_SCHEME_LOOP;
        spia_status st;
        spia_stencils *s = NULL;
        CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_ERROR_TOPOLOGY, "quads for Loop");
        CHECK(strstr(st.message, "9 of 9 faces") != NULL, "message: %s", st.message);
        tmesh_free(&m);
    }

    /* max_iterations: a usable cage and the code that says so. */
    {
        m = make_torus(12, 8, 0);
        spia_mesh mesh = tmesh_view(&m);
        spia_options o = spia_options_default();
        o.max_iterations = 2;
        o.method = SPIA_METHOD_PIA;
        float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
        spia_report rep;
        memset(&rep, 0, sizeof rep);
        spia_status st;
        spia_result r = spia_interpolate(&mesh, &o, cage, &rep, &st);
        CHECK(r == SPIA_MAX_ITERATIONS, "max_iterations: %s", spia_result_name(r));
        CHECK(rep.iterations == 2, "iterations %d", (int)rep.iterations);
        CHECK(rep.max_error_relative < rep.initial_max_error_relative, "no progress in 2 iterations");
        CHECK(strstr(st.message, "max_iterations") != NULL, "message: %s", st.message);
        free(cage);
        tmesh_free(&m);
    }

    /* A double-sided triangle beside a torus: its three vertices share one
     * limit point, the centroid, so they cannot be interpolated; they are
     * reported, least squares puts their limit point on their targets'
     * centroid, and the torus still converges. */
    for (int method = SPIA_METHOD_AUTO; method <= SPIA_METHOD_GS_PIA_FAST; ++method) {
        if (method == SPIA_METHOD_WPIA || method == SPIA_METHOD_CG) continue;
        m = make_torus(10, 6, 0);
        int32_t a = tmesh_vertex(&m, 5, 0, 0), b = tmesh_vertex(&m, 6, 0, 0), c = tmesh_vertex(&m, 5, 1, 0.5);
        tmesh_tri(&m, a, b, c);
        tmesh_tri(&m, b, a, c);
        spia_mesh mesh = tmesh_view(&m);
        spia_options o = spia_options_default();
        o.method = (spia_method)method;
        spia_status st;
        spia_stencils *s = NULL;
        CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "%s", st.message);
        float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
        uint8_t *flags = (uint8_t *)calloc((size_t)m.nv, 1);
        spia_report rep;
        memset(&rep, 0, sizeof rep);
        rep.unreachable = flags;
        spia_result r = spia_solve(s, m.pos, &o, cage, &rep, &st);
        CHECK(r == SPIA_STAGNATED, "double-sided triangle, method %d: %s", method, spia_result_name(r));
        CHECK(rep.unreachable_count == 3, "method %d: unreachable %d", method, (int)rep.unreachable_count);
        CHECK(flags[a] && flags[b] && flags[c], "wrong vertices flagged");
        const int32_t tri[3] = {a, b, c};
        CHECK(double_sided_miss(s, m.pos, cage, tri) <= 1e-6 * diag_of(&m),
              "method %d: the triangle's limit point %g from its targets' centroid", method,
              double_sided_miss(s, m.pos, cage, tri));
        CHECK(rep.method == SPIA_METHOD_LEAST_SQUARES, "method %d: reported %d", method, (int)rep.method);
        double err = limit_error(s, &m, cage, flags);
        CHECK(err <= 1e-6 + 4e-7, "the rest: %g", err);
        CHECK(rep.reachable_max_error_relative <= 1e-6 + 4e-7, "reported rest %g", rep.reachable_max_error_relative);
        CHECK(strstr(st.message, "3 vertices cannot be reached") != NULL, "message: %s", st.message);
        /* One message for the whole solve: the method that stagnated, that
         * least squares took over, and the least-squares result as the
         * report gives it (not the iteration's own stagnation message). */
        CHECK(st.code == r, "method %d: status code %d, returned %d", method, (int)st.code, (int)r);
        static const char *const names[] = {"AUTO", "PIA", "GS_PIA", "CHEBYSHEV", "WPIA", "CG", "GS_PIA_FAST"};
        char gave_up[32] = "";
        int after = -1;
        CHECK(sscanf(st.message, "%31s stagnated after %d iterations and least squares took over:", gave_up,
                     &after) == 2 &&
                  after > 0 && after <= rep.iterations,
              "method %d (%d iterations): message: %s", method, (int)rep.iterations, st.message);
        if (method != SPIA_METHOD_AUTO)
            CHECK(strcmp(gave_up, names[method]) == 0, "method %d: message names %s", method, gave_up);
        char result[128];
        snprintf(result, sizeof result, "it puts them within %.3g of the diagonal, the others within %.3g",
                 rep.max_error_relative, rep.reachable_max_error_relative);
        CHECK(strstr(st.message, result) != NULL, "method %d: message %s; report: %s", method, st.message, result);
        CHECK(strstr(st.message, "cannot reach their targets") == NULL, "method %d: GS_PIA_FAST's own message: %s",
              method, st.message);
        /* Without a report the message counts the same iterations. */
        char with_report[SPIA_MESSAGE_SIZE];
        memcpy(with_report, st.message, sizeof with_report);
        CHECK(spia_solve(s, m.pos, &o, cage, NULL, &st) == SPIA_STAGNATED && strcmp(st.message, with_report) == 0,
              "method %d without a report: %s", method, st.message);
        free(cage);
        free(flags);
        spia_stencils_free(s);
        tmesh_free(&m);
    }
    TEST_MAIN_END();
}
