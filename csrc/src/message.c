// SPDX-License-Identifier: GPL-3.0-or-later
/* Filling in a spia_status: the one place the library writes a message.
 * On its own so that tests and benchmarks that compile private sources
 * (bvh.c) can compile it with them. */
#include "internal.h"

#include <stdarg.h>
#include <stdio.h>

spia_result spia__fail(spia_status *status, spia_result code, int64_t index, const char *fmt, ...) {
    if (status) {
        va_list ap;
        status->code = code;
        status->index = index;
        va_start(ap, fmt);
        vsnprintf(status->message, sizeof status->message, fmt, ap);
        va_end(ap);
    }
    return code;
}

void spia__ok(spia_status *status) {
    if (status) {
        status->code = SPIA_OK;
        status->index = -1;
        status->message[0] = '\0';
    }
}
