// SPDX-License-Identifier: GPL-3.0-or-later
/* The library's own threads: a parallel loop over a range of items, on
 * POSIX threads or Windows threads, with no runtime beside the C library's.
 * (OpenMP would bring libgomp, which cannot be linked statically into a
 * shared library and which a host program may already hold in another
 * version.) */
#ifndef SPIA_THREADS_H
#define SPIA_THREADS_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Work on the items [begin, end), done by thread number `thread`
 * (0 .. threads - 1; 0 is the calling thread). */
typedef void (*spia__range_fn)(void *context, int64_t begin, int64_t end, int thread);

/* Calls fn over [0, count) in pieces of `grain` items (the last one
 * shorter), or with grain <= 0 in `threads` contiguous pieces of nearly
 * equal size.  Pieces are taken in order by whichever thread is free, the
 * caller working as thread 0 beside threads - 1 new ones; it returns when
 * every piece is done.  A thread that cannot be started only leaves its
 * share to the others, so the loop always completes.  Whatever writes
 * depend on the piece and not on the thread make results independent of
 * the thread count. */
void spia__parallel_for(int threads, int64_t count, int64_t grain, spia__range_fn fn, void *context);

/* Work on the items [begin, end) that returns a share of a sum. */
typedef double (*spia__sum_fn)(void *context, int64_t begin, int64_t end);

/* Calls fn over [0, count) in chunks whose size depends on count only (at
 * least min_chunk items, at most SPIA__SUM_CHUNKS chunks), on up to
 * `threads` threads, and returns the sum of what the chunks return, added
 * in chunk order: the same to the bit whatever the threads. */
#define SPIA__SUM_CHUNKS 1024
double spia__parallel_sum(int threads, int64_t count, int64_t min_chunk, spia__sum_fn fn, void *context);

/* The processors this process may run on (at least 1). */
int spia__processor_count(void);

/* Room for a large array a solve fills at once, freed with free(): on
 * Linux, from 4 MB, in 2 MB-aligned blocks the kernel is asked to back with
 * huge pages (a fault per 4 KB page costs microseconds, more in virtual
 * machines, and a solve of a million vertices touches some 50 MB afresh);
 * elsewhere malloc's.  Not zeroed. */
void *spia__alloc_large(size_t bytes);

#ifndef __cplusplus
/* A counter that threads of one loop share (the sweep pipeline's progress
 * marks): every operation is atomic and sequentially consistent, so what a
 * thread wrote before raising a counter is seen by a thread that has read
 * the raised value. */
typedef struct spia__counter {
#if defined(_MSC_VER) && !defined(__clang__)
    volatile long long value;
#else
    _Atomic long long value;
#endif
} spia__counter;
void spia__counter_set(spia__counter *c, int64_t value);
int64_t spia__counter_get(spia__counter *c);
/* Adds `value`; returns the value before. */
int64_t spia__counter_add(spia__counter *c, int64_t value);

/* One round of waiting for another thread: a processor pause while
 * `*rounds` is small, then giving the processor up (the machine may have
 * fewer free processors than threads). */
void spia__wait(int *rounds);
#endif

#ifdef __cplusplus
}
#endif

#endif
