// SPDX-License-Identifier: GPL-3.0-or-later
/* Out of memory: under an address-space limit (setrlimit) too small for the
 * stencil table of a large mesh, every entry point that needs memory
 * returns SPIA_ERROR_OUT_OF_MEMORY with a message, writes nothing and
 * leaks nothing.  Leaks are counted by this program's own malloc, free and
 * friends, which the library's calls (its C++ runtime's too) reach: the
 * bytes in use after a failed call must be those in use before it.
 *
 * Linux only (glibc's __libc_malloc, /proc/self/statm), and a plain build
 * only: AddressSanitizer reserves terabytes of address space. */
#include "support.h"

#include <malloc.h>
#include <stdatomic.h>
#include <sys/resource.h>

extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
extern void *__libc_memalign(size_t, size_t);
extern void __libc_free(void *);

static _Atomic long long live_bytes;
static _Atomic long long failed_allocations;

static void *counted(void *p, size_t asked) {
    if (p) atomic_fetch_add(&live_bytes, (long long)malloc_usable_size(p));
    else if (asked) atomic_fetch_add(&failed_allocations, 1);
    return p;
}
void *malloc(size_t n) { return counted(__libc_malloc(n), n); }
void *calloc(size_t n, size_t size) { return counted(__libc_calloc(n, size), n * size); }
void free(void *p) {
    if (p) atomic_fetch_sub(&live_bytes, (long long)malloc_usable_size(p));
    __libc_free(p);
}
void *realloc(void *p, size_t n) {
    long long before = p ? (long long)malloc_usable_size(p) : 0;
    void *q = __libc_realloc(p, n);
    if (q) {
        atomic_fetch_sub(&live_bytes, before);
        atomic_fetch_add(&live_bytes, (long long)malloc_usable_size(q));
    } else if (n == 0) {
        atomic_fetch_sub(&live_bytes, before);
    } else {
        atomic_fetch_add(&failed_allocations, 1);
    }
    return q;
}
void *memalign(size_t alignment, size_t n) { return counted(__libc_memalign(alignment, n), n); }
void *aligned_alloc(size_t alignment, size_t n) { return counted(__libc_memalign(alignment, n), n); }
int posix_memalign(void **out, size_t alignment, size_t n) {
    void *p = counted(__libc_memalign(alignment, n), n);
    if (!p && n) return 12; /* ENOMEM */
    *out = p;
    return 0;
}

/* Address space in use now, from /proc/self/statm (pages). */
static long long address_space(void) {
    FILE *f = fopen("/proc/self/statm", "r");
    long long pages = 0;
    if (f) {
        if (fscanf(f, "%lld", &pages) != 1) pages = 0;
        fclose(f);
    }
    return pages * 4096;
}

static struct rlimit original;

/* Free space inside the heap serves allocations whatever the limit says;
 * ballast fills it (in pieces below the mmap threshold) before a tight
 * limit is set, and is given back after. */
static void *ballast = NULL;
/* mallinfo2 is glibc 2.33 and later; the package's tests run on 2.31 too,
 * where mallinfo's int fields are enough for this test's heap. */
static size_t heap_free_bytes(void) {
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
    return mallinfo2().fordblks;
#else
    return (size_t)(unsigned)mallinfo().fordblks;
#endif
}
static void fill_heap(void) {
    while (heap_free_bytes() > (512u << 10)) {
        void **piece = (void **)malloc(16u << 10);
        if (!piece) break;
        *piece = ballast;
        ballast = piece;
    }
}
static void empty_heap(void) {
    while (ballast) {
        void *next = *(void **)ballast;
        free(ballast);
        ballast = next;
    }
}

static int limit_to(long long margin) {
    malloc_trim(0);
    if (margin < (8ll << 20)) fill_heap();
    struct rlimit r = original;
    r.rlim_cur = (rlim_t)(address_space() + margin);
    return setrlimit(RLIMIT_AS, &r) == 0;
}
static void unlimit(void) {
    setrlimit(RLIMIT_AS, &original);
    empty_heap();
}


static int run = 0;
/* The memory_budget of every call: -1 (no estimate, so that the
 * allocations themselves fail), or 0 (the estimates refuse up front). */
