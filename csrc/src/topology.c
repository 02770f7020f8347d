// SPDX-License-Identifier: GPL-3.0-or-later
/* Mesh validation, vertex-to-corner adjacency and the surface samples' count. */
#include "internal.h"
#include "threads.h"

#include <stdint.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

spia_result spia_mesh_validate(const spia_mesh *m, spia_status *status) {
    if (!m) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "mesh is NULL");
    if (m->vertex_count < 0 || m->face_count < 0 || m->edge_count < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "negative vertex, face or edge count");
    if (m->vertex_count == 0) return spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the mesh has no vertices");
    if (m->face_count == 0)
        return spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the mesh has no faces, so it has no surface to subdivide");
    if (!m->positions || !m->face_sizes || !m->face_vertices)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "positions, face_sizes and face_vertices must not be NULL");
    if (m->edge_count > 0 && !m->edges)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "edge_count is %d but edges is NULL", (int)m->edge_count);

    const int32_t n = m->vertex_count;
    int64_t bad = 0, first_bad = -1;
    for (int32_t v = 0; v < n; ++v) {
        const float *p = m->positions + 3 * (int64_t)v;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) {
            if (first_bad < 0) first_bad = v;
            ++bad;
        }
    }
    if (bad)
        return spia__fail(status, SPIA_ERROR_NONFINITE, first_bad,
                          "%lld vertices have NaN or infinite coordinates (first: vertex %lld)", (long long)bad,
                          (long long)first_bad);

    for (int32_t f = 0; f < m->face_count; ++f) {
        if (m->face_sizes[f] < 3) {
            if (first_bad < 0) first_bad = f;
            ++bad;
        }
    }
    if (bad)
        return spia__fail(status, SPIA_ERROR_FACE_SIZE, first_bad,
                          "%lld faces have fewer than 3 vertices (first: face %lld)", (long long)bad,
                          (long long)first_bad);

    int32_t *stamp = (int32_t *)malloc(sizeof(int32_t) * (size_t)n);
    if (!stamp) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory validating the mesh");
    for (int32_t v = 0; v < n; ++v) stamp[v] = -1;
    int64_t c = 0, degenerate = 0, first_degenerate = -1;
    spia_result r = SPIA_OK;
    for (int32_t f = 0; f < m->face_count && r == SPIA_OK; ++f) {
        int is_degenerate = 0;
        for (int32_t k = 0; k < m->face_sizes[f]; ++k, ++c) {
            int32_t v = m->face_vertices[c];
            if (v < 0 || v >= n) {
                r = spia__fail(status, SPIA_ERROR_INDEX_RANGE, f,
                               "face %d uses vertex index %d, outside 0..%d", (int)f, (int)v, (int)(n - 1));
                break;
            }
            if (stamp[v] == f) is_degenerate = 1;
            stamp[v] = f;
        }
        if (is_degenerate) {
            if (first_degenerate < 0) first_degenerate = f;
            ++degenerate;
        }
    }
    free(stamp);
    if (r != SPIA_OK) return r;
    if (degenerate)
        return spia__fail(status, SPIA_ERROR_DEGENERATE_FACE, first_degenerate,
                          "%lld degenerate faces use one vertex more than once (first: face %lld); "
                          "merge or dissolve them first",
                          (long long)degenerate, (long long)first_degenerate);

    for (int32_t e = 0; e < m->edge_count; ++e) {
        int32_t a = m->edges[2 * (int64_t)e], b = m->edges[2 * (int64_t)e + 1];
        if (a < 0 || a >= n || b < 0 || b >= n)
            return spia__fail(status, SPIA_ERROR_INDEX_RANGE, e, "edge %d joins vertices %d and %d, outside 0..%d",
                              (int)e, (int)a, (int)b, (int)(n - 1));
        if (a == b)
            return spia__fail(status, SPIA_ERROR_DEGENERATE_FACE, e, "edge %d joins vertex %d to itself", (int)e, (int)a);
        if (m->edge_creases) {
            float w = m->edge_creases[e];
            if (!isfinite(w)) return spia__fail(status, SPIA_ERROR_NONFINITE, e, "edge %d has a NaN or infinite crease", (int)e);
            if (w < 0.0f || w > 1.0f)
                return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, e, "edge %d has crease %g, outside 0..1", (int)e, (double)w);
        }
    }
    if (m->vertex_creases) {
        for (int32_t v = 0; v < n; ++v) {
            float w = m->vertex_creases[v];
            if (!isfinite(w)) return spia__fail(status, SPIA_ERROR_NONFINITE, v, "vertex %d has a NaN or infinite crease", (int)v);
            if (w < 0.0f || w > 1.0f)
                return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, v, "vertex %d has crease %g, outside 0..1", (int)v, (double)w);
        }
    }
    spia__ok(status);
    return SPIA_OK;
}

void spia__adjacency_release_vertex_lists(spia_adjacency *a) {
    free(a->face_of_corner);
    free(a->first);
    free(a->corner_of);
    a->face_of_corner = NULL;
    a->first = NULL;
    a->corner_of = NULL;
}

