// SPDX-License-Identifier: GPL-3.0-or-later
/* Every bad input comes back as its result code with a message; nothing is
 * written to the caller's buffers and nothing is printed. */
#include "support.h"

static float cage_sentinel = 12345.0f;

/* Runs spia_interpolate and spia_limit_stencils_create on the mesh and
 * checks both return `expect` with a non-empty message. */
static void expect_code(const spia_mesh *mesh, const spia_options *o, spia_result expect, const char *what) {
    float cage[3 * 64];
    for (int i = 0; i < 3 * 64; ++i) cage[i] = cage_sentinel;
    spia_status st;
    memset(&st, 0, sizeof st);
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    spia_result r = spia_interpolate(mesh, o, cage, &rep, &st);
    CHECK(r == expect, "%s: got %s, expected %s (%s)", what, spia_result_name(r), spia_result_name(expect), st.message);
    CHECK(st.code == expect, "%s: status code %d", what, (int)st.code);
    CHECK(strlen(st.message) > 10, "%s: message '%s'", what, st.message);
    CHECK(rep.result == expect, "%s: report result %d", what, (int)rep.result);
    int untouched = 1;
    for (int i = 0; i < 3 * 64; ++i) untouched &= cage[i] == cage_sentinel;
    CHECK(untouched, "%s: the cage buffer was written", what);
    spia_stencils *s = (spia_stencils *)&st; /* must be reset to NULL */
    r = spia_limit_stencils_create(mesh, o, &s, &st);
    CHECK(r == expect, "%s (stencils): got %s", what, spia_result_name(r));
    CHECK(s == NULL, "%s: stencils not NULL on failure", what);
}

/* Faults in a scan of 400 x 400 quads (160,000 faces: three of the pieces
 * its checks work in), in its later pieces: the first in the mesh's order
 * is the one reported, and nothing is made. */
static const struct {
    int64_t nan_vertex, small_face, bad_face;
    spia_result expect;
    int64_t index;
} scan_cases[] = {
    {150000, 70000, -1, SPIA_ERROR_NONFINITE, 150000},
    {-1, 140000, 100000, SPIA_ERROR_INDEX_RANGE, 100000},
    {-1, 131072, 150000, SPIA_ERROR_FACE_SIZE, 131072},
    {-1, -1, 159999, SPIA_ERROR_INDEX_RANGE, 159999},
};

static int cancel_now(void *user, int32_t it, double err) {
    (void)it;
    (void)err;
    ++*(int *)user;
    return 1;
}

static int cancel_at_3(void *user, int32_t it, double err) {
    (void)user;
    (void)err;
    return it >= 3;
}

