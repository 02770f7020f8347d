// SPDX-License-Identifier: GPL-3.0-or-later
/* The refinement's progress clock (spia__refine_clock in internal.h), shared
 * by the refining schemes (loop.c, doosabin.c, osd_refine.cpp). */
#include "internal.h"

#define REFINE_INTERVAL 0.1

void spia__refine_clock_start(spia__refine_clock *c, const spia_options *o, int32_t levels) {
    c->fn = o->progress;
    c->user = o->progress_user_data;
    c->last = spia__now();
    c->level = levels > 0 ? 1 : 0;
    c->levels = levels;
    c->cancelled = 0;
}

/* The share of the faces of levels 1..done among those of 1..levels. */
static double refine_share(int32_t done, int32_t levels) {
    double part = 0.0, whole = 0.0, faces = 1.0;
    for (int32_t l = 1; l <= levels; ++l) {
        faces *= 4.0;
        whole += faces;
        if (l <= done) part += faces;
    }
    return whole > 0.0 ? part / whole : 1.0;
}

static int refine_call(spia__refine_clock *c, int32_t done) {
    c->last = spia__now();
    if (c->fn(c->user, c->level, refine_share(done, c->levels))) c->cancelled = 1;
    return c->cancelled;
}

int spia__refine_tick(spia__refine_clock *c, int64_t k) {
    if (!c || !c->fn || c->cancelled || (k & 1023) != 0) return c ? c->cancelled : 0;
    if (spia__now() - c->last < REFINE_INTERVAL) return 0;
    return refine_call(c, c->level - 1);
}

int spia__refine_level_done(spia__refine_clock *c, int32_t level) {
    if (!c || !c->fn || c->cancelled) return c ? c->cancelled : 0;
    c->level = level;
    const int stop = refine_call(c, level);
    if (!stop && level < c->levels) c->level = level + 1;
    return stop;
}

spia_result spia__refine_cancelled(spia_status *status, const spia__refine_clock *c) {
    return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled refining level %d of %d", (int)c->level,
                      (int)c->levels);
}
