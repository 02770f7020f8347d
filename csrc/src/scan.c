// SPDX-License-Identifier: GPL-3.0-or-later
/* Closest points on a scan: the library's bounding volume hierarchy over the
 * scan's triangles (bvh.c) with the exact point-triangle distance in double,
 * and a smooth normal (area-weighted vertex normals interpolated at the
 * closest point) for point-to-plane fitting. */
#include "bvh.h"
#include "internal.h"
#include "threads.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

struct spia_scan {
    spia__bvh bvh;
    int32_t vertex_count;
    int64_t triangle_count;
    float *positions;      /* vertex_count * 3 (our copy)                           */
    float *normals;        /* vertex_count * 3, unit or zero                        */
    int32_t *triangles;    /* triangle_count * 3, in the hierarchy's leaf order      */
    int32_t *polygon_of;   /* triangle -> the scan polygon it was cut from           */
    /* Per triangle, bit k set when its edge k (corner k to corner k + 1) is
     * on the scan's boundary (used by no other triangle); bit 3 + k when
     * corner k is a boundary vertex. */
    unsigned char *boundary_bits;
    double diagonal;
    int64_t skipped_faces; /* faces that repeat a vertex: left out              */
    /* Seconds of spia_scan_create's phases: checks, copy and fans with the
     * normals, hierarchy, boundary (for benchmarks: spia__scan_timings). */
    double seconds[4];
};

/* The library does not export it; benchmarks that compile scan.c in do. */
void spia__scan_timings(const spia_scan *scan, double seconds[4]);
void spia__scan_timings(const spia_scan *scan, double seconds[4]) {
    for (int i = 0; i < 4; ++i) seconds[i] = scan ? scan->seconds[i] : 0.0;
}

static void scan_release(spia_scan *s) {
    if (!s) return;
    spia__bvh_free(&s->bvh);
    free(s->positions);
    free(s->normals);
    free(s->triangles);
    free(s->polygon_of);
    free(s->boundary_bits);
    free(s);
}

void spia_scan_free(spia_scan *scan) { scan_release(scan); }

double spia_scan_diagonal(const spia_scan *scan) { return scan ? scan->diagonal : 0.0; }

/* Boundary edges: sort the triangles' edges by (low, high) vertex and find
 * those that occur once. */
typedef struct edge_ref {
    int32_t lo, hi;
    int64_t slot; /* 3 * triangle + k */
} edge_ref;

static int compare_edge(const void *a, const void *b) {
    const edge_ref *x = (const edge_ref *)a, *y = (const edge_ref *)b;
    if (x->lo != y->lo) return x->lo < y->lo ? -1 : 1;
    if (x->hi != y->hi) return x->hi < y->hi ? -1 : 1;
    return (x->slot > y->slot) - (x->slot < y->slot);
}

static spia_result mark_boundary(spia_scan *s) {
    const int64_t m = 3 * s->triangle_count;
    edge_ref *e = malloc(sizeof(edge_ref) * (size_t)m);
    unsigned char *vertex_boundary = calloc((size_t)s->vertex_count, 1);
    s->boundary_bits = calloc((size_t)s->triangle_count, 1);
    if (!e || !vertex_boundary || !s->boundary_bits) {
        free(e), free(vertex_boundary);
        return SPIA_ERROR_OUT_OF_MEMORY;
    }
    for (int64_t i = 0; i < m; ++i) {
        const int32_t a = s->triangles[i], b = s->triangles[i % 3 == 2 ? i - 2 : i + 1];
        e[i].lo = a < b ? a : b;
        e[i].hi = a < b ? b : a;
        e[i].slot = i;
    }
    qsort(e, (size_t)m, sizeof(edge_ref), compare_edge);
    for (int64_t i = 0; i < m;) {
        int64_t j = i + 1;
        while (j < m && e[j].lo == e[i].lo && e[j].hi == e[i].hi) ++j;
        if (j - i == 1) {
            s->boundary_bits[e[i].slot / 3] |= (unsigned char)(1u << (e[i].slot % 3));
            vertex_boundary[e[i].lo] = vertex_boundary[e[i].hi] = 1;
        }
        i = j;
    }
    for (int64_t t = 0; t < s->triangle_count; ++t)
        for (int k = 0; k < 3; ++k)
            if (vertex_boundary[s->triangles[3 * t + k]]) s->boundary_bits[t] |= (unsigned char)(1u << (3 + k));
    free(e), free(vertex_boundary);
    return SPIA_OK;
}

