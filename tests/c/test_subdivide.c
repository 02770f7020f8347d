// SPDX-License-Identifier: GPL-3.0-or-later
/* Subdivision of the cage (spia_subdivide) and its flat positions
 * (spia_flat_positions): the counts against Catmull-Clark's
 * closed forms, the same limit surface (the subdivided cage's limit points at
 * the cage's vertices are the cage's own, smooth and with creases), every
 * face a quad whose vertices are in range, and the bad inputs (codes,
 * buffers untouched) and cancelling. */
#include "support.h"

static int cancel_at_once(void *user, int32_t level, double share) {
    (void)user, (void)level, (void)share;
    return 1;
}

/* Largest distance between the limit points of `mesh`'s vertices and those
 * of the first mesh->vertex_count vertices of the subdivided mesh. */
static double limit_gap(const spia_mesh *mesh, const spia_mesh *fine, const spia_options *o) {
    spia_stencils *a = NULL, *b = NULL;
    double gap = INFINITY;
    if (spia_limit_stencils_create(mesh, o, &a, NULL) == SPIA_OK &&
        spia_limit_stencils_create(fine, o, &b, NULL) == SPIA_OK) {
        double *pa = (double *)malloc(sizeof(double) * 3 * (size_t)mesh->vertex_count);
        double *pb = (double *)malloc(sizeof(double) * 3 * (size_t)fine->vertex_count);
        double *ca = (double *)malloc(sizeof(double) * 3 * (size_t)mesh->vertex_count);
        double *cb = (double *)malloc(sizeof(double) * 3 * (size_t)fine->vertex_count);
        for (int64_t i = 0; i < 3 * (int64_t)mesh->vertex_count; ++i) ca[i] = mesh->positions[i];
        for (int64_t i = 0; i < 3 * (int64_t)fine->vertex_count; ++i) cb[i] = fine->positions[i];
        spia_stencils_apply(a, ca, pa);
        spia_stencils_apply(b, cb, pb);
        gap = 0.0;
        for (int64_t i = 0; i < 3 * (int64_t)mesh->vertex_count; ++i) gap = fmax(gap, fabs(pa[i] - pb[i]));
        free(pa), free(pb), free(ca), free(cb);
    }
    spia_stencils_free(a);
    spia_stencils_free(b);
    return gap;
}

static void check_levels(const char *name, const spia_mesh *mesh, int32_t edges_of_cage, int32_t quality,
                         double tolerance) {
    spia_options o = spia_options_default();
    o.quality = quality;
    int64_t corners = 0;
    for (int32_t f = 0; f < mesh->face_count; ++f) corners += mesh->face_sizes[f];
    int64_t nv = mesh->vertex_count, ne = edges_of_cage, nf = mesh->face_count;
    for (int32_t levels = 1; levels <= 2; ++levels) {
        /* V' = V + E + F, E' = 2 E + corners, F' = corners (then quads). */
        nv += ne + nf;
        ne = 2 * ne + corners;
        nf = corners;
        corners = 4 * nf;
        int32_t v = 0, f = 0, e = 0;
        spia_status st;
        CHECK(spia_subdivide_size(mesh, &o, levels, &v, &f, &e, &st) == SPIA_OK, "%s: %s", name, st.message);
        CHECK(v == nv && f == nf && e == ne, "%s level %d: %d %d %d, expected %lld %lld %lld", name, (int)levels,
              (int)v, (int)f, (int)e, (long long)nv, (long long)nf, (long long)ne);
        float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)v);
        int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * 4 * (size_t)f);
        int32_t *ev = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)e);
        float *ec = (float *)malloc(sizeof(float) * (size_t)e);
        float *vc = (float *)malloc(sizeof(float) * (size_t)v);
        int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)f);
        CHECK(spia_subdivide(mesh, &o, levels, pos, fv, ev, ec, vc, &st) == SPIA_OK, "%s: %s", name, st.message);
        int in_range = 1;
        for (int64_t i = 0; i < 4 * (int64_t)f; ++i) in_range = in_range && fv[i] >= 0 && fv[i] < v;
        for (int64_t i = 0; i < 2 * (int64_t)e; ++i) in_range = in_range && ev[i] >= 0 && ev[i] < v;
        CHECK(in_range, "%s level %d: an index out of range", name, (int)levels);
        for (int32_t i = 0; i < f; ++i) sizes[i] = 4;
        spia_mesh fine = {v, pos, f, sizes, fv, e, ev, ec, vc};
        CHECK(spia_mesh_validate(&fine, &st) == SPIA_OK, "%s level %d: %s", name, (int)levels, st.message);
        const double gap = limit_gap(mesh, &fine, &o);
        CHECK(gap < tolerance, "%s level %d: limit points moved by %g", name, (int)levels, gap);
        free(pos), free(fv), free(ev), free(ec), free(vc), free(sizes);
    }
}

