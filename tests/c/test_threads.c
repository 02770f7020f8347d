// SPDX-License-Identifier: GPL-3.0-or-later
/* Thread counts: the stencil table and every solver's cage must be the same,
 * to the bit, whatever spia_options.threads says.  The meshes are large
 * enough (over 50,000 rows) for the solvers to share their products, and
 * carry random semi-sharp creases so that stencil rows come from Bfr at both
 * its default and its isolation levels. */
#include "support.h"

static spia_stencils *stencils_with(const tmesh *m, spia_scheme scheme, int32_t threads) {
    spia_mesh mesh = tmesh_view(m);
    spia_options o = spia_options_default();
    o.scheme = scheme;
    o.threads = threads;
    spia_stencils *s = NULL;
    spia_status st;
    CHECK(spia_limit_stencils_create(&mesh, &o, &s, &st) == SPIA_OK, "threads=%d: %s", (int)threads, st.message);
    return s;
}

static int same_table(const spia_stencils *a, const spia_stencils *b) {
    const int32_t n = spia_stencils_row_count(a);
    const int64_t nnz = spia_stencils_weight_count(a);
    if (n != spia_stencils_row_count(b) || nnz != spia_stencils_weight_count(b)) return 0;
    int64_t *oa = (int64_t *)malloc(sizeof(int64_t) * ((size_t)n + 1)), *ob = (int64_t *)malloc(sizeof(int64_t) * ((size_t)n + 1));
    int32_t *ia = (int32_t *)malloc(sizeof(int32_t) * (size_t)nnz), *ib = (int32_t *)malloc(sizeof(int32_t) * (size_t)nnz);
    double *wa = (double *)malloc(sizeof(double) * (size_t)nnz), *wb = (double *)malloc(sizeof(double) * (size_t)nnz);
    spia_stencils_copy_csr(a, oa, ia, wa);
    spia_stencils_copy_csr(b, ob, ib, wb);
    int same = memcmp(oa, ob, sizeof(int64_t) * ((size_t)n + 1)) == 0 && memcmp(ia, ib, sizeof(int32_t) * (size_t)nnz) == 0 &&
               memcmp(wa, wb, sizeof(double) * (size_t)nnz) == 0;
    free(oa); free(ob); free(ia); free(ib); free(wa); free(wb);
    return same;
}

static void check(tmesh *m, const char *name, spia_scheme scheme) {
    spia_stencils *one = stencils_with(m, scheme, 1), *two = stencils_with(m, scheme, 2), *three = stencils_with(m, scheme, 3);
    if (!one || !two || !three) return;
    CHECK(same_table(one, two), "%s: stencils differ between 1 and 2 threads", name);
    CHECK(same_table(one, three), "%s: stencils differ between 1 and 3 threads", name);
    /* (WPIA's steps are PIA's, with another weight) */
    static const spia_method methods[] = {SPIA_METHOD_AUTO,        SPIA_METHOD_PIA,         SPIA_METHOD_GS_PIA,
                                          SPIA_METHOD_CHEBYSHEV,   SPIA_METHOD_CG,          SPIA_METHOD_GS_PIA,
                                          SPIA_METHOD_GS_PIA_FAST, SPIA_METHOD_GS_PIA_FAST, SPIA_METHOD_GS_PIA_FAST};
    static const int32_t flags[] = {0, 0, 0, 0, 0, SPIA_SOLVE_MULTICOLOUR, 0, SPIA_SOLVE_FIRST_STEP,
                                    SPIA_SOLVE_DOUBLE_SWEEPS};
    const size_t size = sizeof(float) * 3 * (size_t)m->nv;
    float *c1 = (float *)malloc(size), *c2 = (float *)malloc(size);
    spia_method auto_method = SPIA_METHOD_AUTO;
    for (size_t k = 0; k < sizeof methods / sizeof methods[0]; ++k) {
        spia_options o = spia_options_default();
        o.method = methods[k];
        o.solve_flags = flags[k];
        o.tolerance = 1e-5;
        o.max_iterations = 40;
        spia_report r1, r2;
        memset(&r1, 0, sizeof r1);
        memset(&r2, 0, sizeof r2);
        spia_status st;
        o.threads = 1;
        spia_result a = spia_solve(one, m->pos, &o, c1, &r1, &st);
        /* CG is refused where creases break the symmetry, the same way for both */
        CHECK(a >= 0 || (methods[k] == SPIA_METHOD_CG && a == SPIA_ERROR_INVALID_ARGUMENT), "%s method %d: %s", name,
              (int)methods[k], st.message);
        if (methods[k] == SPIA_METHOD_AUTO) auto_method = r1.method;
        o.threads = 2;
        spia_result b = spia_solve(one, m->pos, &o, c2, &r2, &st);
        CHECK(a == b && r1.iterations == r2.iterations && r1.method == r2.method,
              "%s method %d: %d/%d iterations with 1/2 threads", name, (int)methods[k], (int)r1.iterations,
              (int)r2.iterations);
        CHECK(a < 0 || memcmp(c1, c2, size) == 0, "%s method %d: cages differ between 1 and 2 threads", name,
              (int)methods[k]);
            CHECK(r1.max_error == r2.max_error, "%s method %d: reported errors differ", name, (int)methods[k]);
        if (methods[k] == SPIA_METHOD_GS_PIA_FAST || (flags[k] & SPIA_SOLVE_MULTICOLOUR)) {
            /* the threads really share the sweeps here: three of them too */
            o.threads = 3;
            spia_result c = spia_solve(one, m->pos, &o, c2, &r2, &st);
            CHECK(c == a && r2.iterations == r1.iterations && memcmp(c1, c2, size) == 0,
                  "%s method %d flags %d: cages differ between 1 and 3 threads", name, (int)methods[k], (int)flags[k]);
        }
    }
    printf("%-32s %7d vertices: same stencils and cages with 1, 2 (and 3) threads (AUTO took method %d)\n", name,
           (int)m->nv, (int)auto_method);
    free(c1);
    free(c2);
    spia_stencils_free(one);
    spia_stencils_free(two);
    spia_stencils_free(three);
}

