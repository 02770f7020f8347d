// SPDX-License-Identifier: GPL-3.0-or-later
/* The library's clock for the tests that compile its private sources in.
 * (status.c holds it too, beside exported functions that a Windows import
 * library would then define a second time.) */
#define _POSIX_C_SOURCE 200809L
#include <time.h>

double spia__now(void);
double spia__now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
