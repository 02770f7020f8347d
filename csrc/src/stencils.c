// SPDX-License-Identifier: GPL-3.0-or-later
/* The CSR stencil table shared by every scheme: storage, access, product. */
#include "internal.h"
#include "threads.h"

#include <stdlib.h>
#include <string.h>

spia_stencils *spia__stencils_alloc(int32_t rows, int64_t nnz) {
    spia_stencils *s = (spia_stencils *)calloc(1, sizeof *s);
    if (!s) return NULL;
    s->rows = rows;
    s->nnz = nnz;
    s->offsets = (int64_t *)calloc((size_t)rows + 1, sizeof(int64_t));
    /* Large arrays in huge pages where the system gives them: fewer page
     * faults as the builders fill them, and less work giving them back
     * when the plan takes their place (spia__stencils_compact). */
    s->indices = (int32_t *)spia__alloc_large(sizeof(int32_t) * (size_t)(nnz > 0 ? nnz : 1));
    s->weights = (double *)spia__alloc_large(sizeof(double) * (size_t)(nnz > 0 ? nnz : 1));
    s->boundary = (unsigned char *)calloc((size_t)rows + 1, 1);
    if (!s->offsets || !s->indices || !s->weights || !s->boundary) {
        spia_stencils_free(s);
        return NULL;
    }
    return s;
}

void spia_stencils_free(spia_stencils *s) {
    if (!s) return;
    free(s->offsets);
    free(s->indices);
    free(s->weights);
    free(s->boundary);
    spia__plan_free(s->plan);
    free(s);
}

void spia__stencils_canonicalize(spia_stencils *s) {
    int64_t out = 0;
    for (int32_t r = 0; r < s->rows; ++r) {
        int64_t b = s->offsets[r], e = s->offsets[r + 1];
        /* Insertion sort: rows are short (the vertices of the incident faces). */
        for (int64_t i = b + 1; i < e; ++i) {
            int32_t ki = s->indices[i];
            double wi = s->weights[i];
            int64_t j = i - 1;
            while (j >= b && s->indices[j] > ki) {
                s->indices[j + 1] = s->indices[j];
                s->weights[j + 1] = s->weights[j];
                --j;
            }
            s->indices[j + 1] = ki;
            s->weights[j + 1] = wi;
        }
        s->offsets[r] = out;
        for (int64_t i = b; i < e;) {
            int32_t k = s->indices[i];
            double w = 0.0;
            while (i < e && s->indices[i] == k) w += s->weights[i++];
            if (w != 0.0) {
                s->indices[out] = k;
                s->weights[out] = w;
                ++out;
            }
        }
    }
    s->offsets[s->rows] = out;
    s->nnz = out;
}

void spia__stencils_shrink(spia_stencils *s) {
    const size_t n = (size_t)(s->nnz > 0 ? s->nnz : 1);
    int32_t *indices = (int32_t *)realloc(s->indices, sizeof(int32_t) * n);
    if (indices) s->indices = indices;
    double *weights = (double *)realloc(s->weights, sizeof(double) * n);
    if (weights) s->weights = weights;
}

int32_t spia_stencils_row_count(const spia_stencils *s) { return s ? s->rows : 0; }

int64_t spia_stencils_weight_count(const spia_stencils *s) { return s ? s->nnz : 0; }

spia_result spia_stencils_copy_csr(const spia_stencils *s, int64_t *offsets, int32_t *indices, double *weights) {
    if (!s) return SPIA_ERROR_INVALID_ARGUMENT;
    if (!s->offsets) {
        if (!offsets && !indices && !weights) return SPIA_OK;
        /* Rows are placed by their offsets, so those are needed either way. */
        int64_t *at = offsets ? offsets : (int64_t *)malloc(sizeof(int64_t) * ((size_t)s->rows + 1));
        if (!at) return SPIA_ERROR_OUT_OF_MEMORY;
        spia__plan_table(s->plan, at, indices, weights, 1);
        if (at != offsets) free(at);
        return SPIA_OK;
    }
    if (offsets) memcpy(offsets, s->offsets, sizeof(int64_t) * ((size_t)s->rows + 1));
    if (indices) memcpy(indices, s->indices, sizeof(int32_t) * (size_t)s->nnz);
    if (weights) memcpy(weights, s->weights, sizeof(double) * (size_t)s->nnz);
    return SPIA_OK;
}

spia_result spia_stencils_apply(const spia_stencils *s, const double *cage, double *out) {
    if (!s || !cage || !out) return SPIA_ERROR_INVALID_ARGUMENT;
    if (!s->offsets) {
        spia__plan_apply(s->plan, cage, out);
        return SPIA_OK;
    }
    for (int32_t r = 0; r < s->rows; ++r) spia__row_product(s, r, cage, out + 3 * (int64_t)r);
    return SPIA_OK;
}

/* Frees the CSR arrays of s and sets them to NULL. */
static void drop_arrays(spia_stencils *s) {
    free(s->offsets);
    free(s->indices);
    free(s->weights);
    s->offsets = NULL;
    s->indices = NULL;
    s->weights = NULL;
}

void spia__stencils_compact(spia_stencils *s) {
    if (s->plan && s->plan->holds_table) drop_arrays(s);
}

spia_result spia__stencils_expand(const spia_stencils *s, spia_stencils *full, int threads) {
    *full = *s;
    if (s->offsets) return SPIA_OK;
    const size_t nnz = (size_t)(s->nnz > 0 ? s->nnz : 1);
    full->offsets = (int64_t *)malloc(sizeof(int64_t) * ((size_t)s->rows + 1));
    full->indices = (int32_t *)spia__alloc_large(sizeof(int32_t) * nnz);
    full->weights = (double *)spia__alloc_large(sizeof(double) * nnz);
    if (!full->offsets || !full->indices || !full->weights) {
        spia__stencils_expanded_free(s, full);
        return SPIA_ERROR_OUT_OF_MEMORY;
    }
    spia__plan_table(s->plan, full->offsets, full->indices, full->weights, threads);
    return SPIA_OK;
}

void spia__stencils_expanded_free(const spia_stencils *s, spia_stencils *full) {
    if (!s->offsets) drop_arrays(full); /* (else they are s's own) */
}

void spia__stencils_mark_boundary(spia_stencils *s, const unsigned char *on_boundary) {
    s->boundary_count = 0;
    for (int32_t r = 0; r < s->rows; ++r) {
        int closed = on_boundary[r];
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1] && closed; ++k) closed = on_boundary[s->indices[k]];
        s->boundary[r] = (unsigned char)closed;
        s->boundary_count += closed;
    }
}
