// SPDX-License-Identifier: GPL-3.0-or-later
/* The vertex lists (csrc/src/topology.c, compiled in: they are private to
 * the library) on 1 to 5 threads against their definition: for each
 * vertex, every corner that uses it, in increasing order (face order, which
 * OpenSubdiv's first-face rules depend on), and for each corner its face.
 * The mesh is big enough for the threaded build (faces of 3 to 9 sides
 * over scattered vertex numbers, two vertices used by a few hundred faces
 * each, a vertex no face uses), and a small one stays on one thread. */
#include "support.h"

#include "internal.h"

static uint64_t next(uint64_t *seed) {
    *seed = *seed * 6364136223846793005ULL + 1442695040888963407ULL;
    return *seed >> 33;
}

static void check_lists(const spia_mesh *m, int threads, const char *name) {
    spia_adjacency a;
    spia_status st;
    if (spia__adjacency_build_threads(m, &a, threads, &st) != SPIA_OK) {
        CHECK(0, "%s, %d threads: %s", name, threads, st.message);
        return;
    }
    int64_t corners = 0;
    for (int32_t f = 0; f < m->face_count; ++f) {
        CHECK(a.corner_start[f] == corners, "%s, %d threads: face %d starts at %lld", name, threads, (int)f,
              (long long)a.corner_start[f]);
        for (int32_t k = 0; k < m->face_sizes[f]; ++k, ++corners)
            if (a.face_of_corner[corners] != f) {
                CHECK(0, "%s, %d threads: corner %lld is of face %d, not %d", name, threads, (long long)corners,
                      (int)a.face_of_corner[corners], (int)f);
                spia__adjacency_free(&a);
                return;
            }
    }
    CHECK(a.corner_count == corners && a.corner_start[m->face_count] == corners, "%s: corner count", name);
    /* Each vertex's list, rebuilt by walking the corners in order. */
    int64_t *seen = (int64_t *)calloc((size_t)m->vertex_count, sizeof(int64_t));
    int bad = 0;
    CHECK(a.first[0] == 0, "%s, %d threads: the first list starts at %lld", name, threads, (long long)a.first[0]);
    for (int64_t c = 0; c < corners && !bad; ++c) {
        const int32_t v = m->face_vertices[c];
        const int64_t at = a.first[v] + seen[v]++;
        if (at >= a.first[v + 1] || a.corner_of[at] != c) bad = 1;
        if (bad)
            CHECK(0, "%s, %d threads: corner %lld of vertex %d is not at place %lld of its list", name, threads,
                  (long long)c, (int)v, (long long)(at - a.first[v]));
    }
    for (int32_t v = 0; v < m->vertex_count && !bad; ++v)
        if (a.first[v] + seen[v] != a.first[v + 1]) {
            bad = 1;
            CHECK(0, "%s, %d threads: vertex %d has %lld corners, its list %lld", name, threads, (int)v,
                  (long long)seen[v], (long long)(a.first[v + 1] - a.first[v]));
        }
    free(seen);
    spia__adjacency_free(&a);
}

static void check_mesh(int32_t faces, uint64_t seed, const char *name) {
    tmesh t;
    memset(&t, 0, sizeof t);
    t.nv = faces; /* vertex numbers scattered over as many vertices as faces; the last one unused */
    t.pos = (float *)calloc(3 * (size_t)t.nv, sizeof(float));
    t.sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)faces);
    t.fv = (int32_t *)malloc(sizeof(int32_t) * 9 * (size_t)faces);
    for (int32_t f = 0; f < faces; ++f) {
        const int32_t size = 3 + (int32_t)(next(&seed) % 7);
        t.sizes[f] = size;
        for (int32_t k = 0; k < size; ++k) {
            int32_t v = (int32_t)(next(&seed) % (uint64_t)(t.nv - 1));
            if (f % 400 == 0 && k == 0) v = 7;       /* used by many faces */
            if (f % 300 == 1 && k == size - 1) v = 8; /* at the end of many */
            t.fv[t.nfv++] = v;
        }
        ++t.nf;
    }
    spia_mesh m = tmesh_view(&t);
    for (int threads = 1; threads <= 5; ++threads) check_lists(&m, threads, name);
    printf("%-24s %7d faces %8lld corners: the same lists on 1 to 5 threads\n", name, (int)faces, (long long)t.nfv);
    tmesh_free(&t);
}

int main(void) {
    check_mesh(60000, 5, "scattered polygons");
    check_mesh(200, 6, "small (one thread)");
    TEST_MAIN_END();
}
