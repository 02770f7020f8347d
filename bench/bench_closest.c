// SPDX-License-Identifier: GPL-3.0-or-later
/* Closest points on a scan: the library's bounding volume hierarchy
 * (csrc/src/bvh.c) against Embree's point query, side by side on the same
 * triangles and query points.
 *
 * The Embree path is the one the library used before it had its own
 * hierarchy: rtcPointQuery over one triangle geometry, a callback that
 * computes the exact distance in double (the same spia__triangle_distance2)
 * and keeps the nearest, ties to the lower triangle index, shrinking the
 * query radius a hair wider than the best distance.  Embree lives only in
 * this program (found at configure time, Embree 4 or 3), never in the
 * library.
 *
 *   spia_bench_closest [--data DIR] [--out FILE.md] [--queries N]
 *                      [--large TRIANGLES] [--reps R]
 *
 * Scans: tests/data/bun_zipper.obj and dragon_res2.obj with query points
 * from their QuadriFlow cages (level-0 vertices, jittered) and from near
 * their surfaces (offset along the normal by up to 2% of the diagonal), and
 * a synthetic bumpy torus of about --large triangles.  Prints a Markdown
 * table (and writes it to --out) and fails if the two ever disagree by more
 * than 1e-6 of the diagonal. */
#if !defined(_WIN32) && !defined(_GNU_SOURCE)
#define _GNU_SOURCE /* dladdr */
#endif
#include "bvh.h"
#include "internal.h"
#include "threads.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#if defined(SPIA_EMBREE_VERSION)
#if SPIA_EMBREE_VERSION >= 4
#include <embree4/rtcore.h>
#else
#include <embree3/rtcore.h>
#endif
#include <dlfcn.h>
#include <stdatomic.h>
#include <sys/stat.h>
#endif

#ifndef SPIA_BENCH_DATA_DIR
#define SPIA_BENCH_DATA_DIR "tests/data"
#endif

static void *xmalloc(size_t n) {
    void *p = malloc(n ? n : 1);
    if (!p) {
        fprintf(stderr, "out of memory (%zu bytes)\n", n);
        exit(2);
    }
    return p;
}

/* ------------------------------------------------------------------------ */
/* Meshes                                                                    */
/* ------------------------------------------------------------------------ */

typedef struct scan {
    char name[64];
    int32_t vertex_count;
    int64_t triangle_count;
    float *positions;
    int32_t *triangles; /* fans of the faces; faces that repeat a vertex left out, as scan.c does */
    double diagonal;
    float *cage; /* level-0 cage vertices, or NULL */
    int32_t cage_count;
} scan;

/* Reads the vertices and (when triangles is not NULL) the faces of an OBJ
 * file, cut into fans. */
static int read_obj(const char *path, float **positions, int32_t *vertex_count, int32_t **triangles,
                    int64_t *triangle_count) {
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    fseek(f, 0, SEEK_END);
    const long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *text = xmalloc((size_t)size + 1);
    const size_t got = fread(text, 1, (size_t)size, f);
    fclose(f);
    text[got] = '\0';
    int64_t nv = 0, cap_v = 1024, nt = 0, cap_t = 1024;
    float *p = xmalloc(sizeof(float) * 3 * (size_t)cap_v);
    int32_t *t = xmalloc(sizeof(int32_t) * 3 * (size_t)cap_t);
    for (char *line = text; *line;) {
        char *next = strchr(line, '\n');
        if (next) *next = '\0';
        if (line[0] == 'v' && line[1] == ' ') {
            if (nv == cap_v) p = realloc(p, sizeof(float) * 3 * (size_t)(cap_v *= 2));
            if (!p) return 0;
            char *s = line + 2;
            for (int k = 0; k < 3; ++k) p[3 * nv + k] = strtof(s, &s);
            ++nv;
        } else if (line[0] == 'f' && line[1] == ' ' && triangles) {
            int32_t v[256];
            int n = 0;
            char *s = line + 2;
            while (n < 256) {
                while (*s == ' ' || *s == '\t') ++s;
                if (!*s || *s == '\r') break;
                v[n++] = (int32_t)strtol(s, &s, 10) - 1;
                while (*s && *s != ' ' && *s != '\t' && *s != '\r') ++s;
            }
            int repeats = 0;
            for (int a = 0; a < n; ++a)
                for (int b = a + 1; b < n; ++b) repeats |= v[a] == v[b];
            for (int k = 1; !repeats && k + 1 < n; ++k) {
                if (nt == cap_t) t = realloc(t, sizeof(int32_t) * 3 * (size_t)(cap_t *= 2));
                if (!t) return 0;
                t[3 * nt] = v[0], t[3 * nt + 1] = v[k], t[3 * nt + 2] = v[k + 1];
                ++nt;
            }
        }
        if (!next) break;
        line = next + 1;
    }
    free(text);
    *positions = p;
    *vertex_count = (int32_t)nv;
    if (triangles) {
        *triangles = t;
        *triangle_count = nt;
    } else {
        free(t);
    }
    return 1;
}