static int face_repeats_vertex(const int32_t *fv, int32_t size) {
    for (int32_t a = 0; a < size; ++a)
        for (int32_t b = a + 1; b < size; ++b)
            if (fv[a] == fv[b]) return 1;
    return 0;
}

spia_result spia_scan_create(const spia_mesh *mesh, spia_scan **out, spia_status *status) {
    if (!out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "out must not be NULL");
    *out = NULL;
    if (!mesh) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the scan mesh must not be NULL");
    if (mesh->vertex_count < 0 || mesh->face_count < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "negative vertex or face count in the scan");
    if (mesh->vertex_count == 0 || mesh->face_count == 0)
        return spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the scan has no %s",
                          mesh->vertex_count == 0 ? "vertices" : "faces");
    if (!mesh->positions || !mesh->face_sizes || !mesh->face_vertices)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the scan's positions and faces must not be NULL");
    const int32_t n = mesh->vertex_count;
    double t0 = spia__now();
    const double start = t0;
    for (int64_t i = 0; i < 3 * (int64_t)n; ++i)
        if (!isfinite(mesh->positions[i]))
            return spia__fail(status, SPIA_ERROR_NONFINITE, i / 3, "scan vertex %lld has a non-finite coordinate",
                              (long long)(i / 3));
    /* Count triangles (fans), checking sizes and indices. */
    int64_t tris = 0, corner = 0, skipped = 0;
    for (int32_t f = 0; f < mesh->face_count; ++f) {
        const int32_t size = mesh->face_sizes[f];
        if (size < 3)
            return spia__fail(status, SPIA_ERROR_FACE_SIZE, f, "scan face %d has %d corners (at least 3 needed)", f,
                              size);
        for (int32_t k = 0; k < size; ++k) {
            const int32_t v = mesh->face_vertices[corner + k];
            if (v < 0 || v >= n)
                return spia__fail(status, SPIA_ERROR_INDEX_RANGE, f, "scan face %d refers to vertex %d of %d", f, v, n);
        }
        if (face_repeats_vertex(mesh->face_vertices + corner, size))
            ++skipped;
        else
            tris += size - 2;
        corner += size;
    }
    if (tris == 0)
        return spia__fail(status, SPIA_ERROR_EMPTY_MESH, -1, "the scan has no usable faces (%lld degenerate)",
                          (long long)skipped);
    if (tris > UINT32_MAX / 3)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the scan has too many triangles (%lld)",
                          (long long)tris);

    spia_scan *s = calloc(1, sizeof *s);
    if (!s) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the scan");
    s->vertex_count = n;
    s->triangle_count = tris;
    s->skipped_faces = skipped;
    s->seconds[0] = spia__now() - start;
    t0 = spia__now();
    s->positions = malloc(sizeof(float) * 3 * (size_t)n);
    s->normals = calloc(3 * (size_t)n, sizeof(float));
    s->triangles = malloc(sizeof(int32_t) * 3 * (size_t)tris);
    s->polygon_of = malloc(sizeof(int32_t) * (size_t)tris);
    double *acc = calloc(3 * (size_t)n, sizeof(double));
    if (!s->positions || !s->normals || !s->triangles || !s->polygon_of || !acc) {
        free(acc);
        scan_release(s);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the scan");
    }
    memcpy(s->positions, mesh->positions, sizeof(float) * 3 * (size_t)n);

    /* Bounding box of the vertices faces use. */
    double lo[3] = {DBL_MAX, DBL_MAX, DBL_MAX}, hi[3] = {-DBL_MAX, -DBL_MAX, -DBL_MAX};
    int64_t t = 0;
    corner = 0;
    for (int32_t f = 0; f < mesh->face_count; ++f) {
        const int32_t size = mesh->face_sizes[f];
        const int32_t *fv = mesh->face_vertices + corner;
        corner += size;
        for (int32_t k = 0; k < size; ++k)
            for (int c = 0; c < 3; ++c) {
                const double x = mesh->positions[3 * (int64_t)fv[k] + c];
                lo[c] = x < lo[c] ? x : lo[c];
                hi[c] = x > hi[c] ? x : hi[c];
            }
        if (face_repeats_vertex(fv, size)) continue;
        for (int32_t k = 1; k + 1 < size; ++k) {
            int32_t *tri = s->triangles + 3 * t;
            tri[0] = fv[0];
            tri[1] = fv[k];
            tri[2] = fv[k + 1];
            s->polygon_of[t++] = f;
            /* Area-weighted normal: the cross product, added to each corner. */
            const float *a = s->positions + 3 * (int64_t)tri[0], *b = s->positions + 3 * (int64_t)tri[1],
                        *c = s->positions + 3 * (int64_t)tri[2];
            const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
            const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
            const double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                                  e1[0] * e2[1] - e1[1] * e2[0]};
            for (int j = 0; j < 3; ++j)
                for (int q = 0; q < 3; ++q) acc[3 * (int64_t)tri[j] + q] += cr[q];
        }
    }
    s->diagonal = sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                       (hi[2] - lo[2]) * (hi[2] - lo[2]));
    for (int32_t v = 0; v < n; ++v) {
        const double *a = acc + 3 * (int64_t)v;
        const double len = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        if (len > 0.0)
            for (int q = 0; q < 3; ++q) s->normals[3 * (int64_t)v + q] = (float)(a[q] / len);
    }
    free(acc);
    s->seconds[1] = spia__now() - t0;
    t0 = spia__now();

    /* The hierarchy sorts the triangles into its leaf order; the polygons
     * they came from follow. */
    {
        const spia_result r = spia__bvh_build(&s->bvh, s->positions, s->triangles, tris, spia__processor_count(),
                                              status);
        if (r != SPIA_OK) {
            scan_release(s);
            return r;
        }
        int32_t *polygon_of = malloc(sizeof(int32_t) * (size_t)tris);
        if (!polygon_of) {
            scan_release(s);
            return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the scan");
        }
        for (int64_t i = 0; i < tris; ++i) polygon_of[i] = s->polygon_of[s->bvh.order[i]];
        free(s->polygon_of);
        s->polygon_of = polygon_of;
    }
    s->seconds[2] = spia__now() - t0;
    t0 = spia__now();
    if (mark_boundary(s) != SPIA_OK) {
        scan_release(s);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the scan's boundary");
    }
    s->seconds[3] = spia__now() - t0;
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

