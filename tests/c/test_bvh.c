// SPDX-License-Identifier: GPL-3.0-or-later
/* The scan's bounding volume hierarchy (csrc/src/bvh.c) against a search
 * over every triangle: on the bunny scan and a piece of the dragon, with
 * query points from the QuadriFlow cage and random ones in and beyond the
 * box; and on nasty cases: triangles without area, duplicates, a flat scan,
 * one triangle, coordinates near 1e6, points on vertices and edges (ties),
 * a tree the heuristic would make too deep, 1, 2 and 3 threads, radius
 * hints that are too small, searches from a given start triangle (the
 * answer's, a neighbour, a far one, out of range), every allocation
 * failing in turn, and a tree
 * refitted to moved positions.  The hit
 * must be the very triangle the full search finds (least distance, then
 * lowest index) at the very same distance. */
#include "support.h"

#include "bvh.h"
#include "internal.h"
#include "threads.h"

#include <stdatomic.h>

/* The allocator of bvh_counted.c: counts calls and live blocks, and fails
 * call number fail_at. */
static atomic_long alloc_calls, live_blocks;
static long fail_at = -1;
void *spia_test_malloc(size_t size) {
    if (atomic_fetch_add(&alloc_calls, 1) == fail_at) return NULL;
    void *p = malloc(size);
    if (p) atomic_fetch_add(&live_blocks, 1);
    return p;
}
void *spia_test_calloc(size_t count, size_t size) {
    if (atomic_fetch_add(&alloc_calls, 1) == fail_at) return NULL;
    void *p = calloc(count, size);
    if (p) atomic_fetch_add(&live_blocks, 1);
    return p;
}
void *spia_test_realloc(void *p, size_t size) {
    if (atomic_fetch_add(&alloc_calls, 1) == fail_at) return NULL;
    void *q = realloc(p, size);
    if (q && !p) atomic_fetch_add(&live_blocks, 1);
    return q;
}
void spia_test_free(void *p) {
    if (p) atomic_fetch_sub(&live_blocks, 1);
    free(p);
}

/* Positions and faces of an OBJ file, read in two passes (counting first:
 * support.h's reader grows its arrays one item at a time, which the
 * sanitizers' realloc makes quadratic on a scan). */
static int read_scan(const char *path, tmesh *m) {
    memset(m, 0, sizeof *m);
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    char line[4096];
    int64_t nv = 0, nf = 0, nfv = 0;
    for (int pass = 0; pass < 2; ++pass) {
        rewind(f);
        while (fgets(line, sizeof line, f)) {
            if (line[0] == 'v' && line[1] == ' ') {
                if (pass) sscanf(line + 2, "%f %f %f", &m->pos[3 * m->nv], &m->pos[3 * m->nv + 1], &m->pos[3 * m->nv + 2]);
                if (pass) ++m->nv;
                else ++nv;
            } else if (line[0] == 'f' && line[1] == ' ') {
                int n = 0;
                for (char *p = line + 2; *p;) {
                    while (*p == ' ' || *p == '\t') ++p;
                    if (*p == '\n' || *p == '\r' || !*p) break;
                    const long v = strtol(p, &p, 10) - 1;
                    if (pass) m->fv[m->nfv++] = (int32_t)v;
                    ++n;
                    while (*p && *p != ' ' && *p != '\t' && *p != '\n') ++p;
                }
                if (pass) m->sizes[m->nf++] = n;
                else ++nf, nfv += n;
            }
        }
        if (!pass) {
            m->pos = (float *)malloc(sizeof(float) * 3 * (size_t)(nv ? nv : 1));
            m->sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nf ? nf : 1));
            m->fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nfv ? nfv : 1));
        }
    }
    fclose(f);
    return m->nv > 0;
}

static uint64_t rng = 1;
static double uniform(void) {
    uint64_t z = (rng += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return (double)((z ^ (z >> 31)) >> 11) * 0x1p-53;
}

/* Triangles: fans of a mesh's faces, faces that repeat a vertex left out
 * (as scan.c cuts them), each with the face it came from. */
typedef struct tris {
    const float *pos;
    int64_t n;
    int32_t *v;
    int32_t *face;
} tris;

static tris fans(const tmesh *m) {
    tris t = {m->pos, 0, NULL, NULL};
    t.v = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)m->nfv);
    t.face = (int32_t *)malloc(sizeof(int32_t) * (size_t)m->nfv);
    int64_t c = 0;
    for (int32_t f = 0; f < m->nf; ++f) {
        const int32_t *fv = m->fv + c, size = m->sizes[f];
        c += size;
        int repeats = 0;
        for (int a = 0; a < size; ++a)
            for (int b = a + 1; b < size; ++b) repeats |= fv[a] == fv[b];
        for (int32_t k = 1; !repeats && k + 1 < size; ++k) {
            t.v[3 * t.n] = fv[0], t.v[3 * t.n + 1] = fv[k], t.v[3 * t.n + 2] = fv[k + 1];
            t.face[t.n++] = f;
        }
    }
    return t;
}

