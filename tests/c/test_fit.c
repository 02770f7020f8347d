// SPDX-License-Identifier: GPL-3.0-or-later
/* Scans and fitting: closest points against a brute-force search over every
 * triangle, a fit that brings a coarse torus cage onto a fine torus, and the
 * bad inputs (codes, messages, buffers untouched). */
#include "support.h"

/* Squared distance from p to triangle abc, by minimising over a fine
 * barycentric lattice refined around the best node: slow, independent of
 * the library's region tests, and exact enough (1e-9) for the check. */
static double brute_triangle_d2(const double p[3], const float *a, const float *b, const float *c) {
    double best = INFINITY, bu = 1.0 / 3.0, bv = 1.0 / 3.0, step = 0.5;
    for (int pass = 0; pass < 40; ++pass) {
        double cu = bu, cv = bv;
        for (int i = -4; i <= 4; ++i)
            for (int j = -4; j <= 4; ++j) {
                double u = cu + i * step / 4, v = cv + j * step / 4;
                if (u < 0) u = 0;
                if (v < 0) v = 0;
                if (u + v > 1) {
                    const double s = u + v;
                    u /= s, v /= s;
                }
                double d2 = 0.0;
                for (int k = 0; k < 3; ++k) {
                    const double x = (1 - u - v) * a[k] + u * b[k] + v * c[k] - p[k];
                    d2 += x * x;
                }
                if (d2 < best) best = d2, bu = u, bv = v;
            }
        step *= 0.6;
    }
    return best;
}

static int cancel_after_first(void *user, int32_t round, double err) {
    (void)err;
    (void)user;
    return round >= 1;
}