static void set_diagonal(scan *s) {
    double lo[3] = {DBL_MAX, DBL_MAX, DBL_MAX}, hi[3] = {-DBL_MAX, -DBL_MAX, -DBL_MAX};
    for (int64_t i = 0; i < 3 * s->triangle_count; ++i)
        for (int k = 0; k < 3; ++k) {
            const double x = s->positions[3 * (int64_t)s->triangles[i] + k];
            lo[k] = x < lo[k] ? x : lo[k];
            hi[k] = x > hi[k] ? x : hi[k];
        }
    s->diagonal = sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                       (hi[2] - lo[2]) * (hi[2] - lo[2]));
}

static int load_scan(const char *dir, const char *name, scan *s) {
    memset(s, 0, sizeof *s);
    snprintf(s->name, sizeof s->name, "%s", name);
    char path[4096];
    snprintf(path, sizeof path, "%s/%s.obj", dir, name);
    if (!read_obj(path, &s->positions, &s->vertex_count, &s->triangles, &s->triangle_count)) {
        fprintf(stderr, "cannot read %s\n", path);
        return 0;
    }
    snprintf(path, sizeof path, "%s/%s_quadriflow_cage.obj", dir, name);
    if (!read_obj(path, &s->cage, &s->cage_count, NULL, NULL)) {
        fprintf(stderr, "cannot read %s\n", path);
        return 0;
    }
    set_diagonal(s);
    return 1;
}

/* A torus of nu x nv quads (2 triangles each) with bumps a tenth of its
 * tube radius high: a closed, scan-like surface of any size. */
static void make_torus(int64_t triangles, scan *s) {
    memset(s, 0, sizeof *s);
    const int32_t nv = (int32_t)ceil(sqrt((double)triangles / 4.0)), nu = 2 * nv;
    s->vertex_count = nu * nv;
    s->triangle_count = 2 * (int64_t)nu * nv;
    snprintf(s->name, sizeof s->name, "synthetic torus");
    s->positions = xmalloc(sizeof(float) * 3 * (size_t)s->vertex_count);
    s->triangles = xmalloc(sizeof(int32_t) * 3 * (size_t)s->triangle_count);
    for (int32_t j = 0; j < nv; ++j)
        for (int32_t i = 0; i < nu; ++i) {
            const double u = 2.0 * M_PI * i / nu, v = 2.0 * M_PI * j / nv;
            const double r = 0.3 * (1.0 + 0.1 * sin(7.0 * u) * sin(5.0 * v) + 0.02 * sin(61.0 * u + 37.0 * v));
            float *p = s->positions + 3 * ((int64_t)j * nu + i);
            p[0] = (float)((1.0 + r * cos(v)) * cos(u));
            p[1] = (float)((1.0 + r * cos(v)) * sin(u));
            p[2] = (float)(r * sin(v));
        }
    int64_t t = 0;
    for (int32_t j = 0; j < nv; ++j)
        for (int32_t i = 0; i < nu; ++i) {
            const int32_t a = j * nu + i, b = j * nu + (i + 1) % nu, c = ((j + 1) % nv) * nu + (i + 1) % nu,
                          d = ((j + 1) % nv) * nu + i;
            int32_t *x = s->triangles + 6 * t++;
            x[0] = a, x[1] = b, x[2] = c, x[3] = a, x[4] = c, x[5] = d;
        }
    set_diagonal(s);
}

static void scan_free(scan *s) {
    free(s->positions);
    free(s->triangles);
    free(s->cage);
}

/* ------------------------------------------------------------------------ */
/* Query points                                                              */
/* ------------------------------------------------------------------------ */