static tris raw(const float *pos, const int32_t *v, int64_t n) {
    tris t = {pos, n, (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)n), NULL};
    memcpy(t.v, v, sizeof(int32_t) * 3 * (size_t)n);
    return t;
}

static void tris_free(tris *t) {
    free(t->v);
    free(t->face);
}

/* The full search: least distance, ties to the lowest index. */
typedef struct answer {
    int64_t triangle;
    double d2, point[3];
} answer;

static answer full_search(const tris *t, const double p[3]) {
    answer a = {-1, INFINITY, {0, 0, 0}};
    for (int64_t i = 0; i < t->n; ++i) {
        double bary[3], x[3];
        const int32_t *v = t->v + 3 * i;
        const double d2 = spia__triangle_distance2(p, t->pos + 3 * (int64_t)v[0], t->pos + 3 * (int64_t)v[1],
                                                   t->pos + 3 * (int64_t)v[2], bary, x);
        if (d2 < a.d2) a.triangle = i, a.d2 = d2, memcpy(a.point, x, sizeof x);
    }
    return a;
}

/* The hierarchy's answer, in the triangles' first order. */
static answer bvh_search(const spia__bvh *b, const double p[3], double radius) {
    spia__bvh_hit hit;
    spia__bvh_closest(b, p, radius, &hit);
    answer a = {hit.triangle < 0 ? -1 : (int64_t)b->order[hit.triangle], hit.d2,
                {hit.point[0], hit.point[1], hit.point[2]}};
    return a;
}

static int same_answer(answer a, answer b) {
    return a.triangle == b.triangle && a.d2 == b.d2 && memcmp(a.point, b.point, sizeof a.point) == 0;
}

/* Builds over a copy of t's triangles (the build sorts them). */
static int build(const tris *t, int threads, spia__bvh *b, int32_t **sorted) {
    *sorted = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)t->n);
    memcpy(*sorted, t->v, sizeof(int32_t) * 3 * (size_t)t->n);
    spia_status st;
    const spia_result r = spia__bvh_build(b, t->pos, *sorted, t->n, threads, &st);
    CHECK(r == SPIA_OK, "build of %lld triangles on %d threads: %s", (long long)t->n, threads, st.message);
    if (r != SPIA_OK) {
        free(*sorted);
        return 0;
    }
    CHECK(b->depth <= SPIA__BVH_MAX_DEPTH, "depth %d", (int)b->depth);
    /* Leaf order is a permutation of the triangles. */
    char *seen = (char *)calloc((size_t)t->n, 1);
    int ok = 1;
    for (int64_t i = 0; i < t->n; ++i) {
        const uint32_t o = b->order[i];
        ok &= o < t->n && !seen[o] && !memcmp(*sorted + 3 * i, t->v + 3 * (int64_t)o, 3 * sizeof(int32_t));
        if (o < t->n) seen[o] = 1;
    }
    CHECK(ok, "the leaf order is not a permutation of the triangles");
    free(seen);
    return 1;
}

/* Every point against the full search; returns the number that differ. */
static int64_t compare(const char *what, const tris *t, const spia__bvh *b, const double *points, int64_t count) {
    int64_t wrong = 0;
    for (int64_t i = 0; i < count; ++i) {
        const answer want = full_search(t, points + 3 * i), got = bvh_search(b, points + 3 * i, INFINITY);
        if (!same_answer(want, got)) {
            if (++wrong <= 5)
                fprintf(stderr, "%s: point %lld (%.9g %.9g %.9g): triangle %lld at d2 %.17g, the full search %lld at %.17g\n",
                        what, (long long)i, points[3 * i], points[3 * i + 1], points[3 * i + 2], (long long)got.triangle,
                        got.d2, (long long)want.triangle, want.d2);
        }
    }
    CHECK(wrong == 0, "%s: %lld of %lld points differ from the full search", what, (long long)wrong, (long long)count);
    return wrong;
}

/* count points: uniform in t's box grown by `grow` of its size on every side. */
static double *box_points(const tris *t, int64_t count, double grow) {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int64_t i = 0; i < 3 * t->n; ++i)
        for (int k = 0; k < 3; ++k) {
            const double x = t->pos[3 * (int64_t)t->v[i] + k];
            lo[k] = x < lo[k] ? x : lo[k];
            hi[k] = x > hi[k] ? x : hi[k];
        }
    double *p = (double *)malloc(sizeof(double) * 3 * (size_t)count);
    for (int64_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const double size = hi[k] - lo[k] > 0 ? hi[k] - lo[k] : 1.0;
            p[3 * i + k] = lo[k] - grow * size + (1.0 + 2.0 * grow) * size * uniform();
        }
    return p;
}

