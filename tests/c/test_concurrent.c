// SPDX-License-Identifier: GPL-3.0-or-later
/* Reentrancy: interpolations of different meshes (every scheme), fits to
 * one shared scan and closest-point queries on it, from several threads at
 * once, each call also using the library's own threads.  Every result must
 * be the one the same call gives alone, to the bit, and every progress
 * callback must see its own call's iterations and no other's.  `make test-tsan` runs it under
 * ThreadSanitizer, which must report nothing. */
#include "support.h"

#ifdef _WIN32
#include <windows.h>
#else
#include <pthread.h>
#endif

#define WORKERS 4
#define ROUNDS 3
#define QUERIES 2000

typedef struct job {
    const char *name;
    int kind; /* 0 interpolate, 1 fit, 2 closest points */
    tmesh mesh;
    spia_options options;
    spia_fit_options fit;
    /* the result alone, and its size in bytes */
    float *expected;
    size_t size;
    int32_t expected_iterations, expected_calls;
    double expected_sum;
} job;

typedef struct shared {
    const spia_scan *scan;
    const float *queries;
    job *jobs;
    int job_count;
} shared;

typedef struct counter {
    int32_t calls;
    double sum;
    int32_t last_iteration;
    double last_error;
} counter;

/* Counts the calls that report something new: the fit's calls within a
 * round repeat the last round's figures, as often as time says. */
static int count_progress(void *user, int32_t iteration, double relative_error) {
    counter *c = (counter *)user;
    if (c->calls > 0 && iteration == c->last_iteration && relative_error == c->last_error) return 0;
    if (c->calls == 0 && iteration == 0) return 0; /* a fit's calls before its first round */
    ++c->calls;
    c->sum += iteration + relative_error;
    c->last_iteration = iteration;
    c->last_error = relative_error;
    return 0;
}

/* Runs one job into `out`; *iterations gets its iterations (rounds) and
 * *calls the progress calls it saw; returns the result code. */
static int run_job(const shared *s, const job *j, float *out, int32_t *iterations, int32_t *calls, double *sum) {
    spia_status st;
    counter c = {0, 0.0, 0, 0.0};
    spia_options o = j->options;
    o.progress = count_progress;
    o.progress_user_data = &c;
    spia_result r;
    *iterations = -1;
    if (j->kind == 0) {
        spia_mesh m = tmesh_view(&j->mesh);
        spia_report rep;
        memset(&rep, 0, sizeof rep);
        r = spia_interpolate(&m, &o, out, &rep, &st);
        *iterations = rep.iterations;
    } else if (j->kind == 1) {
        spia_mesh m = tmesh_view(&j->mesh);
        spia_fit_report rep;
        memset(&rep, 0, sizeof rep);
        r = spia_fit(&m, s->scan, &o, &j->fit, out, &rep, &st);
        *iterations = rep.rounds;
    } else {
        /* closest points (3 floats) then distances (1 float) per query */
        r = spia_scan_closest_points(s->scan, QUERIES, s->queries, out, NULL, out + 3 * QUERIES, NULL, NULL, &st);
        *iterations = 0;
    }
    *calls = c.calls;
    *sum = c.sum;
    return (int)r;
}

typedef struct worker {
    const shared *s;
    int id;
    int failures;
} worker;

static void work(worker *w) {
    const shared *s = w->s;
    for (int round = 0; round < ROUNDS; ++round)
        for (int k = 0; k < s->job_count; ++k) {
            const job *j = &s->jobs[(k + w->id + round) % s->job_count];
            float *out = (float *)malloc(j->size);
            if (!out) abort();
            int32_t iterations, calls;
            double sum;
            int r = run_job(s, j, out, &iterations, &calls, &sum);
            if (r < 0) {
                fprintf(stderr, "worker %d, %s: result %d\n", w->id, j->name, r);
                ++w->failures;
            } else if (memcmp(out, j->expected, j->size) != 0 || iterations != j->expected_iterations ||
                       calls != j->expected_calls || sum != j->expected_sum) {
                fprintf(stderr, "worker %d, %s: differs from the result alone\n", w->id, j->name);
                ++w->failures;
            }
            free(out);
        }
}

#ifdef _WIN32
static DWORD WINAPI thread_main(LPVOID p) {
    work((worker *)p);
    return 0;
}
#else
static void *thread_main(void *p) {
    work((worker *)p);
    return NULL;
}
#endif