static uint64_t rng_state;
static double uniform(void) { /* splitmix64, in [0, 1) */
    uint64_t z = (rng_state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1p-53;
}

/* A quarter from the cage's vertices (in the cage's order, each jittered by
 * up to 0.5% of the diagonal on each axis), the rest near the surface: a
 * triangle drawn by area, a point on it drawn uniformly, moved along the
 * triangle's normal by up to 2% of the diagonal either way. */
static double *make_queries(const scan *s, int64_t count) {
    rng_state = 12345;
    double *q = xmalloc(sizeof(double) * 3 * (size_t)count);
    const int64_t from_cage = s->cage ? count / 4 : 0;
    for (int64_t i = 0; i < from_cage; ++i)
        for (int k = 0; k < 3; ++k)
            q[3 * i + k] = s->cage[3 * (i % s->cage_count) + k] + (2.0 * uniform() - 1.0) * 0.005 * s->diagonal;
    double *cdf = xmalloc(sizeof(double) * (size_t)s->triangle_count);
    double total = 0.0;
    for (int64_t t = 0; t < s->triangle_count; ++t) {
        const float *a = s->positions + 3 * (int64_t)s->triangles[3 * t], *b = s->positions + 3 * (int64_t)s->triangles[3 * t + 1],
                    *c = s->positions + 3 * (int64_t)s->triangles[3 * t + 2];
        const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        total += sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        cdf[t] = total;
    }
    for (int64_t i = from_cage; i < count; ++i) {
        const double x = uniform() * total;
        int64_t lo = 0, hi = s->triangle_count - 1;
        while (lo < hi) {
            const int64_t mid = (lo + hi) / 2;
            if (cdf[mid] <= x) lo = mid + 1;
            else hi = mid;
        }
        const int32_t *tri = s->triangles + 3 * lo;
        const float *a = s->positions + 3 * (int64_t)tri[0], *b = s->positions + 3 * (int64_t)tri[1],
                    *c = s->positions + 3 * (int64_t)tri[2];
        double r1 = sqrt(uniform()), r2 = uniform();
        const double w[3] = {1.0 - r1, r1 * (1.0 - r2), r1 * r2};
        const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const double off = (2.0 * uniform() - 1.0) * 0.02 * s->diagonal / (len > 0.0 ? len : 1.0);
        for (int k = 0; k < 3; ++k) q[3 * i + k] = w[0] * a[k] + w[1] * b[k] + w[2] * c[k] + off * n[k];
    }
    free(cdf);
    return q;
}

/* ------------------------------------------------------------------------ */
/* Measuring                                                                 */
/* ------------------------------------------------------------------------ */

static long resident_bytes(void) {
#ifdef __linux__
    FILE *f = fopen("/proc/self/statm", "r");
    long pages = 0, resident = 0;
    if (!f) return 0;
    if (fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
    fclose(f);
    return resident * 4096;
#else
    return 0;
#endif
}

/* One query's answer: the closest point, its squared distance and the
 * triangle (its index in the scan's own order). */
typedef struct answer {
    double point[3];
    double d2;
    int64_t triangle;
} answer;

typedef struct run {
    const double *queries;
    answer *answers;
    const spia__bvh *bvh;
#if defined(SPIA_EMBREE_VERSION)
    RTCScene scene;
    const scan *s;
#endif
} run;

static void bvh_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const run *r = (const run *)context;
    for (int64_t i = begin; i < end; ++i) {
        spia__bvh_hit hit;
        spia__bvh_closest(r->bvh, r->queries + 3 * i, INFINITY, &hit);
        answer *a = r->answers + i;
        memcpy(a->point, hit.point, sizeof a->point);
        a->d2 = hit.d2;
        a->triangle = hit.triangle < 0 ? -1 : (int64_t)r->bvh->order[hit.triangle];
    }
}

#if defined(SPIA_EMBREE_VERSION)
typedef struct query_state {
    const scan *s;
    double p[3];
    double best_d2;
    int64_t best_tri;
    double best_point[3];
} query_state;

/* The callback of the library's former Embree path. */
static bool query_triangle(struct RTCPointQueryFunctionArguments *args) {
    query_state *q = (query_state *)args->userPtr;
    const int32_t *tri = q->s->triangles + 3 * (int64_t)args->primID;
    const float *pos = q->s->positions;
    double bary[3], x[3];
    const double d2 = spia__triangle_distance2(q->p, pos + 3 * (int64_t)tri[0], pos + 3 * (int64_t)tri[1],
                                               pos + 3 * (int64_t)tri[2], bary, x);
    if (d2 < q->best_d2 || (d2 == q->best_d2 && (int64_t)args->primID < q->best_tri)) {
        q->best_d2 = d2;
        q->best_tri = (int64_t)args->primID;
        memcpy(q->best_point, x, sizeof x);
        /* Shrink the search; a hair wider than sqrt(d2) so that float
         * rounding never culls a triangle at the same distance. */
        const float r = (float)(sqrt(d2) * (1.0 + 1e-6)) + FLT_MIN;
        if (r < args->query->radius) {
            args->query->radius = r;
            return true;
        }
    }
    return false;
}

static void embree_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const run *r = (const run *)context;
    for (int64_t i = begin; i < end; ++i) {
        query_state q;
        q.s = r->s;
        memcpy(q.p, r->queries + 3 * i, sizeof q.p);
        q.best_d2 = INFINITY;
        q.best_tri = -1;
        struct RTCPointQuery query;
        query.x = (float)q.p[0];
        query.y = (float)q.p[1];
        query.z = (float)q.p[2];
        query.time = 0.0f;
        query.radius = INFINITY;
        struct RTCPointQueryContext context;
        rtcInitPointQueryContext(&context);
        rtcPointQuery(r->scene, &query, &context, query_triangle, &q);
        answer *a = r->answers + i;
        memcpy(a->point, q.best_point, sizeof a->point);
        a->d2 = q.best_d2;
        a->triangle = q.best_tri;
    }
}