static int64_t budget = -1;

/* One call's outcome: out of memory, with a message, nothing leaked. */
static void expect_oom(const char *what, spia_result r, const spia_status *st, long long before) {
    ++run;
    const long long after = atomic_load(&live_bytes);
    CHECK(r == SPIA_ERROR_OUT_OF_MEMORY, "%s: %s (%s)", what, spia_result_name(r), st->message);
    CHECK(st->code == r, "%s: status code %d", what, (int)st->code);
    CHECK(strstr(st->message, "memory") != NULL, "%s: message \"%s\" does not say so", what, st->message);
    CHECK(after == before, "%s: %lld bytes leaked", what, after - before);
}

static int untouched(const float *p, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (p[i] != -7.0f) return 0;
    return 1;
}

typedef struct big {
    tmesh quads, triangles;
    spia_mesh qm, tm;
    spia_scan *small_scan;
    spia_stencils *table; /* of a mesh whose table fits, for spia_solve */
    tmesh table_mesh;
    float *cage, *refined;
    int32_t *refined_sizes, *refined_faces;
    size_t cage_floats;
} big;

/* Every entry point that needs memory, under the limit `margin` bytes
 * above what is in use. */
static void all_calls(big *b, long long margin, int tight) {
    spia_status st;
    spia_result r;
    long long before;
    static const spia_scheme schemes[3] = {SPIA_SCHEME_CATMULL_CLARK, SPIA_SCHEME_LOOP, SPIA_SCHEME_DOO_SABIN};
    char what[128];
    for (int k = 0; k < 3; ++k)
        for (int hoppe = 0; hoppe < (schemes[k] == SPIA_SCHEME_LOOP ? 2 : 1); ++hoppe) {
            spia_options o = spia_options_default();
            o.memory_budget = budget;
            o.scheme = schemes[k];
            o.boundary_rule = hoppe ? SPIA_BOUNDARY_RULE_HOPPE : SPIA_BOUNDARY_RULE_SMOOTH;
            const spia_mesh *m = schemes[k] == SPIA_SCHEME_LOOP ? &b->tm : &b->qm;
            spia_stencils *s = (spia_stencils *)&st;
            before = atomic_load(&live_bytes);
            if (!limit_to(margin)) CHECK(0, "setrlimit failed");
            r = spia_limit_stencils_create(m, &o, &s, &st);
            unlimit();
            snprintf(what, sizeof what, "%s stencils, scheme %d%s", tight ? "tight" : "medium", (int)schemes[k],
                     hoppe ? " (Hoppe)" : "");
            expect_oom(what, r, &st, before);
            CHECK(s == NULL, "%s: a table came back", what);
            if (s && r == SPIA_OK) spia_stencils_free(s);

            for (size_t i = 0; i < b->cage_floats; ++i) b->cage[i] = -7.0f;
            spia_report rep;
            memset(&rep, 0, sizeof rep);
            before = atomic_load(&live_bytes);
            if (!limit_to(margin)) CHECK(0, "setrlimit failed");
            r = spia_interpolate(m, &o, b->cage, &rep, &st);
            unlimit();
            snprintf(what, sizeof what, "%s interpolate, scheme %d%s", tight ? "tight" : "medium", (int)schemes[k],
                     hoppe ? " (Hoppe)" : "");
            expect_oom(what, r, &st, before);
            CHECK(rep.result == r, "%s: report says %d", what, (int)rep.result);
            CHECK(untouched(b->cage, 3 * (size_t)m->vertex_count), "%s: the cage was written", what);

            if (schemes[k] != SPIA_SCHEME_CATMULL_CLARK) {
                int32_t nv = 0, nf = 0;
                int64_t nc = 0;
                before = atomic_load(&live_bytes);
                if (!limit_to(margin)) CHECK(0, "setrlimit failed");
                r = spia_refine(m, &o, 1, b->refined, b->refined_sizes, b->refined_faces, &st);
                unlimit();
                snprintf(what, sizeof what, "%s refine, scheme %d%s", tight ? "tight" : "medium", (int)schemes[k],
                         hoppe ? " (Hoppe)" : "");
                expect_oom(what, r, &st, before);
                (void)nv;
                (void)nf;
                (void)nc;
            }
        }

    spia_options with_budget = spia_options_default();
    with_budget.memory_budget = budget;
    spia_stencils *s = (spia_stencils *)&st;
    before = atomic_load(&live_bytes);
    if (!limit_to(margin)) CHECK(0, "setrlimit failed");
    r = spia_surface_stencils_create(&b->qm, &with_budget, 4, &s, &st);
    unlimit();
    expect_oom(tight ? "tight surface stencils" : "medium surface stencils", r, &st, before);
    CHECK(s == NULL, "surface stencils: a table came back");

    spia_scan *scan = (spia_scan *)&st;
    before = atomic_load(&live_bytes);
    if (!limit_to(margin)) CHECK(0, "setrlimit failed");
    r = spia_scan_create(&b->tm, &scan, &st);
    unlimit();
    expect_oom(tight ? "tight scan" : "medium scan", r, &st, before);
    CHECK(scan == NULL, "scan: a scan came back");

    for (int mode = 0; mode < 2; ++mode) {
        spia_fit_options fo;
        memset(&fo, 0, sizeof fo);
        fo.mode = mode ? SPIA_FIT_VERTICES : SPIA_FIT_SURFACE;
        for (size_t i = 0; i < b->cage_floats; ++i) b->cage[i] = -7.0f;
        before = atomic_load(&live_bytes);
        if (!limit_to(margin)) CHECK(0, "setrlimit failed");
        r = spia_fit(&b->qm, b->small_scan, &with_budget, &fo, b->cage, NULL, &st);
        unlimit();
        snprintf(what, sizeof what, "%s fit, mode %d", tight ? "tight" : "medium", mode);
        expect_oom(what, r, &st, before);
        CHECK(untouched(b->cage, 3 * (size_t)b->qm.vertex_count), "%s: the cage was written", what);
    }

    if (tight) {
        before = atomic_load(&live_bytes);
        if (!limit_to(margin)) CHECK(0, "setrlimit failed");
        r = spia_mesh_validate(&b->qm, &st);
        unlimit();
        expect_oom("tight validate", r, &st, before);

        static const spia_method methods[] = {SPIA_METHOD_AUTO,      SPIA_METHOD_PIA,  SPIA_METHOD_GS_PIA,
                                              SPIA_METHOD_CHEBYSHEV, SPIA_METHOD_WPIA, SPIA_METHOD_CG,
                                              SPIA_METHOD_GS_PIA_FAST};
        for (size_t k = 0; k < sizeof methods / sizeof methods[0]; ++k) {
            spia_options o = spia_options_default();
            o.memory_budget = budget;
            o.method = methods[k];
            for (size_t i = 0; i < b->cage_floats; ++i) b->cage[i] = -7.0f;
            before = atomic_load(&live_bytes);
            if (!limit_to(margin)) CHECK(0, "setrlimit failed");
            r = spia_solve(b->table, b->table_mesh.pos, &o, b->cage, NULL, &st);
            unlimit();
            snprintf(what, sizeof what, "tight solve, method %d", (int)methods[k]);
            expect_oom(what, r, &st, before);
            CHECK(untouched(b->cage, 3 * (size_t)b->table_mesh.nv), "%s: the cage was written", what);
        }
    }
}