int main(void) {
    /* The scan: a dense triangulated torus; the cages to fit are coarse
     * tori, slightly off it. */
    tmesh scan_mesh = make_torus(90, 60, 1);
    spia_mesh sm = tmesh_view(&scan_mesh);
    spia_scan *scan = NULL;
    spia_status st;
    CHECK(spia_scan_create(&sm, &scan, &st) == SPIA_OK, "scan: %s", st.message);
    if (!scan) TEST_MAIN_END();

    job jobs[7];
    memset(jobs, 0, sizeof jobs);
    int n = 0;
    jobs[n].name = "Catmull-Clark torus";
    jobs[n].mesh = make_torus(40, 24, 0);
    ++n;
    jobs[n].name = "Catmull-Clark grid, staged";
    jobs[n].mesh = make_grid(30, 20);
    jobs[n].options.staged = 1;
    ++n;
    jobs[n].name = "Loop torus";
    jobs[n].mesh = make_torus(36, 20, 1);
    jobs[n].options.scheme = SPIA_SCHEME_LOOP;
    ++n;
    jobs[n].name = "Doo-Sabin torus";
    jobs[n].mesh = make_torus(30, 20, 0);
    jobs[n].options.scheme = SPIA_SCHEME_DOO_SABIN;
    ++n;
    for (int mode = 0; mode < 2; ++mode) {
        jobs[n].name = mode ? "fit, vertices" : "fit, surface";
        jobs[n].kind = 1;
        jobs[n].mesh = make_torus(16, 10, 0);
        for (int32_t i = 0; i < 3 * jobs[n].mesh.nv; ++i) jobs[n].mesh.pos[i] *= 1.04f;
        jobs[n].fit.mode = mode ? SPIA_FIT_VERTICES : SPIA_FIT_SURFACE;
        jobs[n].fit.max_rounds = 4;
        jobs[n].fit.cutoff = 0.2;
        ++n;
    }
    jobs[n].name = "closest points";
    jobs[n].kind = 2;
    ++n;
    float *queries = (float *)malloc(sizeof(float) * 3 * QUERIES);
    uint32_t seed = 12345;
    for (int i = 0; i < 3 * QUERIES; ++i) {
        seed = seed * 1664525u + 1013904223u;
        queries[i] = ((float)(seed >> 8) / 16777216.0f - 0.5f) * 7.0f;
    }
    shared s = {scan, queries, jobs, n};

    /* Each alone first, with the library's own threads (2) inside. */
    for (int k = 0; k < n; ++k) {
        jobs[k].options.threads = 2;
        jobs[k].options.max_iterations = 200;
        jobs[k].options.tolerance = 1e-5;
        jobs[k].size = jobs[k].kind == 2 ? sizeof(float) * 4 * QUERIES : sizeof(float) * 3 * (size_t)jobs[k].mesh.nv;
        jobs[k].expected = (float *)malloc(jobs[k].size);
        int r = run_job(&s, &jobs[k], jobs[k].expected, &jobs[k].expected_iterations, &jobs[k].expected_calls,
                        &jobs[k].expected_sum);
        CHECK(r >= 0, "%s alone: result %d", jobs[k].name, r);
        CHECK(jobs[k].kind == 2 || jobs[k].expected_iterations > 0, "%s alone: no iterations", jobs[k].name);
        CHECK(jobs[k].kind == 2 || jobs[k].expected_calls > 0, "%s alone: no progress calls", jobs[k].name);
    }
    /* Again on its own: the reference itself is repeatable. */
    for (int k = 0; k < n; ++k) {
        float *again = (float *)malloc(jobs[k].size);
        int32_t it, calls;
        double sum;
        run_job(&s, &jobs[k], again, &it, &calls, &sum);
        CHECK(memcmp(again, jobs[k].expected, jobs[k].size) == 0, "%s: not repeatable", jobs[k].name);
        free(again);
    }

    worker workers[WORKERS];
#ifdef _WIN32
    HANDLE handles[WORKERS];
#else
    pthread_t handles[WORKERS];
#endif
    for (int t = 0; t < WORKERS; ++t) {
        workers[t].s = &s;
        workers[t].id = t;
        workers[t].failures = 0;
#ifdef _WIN32
        handles[t] = CreateThread(NULL, 0, thread_main, &workers[t], 0, NULL);
        CHECK(handles[t] != NULL, "thread %d not started", t);
#else
        CHECK(pthread_create(&handles[t], NULL, thread_main, &workers[t]) == 0, "thread %d not started", t);
#endif
    }
    int failures = 0;
    for (int t = 0; t < WORKERS; ++t) {
#ifdef _WIN32
        WaitForSingleObject(handles[t], INFINITE);
        CloseHandle(handles[t]);
#else
        pthread_join(handles[t], NULL);
#endif
        failures += workers[t].failures;
    }
    CHECK(failures == 0, "%d concurrent calls differ from the same calls alone", failures);
    printf("%d threads x %d rounds x %d jobs\n", WORKERS, ROUNDS, n);

    for (int k = 0; k < n; ++k) {
        free(jobs[k].expected);
        tmesh_free(&jobs[k].mesh);
    }
    free(queries);
    spia_scan_free(scan);
    tmesh_free(&scan_mesh);
    TEST_MAIN_END();
}