void spia__adjacency_free(spia_adjacency *a) {
    free(a->corner_start);
    free(a->face_of_corner);
    free(a->first);
    free(a->corner_of);
    memset(a, 0, sizeof *a);
}

/* The vertex lists are a counting sort of the corners by vertex, which
 * keeps face order within a vertex.  On several threads each takes a
 * contiguous range of corners with counts of its own, so that a vertex's
 * corners from an earlier range come first, as on one thread. */
enum { ADJACENCY_PARALLEL_CORNERS = 1 << 17, ADJACENCY_THREADS = 8 };

typedef struct adjacency_job {
    const spia_mesh *m;
    spia_adjacency *a;
    int32_t parts;
    int32_t *count[ADJACENCY_THREADS]; /* per part: corners of each vertex, then where the next one goes */
} adjacency_job;

static int64_t part_corner(const adjacency_job *j, int64_t t) { return j->a->corner_count * t / j->parts; }

static void corner_faces(void *context, int64_t f0, int64_t f1, int thread) {
    (void)thread;
    const adjacency_job *j = (const adjacency_job *)context;
    for (int64_t f = f0; f < f1; ++f)
        for (int64_t c = j->a->corner_start[f]; c < j->a->corner_start[f + 1]; ++c) j->a->face_of_corner[c] = (int32_t)f;
}

static void count_corners(void *context, int64_t t0, int64_t t1, int thread) {
    (void)thread;
    adjacency_job *j = (adjacency_job *)context;
    for (int64_t t = t0; t < t1; ++t) {
        int32_t *count = j->count[t];
        memset(count, 0, sizeof(int32_t) * (size_t)j->a->vertex_count);
        for (int64_t c = part_corner(j, t); c < part_corner(j, t + 1); ++c) count[j->m->face_vertices[c]]++;
    }
}

/* Vertices [v0, v1): first[v + 1] from the parts' counts, which become
 * each part's first place for the vertex (first[v] still to be added). */
static void add_counts(void *context, int64_t v0, int64_t v1, int thread) {
    (void)thread;
    adjacency_job *j = (adjacency_job *)context;
    for (int64_t v = v0; v < v1; ++v) {
        int32_t before = 0;
        for (int32_t t = 0; t < j->parts; ++t) {
            const int32_t c = j->count[t][v];
            j->count[t][v] = before;
            before += c;
        }
        j->a->first[v + 1] = before;
    }
}

static void place_corners(void *context, int64_t t0, int64_t t1, int thread) {
    (void)thread;
    adjacency_job *j = (adjacency_job *)context;
    for (int64_t t = t0; t < t1; ++t) {
        int32_t *next = j->count[t];
        for (int64_t c = part_corner(j, t); c < part_corner(j, t + 1); ++c) {
            const int32_t v = j->m->face_vertices[c];
            j->a->corner_of[j->a->first[v] + next[v]++] = (int32_t)c;
        }
    }
}

/* Assumes a validated mesh. */
spia_result spia__adjacency_build(const spia_mesh *m, spia_adjacency *a, spia_status *status) {
    return spia__adjacency_build_threads(m, a, 1, status);
}

spia_result spia__adjacency_build_threads(const spia_mesh *m, spia_adjacency *a, int threads, spia_status *status) {
    memset(a, 0, sizeof *a);
    a->vertex_count = m->vertex_count;
    a->face_count = m->face_count;
    a->corner_start = (int64_t *)malloc(sizeof(int64_t) * ((size_t)m->face_count + 1));
    a->first = (int64_t *)malloc(sizeof(int64_t) * ((size_t)m->vertex_count + 1));
    if (!a->corner_start || !a->first) goto oom;
    int64_t cc = 0;
    for (int32_t f = 0; f < m->face_count; ++f) {
        a->corner_start[f] = cc;
        cc += m->face_sizes[f];
    }
    a->corner_start[m->face_count] = cc;
    a->corner_count = cc;
    if (cc > INT32_MAX) {
        spia__adjacency_free(a);
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "the faces have %lld corners; at most 2147483647 are supported", (long long)cc);
    }
    a->face_of_corner = (int32_t *)malloc(sizeof(int32_t) * (size_t)(cc > 0 ? cc : 1));
    a->corner_of = (int32_t *)malloc(sizeof(int32_t) * (size_t)(cc > 0 ? cc : 1));
    if (!a->face_of_corner || !a->corner_of) goto oom;
    {
        adjacency_job j;
        memset(&j, 0, sizeof j);
        j.m = m;
        j.a = a;
        j.parts = cc >= ADJACENCY_PARALLEL_CORNERS && threads > 1 ? threads : 1;
        if (j.parts > ADJACENCY_THREADS) j.parts = ADJACENCY_THREADS;
        int ok = 1;
        for (int32_t t = 0; t < j.parts; ++t)
            ok = ok && (j.count[t] = (int32_t *)malloc(sizeof(int32_t) * ((size_t)m->vertex_count + 1))) != NULL;
        if (ok) {
            spia__parallel_for(j.parts, m->face_count, 0, corner_faces, &j);
            spia__parallel_for(j.parts, j.parts, 1, count_corners, &j);
            spia__parallel_for(j.parts, m->vertex_count, 0, add_counts, &j);
            a->first[0] = 0;
            for (int32_t v = 0; v < m->vertex_count; ++v) a->first[v + 1] += a->first[v];
            spia__parallel_for(j.parts, j.parts, 1, place_corners, &j);
        }
        for (int32_t t = 0; t < j.parts; ++t) free(j.count[t]);
        if (!ok) goto oom;
    }
    spia__ok(status);
    return SPIA_OK;
