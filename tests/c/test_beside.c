// SPDX-License-Identifier: GPL-3.0-or-later
/* spia__run_beside (csrc/src/threads.c, compiled in): the work runs to its
 * end on a thread of its own while the calling thread polls; a poll that
 * stops ends the polling only; with one thread, the work runs on the
 * caller and nothing polls. */
#include "support.h"

#include "threads.h"

typedef struct job {
    spia__counter polls; /* polls so far */
    int64_t polls_seen;  /* by the work, when it ended */
    int64_t stop_at;     /* the poll that returns nonzero (0: none) */
    int64_t wait_for;    /* the polls the work waits for */
    int done;
} job;

/* Waits (for at most about ten seconds) until the caller has polled
 * wait_for times, which it can only do while the work runs beside it. */
static void work(void *context) {
    job *j = (job *)context;
    int rounds = 0;
    for (long k = 0; k < 200000000L && spia__counter_get(&j->polls) < j->wait_for; ++k) spia__wait(&rounds);
    j->polls_seen = spia__counter_get(&j->polls);
    j->done = 1;
}

static int poll(void *user) {
    job *j = (job *)user;
    const int64_t n = spia__counter_add(&j->polls, 1) + 1;
    return j->stop_at > 0 && n >= j->stop_at;
}

/* Work that does not wait for polls. */
static void quick(void *context) { ((job *)context)->done = 1; }

int main(void) {
    for (int threads = 2; threads <= 3; ++threads) {
        job j;
        spia__counter_set(&j.polls, 0);
        j.polls_seen = 0, j.stop_at = 0, j.wait_for = 5, j.done = 0;
        const int stopped = spia__run_beside(threads, work, &j, poll, &j);
        CHECK(j.done && j.polls_seen >= 5 && !stopped, "%d threads: done %d, the work saw %lld polls, stopped %d",
              threads, j.done, (long long)j.polls_seen, stopped);
    }
    {   /* the third poll stops the polling, and the work still ends */
        job j;
        spia__counter_set(&j.polls, 0);
        j.polls_seen = 0, j.stop_at = 3, j.wait_for = 3, j.done = 0;
        const int stopped = spia__run_beside(2, work, &j, poll, &j);
        CHECK(stopped && j.done && j.polls_seen == 3 && spia__counter_get(&j.polls) == 3,
              "a stopping poll: stopped %d, done %d, %lld polls (3 expected)", stopped, j.done,
              (long long)spia__counter_get(&j.polls));
    }
    for (int threads = 0; threads <= 1; ++threads) { /* on the caller: no poll */
        job j;
        spia__counter_set(&j.polls, 0);
        j.polls_seen = 0, j.stop_at = 0, j.wait_for = 0, j.done = 0;
        const int stopped = spia__run_beside(threads, quick, &j, poll, &j);
        CHECK(j.done && !stopped && spia__counter_get(&j.polls) == 0, "%d threads: done %d, %lld polls", threads,
              j.done, (long long)spia__counter_get(&j.polls));
    }
    {   /* no poll function: the work on the caller */
        job j;
        spia__counter_set(&j.polls, 0);
        j.done = 0;
        CHECK(spia__run_beside(2, quick, &j, NULL, NULL) == 0 && j.done, "no poll function: the work did not run");
    }
    TEST_MAIN_END();
}