/* Queries on threads, through spia__parallel_for as scan.c makes them. */
typedef struct job {
    const spia__bvh *b;
    const double *points;
    const float *radius;
    answer *out;
} job;

static void job_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = (const job *)context;
    for (int64_t i = begin; i < end; ++i)
        j->out[i] = bvh_search(j->b, j->points + 3 * i, j->radius ? j->radius[i] : INFINITY);
}

/* The bunny scan: cage vertices, points in and beyond its box; the same on
 * 1, 2 and 3 threads (build and queries); radius hints; and the public
 * entry points on the same points. */
static void bunny(void) {
    tmesh m, cage;
    CHECK(read_scan(SPIA_TEST_DATA_DIR "/bun_zipper.obj", &m), "cannot read bun_zipper.obj");
    CHECK(read_scan(SPIA_TEST_DATA_DIR "/bun_zipper_quadriflow_cage.obj", &cage), "cannot read the bunny's cage");
    if (!m.nv || !cage.nv) return;
    tris t = fans(&m);
    spia__bvh b[3];
    int32_t *sorted[3];
    for (int k = 0; k < 3; ++k)
        if (!build(&t, k + 1, &b[k], &sorted[k])) return;
    printf("bunny: %lld triangles, %lld nodes, depth %d, %.1f bytes a triangle\n", (long long)t.n,
           (long long)b[0].node_count, (int)b[0].depth, (double)spia__bvh_bytes(&b[0]) / (double)t.n);
    for (int k = 1; k < 3; ++k)
        CHECK(b[k].node_count == b[0].node_count && !memcmp(b[k].order, b[0].order, sizeof(uint32_t) * (size_t)t.n),
              "the tree differs between 1 and %d threads", k + 1);

    /* Every 16th cage vertex, 100 points in the box, 50 beyond it. */
    enum { IN_BOX = 100, BEYOND = 50 };
    const int64_t from_cage = (cage.nv + 15) / 16, count = from_cage + IN_BOX + BEYOND;
    double *points = (double *)malloc(sizeof(double) * 3 * (size_t)count);
    for (int64_t i = 0; i < from_cage; ++i)
        for (int k = 0; k < 3; ++k) points[3 * i + k] = cage.pos[3 * (16 * i) + k];
    rng = 11;
    double *in = box_points(&t, IN_BOX, 0.0), *out = box_points(&t, BEYOND, 2.0);
    memcpy(points + 3 * from_cage, in, sizeof(double) * 3 * IN_BOX);
    memcpy(points + 3 * (from_cage + IN_BOX), out, sizeof(double) * 3 * BEYOND);
    free(in), free(out);
    for (int64_t i = 0; i < 3 * count; ++i) points[i] = (float)points[i]; /* for the public entry points too */
    answer *want = (answer *)malloc(sizeof(answer) * (size_t)count);
    int64_t wrong = 0;
    for (int64_t i = 0; i < count; ++i) {
        want[i] = full_search(&t, points + 3 * i);
        wrong += !same_answer(want[i], bvh_search(&b[0], points + 3 * i, INFINITY));
    }
    CHECK(wrong == 0, "bunny: %lld of %lld points differ from the full search", (long long)wrong, (long long)count);

    /* Threads: each tree queried on 1, 2 and 3 threads, in pieces of 7. */
    answer *got = (answer *)malloc(sizeof(answer) * (size_t)count);
    for (int k = 0; k < 3; ++k)
        for (int threads = 1; threads <= 3; ++threads) {
            job j = {&b[k], points, NULL, got};
            spia__parallel_for(threads, count, 7, job_range, &j);
            int64_t differ = 0;
            for (int64_t i = 0; i < count; ++i) differ += !same_answer(want[i], got[i]);
            CHECK(differ == 0, "bunny: tree of %d threads queried on %d: %lld points differ", k + 1, threads,
                  (long long)differ);
        }

    /* Radius hints: far too small (nothing within: a full search follows),
     * exactly the distance, a little larger, zero. */
    float *radius = (float *)malloc(sizeof(float) * (size_t)count);
    const double scale[4] = {1e-3, 1.0, 1.01, 0.0};
    for (int s = 0; s < 4; ++s) {
        for (int64_t i = 0; i < count; ++i) radius[i] = (float)(sqrt(want[i].d2) * scale[s]);
        job j = {&b[0], points, radius, got};
        spia__parallel_for(2, count, 16, job_range, &j);
        int64_t differ = 0;
        for (int64_t i = 0; i < count; ++i) differ += !same_answer(want[i], got[i]);
        CHECK(differ == 0, "bunny: radius hints %g of the distance: %lld points differ", scale[s], (long long)differ);
    }

    /* Start triangles (spia__bvh_closest_from): the answer itself, its
     * leaf neighbour, one far away, the last, and ones out of range. */
    {
        const int64_t starts = 6;
        int64_t differ = 0;
        int64_t *leaf_of = (int64_t *)malloc(sizeof(int64_t) * (size_t)t.n); /* triangle -> its place in leaf order */
        for (int64_t k = 0; k < t.n; ++k) leaf_of[b[0].order[k]] = k;
        for (int64_t i = 0; i < count; ++i) {
            const int64_t hit_leaf = want[i].triangle >= 0 ? leaf_of[want[i].triangle] : -1;
            const int64_t start[6] = {hit_leaf, hit_leaf + 1 < t.n ? hit_leaf + 1 : 0, (hit_leaf + t.n / 2) % t.n,
                                      t.n - 1, t.n, -7};
            for (int64_t s = 0; s < starts; ++s) {
                spia__bvh_hit hit;
                spia__bvh_closest_from(&b[0], points + 3 * i, start[s], &hit);
                const answer a = {hit.triangle < 0 ? -1 : (int64_t)b[0].order[hit.triangle], hit.d2,
                                  {hit.point[0], hit.point[1], hit.point[2]}};
                differ += !same_answer(want[i], a);
            }
        }
        CHECK(differ == 0, "bunny: %lld of %lld searches from a start triangle differ", (long long)differ,
              (long long)(starts * count));
        free(leaf_of);
    }

    /* The public entry points (the library's own tree, on every
     * processor): the same distances and faces. */
    {
        spia_mesh sm = tmesh_view(&m);
        spia_scan *scan = NULL;
        spia_status st;
        CHECK(spia_scan_create(&sm, &scan, &st) == SPIA_OK, "bunny scan: %s", st.message);
        float *fp = (float *)malloc(sizeof(float) * 3 * (size_t)count), *cl = (float *)malloc(sizeof(float) * 3 * (size_t)count);
        float *d = (float *)malloc(sizeof(float) * (size_t)count);
        int32_t *face = (int32_t *)malloc(sizeof(int32_t) * (size_t)count);
        for (int64_t i = 0; i < 3 * count; ++i) fp[i] = (float)points[i];
        CHECK(spia_scan_closest_points(scan, count, fp, cl, NULL, d, face, NULL, &st) == SPIA_OK, "bunny query: %s",
              st.message);
        int64_t differ = 0;
        for (int64_t i = 0; i < count; ++i) {
            const answer a = want[i];
            differ += d[i] != (float)sqrt(a.d2) || face[i] != t.face[a.triangle] || cl[3 * i] != (float)a.point[0] ||
                      cl[3 * i + 1] != (float)a.point[1] || cl[3 * i + 2] != (float)a.point[2];
        }
        CHECK(differ == 0, "bunny: spia_scan_closest_points differs from the full search at %lld of %lld points",
              (long long)differ, (long long)count);
        free(fp), free(cl), free(d), free(face);
        spia_scan_free(scan);
    }

    /* With far more vertices than triangles (loose points put before and
     * after the bunny's), the build's later steps need more memory than its
     * hierarchy worked in and take fresh memory instead: every answer,
     * normals and rim flags included, is the same. */
    {
        const int32_t extra = 40 * m.nf;
        float *pos = (float *)malloc(sizeof(float) * 3 * ((size_t)m.nv + (size_t)extra));
        int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)m.nfv);
        for (int64_t i = 0; i < 3 * ((int64_t)m.nv + extra); ++i) pos[i] = (float)(10.0 * uniform() - 5.0);
        memcpy(pos + 3 * (size_t)(extra / 2), m.pos, sizeof(float) * 3 * (size_t)m.nv);
        for (int64_t c = 0; c < m.nfv; ++c) fv[c] = m.fv[c] + extra / 2;
        spia_mesh plain = tmesh_view(&m), loose = plain;
        loose.positions = pos, loose.vertex_count = m.nv + extra, loose.face_vertices = fv;
        spia_scan *scan[2] = {NULL, NULL};
        spia_status st;
        CHECK(spia_scan_create(&plain, &scan[0], &st) == SPIA_OK, "bunny scan: %s", st.message);
        CHECK(spia_scan_create(&loose, &scan[1], &st) == SPIA_OK, "bunny scan with loose vertices: %s", st.message);
        float *fp = (float *)malloc(sizeof(float) * 3 * (size_t)count);
        float *out[2][3];
        int32_t *face[2];
        uint8_t *rim[2];
        for (int64_t i = 0; i < 3 * count; ++i) fp[i] = (float)points[i];
        for (int k = 0; k < 2 && scan[0] && scan[1]; ++k) {
            for (int j = 0; j < 3; ++j) out[k][j] = (float *)malloc(sizeof(float) * 3 * (size_t)count);
            face[k] = (int32_t *)malloc(sizeof(int32_t) * (size_t)count);
            rim[k] = (uint8_t *)malloc((size_t)count);
            CHECK(spia_scan_closest_points(scan[k], count, fp, out[k][0], out[k][1], out[k][2], face[k], rim[k], &st) ==
                      SPIA_OK,
                  "bunny query: %s", st.message);
        }
        if (scan[0] && scan[1]) {
            int64_t differ = 0, rims = 0;
            for (int64_t i = 0; i < count; ++i) {
                differ += face[0][i] != face[1][i] || rim[0][i] != rim[1][i] || out[0][2][i] != out[1][2][i];
                for (int j = 0; j < 2; ++j)
                    differ += memcmp(out[0][j] + 3 * i, out[1][j] + 3 * i, 3 * sizeof(float)) != 0;
                rims += rim[0][i];
            }
            CHECK(differ == 0, "bunny with loose vertices: %lld answers of %lld differ", (long long)differ,
                  (long long)count);
            CHECK(rims > 0, "bunny: no query point is over a hole (the rim flags go untested)");
            for (int k = 0; k < 2; ++k) {
                for (int j = 0; j < 3; ++j) free(out[k][j]);
                free(face[k]), free(rim[k]);
            }
        }
        spia_scan_free(scan[0]), spia_scan_free(scan[1]);
        free(fp), free(pos), free(fv);
    }

    free(radius), free(got), free(want), free(points);
    for (int k = 0; k < 3; ++k) spia__bvh_free(&b[k]), free(sorted[k]);
    tris_free(&t);
    tmesh_free(&m);
    tmesh_free(&cage);
}