int main(void) {
    tmesh cube = make_cut_cube(3);
    spia_mesh m = tmesh_view(&cube);
    /* The cube's edges: each face's four, counted once (closed: E = 2 F). */
    check_levels("cut cube", &m, 2 * m.face_count, 3, 1e-6);

    /* Infinitely sharp and semi-sharp creases around one face and a vertex
     * crease: the refined sharpness written back as creases keeps the limit
     * surface (at quality 10, where Blender's patches reach the exact limit
     * of semi-sharp creases). */
    int32_t ring[8] = {m.face_vertices[0], m.face_vertices[1], m.face_vertices[1], m.face_vertices[2],
                       m.face_vertices[2], m.face_vertices[3], m.face_vertices[3], m.face_vertices[0]};
    float creases[4] = {1.0f, 1.0f, 0.5f, 0.5f};
    float *vertex_creases = (float *)calloc((size_t)m.vertex_count, sizeof(float));
    vertex_creases[m.face_vertices[10]] = 0.4f;
    spia_mesh creased = m;
    creased.edge_count = 4;
    creased.edges = ring;
    creased.edge_creases = creases;
    creased.vertex_creases = vertex_creases;
    check_levels("creased cube", &creased, 2 * m.face_count, 10, 1e-5);

    /* Bad input: a code, nothing written. */
    float sentinel[3] = {7.0f, 7.0f, 7.0f};
    int32_t fv[4] = {-5, -5, -5, -5};
    spia_status st;
    CHECK(spia_subdivide(&m, NULL, 0, sentinel, fv, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT &&
              strstr(st.message, "levels"),
          "levels 0: %s", st.message);
    CHECK(spia_subdivide(&m, NULL, 7, sentinel, fv, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT,
          "levels 7: %s", st.message);
    spia_options loop = spia_options_default();
    loop.scheme = SPIA_SCHEME_LOOP;
    CHECK(spia_subdivide(&m, &loop, 1, sentinel, fv, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT &&
              strstr(st.message, "Catmull-Clark"),
          "Loop: %s", st.message);
    CHECK(spia_subdivide(&m, NULL, 1, NULL, fv, NULL, NULL, NULL, &st) == SPIA_ERROR_INVALID_ARGUMENT, "NULL: %s",
          st.message);
    int32_t v, f, e;
    CHECK(spia_subdivide_size(&m, NULL, 1, &v, NULL, &e, &st) == SPIA_ERROR_INVALID_ARGUMENT, "NULL count: %s",
          st.message);
    CHECK(sentinel[0] == 7.0f && fv[0] == -5, "a refused call wrote its buffers");

    /* Sizes past int32 are refused by the counts, before any refinement
     * (with no memory budget, which would refuse them first): a 363 x 363
     * grid (131,769 quads) to 6 levels makes 539.7M quads, whose 2,158.8M
     * corners pass INT32_MAX, and to 5 levels a quarter of that; Loop's
     * 11,250 triangles to 8 levels make 737.3M triangles, 2,211.8M
     * corners, and to 7 levels a quarter. */
    spia_options unbudgeted = spia_options_default(), loop_unbudgeted = loop;
    unbudgeted.memory_budget = loop_unbudgeted.memory_budget = -1;
    tmesh big_grid = make_grid(363, 363);
    spia_mesh grid_view = tmesh_view(&big_grid);
    CHECK(spia_subdivide_size(&grid_view, &unbudgeted, 5, &v, &f, &e, &st) == SPIA_OK && f == 131769 * 1024,
          "grid, 5 levels: %s", st.message);
    CHECK(spia_subdivide_size(&grid_view, &unbudgeted, 6, &v, &f, &e, &st) == SPIA_ERROR_INVALID_ARGUMENT &&
              strstr(st.message, "too many"),
          "grid, 6 levels: %s", st.message);
    tmesh torus = make_torus(75, 75, 1);
    spia_mesh torus_view = tmesh_view(&torus);
    int64_t corners = 0;
    CHECK(spia_refine_size(&torus_view, &loop_unbudgeted, 7, &v, &f, &corners, &st) == SPIA_OK && f == 11250 * 16384,
          "Loop, 7 levels: %s", st.message);
    CHECK(spia_refine_size(&torus_view, &loop_unbudgeted, 8, &v, &f, &corners, &st) == SPIA_ERROR_INVALID_ARGUMENT &&
              strstr(st.message, "too many"),
          "Loop, 8 levels: %s", st.message);
    /* Under a budget the size query already refuses what would not fit,
     * before the caller allocates the output, naming the levels that do. */
    spia_options budgeted = spia_options_default();
    budgeted.memory_budget = (int64_t)1 << 30;
    CHECK(spia_subdivide_size(&grid_view, &budgeted, 5, &v, &f, &e, &st) == SPIA_ERROR_OUT_OF_MEMORY &&
              strstr(st.message, "subdividing 5 levels (134931456 faces)") &&
              strstr(st.message, "memory budget of 1.00 GB: at most 2 levels fit"),
          "grid, 5 levels under 1 GB: %s", st.message);
    CHECK(spia_subdivide_size(&grid_view, &budgeted, 2, &v, &f, &e, &st) == SPIA_OK, "grid, 2 levels under 1 GB: %s",
          st.message);
    tmesh_free(&big_grid);
    tmesh_free(&torus);

    /* Cancelling at the first level's end. */
    spia_options cancel = spia_options_default();
    cancel.progress = cancel_at_once;
    CHECK(spia_subdivide_size(&m, NULL, 1, &v, &f, &e, &st) == SPIA_OK, "%s", st.message);
    float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)v);
    int32_t *faces = (int32_t *)malloc(sizeof(int32_t) * 4 * (size_t)f);
    CHECK(spia_subdivide(&m, &cancel, 1, pos, faces, NULL, NULL, NULL, &st) == SPIA_ERROR_CANCELLED, "cancel: %s",
          st.message);
    free(pos), free(faces);

    /* spia_flat_positions: the subdivided cube's flat quads straddle its
     * limit surface (each vertex moves off its limit point, outwards on a
     * convex cube), quads only, nothing written when refused. */
    CHECK(spia_subdivide_size(&m, NULL, 1, &v, &f, &e, &st) == SPIA_OK, "%s", st.message);
    pos = (float *)malloc(sizeof(float) * 3 * (size_t)v);
    faces = (int32_t *)malloc(sizeof(int32_t) * 4 * (size_t)f);
    int32_t *quad_sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)f);
    float *flat = (float *)malloc(sizeof(float) * 3 * (size_t)v);
    CHECK(spia_subdivide(&m, NULL, 1, pos, faces, NULL, NULL, NULL, &st) == SPIA_OK, "%s", st.message);
    for (int32_t i = 0; i < f; ++i) quad_sizes[i] = 4;
    spia_mesh quads = {v, pos, f, quad_sizes, faces, 0, NULL, NULL, NULL};
    CHECK(spia_flat_positions(&quads, NULL, flat, &st) == SPIA_OK, "flat: %s", st.message);
    spia_stencils *L = NULL;
    CHECK(spia_limit_stencils_create(&quads, NULL, &L, &st) == SPIA_OK, "%s", st.message);
    double *cage = (double *)malloc(sizeof(double) * 3 * (size_t)v), *limit = (double *)malloc(sizeof(double) * 3 * (size_t)v);
    for (int64_t i = 0; i < 3 * (int64_t)v; ++i) cage[i] = pos[i];
    spia_stencils_apply(L, cage, limit);
    int outward = 0;
    for (int32_t i = 0; i < v; ++i) {
        double rl = 0.0, rf = 0.0;
        for (int a = 0; a < 3; ++a) rl += limit[3 * i + a] * limit[3 * i + a], rf += (double)flat[3 * i + a] * flat[3 * i + a];
        outward += rf > rl;
    }
    CHECK(outward == v, "%d of %d vertices moved outwards", outward, (int)v);
    float sentinel_flat[3] = {7.0f, 7.0f, 7.0f};
    CHECK(spia_flat_positions(&m, NULL, flat, &st) == SPIA_OK, "the cut cube is all quads: %s", st.message);
    int32_t tri_sizes[2] = {3, 3}, tri_fv[6] = {0, 1, 2, 0, 2, 3};
    float tri_pos[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    spia_mesh tris = {4, tri_pos, 2, tri_sizes, tri_fv, 0, NULL, NULL, NULL};
    CHECK(spia_flat_positions(&tris, NULL, sentinel_flat, &st) == SPIA_ERROR_FACE_SIZE && sentinel_flat[0] == 7.0f,
          "triangles: %s", st.message);
    CHECK(spia_flat_positions(&m, &loop, flat, &st) == SPIA_ERROR_INVALID_ARGUMENT, "Loop: %s", st.message);
    spia_stencils_free(L);
    free(cage), free(limit), free(flat), free(quad_sizes), free(pos), free(faces);
    free(vertex_creases);
    tmesh_free(&cube);
    TEST_MAIN_END();
}
