// SPDX-License-Identifier: GPL-3.0-or-later
/* A parallel loop on the platform's own threads (see threads.h). */
#if !defined(_WIN32) && !defined(_GNU_SOURCE)
#define _GNU_SOURCE /* sched_getaffinity */
#endif
#include "threads.h"

#include <stdlib.h>

#ifdef _WIN32
#include <process.h>
#include <windows.h>
#else
#include <pthread.h>
#include <sched.h>
#include <unistd.h>
#endif
#ifdef __linux__
#include <sys/mman.h>
#endif

#if defined(__x86_64__) || defined(__i386__) || defined(_M_X64) || defined(_M_IX86)
#include <immintrin.h>
#define cpu_pause() _mm_pause()
#elif defined(__aarch64__) && defined(__GNUC__)
#define cpu_pause() __asm__ __volatile__("yield")
#else
#define cpu_pause() ((void)0)
#endif

#if defined(_MSC_VER) && !defined(__clang__)
typedef volatile long long piece_counter;
static int64_t take_piece(piece_counter *next) { return (int64_t)InterlockedIncrement64(next) - 1; }
static void counter_init(piece_counter *next) { *next = 0; }
#else
#include <stdatomic.h>
typedef atomic_llong piece_counter;
static int64_t take_piece(piece_counter *next) { return (int64_t)atomic_fetch_add(next, 1); }
static void counter_init(piece_counter *next) { atomic_init(next, 0); }
#endif

/* More threads than this are never started for one loop. */
#define MAX_THREADS 256

typedef struct loop {
    spia__range_fn fn;
    void *context;
    int64_t count, grain, pieces;
    piece_counter next;
} loop;

typedef struct worker {
    loop *loop;
    int thread;
} worker;

static void work(loop *l, int thread) {
    const int64_t q = l->grain > 0 ? 0 : l->count / l->pieces, r = l->grain > 0 ? 0 : l->count % l->pieces;
    for (;;) {
        const int64_t p = take_piece(&l->next);
        if (p >= l->pieces) return;
        int64_t begin, end;
        if (l->grain > 0) {
            begin = p * l->grain;
            end = l->count - begin < l->grain ? l->count : begin + l->grain;
        } else {
            begin = p * q + (p < r ? p : r);
            end = begin + q + (p < r ? 1 : 0);
        }
        l->fn(l->context, begin, end, thread);
    }
}

#ifdef _WIN32
typedef HANDLE thread_handle;
static unsigned __stdcall thread_main(void *arg) {
    worker *w = (worker *)arg;
    work(w->loop, w->thread);
    return 0;
}
static int thread_start(thread_handle *h, worker *w) {
    const uintptr_t t = _beginthreadex(NULL, 0, thread_main, w, 0, NULL);
    if (t == 0) return 0;
    *h = (HANDLE)t;
    return 1;
}
static void thread_join(thread_handle h) {
    WaitForSingleObject(h, INFINITE);
    CloseHandle(h);
}
#else
typedef pthread_t thread_handle;
static void *thread_main(void *arg) {
    worker *w = (worker *)arg;
    work(w->loop, w->thread);
    return NULL;
}
static int thread_start(thread_handle *h, worker *w) { return pthread_create(h, NULL, thread_main, w) == 0; }
static void thread_join(thread_handle h) { pthread_join(h, NULL); }
#endif

void spia__parallel_for(int threads, int64_t count, int64_t grain, spia__range_fn fn, void *context) {
    if (count <= 0) return;
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    loop l;
    l.fn = fn;
    l.context = context;
    l.count = count;
    l.grain = grain;
    l.pieces = grain > 0 ? (count - 1) / grain + 1 : (threads < count ? threads : count);
    counter_init(&l.next);
    if (threads > l.pieces) threads = (int)l.pieces;
    if (threads == 1) {
        work(&l, 0);
        return;
    }
    thread_handle handles[MAX_THREADS];
    worker workers[MAX_THREADS];
    int started = 0;
    for (int t = 1; t < threads; ++t) {
        workers[started].loop = &l;
        workers[started].thread = started + 1;
        if (!thread_start(&handles[started], &workers[started])) break; /* the rest is done by those running */
        ++started;
    }
    work(&l, 0);
    for (int t = 0; t < started; ++t) thread_join(handles[t]);
}

typedef struct sum_loop {
    spia__sum_fn fn;
    void *context;
    int64_t count, chunk;
    double sums[SPIA__SUM_CHUNKS];
} sum_loop;

static void sum_chunks(void *context, int64_t c0, int64_t c1, int thread) {
    (void)thread;
    sum_loop *s = (sum_loop *)context;
    for (int64_t c = c0; c < c1; ++c) {
        const int64_t begin = c * s->chunk, end = s->count - begin < s->chunk ? s->count : begin + s->chunk;
        s->sums[c] = s->fn(s->context, begin, end);
    }
}

double spia__parallel_sum(int threads, int64_t count, int64_t min_chunk, spia__sum_fn fn, void *context) {
    if (count <= 0) return 0.0;
    sum_loop s;
    s.fn = fn;
    s.context = context;
    s.count = count;
    s.chunk = (count + SPIA__SUM_CHUNKS - 1) / SPIA__SUM_CHUNKS;
    if (s.chunk < min_chunk) s.chunk = min_chunk;
    const int64_t chunks = (count + s.chunk - 1) / s.chunk;
    spia__parallel_for(threads, chunks, 1, sum_chunks, &s);
    double sum = 0.0;
    for (int64_t c = 0; c < chunks; ++c) sum += s.sums[c];
    return sum;
}

#if defined(_MSC_VER) && !defined(__clang__)
void spia__counter_set(spia__counter *c, int64_t value) { InterlockedExchange64(&c->value, (long long)value); }
int64_t spia__counter_get(spia__counter *c) { return (int64_t)InterlockedCompareExchange64(&c->value, 0, 0); }
int64_t spia__counter_add(spia__counter *c, int64_t value) {
    return (int64_t)InterlockedExchangeAdd64(&c->value, (long long)value);
}
#else
void spia__counter_set(spia__counter *c, int64_t value) { atomic_store(&c->value, (long long)value); }
int64_t spia__counter_get(spia__counter *c) { return (int64_t)atomic_load(&c->value); }
int64_t spia__counter_add(spia__counter *c, int64_t value) {
    return (int64_t)atomic_fetch_add(&c->value, (long long)value);
}
#endif

void spia__wait(int *rounds) {
    if (++*rounds < 64) {
        cpu_pause();
        return;
    }
#ifdef _WIN32
    SwitchToThread();
#else
    sched_yield();
#endif
}

void *spia__alloc_large(size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    const size_t huge = (size_t)2 << 20;
    if (bytes >= 2 * huge) {
        void *p = NULL;
        if (posix_memalign(&p, huge, bytes) != 0) return NULL;
        (void)madvise(p, bytes & ~(huge - 1), MADV_HUGEPAGE); /* advice only: no huge pages is fine */
        return p;
    }
#endif
    return malloc(bytes > 0 ? bytes : 1);
}

int spia__processor_count(void) {
    long n = 0;
#ifdef _WIN32
    n = (long)GetActiveProcessorCount(ALL_PROCESSOR_GROUPS);
#else
#ifdef __linux__
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0) n = CPU_COUNT(&set);
#endif
    if (n < 1) n = sysconf(_SC_NPROCESSORS_ONLN);
#endif
    if (n < 1) n = 1;
    if (n > MAX_THREADS) n = MAX_THREADS;
    return (int)n;
}