/* The dragon's first 40,000 triangles: its cage vertices and random points. */
static void dragon(void) {
    tmesh m, cage;
    CHECK(read_scan(SPIA_TEST_DATA_DIR "/dragon_res2.obj", &m), "cannot read dragon_res2.obj");
    CHECK(read_scan(SPIA_TEST_DATA_DIR "/dragon_res2_quadriflow_cage.obj", &cage), "cannot read the dragon's cage");
    if (!m.nv || !cage.nv) return;
    tris t = fans(&m);
    t.n = t.n < 40000 ? t.n : 40000;
    spia__bvh b;
    int32_t *sorted;
    if (!build(&t, 2, &b, &sorted)) return;
    enum { FROM_CAGE = 150, RANDOM = 100 };
    double *points = (double *)malloc(sizeof(double) * 3 * (FROM_CAGE + RANDOM));
    for (int i = 0; i < FROM_CAGE; ++i)
        for (int k = 0; k < 3; ++k) points[3 * i + k] = cage.pos[3 * (int64_t)(i * (cage.nv / FROM_CAGE)) + k];
    rng = 12;
    double *r = box_points(&t, RANDOM, 0.5);
    memcpy(points + 3 * FROM_CAGE, r, sizeof(double) * 3 * RANDOM);
    free(r);
    compare("dragon, 40,000 triangles", &t, &b, points, FROM_CAGE + RANDOM);
    free(points);
    spia__bvh_free(&b);
    free(sorted);
    tris_free(&t);
    tmesh_free(&m);
    tmesh_free(&cage);
}

