// SPDX-License-Identifier: GPL-3.0-or-later
/* bvh.c built with an allocator that fails when test_bvh.c asks it to:
 * every failure must come back as SPIA_ERROR_OUT_OF_MEMORY with nothing
 * left allocated. */
#include <stdlib.h>

void *spia_test_malloc(size_t size);
void *spia_test_calloc(size_t count, size_t size);
void *spia_test_realloc(void *p, size_t size);
void spia_test_free(void *p);

#define malloc spia_test_malloc
#define calloc spia_test_calloc
#define realloc spia_test_realloc
#define free spia_test_free
#include "bvh.c"