oom:
    spia__adjacency_free(a);
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory building vertex adjacency");
}

int32_t spia__vertex_neighbours(const spia_mesh *m, const spia_adjacency *a, int32_t v, int32_t *nb,
                                int32_t *faces_on_edge, int32_t cap) {
    int32_t count = 0;
    for (int64_t i = a->first[v]; i < a->first[v + 1]; ++i) {
        int64_t c = a->corner_of[i];
        int32_t ends[2] = {spia__corner_next(m, a, c), spia__corner_prev(m, a, c)};
        for (int e = 0; e < 2; ++e) {
            int32_t k = 0;
            while (k < count && k < cap && nb[k] != ends[e]) ++k;
            if (k < count && k < cap) {
                faces_on_edge[k]++;
            } else {
                if (count < cap) {
                    nb[count] = ends[e];
                    faces_on_edge[count] = 1;
                }
                ++count;
            }
        }
    }
    return count;
}

int32_t spia__max_corners_per_vertex(const spia_adjacency *a) {
    int64_t most = 0;
    for (int32_t v = 0; v < a->vertex_count; ++v)
        if (a->first[v + 1] - a->first[v] > most) most = a->first[v + 1] - a->first[v];
    return (int32_t)most;
}

typedef struct boundary_job {
    const spia_mesh *m;
    const spia_adjacency *a;
    unsigned char *boundary;
    int32_t cap;
    int only_unknown;
    int failed;
} boundary_job;

static void boundary_range(void *context, int64_t v0, int64_t v1, int thread) {
    (void)thread;
    boundary_job *job = (boundary_job *)context;
    int32_t *nb = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)job->cap);
    if (!nb) {
        job->failed = 1; /* only ever set to 1: no other value to race with */
        return;
    }
    int32_t *fe = nb + job->cap;
    for (int64_t v = v0; v < v1; ++v) {
        if (job->only_unknown && job->boundary[v] != SPIA__BOUNDARY_UNKNOWN) continue;
        int32_t n = spia__vertex_neighbours(job->m, job->a, (int32_t)v, nb, fe, job->cap);
        job->boundary[v] = 0;
        for (int32_t k = 0; k < n; ++k)
            if (fe[k] == 1) job->boundary[v] = 1;
    }
    free(nb);
}

static spia_result boundary_vertices(const spia_mesh *m, const spia_adjacency *a, unsigned char *boundary,
                                     int threads, int only_unknown) {
    boundary_job job = {m, a, boundary, 2 * spia__max_corners_per_vertex(a) + 2, only_unknown, 0};
    spia__parallel_for(threads, m->vertex_count, 16384, boundary_range, &job);
    return job.failed ? SPIA_ERROR_OUT_OF_MEMORY : SPIA_OK;
}

spia_result spia__boundary_vertices(const spia_mesh *m, const spia_adjacency *a, unsigned char *boundary,
                                    int threads) {
    return boundary_vertices(m, a, boundary, threads, 0);
}

spia_result spia__boundary_vertices_unknown(const spia_mesh *m, const spia_adjacency *a, unsigned char *boundary,
                                            int threads) {
    return boundary_vertices(m, a, boundary, threads, 1);
}

spia_result spia__require_triangles(const spia_mesh *m, spia_status *status) {
    int64_t other = 0, first = -1;
    for (int32_t f = 0; f < m->face_count; ++f)
        if (m->face_sizes[f] != 3) {
            if (first < 0) first = f;
            ++other;
        }
    if (other)
        return spia__fail(status, SPIA_ERROR_TOPOLOGY, first,
                          "Loop subdivision needs triangles: %lld of %d faces are not (first: face %lld); "
                          "triangulate the mesh first",
                          (long long)other, (int)m->face_count, (long long)first);
    return SPIA_OK;
}

int64_t spia_surface_sample_count(const spia_mesh *mesh, int32_t samples_per_edge) {
    if (!mesh || !mesh->face_sizes || mesh->face_count <= 0 || samples_per_edge < 1 || samples_per_edge > 64) return 0;
    int64_t ptex = 0;
    for (int32_t f = 0; f < mesh->face_count; ++f) ptex += spia__ptex_of_face(mesh->face_sizes[f]);
    return ptex * samples_per_edge * samples_per_edge;
}