static atomic_llong embree_bytes;
static bool monitor(void *user, ssize_t bytes, bool post) {
    (void)user, (void)post;
    atomic_fetch_add(&embree_bytes, (long long)bytes);
    return true;
}

typedef struct embree_scene {
    RTCDevice device;
    RTCScene scene;
} embree_scene;

/* Device, then scene; returns the seconds the scene took to build. */
static double embree_build(const scan *s, const char *config, embree_scene *e, long long *bytes, long *rss) {
    e->device = rtcNewDevice(config);
    if (!e->device) {
        fprintf(stderr, "Embree could not create a device\n");
        exit(2);
    }
    rtcSetDeviceMemoryMonitorFunction(e->device, monitor, NULL);
    const long long bytes0 = atomic_load(&embree_bytes);
    const long rss0 = resident_bytes();
    const double t0 = spia__now();
    e->scene = rtcNewScene(e->device);
    RTCGeometry geom = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                        (size_t)s->vertex_count);
    unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                           (size_t)s->triangle_count);
    memcpy(vb, s->positions, sizeof(float) * 3 * (size_t)s->vertex_count);
    for (int64_t i = 0; i < 3 * s->triangle_count; ++i) ib[i] = (unsigned)s->triangles[i];
    rtcCommitGeometry(geom);
    rtcAttachGeometry(e->scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(e->scene);
    const double seconds = spia__now() - t0;
    if (rtcGetDeviceError(e->device) != RTC_ERROR_NONE) {
        fprintf(stderr, "Embree failed to build the scene\n");
        exit(2);
    }
    /* Less the two buffers (the scan's own copy, which the library kept
     * anyway): the hierarchy itself. */
    *bytes = atomic_load(&embree_bytes) - bytes0 - (long long)(sizeof(float) * 3 * (size_t)s->vertex_count) -
             (long long)(sizeof(unsigned) * 3 * (size_t)s->triangle_count);
    *rss = resident_bytes() - rss0;
    return seconds;
}

static void embree_release(embree_scene *e) {
    rtcReleaseScene(e->scene);
    rtcReleaseDevice(e->device);
}

static long long embree_library_size(char *path, size_t cap) {
    Dl_info info;
    struct stat st;
    char real[4096];
    if (!dladdr((void *)&rtcNewDevice, &info) || !info.dli_fname) return 0;
    if (!realpath(info.dli_fname, real)) snprintf(real, sizeof real, "%s", info.dli_fname);
    snprintf(path, cap, "%s", real);
    return stat(real, &st) == 0 ? (long long)st.st_size : 0;
}
#endif

/* One run, in queries per second. */
static double time_queries(spia__range_fn fn, run *r, int64_t count, int threads) {
    const double t0 = spia__now();
    spia__parallel_for(threads, count, 256, fn, r);
    return (double)count / (spia__now() - t0);
}

typedef struct row {
    char scan[64], structure[32];
    int64_t triangles;
    double build1, build2, qps1, qps2;
    long long bytes;
    long rss;
    double max_difference; /* relative to the diagonal; < 0: not compared */
    int64_t other_triangle, other_d2;
} row;