/* Whether barycentric weights (of corners 0, 1, 2) put a point on the scan's
 * boundary: on a boundary edge, or at a boundary vertex. */
static int on_scan_boundary(unsigned char bits, const double bary[3]) {
    const int zero[3] = {bary[0] == 0.0, bary[1] == 0.0, bary[2] == 0.0};
    if (zero[0] + zero[1] + zero[2] == 2) /* a corner */
        for (int k = 0; k < 3; ++k)
            if (!zero[k]) return (bits >> (3 + k)) & 1;
    /* edge k runs from corner k to corner k + 1: the third weight is 0 */
    for (int k = 0; k < 3; ++k)
        if (zero[(k + 2) % 3] && ((bits >> k) & 1)) return 1;
    return 0;
}

/* One query; writes the outputs for point i. */
static void closest_one(const spia_scan *s, const double p[3], float radius, int64_t i, float *closest,
                        float *normals, float *distances, int32_t *faces, uint8_t *on_boundary) {
    spia__bvh_hit q;
    spia__bvh_closest(&s->bvh, p, radius, &q);
    if (q.triangle < 0) { /* a point that is not finite (the internal entry point does not check) */
        q.triangle = 0;
        const int32_t *tri = s->triangles;
        for (int c = 0; c < 3; ++c) q.point[c] = s->positions[3 * (int64_t)tri[0] + c];
        q.bary[0] = 1.0, q.bary[1] = 0.0, q.bary[2] = 0.0;
        q.d2 = 0.0;
        for (int c = 0; c < 3; ++c) q.d2 += (q.point[c] - p[c]) * (q.point[c] - p[c]);
    }
    if (closest)
        for (int c = 0; c < 3; ++c) closest[3 * i + c] = (float)q.point[c];
    if (distances) distances[i] = (float)sqrt(q.d2);
    if (faces) faces[i] = s->polygon_of[q.triangle];
    if (on_boundary) on_boundary[i] = (uint8_t)on_scan_boundary(s->boundary_bits[q.triangle], q.bary);
    if (normals) {
        const int32_t *tri = s->triangles + 3 * q.triangle;
        double nrm[3] = {0.0, 0.0, 0.0};
        for (int k = 0; k < 3; ++k)
            for (int c = 0; c < 3; ++c) nrm[c] += q.bary[k] * s->normals[3 * (int64_t)tri[k] + c];
        double len = sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
        if (!(len > 1e-12)) { /* opposite vertex normals cancel: the face's own normal */
            const float *a = s->positions + 3 * (int64_t)tri[0], *b = s->positions + 3 * (int64_t)tri[1],
                        *c = s->positions + 3 * (int64_t)tri[2];
            const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
            const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
            nrm[0] = e1[1] * e2[2] - e1[2] * e2[1];
            nrm[1] = e1[2] * e2[0] - e1[0] * e2[2];
            nrm[2] = e1[0] * e2[1] - e1[1] * e2[0];
            len = sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
        }
        for (int c = 0; c < 3; ++c) normals[3 * i + c] = len > 0.0 ? (float)(nrm[c] / len) : 0.0f;
    }
}