int main(void) {
    spia_status st;
    /* A fine triangulated torus as the scan; a coarse quad torus as the cage. */
    tmesh fine = make_torus(96, 48, 1);
    spia_mesh fm = tmesh_view(&fine);
    spia_scan *scan = NULL;
    spia_result r = spia_scan_create(&fm, &scan, &st);
    CHECK(r == SPIA_OK && scan, "scan: %s", st.message);
    const double diag = spia_scan_diagonal(scan);
    CHECK(fabs(diag - sqrt(2 * 5.4 * 5.4 + 1.4 * 1.4)) < 1e-2, "diagonal %g", diag);

    /* Closest points against brute force over all triangles. */
    {
        enum { Q = 40 };
        float pts[3 * Q], cl[3 * Q], nr[3 * Q], d[Q];
        int32_t face[Q];
        srand(7);
        for (int i = 0; i < 3 * Q; ++i) pts[i] = (float)(6.0 * rand() / RAND_MAX - 3.0);
        r = spia_scan_closest_points(scan, Q, pts, cl, nr, d, face, NULL, &st);
        CHECK(r == SPIA_OK, "closest: %s", st.message);
        for (int q = 0; q < Q; ++q) {
            const double p[3] = {pts[3 * q], pts[3 * q + 1], pts[3 * q + 2]};
            /* Every triangle that may hold the closest point: its centroid
             * distance minus its radius does not exceed the nearest vertex's
             * distance. */
            double upper = INFINITY;
            for (int32_t v = 0; v < fine.nv; ++v) {
                double d2 = 0.0;
                for (int k = 0; k < 3; ++k) d2 += (fine.pos[3 * v + k] - p[k]) * (fine.pos[3 * v + k] - p[k]);
                upper = d2 < upper ? d2 : upper;
            }
            double best = INFINITY;
            for (int32_t f = 0; f < fine.nf; ++f) {
                const int32_t *t = fine.fv + 3 * (int64_t)f;
                double cen[3] = {0, 0, 0}, rad = 0.0, dc = 0.0;
                for (int j = 0; j < 3; ++j)
                    for (int k = 0; k < 3; ++k) cen[k] += fine.pos[3 * t[j] + k] / 3.0;
                for (int j = 0; j < 3; ++j) {
                    double r2 = 0.0;
                    for (int k = 0; k < 3; ++k) r2 += (fine.pos[3 * t[j] + k] - cen[k]) * (fine.pos[3 * t[j] + k] - cen[k]);
                    rad = sqrt(r2) > rad ? sqrt(r2) : rad;
                }
                for (int k = 0; k < 3; ++k) dc += (cen[k] - p[k]) * (cen[k] - p[k]);
                if (sqrt(dc) - rad > sqrt(upper) + 1e-9) continue;
                const double d2 = brute_triangle_d2(p, fine.pos + 3 * t[0], fine.pos + 3 * t[1], fine.pos + 3 * t[2]);
                if (d2 < best) best = d2;
            }
            CHECK(fabs(d[q] - sqrt(best)) < 1e-5, "point %d: distance %g, brute force %g", q, d[q], sqrt(best));
            double dd = 0.0, nn = 0.0;
            for (int k = 0; k < 3; ++k) {
                dd += (cl[3 * q + k] - p[k]) * (cl[3 * q + k] - p[k]);
                nn += nr[3 * q + k] * nr[3 * q + k];
            }
            CHECK(fabs(sqrt(dd) - d[q]) < 1e-5, "point %d: closest point not at the distance", q);
            CHECK(fabs(nn - 1.0) < 1e-5, "point %d: normal not unit", q);
            CHECK(face[q] >= 0 && face[q] < fine.nf, "point %d: face %d", q, face[q]);
        }
    }

    /* The boundary flag: on an open grid, points beyond its edges and
     * corners are flagged, points above its interior are not; a closed
     * torus has no boundary. */
    {
        tmesh grid = make_grid(4, 4);
        spia_mesh gm = tmesh_view(&grid);
        spia_scan *gs = NULL;
        CHECK(spia_scan_create(&gm, &gs, &st) == SPIA_OK, "grid scan");
        const float q[3 * 4] = {2.0f, 2.0f, 1.0f, -1.0f, 2.0f, 0.0f, 5.0f, 5.0f, 0.5f, 2.0f, 4.5f, 0.0f};
        uint8_t edge[4] = {9, 9, 9, 9};
        CHECK(spia_scan_closest_points(gs, 4, q, NULL, NULL, NULL, NULL, edge, &st) == SPIA_OK, "grid query");
        CHECK(edge[0] == 0 && edge[1] == 1 && edge[2] == 1 && edge[3] == 1, "boundary flags %d %d %d %d", edge[0],
              edge[1], edge[2], edge[3]);
        spia_scan_free(gs);
        tmesh_free(&grid);
        uint8_t on_torus[3] = {9, 9, 9};
        const float tq[9] = {0.0f, 0.0f, 0.0f, 3.0f, 0.0f, 0.0f, 0.0f, 2.7f, 0.5f};
        CHECK(spia_scan_closest_points(scan, 3, tq, NULL, NULL, NULL, NULL, on_torus, &st) == SPIA_OK, "torus query");
        CHECK(!on_torus[0] && !on_torus[1] && !on_torus[2], "a closed scan has no boundary");
    }

    /* A triangle with two corners at one place (an unwelded scan) is a
     * segment: its closest point is still found. */
    {
        const float pos[] = {0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 5, 1, 0, 5, 0, 1, 5};
        const int32_t sizes[] = {3, 3}, fv[] = {0, 1, 2, 3, 4, 5};
        spia_mesh dm;
        memset(&dm, 0, sizeof dm);
        dm.vertex_count = 6, dm.positions = pos, dm.face_count = 2, dm.face_sizes = sizes, dm.face_vertices = fv;
        spia_scan *ds = NULL;
        CHECK(spia_scan_create(&dm, &ds, &st) == SPIA_OK, "degenerate scan: %s", st.message);
        const float q[3] = {0.5f, 1.0f, 0.0f};
        float d = -1.0f, cl[3];
        int32_t face = -1;
        CHECK(spia_scan_closest_points(ds, 1, q, cl, NULL, &d, &face, NULL, &st) == SPIA_OK, "degenerate query");
        CHECK(fabs(d - 1.0) < 1e-6 && face == 0 && fabs(cl[0] - 0.5) < 1e-6, "degenerate: distance %g on face %d", d,
              face);
        spia_scan_free(ds);
    }

    tmesh coarse = make_torus(16, 8, 0);
    spia_mesh cm = tmesh_view(&coarse);
    const int32_t nv = coarse.nv;
    float *out = malloc(sizeof(float) * 3 * (size_t)nv);
    float *vd = malloc(sizeof(float) * (size_t)nv);
    spia_options o = spia_options_default();

    /* SURFACE: the mean sample distance falls at least tenfold and every
     * vertex gets a distance. */
    {
        spia_fit_options fo;
        memset(&fo, 0, sizeof fo);
        spia_fit_report rep;
        memset(&rep, 0, sizeof rep);
        rep.vertex_distances = vd;
        double hist[32];
        rep.history = hist;
        rep.history_capacity = 32;
        r = spia_fit(&cm, scan, &o, &fo, out, &rep, &st);
        CHECK(r == SPIA_OK, "surface fit: %s", st.message);
        CHECK(rep.sample_count == spia_surface_sample_count(&cm, 4), "sample count %lld", (long long)rep.sample_count);
        CHECK(rep.after.mean < 0.1 * rep.before.mean, "mean %g -> %g", rep.before.mean, rep.after.mean);
        CHECK(rep.after.max < 1e-3, "max after %g", rep.after.max);
        CHECK(rep.history_count == rep.rounds + 1 && hist[0] == rep.before.mean, "history");
        double vmax = 0.0;
        for (int32_t v = 0; v < nv; ++v) vmax = vd[v] > vmax ? vd[v] : vmax;
        CHECK(fabs(vmax - rep.after.max) < 1e-6, "vertex distances max %g vs %g", vmax, rep.after.max);
        /* The flat positions of the cage written, from the fit's own grid,
         * are spia_flat_positions' to the bit; cancelled there, the fit is. */
        float *flat = malloc(sizeof(float) * 3 * (size_t)nv), *theirs = malloc(sizeof(float) * 3 * (size_t)nv);
        memset(&rep, 0, sizeof rep);
        rep.flat_positions = flat;
        r = spia_fit(&cm, scan, &o, &fo, out, &rep, &st);
        CHECK(r == SPIA_OK && rep.flat_positions_written == 1, "fit with flat positions: %s", st.message);
        spia_mesh written = cm;
        written.positions = out;
        CHECK(spia_flat_positions(&written, &o, theirs, &st) == SPIA_OK, "%s", st.message);
        CHECK(memcmp(flat, theirs, sizeof(float) * 3 * (size_t)nv) == 0, "the fit's flat positions differ");
        memset(&rep, 0, sizeof rep);
        rep.flat_positions = flat;
        fo.flags = SPIA_FIT_NO_SCAN_DISTANCES;
        r = spia_fit(&cm, scan, &o, &fo, out, &rep, &st);
        CHECK(r == SPIA_OK && rep.flat_positions_written == 0, "no grid, no flat positions: %s", st.message);
        /* Without the scan's measure before the fit, the one after it (a
         * search of its own, not started from the first's answers) gives
         * the same distances, the cage and its flat positions the same. */
        float *per_scan[2] = {malloc(sizeof(float) * (size_t)fine.nv), malloc(sizeof(float) * (size_t)fine.nv)};
        float *cages[2] = {malloc(sizeof(float) * 3 * (size_t)nv), malloc(sizeof(float) * 3 * (size_t)nv)};
        spia_fit_report both[2];
        for (int k = 0; k < 2; ++k) {
            memset(&both[k], 0, sizeof both[k]);
            both[k].scan_distances = per_scan[k];
            both[k].flat_positions = k ? theirs : flat;
            fo.flags = k ? SPIA_FIT_NO_SCAN_BEFORE : 0;
            r = spia_fit(&cm, scan, &o, &fo, cages[k], &both[k], &st);
            CHECK(r == SPIA_OK && both[k].flat_positions_written == 1, "fit, flags %u: %s", fo.flags, st.message);
        }
        CHECK(both[0].scan_before.mean > both[0].scan_after.mean && both[0].scan_point_count > 0, "scan before %g after %g",
              both[0].scan_before.mean, both[0].scan_after.mean);
        CHECK(both[1].scan_before.mean == 0.0 && both[1].scan_before.p95 == 0.0 && both[1].scan_before.ignored == 0,
              "no measure before, yet scan_before %g", both[1].scan_before.mean);
        CHECK(both[1].scan_point_count == both[0].scan_point_count, "scan points %lld, %lld",
              (long long)both[1].scan_point_count, (long long)both[0].scan_point_count);
        CHECK(memcmp(&both[1].scan_after, &both[0].scan_after, sizeof both[0].scan_after) == 0,
              "scan after %.9g / %.9g", both[1].scan_after.mean, both[0].scan_after.mean);
        CHECK(memcmp(per_scan[0], per_scan[1], sizeof(float) * (size_t)fine.nv) == 0, "per-vertex scan distances differ");
        CHECK(memcmp(cages[0], cages[1], sizeof(float) * 3 * (size_t)nv) == 0, "the cages differ");
        CHECK(memcmp(flat, theirs, sizeof(float) * 3 * (size_t)nv) == 0, "the flat positions differ");
        free(per_scan[0]), free(per_scan[1]), free(cages[0]), free(cages[1]);
        fo.flags = 0;
        free(flat), free(theirs);
    }
    /* A low-poly target with flat facets (tests/data's Chinese dragon and
     * its QuadriFlow cage): without the fold guard the surface pleats along
     * the facets' edges; with it (and its barrier, whose pairs this fit is
     * the C tests' only user of) at most 0.1% of the samples face away. */
    {
        tmesh target, low;
        CHECK(read_obj(SPIA_TEST_DATA_DIR "/ChineseDragon-10kv.obj", &target), "cannot read ChineseDragon-10kv.obj");
        CHECK(read_obj(SPIA_TEST_DATA_DIR "/ChineseDragon-10kv_quadriflow_cage.obj", &low), "cannot read its cage");
        spia_mesh tm = tmesh_view(&target), lm = tmesh_view(&low);
        spia_scan *facets = NULL;
        r = spia_scan_create(&tm, &facets, &st);
        CHECK(r == SPIA_OK, "low-poly scan: %s", st.message);
        float *lout = malloc(sizeof(float) * 3 * (size_t)low.nv);
        int64_t folded[2] = {0, 0}, samples = 0;
        double mean[2] = {0.0, 0.0};
        for (int guarded = 0; guarded < 2 && r == SPIA_OK; ++guarded) {
            spia_fit_options fo;
            memset(&fo, 0, sizeof fo);
            fo.flags = guarded ? 0 : SPIA_FIT_ALLOW_FOLDS | SPIA_FIT_HARD_CUTOFF;
            spia_fit_report rep;
            memset(&rep, 0, sizeof rep);
            r = spia_fit(&lm, facets, &o, &fo, lout, &rep, &st);
            CHECK(r == SPIA_OK, "low-poly fit: %s", st.message);
            folded[guarded] = rep.folded_after, samples = rep.sample_count, mean[guarded] = rep.after.mean;
            CHECK(rep.after.mean < 0.2 * rep.before.mean, "mean %g -> %g", rep.before.mean, rep.after.mean);
        }
        CHECK(folded[0] > samples / 100, "without the guard %lld of %lld samples face away", (long long)folded[0],
              (long long)samples);
        CHECK(folded[1] <= samples / 1000, "with the guard %lld of %lld samples face away", (long long)folded[1],
              (long long)samples);
        CHECK(mean[1] < 1.1 * mean[0], "guarded mean %g against %g", mean[1], mean[0]);
        free(lout);
        spia_scan_free(facets);
        tmesh_free(&target), tmesh_free(&low);
    }
    /* VERTICES: every limit point on the scan. */
    {
        spia_fit_options fo;
        memset(&fo, 0, sizeof fo);
        fo.mode = SPIA_FIT_VERTICES;
        r = spia_fit(&cm, scan, &o, &fo, out, NULL, &st);
        CHECK(r == SPIA_OK, "vertex fit: %s", st.message);
        spia_mesh fitted = cm;
        fitted.positions = out;
        spia_stencils *L = NULL;
        r = spia_limit_stencils_create(&fitted, &o, &L, &st);
        CHECK(r == SPIA_OK, "stencils: %s", st.message);
        double *cage = malloc(sizeof(double) * 3 * (size_t)nv), *lim = malloc(sizeof(double) * 3 * (size_t)nv);
        float *limf = malloc(sizeof(float) * 3 * (size_t)nv), *d = malloc(sizeof(float) * (size_t)nv);
        for (int64_t i = 0; i < 3 * (int64_t)nv; ++i) cage[i] = out[i];
        spia_stencils_apply(L, cage, lim);
        for (int64_t i = 0; i < 3 * (int64_t)nv; ++i) limf[i] = (float)lim[i];
        spia_scan_closest_points(scan, nv, limf, NULL, NULL, d, NULL, NULL, &st);
        double worst = 0.0;
        for (int32_t v = 0; v < nv; ++v) worst = d[v] > worst ? d[v] : worst;
        CHECK(worst < 1e-5 * diag, "a limit point %g off the scan", worst / diag);
        free(cage), free(lim), free(limf), free(d);
        spia_stencils_free(L);
    }

    /* Bad input: a code, a message, the output untouched. */
    for (int32_t i = 0; i < 3 * nv; ++i) out[i] = 777.0f;
    {
        spia_fit_options fo;
        memset(&fo, 0, sizeof fo);
        spia_scan *none = (spia_scan *)&st;
        spia_mesh empty = fm;
        empty.face_count = 0;
        r = spia_scan_create(&empty, &none, &st);
        CHECK(r == SPIA_ERROR_EMPTY_MESH && none == NULL && strlen(st.message) > 10, "empty scan: %s", st.message);
        r = spia_fit(&cm, NULL, &o, &fo, out, NULL, &st);
        CHECK(r == SPIA_ERROR_INVALID_ARGUMENT, "NULL scan");
        fo.samples_per_edge = 65;
        r = spia_fit(&cm, scan, &o, &fo, out, NULL, &st);
        CHECK(r == SPIA_ERROR_INVALID_ARGUMENT && strstr(st.message, "samples_per_edge"), "samples: %s", st.message);
        fo.samples_per_edge = 0;
        fo.cutoff = -1.0;
        r = spia_fit(&cm, scan, &o, &fo, out, NULL, &st);
        CHECK(r == SPIA_ERROR_INVALID_ARGUMENT && strstr(st.message, "cutoff"), "cutoff: %s", st.message);
        fo.cutoff = 0.0;
        spia_options loop = o;
        loop.scheme = SPIA_SCHEME_LOOP;
        tmesh tri = make_torus(16, 8, 1);
        spia_mesh tm = tmesh_view(&tri);
        r = spia_fit(&tm, scan, &loop, &fo, out, NULL, &st);
        CHECK(r == SPIA_ERROR_INVALID_ARGUMENT && strstr(st.message, "VERTICES"), "Loop surface: %s", st.message);
        tmesh_free(&tri);
        spia_options cancel = o;
        cancel.progress = cancel_after_first;
        r = spia_fit(&cm, scan, &cancel, &fo, out, NULL, &st);
        CHECK(r == SPIA_ERROR_CANCELLED, "cancel: %s", spia_result_name(r));
        float nan_point[3] = {0.0f, NAN, 0.0f};
        r = spia_scan_closest_points(scan, 1, nan_point, NULL, NULL, NULL, NULL, NULL, &st);
        CHECK(r == SPIA_ERROR_NONFINITE, "NaN query: %s", spia_result_name(r));
        int untouched = 1;
        for (int32_t i = 0; i < 3 * nv; ++i) untouched &= out[i] == 777.0f;
        CHECK(untouched, "output written on failure");
    }
    /* Surface stencils: rows are affine combinations (weights sum to 1). */
    {
        spia_stencils *M = NULL;
        r = spia_surface_stencils_create(&cm, &o, 3, &M, &st);
        CHECK(r == SPIA_OK && spia_stencils_row_count(M) == spia_surface_sample_count(&cm, 3), "sample stencils");
        const int32_t rows = spia_stencils_row_count(M);
        int64_t *off = malloc(sizeof(int64_t) * ((size_t)rows + 1));
        double *w = malloc(sizeof(double) * (size_t)spia_stencils_weight_count(M));
        spia_stencils_copy_csr(M, off, NULL, w);
        double worst = 0.0;
        for (int32_t i = 0; i < rows; ++i) {
            double sum = 0.0;
            for (int64_t k = off[i]; k < off[i + 1]; ++k) sum += w[k];
            worst = fabs(sum - 1.0) > worst ? fabs(sum - 1.0) : worst;
        }
        CHECK(worst < 1e-12, "row sums off by %g", worst);
        free(off), free(w);
        spia_stencils_free(M);
    }
    free(out), free(vd);
    spia_scan_free(scan);
    spia_scan_free(NULL);
    tmesh_free(&coarse);
    tmesh_free(&fine);
    TEST_MAIN_END();
}