static void print_row(FILE *f, const row *r) {
    char diff[64] = "";
    if (r->max_difference >= 0.0) snprintf(diff, sizeof diff, "%.1e", r->max_difference);
    fprintf(f, "| %s | %lld | %s | %.3f | %.3f | %.0f | %.0f | %.1f MB (%.1f) | %.1f MB | %s |\n", r->scan,
            (long long)r->triangles, r->structure, r->build1, r->build2, r->qps1, r->qps2, r->bytes / 1e6,
            (double)r->bytes / (double)r->triangles, r->rss / 1e6, diff);
}

int main(int argc, char **argv) {
    const char *data = SPIA_BENCH_DATA_DIR, *out = NULL;
    int64_t queries = 1000000, large = 4000000;
    int reps = 3;
    for (int i = 1; i < argc; ++i) {
        if (!strcmp(argv[i], "--data") && i + 1 < argc) data = argv[++i];
        else if (!strcmp(argv[i], "--out") && i + 1 < argc) out = argv[++i];
        else if (!strcmp(argv[i], "--queries") && i + 1 < argc) queries = atoll(argv[++i]);
        else if (!strcmp(argv[i], "--large") && i + 1 < argc) large = atoll(argv[++i]);
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc) reps = atoi(argv[++i]);
        else {
            fprintf(stderr, "usage: %s [--data DIR] [--out FILE.md] [--queries N] [--large TRIANGLES] [--reps R]\n",
                    argv[0]);
            return 2;
        }
    }
    const int threads = spia__processor_count();
    const int two = threads < 2 ? threads : 2;
    row rows[8];
    int nrows = 0, failed = 0;
    char notes[2048] = "";
#if defined(SPIA_EMBREE_VERSION)
    char lib_path[4096] = "?";
    const long long lib_size = embree_library_size(lib_path, sizeof lib_path);
    snprintf(notes, sizeof notes, "Embree %s (%s, %.1f MB).", RTC_VERSION_STRING, lib_path, lib_size / 1e6);
#else
    snprintf(notes, sizeof notes, "Embree not found: the library's hierarchy alone.");
    printf("Embree not found\n");