/* The torus of make_torus, with its arrays allocated once (growing them
 * vertex by vertex takes minutes under AddressSanitizer at this size). */
static tmesh big_torus(int nu, int nv, int triangles) {
    tmesh m;
    memset(&m, 0, sizeof m);
    m.nv = nu * nv;
    m.pos = (float *)malloc(sizeof(float) * 3 * (size_t)m.nv);
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv;
            float *p = m.pos + 3 * (size_t)(j * nu + i);
            p[0] = (float)((2 + 0.7 * cos(v)) * cos(u));
            p[1] = (float)((2 + 0.7 * cos(v)) * sin(u));
            p[2] = (float)(0.7 * sin(v));
        }
    m.nf = nu * nv * (triangles ? 2 : 1);
    m.nfv = (int64_t)nu * nv * 4 * (triangles ? 6 : 4) / 4;
    m.sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)m.nf);
    m.fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)m.nfv);
    int64_t k = 0;
    int32_t f = 0;
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            int32_t a = j * nu + i, b = j * nu + (i + 1) % nu, c = ((j + 1) % nv) * nu + (i + 1) % nu,
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

int main(void) {
    tmesh m = big_torus(320, 170, 0);
    uint64_t seed = 99;
    m.edges = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)m.nf);
    m.edge_creases = (float *)malloc(sizeof(float) * (size_t)m.nf);
    for (int32_t f = 0; f < m.nf; ++f) {
        seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
        if ((seed >> 40) % 10 == 0) {
            const int32_t *q = m.fv + 4 * (int64_t)f;
            m.edges[2 * m.ne] = q[0];
            m.edges[2 * m.ne + 1] = q[1];
            m.edge_creases[m.ne++] = (seed >> 20) % 2 ? 0.5f : 0.3f;
        }
    }
    /* roughen the target so that AUTO takes GS-PIA, as on scans */
    for (int64_t k = 0; k < 3 * (int64_t)m.nv; ++k) {
        seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
        m.pos[k] += 0.002f * (float)((double)(seed >> 11) / 9007199254740992.0 - 0.5);
    }
    check(&m, "creased rough quad torus", SPIA_SCHEME_CATMULL_CLARK);
    tmesh_free(&m);
    m = big_torus(320, 170, 1);
    check(&m, "smooth triangulated torus (Loop)", SPIA_SCHEME_LOOP);
    tmesh_free(&m);
    TEST_MAIN_END();
}