/* A case of its own: built on 1 and 3 threads, points against the full
 * search. */
static void check_case(const char *what, const tris *t, const double *points, int64_t count) {
    for (int threads = 1; threads <= 3; threads += 2) {
        spia__bvh b;
        int32_t *sorted;
        if (!build(t, threads, &b, &sorted)) return;
        char name[128];
        snprintf(name, sizeof name, "%s (%d threads)", what, threads);
        compare(name, t, &b, points, count);
        spia__bvh_free(&b);
        free(sorted);
    }
}

/* A flat n x n grid of unit squares in z = 0, two triangles each, moved by
 * `offset`; query points on every vertex, on edge midpoints, above, below
 * and beyond it. */
static void grid_case(const char *what, int n, double offset) {
    const int nv = (n + 1) * (n + 1);
    float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)nv);
    int32_t *v = (int32_t *)malloc(sizeof(int32_t) * 6 * (size_t)n * (size_t)n);
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i) {
            float *p = pos + 3 * (j * (n + 1) + i);
            p[0] = (float)(offset + i), p[1] = (float)(offset + j), p[2] = (float)offset;
        }
    int64_t k = 0;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const int32_t a = j * (n + 1) + i;
            const int32_t q[6] = {a, a + 1, a + n + 2, a, a + n + 2, a + n + 1};
            memcpy(v + 6 * k++, q, sizeof q);
        }
    tris t = raw(pos, v, 2 * (int64_t)n * n);
    const int64_t count = nv + 2 * (int64_t)n * (n + 1) + 300;
    double *points = (double *)malloc(sizeof(double) * 3 * (size_t)count);
    int64_t c = 0;
    for (int i = 0; i < nv; ++i) /* on the vertices: up to six triangles at distance 0 */
        for (int d = 0; d < 3; ++d) points[3 * c + d] = pos[3 * i + d];
    c = nv;
    for (int j = 0; j <= n; ++j) /* on the edges' midpoints */
        for (int i = 0; i < n; ++i) {
            const double x[3] = {offset + i + 0.5, offset + j, offset}, y[3] = {offset + j, offset + i + 0.5, offset};
            memcpy(points + 3 * c++, x, sizeof x);
            memcpy(points + 3 * c++, y, sizeof y);
        }
    for (; c < count; ++c) {
        points[3 * c] = offset - 2.0 + (n + 4.0) * uniform();
        points[3 * c + 1] = offset - 2.0 + (n + 4.0) * uniform();
        points[3 * c + 2] = offset + (c % 3 == 0 ? 0.0 : 4.0 * uniform() - 2.0);
    }
    check_case(what, &t, points, count);
    free(points);
    tris_free(&t);
    free(v);
    free(pos);
}