#endif
    for (int which = 0; which < 3; ++which) {
        scan s;
        if (which < 2) {
            if (!load_scan(data, which == 0 ? "bun_zipper" : "dragon_res2", &s)) return 2;
        } else {
            if (large <= 0) break;
            make_torus(large, &s);
        }
        double *q = make_queries(&s, queries);
        fprintf(stderr, "%s: %lld triangles, %lld queries\n", s.name, (long long)s.triangle_count,
                (long long)queries);

        /* Builds on every thread and on one, the best of `reps` each; the
         * first on every thread is kept for the queries (and measured). */
        row *r = &rows[nrows++];
        memset(r, 0, sizeof *r);
        snprintf(r->scan, sizeof r->scan, "%s", s.name);
        snprintf(r->structure, sizeof r->structure, "spia BVH");
        r->triangles = s.triangle_count;
        r->max_difference = -1.0;
        r->build1 = r->build2 = INFINITY;
        int32_t *tris = xmalloc(sizeof(int32_t) * 3 * (size_t)s.triangle_count);
        int32_t *scratch = xmalloc(sizeof(int32_t) * 3 * (size_t)s.triangle_count);
        spia__bvh bvh;
#if defined(SPIA_EMBREE_VERSION)
        row *e = &rows[nrows++];
        memset(e, 0, sizeof *e);
        snprintf(e->scan, sizeof e->scan, "%s", s.name);
        snprintf(e->structure, sizeof e->structure, "Embree %d", RTC_VERSION_MAJOR);
        e->triangles = s.triangle_count;
        e->build1 = e->build2 = INFINITY;
        embree_scene all;
#endif
        for (int rep = 0; rep < reps; ++rep)
            for (int pass = 0; pass < 2; ++pass) {
                const int keep = rep == 0 && pass == 0, t = pass ? 1 : threads;
                spia__bvh other;
                int32_t *into = keep ? tris : scratch;
                memcpy(into, s.triangles, sizeof(int32_t) * 3 * (size_t)s.triangle_count);
                const long rss0 = resident_bytes();
                const double t0 = spia__now();
                spia_status st;
                if (spia__bvh_build(keep ? &bvh : &other, s.positions, into, s.triangle_count, t, &st) != SPIA_OK) {
                    fprintf(stderr, "build: %s\n", st.message);
                    return 2;
                }
                const double seconds = spia__now() - t0;
                double *best = pass ? &r->build1 : &r->build2;
                *best = seconds < *best ? seconds : *best;
                if (keep) r->rss = resident_bytes() - rss0;
                else spia__bvh_free(&other);
#if defined(SPIA_EMBREE_VERSION)
                embree_scene es;
                long long bytes;
                long rss;
                const double es_seconds = embree_build(&s, pass ? "threads=1" : NULL, keep ? &all : &es,
                                                       keep ? &e->bytes : &bytes, keep ? &e->rss : &rss);
                best = pass ? &e->build1 : &e->build2;
                *best = es_seconds < *best ? es_seconds : *best;
                if (!keep) embree_release(&es);
#endif
            }
        r->bytes = (long long)spia__bvh_bytes(&bvh);
        fprintf(stderr, "  BVH: %lld nodes, depth %d\n", (long long)bvh.node_count, bvh.depth);

        /* Queries on 1 and 2 threads, the two structures in turn, the best
         * of `reps` each. */
        answer *mine = xmalloc(sizeof(answer) * (size_t)queries);
        run ctx;
        memset(&ctx, 0, sizeof ctx);
        ctx.queries = q;
        ctx.answers = mine;
        ctx.bvh = &bvh;
#if defined(SPIA_EMBREE_VERSION)
        answer *theirs = xmalloc(sizeof(answer) * (size_t)queries);
        run ectx;
        memset(&ectx, 0, sizeof ectx);
        ectx.queries = q;
        ectx.answers = theirs;
        ectx.scene = all.scene;
        ectx.s = &s;
#endif
        for (int pass = 0; pass < 2; ++pass)
            for (int rep = 0; rep < reps; ++rep) {
                const int t = pass ? two : 1;
                double *qps = pass ? &r->qps2 : &r->qps1;
                double x = time_queries(bvh_range, &ctx, queries, t);
                *qps = x > *qps ? x : *qps;
#if defined(SPIA_EMBREE_VERSION)
                qps = pass ? &e->qps2 : &e->qps1;
                x = time_queries(embree_range, &ectx, queries, t);
                *qps = x > *qps ? x : *qps;
#endif
            }
#if defined(SPIA_EMBREE_VERSION)
        double worst = 0.0;
        for (int64_t i = 0; i < queries; ++i) {
            double d2 = 0.0;
            for (int k = 0; k < 3; ++k)
                d2 += (mine[i].point[k] - theirs[i].point[k]) * (mine[i].point[k] - theirs[i].point[k]);
            worst = d2 > worst ? d2 : worst;
            e->other_triangle += mine[i].triangle != theirs[i].triangle;
            e->other_d2 += mine[i].d2 != theirs[i].d2;
        }
        e->max_difference = sqrt(worst) / s.diagonal;
        if (!(e->max_difference <= 1e-6)) {
            fprintf(stderr, "%s: the closest points differ by %g of the diagonal\n", s.name, e->max_difference);
            failed = 1;
        }
        fprintf(stderr, "  Embree: %lld of %lld on another triangle, %lld at another distance\n",
                (long long)e->other_triangle, (long long)queries, (long long)e->other_d2);
        free(theirs);
        embree_release(&all);
#endif
        free(scratch);
        spia__bvh_free(&bvh);
        free(mine);
        free(tris);
        free(q);
        scan_free(&s);
    }

    char header[1024];
    snprintf(header, sizeof header,
             "Closest points: %lld queries per scan (a quarter from the QuadriFlow cage's vertices jittered by up to "
             "0.5%% of the diagonal, the rest within 2%% of the diagonal of the surface; the synthetic scan has "
             "only the latter), %d processors, the best of %d runs (the two structures in turn). %s\n\n"
             "| scan | triangles | structure | build, 1 thread (s) | build, %d threads (s) | queries/s, 1 thread | "
             "queries/s, %d threads | bytes (per triangle) | RSS growth | max distance to the other's closest "
             "point / diagonal |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|\n",
             (long long)queries, threads, reps, notes, threads, two);
    fputs(header, stdout);
    for (int i = 0; i < nrows; ++i) print_row(stdout, &rows[i]);
    if (out) {
        FILE *f = fopen(out, "w");
        if (!f) {
            fprintf(stderr, "cannot write %s\n", out);
            return 2;
        }
        fputs(header, f);
        for (int i = 0; i < nrows; ++i) print_row(f, &rows[i]);
        fclose(f);
    }
    return failed;
}
