// SPDX-License-Identifier: GPL-3.0-or-later
/* What the processor offers the kernels compiled for it twice
 * (SPIA_AVX_KERNELS in internal.h). */
#include "internal.h"

#ifdef SPIA_AVX_KERNELS
#include <cpuid.h>

/* AVX, and the system saving its registers: OSXSAVE, and XCR0's SSE and
 * AVX state bits. */
int spia__have_avx(void) {
    unsigned a = 0, b = 0, c = 0, d = 0;
    if (!__get_cpuid(1, &a, &b, &c, &d)) return 0;
    if (!(c & (1u << 27)) || !(c & (1u << 28))) return 0;
    unsigned lo = 0, hi = 0;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    (void)hi;
    return (lo & 6u) == 6u;
}
#else
int spia__have_avx(void) { return 0; }
#endif