static void nasty(void) {
    rng = 5;
    /* Triangles without area (two corners at one place, three in a line,
     * all three at one place) among ordinary ones. */
    {
        enum { N = 600 };
        float *pos = (float *)malloc(sizeof(float) * 9 * N);
        int32_t *v = (int32_t *)malloc(sizeof(int32_t) * 3 * N);
        for (int i = 0; i < N; ++i) {
            float *p = pos + 9 * i;
            for (int k = 0; k < 3; ++k) p[k] = (float)(4.0 * uniform());
            for (int k = 0; k < 3; ++k) p[3 + k] = p[k] + (float)(0.3 * uniform() - 0.15);
            for (int k = 0; k < 3; ++k) p[6 + k] = p[k] + (float)(0.3 * uniform() - 0.15);
            switch (i % 4) {
            case 1: memcpy(p + 3, p, 3 * sizeof(float)); break;                                  /* a = b */
            case 2: for (int k = 0; k < 3; ++k) p[6 + k] = 2.0f * p[3 + k] - p[k]; break; /* a line */
            case 3: memcpy(p + 3, p, 3 * sizeof(float)), memcpy(p + 6, p, 3 * sizeof(float)); break; /* a point */
            default: break;
            }
            v[3 * i] = 3 * i, v[3 * i + 1] = 3 * i + 1, v[3 * i + 2] = 3 * i + 2;
        }
        tris t = raw(pos, v, N);
        double *points = box_points(&t, 400, 0.3);
        for (int i = 0; i < 100; ++i) /* on corners of the degenerate ones */
            for (int k = 0; k < 3; ++k) points[3 * i + k] = pos[9 * (4 * i + 1 + i % 3) + 3 * (i % 3) + k];
        check_case("triangles without area", &t, points, 400);
        free(points), tris_free(&t), free(pos), free(v);
    }
    /* Duplicates: every triangle four times over (the same indices, and the
     * same places through other vertices), and 3000 copies of one triangle
     * (all centroids at one place: halved, not split by the heuristic). */
    {
        enum { N = 200, COPIES = 3000 };
        float *pos = (float *)malloc(sizeof(float) * 3 * (2 * N + 3));
        int32_t *v = (int32_t *)malloc(sizeof(int32_t) * 3 * (4 * N + COPIES));
        for (int i = 0; i < 3 * N; ++i) pos[i] = (float)(2.0 * uniform());
        memcpy(pos + 3 * N, pos, sizeof(float) * 3 * N); /* vertices again, other indices */
        const float one[9] = {9.0f, 9.0f, 9.0f, 9.5f, 9.0f, 9.0f, 9.0f, 9.5f, 9.0f};
        memcpy(pos + 6 * N, one, sizeof one); /* vertices 2N .. 2N + 2 */
        int64_t k = 0;
        for (int copy = 0; copy < 4; ++copy)
            for (int i = 0; i < N; ++i, ++k) {
                const int base = copy % 2 ? N : 0;
                v[3 * k] = base + (3 * i) % N, v[3 * k + 1] = base + (3 * i + 1) % N, v[3 * k + 2] = base + (3 * i + 2) % N;
            }
        for (int i = 0; i < COPIES; ++i, ++k) v[3 * k] = 2 * N, v[3 * k + 1] = 2 * N + 1, v[3 * k + 2] = 2 * N + 2;
        tris t = {pos, k, v, NULL};
        double *points = box_points(&t, 300, 0.2);
        for (int i = 0; i < 50; ++i) /* on vertices of the duplicates */
            for (int d = 0; d < 3; ++d) points[3 * i + d] = pos[3 * i + d];
        for (int i = 50; i < 80; ++i) /* near the one copied 3000 times */
            for (int d = 0; d < 3; ++d) points[3 * i + d] = 9.0 + uniform() - 0.25;
        check_case("duplicate triangles", &t, points, 300);
        free(points), free(pos), free(v);
    }
    /* Flat: every triangle in z = 0, points on vertices and edges (ties
     * among up to six triangles at distance 0). */
    grid_case("a flat grid", 24, 0.0);
    /* Coordinates near 1e6 (floats there are 1/16 apart). */
    grid_case("a grid at 1e6", 24, 1e6);
    /* One triangle. */
    {
        const float pos[9] = {0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f};
        const int32_t v[3] = {0, 1, 2};
        tris t = raw(pos, v, 1);
        double *points = box_points(&t, 200, 1.0);
        const double on[5][3] = {{0, 0, 0}, {1, 0, 0}, {0.5, 0.5, 0}, {0.25, 0.25, 0}, {2, 2, 2}};
        memcpy(points, on, sizeof on);
        check_case("one triangle", &t, points, 200);
        free(points), tris_free(&t);
    }
    /* Sizes halving down to float's least: the heuristic peels them off a
     * few at a time and ends on centroids too close to bin (then halves). */
    {
        enum { N = 149 };
        float pos[9 * N];
        int32_t v[3 * N];
        for (int i = 0; i < N; ++i) {
            const float s = ldexpf(1.0f, -i);
            const float p[9] = {s, 0, 0, s, s * 0.5f, 0, s, 0, s * 0.5f};
            memcpy(pos + 9 * i, p, sizeof p);
            v[3 * i] = 3 * i, v[3 * i + 1] = 3 * i + 1, v[3 * i + 2] = 3 * i + 2;
        }
        tris t = raw(pos, v, N);
        double *points = box_points(&t, 100, 0.5);
        for (int i = 0; i < 40; ++i) points[3 * i] = ldexp(1.0, -i), points[3 * i + 1] = points[3 * i + 2] = 1e-3;
        check_case("halving sizes", &t, points, 100);
        free(points), tris_free(&t);
    }
}