int main(void) {
    tmesh g = make_grid(3, 3);
    spia_options o = spia_options_default();
    spia_mesh m;

    m = tmesh_view(&g);
    expect_code(NULL, &o, SPIA_ERROR_INVALID_ARGUMENT, "NULL mesh");

    m = tmesh_view(&g);
    m.vertex_count = -1;
    expect_code(&m, &o, SPIA_ERROR_INVALID_ARGUMENT, "negative vertex count");

    m = tmesh_view(&g);
    m.vertex_count = 0;
    expect_code(&m, &o, SPIA_ERROR_EMPTY_MESH, "no vertices");

    m = tmesh_view(&g);
    m.face_count = 0;
    expect_code(&m, &o, SPIA_ERROR_EMPTY_MESH, "no faces");

    m = tmesh_view(&g);
    m.positions = NULL;
    expect_code(&m, &o, SPIA_ERROR_INVALID_ARGUMENT, "NULL positions");

    {
        tmesh t = make_grid(3, 3);
        t.sizes[4] = 2; /* a two-vertex face; the rest shift but stay in range */
        m = tmesh_view(&t);
        m.face_count = 5;
        expect_code(&m, &o, SPIA_ERROR_FACE_SIZE, "face with 2 vertices");
        tmesh_free(&t);
    }
    {
        tmesh t = make_grid(3, 3);
        t.fv[7] = t.nv;
        m = tmesh_view(&t);
        expect_code(&m, &o, SPIA_ERROR_INDEX_RANGE, "face index = vertex_count");
        t.fv[7] = -1;
        expect_code(&m, &o, SPIA_ERROR_INDEX_RANGE, "negative face index");
        tmesh_free(&t);
    }
    {
        tmesh t = make_grid(3, 3);
        t.fv[5] = t.fv[6];
        m = tmesh_view(&t);
        expect_code(&m, &o, SPIA_ERROR_DEGENERATE_FACE, "face repeating a vertex");
        tmesh_free(&t);
    }
    {
        tmesh t = make_grid(3, 3);
        t.pos[3 * 5 + 1] = NAN;
        m = tmesh_view(&t);
        expect_code(&m, &o, SPIA_ERROR_NONFINITE, "NaN position");
        t.pos[3 * 5 + 1] = INFINITY;
        expect_code(&m, &o, SPIA_ERROR_NONFINITE, "infinite position");
        tmesh_free(&t);
    }
    {
        tmesh t = make_grid(3, 3);
        tmesh_edge(&t, 0, 1, NAN);
        m = tmesh_view(&t);
        expect_code(&m, &o, SPIA_ERROR_NONFINITE, "NaN crease");
        t.edge_creases[0] = 1.5f;
        expect_code(&m, &o, SPIA_ERROR_INVALID_ARGUMENT, "crease above 1");
        t.edge_creases[0] = 0.5f;
        t.edges[1] = 99;
        expect_code(&m, &o, SPIA_ERROR_INDEX_RANGE, "edge index out of range");
        t.edges[1] = 0;
        expect_code(&m, &o, SPIA_ERROR_DEGENERATE_FACE, "edge joining a vertex to itself");
        m.edges = NULL;
        expect_code(&m, &o, SPIA_ERROR_INVALID_ARGUMENT, "edges NULL with a count");
        tmesh_free(&t);
    }
    {
        tmesh t = make_grid(3, 3);
        tmesh_vertex_crease(&t, 3, -0.5f);
        m = tmesh_view(&t);
        expect_code(&m, &o, SPIA_ERROR_INVALID_ARGUMENT, "negative vertex crease");
        tmesh_free(&t);
    }

    m = tmesh_view(&g);
    spia_options bad = o;
    bad.quality = 11;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "quality 11");
    bad = o;
    bad.quality = -2;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "quality -2");
    bad = o;
    bad.tolerance = -1.0;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "negative tolerance");
    bad = o;
    bad.tolerance = NAN;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "NaN tolerance");
    bad = o;
    bad.max_iterations = -5;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "negative max_iterations");
    bad = o;
    bad.scheme = (spia_scheme)7;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "unknown scheme");
    bad = o;
    bad.method = (spia_method)9;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "unknown method");
    bad.method = (spia_method)(SPIA_METHOD_LEAST_SQUARES + 1);
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "the method after the last");
    bad = o;
    bad.solve_flags = 16;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "unknown solve flag");
    bad.solve_flags = -1;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "negative solve flags");
    bad = o;
    bad = o;
    bad.boundary_smooth = (spia_boundary_smooth)4;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "unknown boundary_smooth");
    bad = o;
    bad.opensubdiv_version = -30700;
    expect_code(&m, &bad, SPIA_ERROR_INVALID_ARGUMENT, "negative opensubdiv_version");

    /* Cancellation, before the stencils and during the solve. */
    int calls = 0;
    bad = o;
    bad.progress = cancel_now;
    bad.progress_user_data = &calls;
    expect_code(&m, &bad, SPIA_ERROR_CANCELLED, "cancel at once");
    CHECK(calls >= 1, "progress callback never called");
    {
        bad = o;
        bad.progress = cancel_at_3;
        bad.method = SPIA_METHOD_PIA;
        bad.tolerance = 1e-12;
        float cage[3 * 16];
        for (int i = 0; i < 3 * 16; ++i) cage[i] = cage_sentinel;
        spia_report rep;
        memset(&rep, 0, sizeof rep);
        spia_status st2;
        spia_result r = spia_interpolate(&m, &bad, cage, &rep, &st2);
        CHECK(r == SPIA_ERROR_CANCELLED, "cancel during the solve: %s", spia_result_name(r));
        CHECK(rep.iterations == 3, "cancelled after %d iterations", (int)rep.iterations);
        CHECK(cage[0] == cage_sentinel, "cage written after cancel");
        bad.method = SPIA_METHOD_GS_PIA_FAST;
        memset(&rep, 0, sizeof rep);
        r = spia_interpolate(&m, &bad, cage, &rep, &st2);
        CHECK(r == SPIA_ERROR_CANCELLED && rep.iterations == 3, "GS_PIA_FAST cancelled: %s after %d iterations",
              spia_result_name(r), (int)rep.iterations);
        CHECK(cage[0] == cage_sentinel, "cage written after cancel");
    }

    /* NULL outputs. */
    spia_status st;
    CHECK(spia_interpolate(&m, &o, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT, "NULL cage");
    CHECK(spia_limit_stencils_create(&m, &o, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT, "NULL out");
    CHECK(spia_solve(NULL, g.pos, &o, g.pos, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT, "NULL stencils");
    CHECK(spia_stencils_apply(NULL, NULL, NULL) == SPIA_ERROR_INVALID_ARGUMENT, "apply on NULL");
    spia_stencils_free(NULL);

    /* Targets with a NaN given to spia_solve. */
    {
        spia_stencils *s = NULL;
        CHECK(spia_limit_stencils_create(&m, &o, &s, &st) == SPIA_OK, "stencils: %s", st.message);
        float *targets = (float *)malloc(sizeof(float) * 3 * (size_t)g.nv);
        float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)g.nv);
        memcpy(targets, g.pos, sizeof(float) * 3 * (size_t)g.nv);
        targets[4] = NAN;
        for (int i = 0; i < 3 * g.nv; ++i) cage[i] = cage_sentinel;
        CHECK(spia_solve(s, targets, &o, cage, NULL, &st) == SPIA_ERROR_NONFINITE, "NaN target: %s", st.message);
        CHECK(cage[0] == cage_sentinel, "cage written on failure");
        free(targets);
        free(cage);
        spia_stencils_free(s);
    }

    /* The scan_cases. */
    {
        const int32_t side = 400, nv = (side + 1) * (side + 1), nf = side * side;
        for (size_t c = 0; c < sizeof scan_cases / sizeof scan_cases[0]; ++c) {
            int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)nf);
            int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * 4 * (size_t)nf);
            float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)nv);
            for (int32_t v = 0; v < nv; ++v)
                pos[3 * v] = (float)(v % (side + 1)), pos[3 * v + 1] = (float)(v / (side + 1)), pos[3 * v + 2] = 0.0f;
            for (int32_t f = 0; f < nf; ++f) {
                const int32_t a = f / side * (side + 1) + f % side;
                sizes[f] = 4;
                fv[4 * f] = a, fv[4 * f + 1] = a + 1, fv[4 * f + 2] = a + side + 2, fv[4 * f + 3] = a + side + 1;
            }
            if (scan_cases[c].nan_vertex >= 0) pos[3 * scan_cases[c].nan_vertex + 2] = NAN;
            if (scan_cases[c].bad_face >= 0) fv[4 * scan_cases[c].bad_face + 1] = nv;
            if (scan_cases[c].small_face >= 0) sizes[scan_cases[c].small_face] = 2; /* its corners go to the next face */
            spia_mesh sm;
            memset(&sm, 0, sizeof sm);
            sm.vertex_count = nv, sm.positions = pos, sm.face_count = nf, sm.face_sizes = sizes, sm.face_vertices = fv;
            spia_scan *scan = (spia_scan *)&st; /* must be reset to NULL */
            const spia_result r = spia_scan_create(&sm, &scan, &st);
            CHECK(r == scan_cases[c].expect && st.index == scan_cases[c].index, "scan case %d: %s at %lld (%s)",
                  (int)c, spia_result_name(r), (long long)st.index, st.message);
            CHECK(scan == NULL, "scan case %d: a scan was made", (int)c);
            free(sizes), free(fv), free(pos);
        }
    }

    /* spia_sharpness: a count pointer, known flags, a valid mesh; then a
     * count of the creased edges alone, with the arrays NULL. */
    {
        spia_mesh gm = tmesh_view(&g);
        int32_t count = -1;
        CHECK(spia_sharpness(&gm, NULL, 0, NULL, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT,
              "sharpness without a count: %s", st.message);
        CHECK(spia_sharpness(&gm, NULL, 6, &count, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT &&
                  strstr(st.message, "flags"),
              "sharpness with unknown flags: %s", st.message);
        CHECK(spia_sharpness(NULL, NULL, 0, &count, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT,
              "sharpness of no mesh: %s", st.message);
        CHECK(spia_sharpness(&gm, NULL, SPIA_SHARPNESS_NO_TWO_EDGE_RULE, &count, NULL, NULL, NULL, &st) == SPIA_OK &&
                  count == 0,
              "sharpness of an uncreased mesh: %d (%s)", (int)count, st.message);
    }

    /* Every code has a distinct name. */
    for (int c = -11; c <= 2; ++c)
        for (int d = c + 1; d <= 2; ++d)
            CHECK(strcmp(spia_result_name((spia_result)c), spia_result_name((spia_result)d)) != 0, "names %d %d", c, d);
    CHECK(strcmp(spia_result_name((spia_result)99), "SPIA_UNKNOWN_RESULT") == 0, "unknown code name");
    CHECK(spia_version() == SPIA_VERSION_MAJOR * 10000 + SPIA_VERSION_MINOR * 100 + SPIA_VERSION_PATCH, "version");

    tmesh_free(&g);
    TEST_MAIN_END();
}
