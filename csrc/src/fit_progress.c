// SPDX-License-Identifier: GPL-3.0-or-later
/* The fit's progress clock (fit_clock, fit.h): the progress callback
 * called from the long steps of a fit and of spia_flat_positions. */
#include "fit.h"

/* Besides after every round, the progress callback is called from the long steps once
 * PROGRESS_INTERVAL seconds have passed since the last call (the sample
 * stencils every BLOCK_TICK faces, closest points in chunks of QUERY_CHUNK,
 * each conjugate-gradient step, the surface's grid: its creation,
 * evaluation and build as a scan), so that a cancel is answered promptly
 * at every scale.  These calls repeat the last call's
 * figures (the rounds done and their mean distance, or the VERTICES
 * solve's last iteration and error; 0 and the cage given's mean before
 * any). */
#define PROGRESS_INTERVAL 0.1

int spia__fit_clock_tick(fit_clock *c) {
    if (!c->fn || c->cancelled) return c->cancelled;
    const double now = spia__now();
    if (now - c->last < PROGRESS_INTERVAL) return 0;
    c->last = now;
    if (c->fn(c->user, c->round, c->mean)) c->cancelled = 1;
    return c->cancelled;
}