/* Every allocation of a build failing in turn, on 1 thread and on 2: out of
 * memory, said in words, the triangles untouched, nothing left allocated. */
static void out_of_memory(void) {
    tmesh m = make_torus(100, 50, 1);
    tris t = fans(&m);
    int32_t *v = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)t.n);
    for (int threads = 1; threads <= 2; ++threads) {
        atomic_store(&alloc_calls, 0);
        fail_at = -1;
        spia__bvh b;
        spia_status st;
        memcpy(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n);
        CHECK(spia__bvh_build(&b, t.pos, v, t.n, threads, &st) == SPIA_OK, "torus: %s", st.message);
        spia__bvh_free(&b);
        const long calls = atomic_load(&alloc_calls);
        CHECK(calls > 5 && atomic_load(&live_blocks) == 0, "%ld allocations, %ld blocks left", calls,
              (long)atomic_load(&live_blocks));
        int failures = 0;
        for (long k = 0; k < calls; ++k) {
            atomic_store(&alloc_calls, 0);
            fail_at = k;
            memcpy(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n);
            memset(&st, 0, sizeof st);
            const spia_result r = spia__bvh_build(&b, t.pos, v, t.n, threads, &st);
            if (r == SPIA_OK) { /* on 2 threads the calls come in another order: this one was not reached */
                CHECK(threads > 1, "allocation %ld of %ld failed unnoticed", k, calls);
                spia__bvh_free(&b);
                continue;
            }
            ++failures;
            CHECK(r == SPIA_ERROR_OUT_OF_MEMORY && st.code == r && strstr(st.message, "out of memory"),
                  "allocation %ld failing: %s (%s)", k, spia_result_name(r), st.message);
            CHECK(b.nodes == NULL && b.order == NULL && b.node_count == 0, "allocation %ld failing: bvh not zeroed", k);
            CHECK(!memcmp(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n), "allocation %ld failing: triangles moved", k);
            CHECK(atomic_load(&live_blocks) == 0, "allocation %ld failing: %ld blocks left", k,
                  (long)atomic_load(&live_blocks));
        }
        CHECK(failures > 0, "no failure on %d threads", threads);
        fail_at = -1;
    }
    free(v);
    tris_free(&t);
    tmesh_free(&m);
}

/* Cancelling: a progress callback called at every poll (interval 0) that
 * asks to stop at its k-th call, for every k a build makes; each cancelled
 * build fails with SPIA_ERROR_CANCELLED, leaving nothing allocated and the
 * triangles in their first order.  (On two threads the calling thread's
 * share of the work, and so its number of polls, varies from build to
 * build: a build that ends before its k-th call is not cancelled.) */
typedef struct cancel_counter {
    long calls, stop_at;
} cancel_counter;