int main(void) {
    if (getrlimit(RLIMIT_AS, &original) != 0) {
        CHECK(0, "getrlimit failed");
        TEST_MAIN_END();
    }
    /* Large blocks always mapped on their own (glibc otherwise raises the
     * threshold and serves them from free heap space the limit does not
     * see), and the heap given back before each limit is set. */
    mallopt(M_MMAP_THRESHOLD, 128 * 1024);
    /* One arena: other arenas are reserved whole when made, so their free
     * room is invisible to the limit too (and a thread whose allocation
     * failed moves to one). */
    mallopt(M_ARENA_MAX, 1);
    big b;
    memset(&b, 0, sizeof b);
    /* A closed quad torus of a million vertices (Catmull-Clark, Doo-Sabin)
     * and its triangulation (Loop, the scan): their stencil tables take
     * hundreds of megabytes. */
    b.quads = make_torus(1000, 1000, 0);
    b.triangles = make_torus(1000, 1000, 1);
    b.qm = tmesh_view(&b.quads);
    b.tm = tmesh_view(&b.triangles);
    b.cage_floats = 3 * (size_t)b.quads.nv;
    b.cage = (float *)malloc(sizeof(float) * b.cage_floats);
    /* Output room for one level of refinement of the triangles (Loop) and
     * of the quads (Doo-Sabin): its counts first, with no limit. */
    spia_status st;
    int32_t nv = 0, nf = 0, lv = 0, lf = 0;
    int64_t nc = 0, lc = 0;
    spia_options loop = spia_options_default(), ds = spia_options_default();
    loop.scheme = SPIA_SCHEME_LOOP;
    ds.scheme = SPIA_SCHEME_DOO_SABIN;
    CHECK(spia_refine_size(&b.tm, &loop, 1, &lv, &lf, &lc, &st) == SPIA_OK, "Loop refine size: %s", st.message);
    CHECK(spia_refine_size(&b.qm, &ds, 1, &nv, &nf, &nc, &st) == SPIA_OK, "Doo-Sabin refine size: %s", st.message);
    if (lv > nv) nv = lv;
    if (lf > nf) nf = lf;
    if (lc > nc) nc = lc;
    b.refined = (float *)malloc(sizeof(float) * 3 * (size_t)nv);
    b.refined_sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)nf);
    b.refined_faces = (int32_t *)malloc(sizeof(int32_t) * (size_t)nc);
    tmesh small = make_torus(40, 30, 1);
    spia_mesh sm = tmesh_view(&small);
    CHECK(spia_scan_create(&sm, &b.small_scan, &st) == SPIA_OK, "small scan: %s", st.message);
    /* A table that fits, for the solvers (a quarter of a million rows). */
    b.table_mesh = make_torus(500, 500, 0);
    spia_mesh table_mesh = tmesh_view(&b.table_mesh);
    CHECK(spia_limit_stencils_create(&table_mesh, NULL, &b.table, &st) == SPIA_OK, "table: %s", st.message);
    if (!b.cage || !b.refined || !b.refined_sizes || !b.refined_faces || !b.small_scan || !b.table) TEST_MAIN_END();

    /* 48 MB above what is in use: the mesh is read and checked, its tables
     * do not fit; 1 MB: not even the checks' scratch arrays fit. */
    all_calls(&b, 48ll << 20, 0);
    all_calls(&b, 1ll << 20, 1);

    /* With the default budget (what is available, within the limit) every
     * call is refused by its estimate before it asks for what it cannot
     * have: not one allocation fails. */
    budget = 0;
    const long long failed_before = atomic_load(&failed_allocations);
    all_calls(&b, 48ll << 20, 0);
    CHECK(atomic_load(&failed_allocations) == failed_before,
          "%lld allocations failed under the estimates", atomic_load(&failed_allocations) - failed_before);
    budget = -1;

    /* With the limit lifted the same library works again. */
    const long long before = atomic_load(&live_bytes);
    tmesh t = make_torus(12, 8, 0);
    spia_mesh tm = tmesh_view(&t);
    float *cage = (float *)malloc(sizeof(float) * 3 * (size_t)t.nv);
    CHECK(spia_interpolate(&tm, NULL, cage, NULL, &st) == SPIA_OK, "after the limit: %s", st.message);
    free(cage);
    tmesh_free(&t);
    CHECK(atomic_load(&live_bytes) == before, "a successful call leaked");
    CHECK(atomic_load(&failed_allocations) > 0, "no allocation ever failed: the limit did not bite");
    printf("%d calls out of memory, %lld allocations refused\n", run, (long long)atomic_load(&failed_allocations));

    spia_stencils_free(b.table);
    spia_scan_free(b.small_scan);
    tmesh_free(&b.table_mesh);
    tmesh_free(&small);
    free(b.cage);
    free(b.refined);
    free(b.refined_sizes);
    free(b.refined_faces);
    tmesh_free(&b.quads);
    tmesh_free(&b.triangles);
    TEST_MAIN_END();
}