typedef struct closest_task {
    const spia_scan *scan;
    const double *points_double;
    const float *points_float;
    const float *radius;
    float *closest, *normals, *distances;
    int32_t *faces;
    uint8_t *on_boundary;
} closest_task;

static void closest_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const closest_task *t = (const closest_task *)context;
    for (int64_t i = begin; i < end; ++i) {
        double p[3];
        for (int c = 0; c < 3; ++c) p[c] = t->points_double ? t->points_double[3 * i + c] : t->points_float[3 * i + c];
        closest_one(t->scan, p, t->radius ? t->radius[i] : INFINITY, i, t->closest, t->normals, t->distances,
                    t->faces, t->on_boundary);
    }
}

void spia__scan_closest_points_double(const spia_scan *s, int64_t count, const double *points, const float *radius,
                                      float *closest, float *normals, float *distances, int32_t *faces,
                                      uint8_t *on_boundary, int threads) {
    closest_task task = {s, points, NULL, radius, closest, normals, distances, faces, on_boundary};
    spia__parallel_for(threads, count, 256, closest_range, &task);
}

spia_result spia_scan_closest_points(const spia_scan *scan, int64_t count, const float *points, float *closest,
                                     float *normals, float *distances, int32_t *faces, uint8_t *on_boundary,
                                     spia_status *status) {
    if (!scan) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "scan must not be NULL");
    if (count < 0) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "negative point count");
    if (count > 0 && !points) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "points must not be NULL");
    for (int64_t i = 0; i < 3 * count; ++i)
        if (!isfinite(points[i]))
            return spia__fail(status, SPIA_ERROR_NONFINITE, i / 3, "query point %lld is not finite",
                              (long long)(i / 3));
    closest_task task = {scan, NULL, points, NULL, closest, normals, distances, faces, on_boundary};
    spia__parallel_for(spia__processor_count(), count, 256, closest_range, &task);
    spia__ok(status);
    return SPIA_OK;
}
