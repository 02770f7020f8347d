// SPDX-License-Identifier: GPL-3.0-or-later
/* The library's clock (spia__now), in a file of its own so that the tests
 * and benchmarks that compile private sources in can take it without
 * status.c's exported functions (which a Windows import library would then
 * define a second time). */
#define _POSIX_C_SOURCE 200809L
#include "internal.h"

#include <time.h>

double spia__now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
