// SPDX-License-Identifier: GPL-3.0-or-later
/* Closed-form limit masks (Blender's modifier matches them, see
 * ../shared facts): the library's Catmull-Clark stencils must equal
 *   interior vertex of valence n, all faces quads:
 *       (n^2 V + 4 sum E_i + sum F_i) / (n (n + 5))
 *   smooth boundary vertex:       (E_prev + 4 V + E_next) / 6
 *   corner, PRESERVE_CORNERS:     V
 *   corner, boundary_smooth ALL:  L + 4^-Q (V - L),  L = (E1 + 4 V + E2) / 6
 */
#include "support.h"

typedef struct table {
    spia_stencils *s;
    int64_t *off;
    int32_t *idx;
    double *w;
} table;

static table get_table(const tmesh *m, spia_options o) {
    table t;
    memset(&t, 0, sizeof t);
    spia_mesh mesh = tmesh_view(m);
    spia_status st;
    spia_result r = spia_limit_stencils_create(&mesh, &o, &t.s, &st);
    CHECK(r == SPIA_OK, "stencils: %s", st.message);
    if (r != SPIA_OK) exit(1);
    int64_t nnz = spia_stencils_weight_count(t.s);
    t.off = (int64_t *)malloc(sizeof(int64_t) * (size_t)(m->nv + 1));
    t.idx = (int32_t *)malloc(sizeof(int32_t) * (size_t)nnz);
    t.w = (double *)malloc(sizeof(double) * (size_t)nnz);
    spia_stencils_copy_csr(t.s, t.off, t.idx, t.w);
    return t;
}

static void free_table(table *t) {
    spia_stencils_free(t->s);
    free(t->off);
    free(t->idx);
    free(t->w);
}

/* Expected interior mask of v in a closed all-quad mesh. */
static void interior_mask(const tmesh *m, int32_t v, double *expect) {
    int64_t c = 0;
    int n = 0;
    for (int32_t j = 0; j < m->nv; ++j) expect[j] = 0.0;
    for (int32_t f = 0; f < m->nf; ++f, c += 4)
        for (int k = 0; k < 4; ++k)
            if (m->fv[c + k] == v) ++n;
    double d = (double)n * (n + 5);
    c = 0;
    for (int32_t f = 0; f < m->nf; ++f, c += 4)
        for (int k = 0; k < 4; ++k)
            if (m->fv[c + k] == v) {
                /* Each edge neighbour is seen from its two faces: 2 x 2/d. */
                expect[m->fv[c + (k + 1) % 4]] += 2.0 / d;
                expect[m->fv[c + (k + 3) % 4]] += 2.0 / d;
                expect[m->fv[c + (k + 2) % 4]] += 1.0 / d;
            }
    expect[v] = (double)n * n / d;
}

static double max_row_diff(const table *t, int32_t v, const double *expect, int32_t n, double *row) {
    stencil_row(t->off, t->idx, t->w, v, row, n);
    double worst = 0.0;
    for (int32_t j = 0; j < n; ++j) worst = fmax(worst, fabs(row[j] - expect[j]));
    return worst;
}

static void check_closed(const tmesh *m, const char *name) {
    for (int q = 1; q <= 10; q += 3) {
        spia_options o = spia_options_default();
        o.quality = q;
        table t = get_table(m, o);
        double *expect = (double *)malloc(sizeof(double) * (size_t)m->nv);
        double *row = (double *)malloc(sizeof(double) * (size_t)m->nv);
        double worst = 0.0;
        for (int32_t v = 0; v < m->nv; ++v) {
            interior_mask(m, v, expect);
            worst = fmax(worst, max_row_diff(&t, v, expect, m->nv, row));
        }
        CHECK(worst < 1e-12, "%s quality %d: interior masks off by %g", name, q, worst);
        free(expect);
        free(row);
        free_table(&t);
    }
}

static void check_grid(void) {
    const int nx = 5, ny = 4;
    tmesh m = make_grid(nx, ny);
    double *expect = (double *)malloc(sizeof(double) * (size_t)m.nv);
    double *row = (double *)malloc(sizeof(double) * (size_t)m.nv);
    for (int bs = 0; bs < 2; ++bs)
        for (int q = 1; q <= 10; q += (q < 3 ? 1 : 3)) {
            spia_options o = spia_options_default();
            o.boundary_smooth = bs ? SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS : SPIA_BOUNDARY_SMOOTH_ALL;
            o.quality = q;
            table t = get_table(&m, o);
            double w_interior = 0, w_boundary = 0, w_corner = 0;
            for (int j = 0; j <= ny; ++j)
                for (int i = 0; i <= nx; ++i) {
                    int32_t v = j * (nx + 1) + i;
                    int bi = i == 0 || i == nx, bj = j == 0 || j == ny;
                    for (int32_t k = 0; k < m.nv; ++k) expect[k] = 0.0;
                    if (!bi && !bj) {
                        expect[v] = 16.0 / 36;
                        for (int dj = -1; dj <= 1; ++dj)
                            for (int di = -1; di <= 1; ++di)
                                if (di || dj) expect[v + dj * (nx + 1) + di] = (di && dj) ? 1.0 / 36 : 4.0 / 36;
                        w_interior = fmax(w_interior, max_row_diff(&t, v, expect, m.nv, row));
                    } else if (bi != bj) {
                        int32_t a = bi ? v - (nx + 1) : v - 1, b = bi ? v + (nx + 1) : v + 1;
                        expect[v] = 4.0 / 6;
                        expect[a] = expect[b] = 1.0 / 6;
                        w_boundary = fmax(w_boundary, max_row_diff(&t, v, expect, m.nv, row));
                    } else {
                        int32_t a = v + (i == 0 ? 1 : -1), b = v + (j == 0 ? nx + 1 : -(nx + 1));
                        if (bs) {
                            expect[v] = 1.0;
                        } else {
                            double f = pow(4.0, -q);
                            expect[v] = (1 - f) * 4.0 / 6 + f;
                            expect[a] = expect[b] = (1 - f) / 6;
                        }
                        w_corner = fmax(w_corner, max_row_diff(&t, v, expect, m.nv, row));
                    }
                }
            CHECK(w_interior < 1e-12, "grid bs=%d q=%d interior off by %g", bs, q, w_interior);
            CHECK(w_boundary < 1e-12, "grid bs=%d q=%d boundary off by %g", bs, q, w_boundary);
            /* Blender evaluates float patches: the corner formula holds to float rounding. */
            CHECK(w_corner < 1e-6, "grid bs=%d q=%d corner off by %g", bs, q, w_corner);
            free_table(&t);
        }
    free(expect);
    free(row);
    tmesh_free(&m);
}

int main(void) {
    tmesh torus = make_torus(9, 7, 0);
    check_closed(&torus, "torus");
    tmesh_free(&torus);
    tmesh cube = make_cut_cube(3);
    check_closed(&cube, "cut cube (valence 3 and 4)");
    tmesh_free(&cube);
    check_grid();
    TEST_MAIN_END();
}