static int cancel_at(void *user, int32_t phase, double fraction) {
    (void)phase, (void)fraction;
    cancel_counter *c = (cancel_counter *)user;
    ++c->calls;
    return c->calls == c->stop_at;
}

static void cancelled(void) {
    tmesh m = make_torus(100, 50, 1);
    tris t = fans(&m);
    int32_t *v = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)t.n);
    for (int threads = 1; threads <= 2; ++threads) {
        cancel_counter all = {0, -1};
        spia__build_progress pr;
        memset(&pr, 0, sizeof pr);
        pr.fn = cancel_at, pr.user_data = &all, pr.interval = 0.0, pr.from = 0.0, pr.to = 1.0;
        spia__bvh b;
        spia_status st;
        memcpy(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n);
        CHECK(spia__bvh_build_progress(&b, t.pos, v, t.n, threads, &pr, &st) == SPIA_OK, "torus: %s", st.message);
        spia__bvh_free(&b);
        CHECK(all.calls > 3, "%ld progress calls on %d threads", all.calls, threads);
        int failures = 0;
        for (long k = 1; k <= all.calls; ++k) {
            cancel_counter c = {0, k};
            memset(&pr, 0, sizeof pr);
            pr.fn = cancel_at, pr.user_data = &c, pr.interval = 0.0, pr.from = 0.0, pr.to = 1.0;
            memcpy(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n);
            memset(&st, 0, sizeof st);
            const spia_result r = spia__bvh_build_progress(&b, t.pos, v, t.n, threads, &pr, &st);
            if (r == SPIA_OK) {
                CHECK(threads > 1 && c.calls < k, "cancelled at call %ld of %ld on %d threads, the build went on", k,
                      all.calls, threads);
                spia__bvh_free(&b);
                continue;
            }
            ++failures;
            CHECK(r == SPIA_ERROR_CANCELLED && st.code == r, "cancelled at call %ld of %ld on %d threads: %s", k,
                  all.calls, threads, spia_result_name(r));
            CHECK(c.calls == k, "%ld calls after cancelling at call %ld", c.calls, k);
            CHECK(b.nodes == NULL && b.order == NULL && b.node_count == 0, "cancelled at call %ld: bvh not zeroed", k);
            CHECK(!memcmp(v, t.v, sizeof(int32_t) * 3 * (size_t)t.n), "cancelled at call %ld: triangles moved", k);
            CHECK(atomic_load(&live_blocks) == 0, "cancelled at call %ld: %ld blocks left", k,
                  (long)atomic_load(&live_blocks));
        }
        CHECK(failures > 0, "no build cancelled on %d threads", threads);
    }
    free(v);
    tris_free(&t);
    tmesh_free(&m);
}

/* Refitting (spia__bvh_refit): on positions that have not moved it gives
 * every node the boxes the build gave, to the bit; after the bunny is bent
 * and shaken (a smooth bend of 5% of its size and a random jitter of 0.1%),
 * the refitted tree answers as a search over every moved triangle does. */
static void refit(void) {
    tmesh m;
    CHECK(read_scan(SPIA_TEST_DATA_DIR "/bun_zipper.obj", &m), "cannot read bun_zipper.obj");
    if (!m.nv) return;
    tris t = fans(&m);
    spia__bvh b;
    int32_t *sorted;
    if (!build(&t, 2, &b, &sorted)) return;
    const size_t bytes = sizeof(spia__bvh_node) * (size_t)b.node_count;
    spia__bvh_node *built = (spia__bvh_node *)malloc(bytes);
    memcpy(built, b.nodes, bytes);
    const double extent = b.extent;
    spia__bvh_refit(&b);
    CHECK(!memcmp(built, b.nodes, bytes) && b.extent == extent, "refitting an unmoved tree changed its boxes");
    rng = 31;
    double *points = box_points(&t, 400, 0.1);
    for (int32_t v = 0; v < m.nv; ++v) { /* m.pos is what t and the tree borrow */
        float *p = m.pos + 3 * (int64_t)v;
        p[1] += (float)(0.008 * sin(40.0 * p[0]) + 0.0002 * (uniform() - 0.5));
        p[2] += (float)(0.008 * cos(30.0 * p[1]) + 0.0002 * (uniform() - 0.5));
    }
    spia__bvh_refit(&b);
    int moved = 0;
    for (int64_t i = 0; i < b.node_count && !moved; ++i) moved = memcmp(&built[i], &b.nodes[i], sizeof *built) != 0;
    CHECK(moved, "refitting a moved tree left its boxes");
    compare("bunny, bent and refitted", &t, &b, points, 400);
    free(points);
    free(built);
    spia__bvh_free(&b);
    free(sorted);
    tris_free(&t);
    tmesh_free(&m);
}

int main(void) {
    nasty();
    out_of_memory();
    cancelled();
    refit();
    bunny();
    dragon();
    TEST_MAIN_END();
}
