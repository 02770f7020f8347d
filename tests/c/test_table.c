// SPDX-License-Identifier: GPL-3.0-or-later
/* A stencil table kept as its sweep layout alone (csrc/src/plan.c and
 * stencils.c, compiled in: they are private to the library).  Once the plan
 * is built, spia_limit_stencils_create drops the CSR arrays of a table the
 * plan holds; spia_stencils_copy_csr, spia_stencils_apply and the solvers'
 * copy then rebuild them from it.  Here random tables, small (vertex order)
 * and large (breadth-first levels, on two threads), with rows of 1 to 300
 * entries, some without their own entry, weights from a small set, are
 * planned and compacted, and every way out of the compact table must give
 * back the original to the bit: the three arrays together and in any
 * subset, and the product, summed in the table's order.  A table with a row
 * out of column order, and one of too many distinct weights for a plan,
 * keep their arrays. */
#include "support.h"

#include "internal.h"

static uint64_t next(uint64_t *seed) {
    *seed = *seed * 6364136223846793005ULL + 1442695040888963407ULL;
    return *seed >> 33;
}

/* A table of n rows; distinct: how many different weights (more than the
 * plan's dictionary takes: no plan); unsorted: one row with two columns
 * swapped. */
static spia_stencils *random_table(int32_t n, int32_t distinct, int unsorted, uint64_t seed) {
    int32_t *length = (int32_t *)malloc(sizeof(int32_t) * (size_t)n);
    int64_t nnz = 0;
    for (int32_t r = 0; r < n; ++r) {
        const uint64_t pick = next(&seed) % 1000;
        length[r] = pick < 3 ? 100 + (int32_t)(next(&seed) % 200) : 1 + (int32_t)(next(&seed) % 12);
        if (length[r] > n) length[r] = n;
        nnz += length[r];
    }
    spia_stencils *s = spia__stencils_alloc(n, nnz);
    unsigned char *taken = (unsigned char *)calloc((size_t)n, 1);
    int32_t *cols = (int32_t *)malloc(sizeof(int32_t) * 400);
    int64_t at = 0;
    for (int32_t r = 0; r < n; ++r) {
        s->offsets[r] = at;
        int32_t k = 0;
        const int own = next(&seed) % 10 != 0;
        if (own) {
            cols[k++] = r;
            taken[r] = 1;
        }
        /* Columns near the row (a mesh's stencils are local), a few far. */
        const int32_t window = length[r] > 50 ? 2 * length[r] : 40;
        while (k < length[r]) {
            int32_t c = next(&seed) % 50 == 0 ? (int32_t)(next(&seed) % (uint64_t)n)
                                              : r - window + (int32_t)(next(&seed) % (uint64_t)(2 * window + 1));
            c = ((c % n) + n) % n;
            if (taken[c] || (c == r && !own)) continue;
            taken[c] = 1;
            cols[k++] = c;
        }
        for (int32_t a = 1; a < k; ++a) /* sorted, as the builders leave them */
            for (int32_t b = a; b > 0 && cols[b] < cols[b - 1]; --b) {
                const int32_t t = cols[b];
                cols[b] = cols[b - 1];
                cols[b - 1] = t;
            }
        for (int32_t a = 0; a < k; ++a) {
            taken[cols[a]] = 0;
            s->indices[at] = cols[a];
            const int32_t w = (int32_t)(next(&seed) % (uint64_t)distinct);
            /* positive on the row's own entry, of either sign elsewhere */
            s->weights[at] = cols[a] == r ? 0.25 + w / 7.0 : (w % 3 == 0 ? -1.0 : 1.0) * (1.0 + w) / 97.0;
            ++at;
        }
    }
    s->offsets[n] = at;
    s->nnz = at;
    if (unsorted)
        for (int32_t r = n / 2; r < n; ++r)
            if (s->offsets[r + 1] - s->offsets[r] >= 2) {
                const int64_t b = s->offsets[r];
                const int32_t t = s->indices[b];
                s->indices[b] = s->indices[b + 1];
                s->indices[b + 1] = t;
                break;
            }
    free(cols);
    free(taken);
    free(length);
    return s;
}

static int same(const void *a, const void *b, size_t bytes) { return memcmp(a, b, bytes) == 0; }

static void check_table(const char *name, int32_t n, int32_t distinct, int unsorted, int threads, uint64_t seed) {
    spia_stencils *s = random_table(n, distinct, unsorted, seed);
    const int64_t nnz = s->nnz;
    int64_t *off0 = (int64_t *)malloc(sizeof(int64_t) * ((size_t)n + 1));
    int32_t *idx0 = (int32_t *)malloc(sizeof(int32_t) * (size_t)nnz);
    double *w0 = (double *)malloc(sizeof(double) * (size_t)nnz);
    memcpy(off0, s->offsets, sizeof(int64_t) * ((size_t)n + 1));
    memcpy(idx0, s->indices, sizeof(int32_t) * (size_t)nnz);
    memcpy(w0, s->weights, sizeof(double) * (size_t)nnz);

    spia_status st;
    CHECK(spia__plan_build(s, threads, &st) == SPIA_OK, "%s: plan", name);
    const int planned = s->plan != NULL, levels = planned && s->plan->order != NULL;
    CHECK(planned == (distinct <= 32768), "%s: a plan %s", name, planned ? "made" : "missing");
    CHECK(levels == (n >= SPIA_PARALLEL_ROWS && planned), "%s: the plan's order", name);
    spia__stencils_compact(s);
    const int compact = s->offsets == NULL;
    CHECK(compact == (planned && !unsorted), "%s: the arrays %s", name, compact ? "dropped" : "kept");
    CHECK(spia_stencils_row_count(s) == n && spia_stencils_weight_count(s) == nnz, "%s: counts", name);

    /* The arrays, all three and every subset. */
    int64_t *off = (int64_t *)malloc(sizeof(int64_t) * ((size_t)n + 1));
    int32_t *idx = (int32_t *)malloc(sizeof(int32_t) * (size_t)nnz);
    double *w = (double *)malloc(sizeof(double) * (size_t)nnz);
    for (int subset = 1; subset < 8; ++subset) {
        memset(off, 0xab, sizeof(int64_t) * ((size_t)n + 1));
        memset(idx, 0xab, sizeof(int32_t) * (size_t)nnz);
        memset(w, 0xab, sizeof(double) * (size_t)nnz);
        CHECK(spia_stencils_copy_csr(s, subset & 1 ? off : NULL, subset & 2 ? idx : NULL, subset & 4 ? w : NULL) ==
                  SPIA_OK,
              "%s: copy_csr", name);
        if (subset & 1) CHECK(same(off, off0, sizeof(int64_t) * ((size_t)n + 1)), "%s: offsets (subset %d)", name, subset);
        if (subset & 2) CHECK(same(idx, idx0, sizeof(int32_t) * (size_t)nnz), "%s: indices (subset %d)", name, subset);
        if (subset & 4) CHECK(same(w, w0, sizeof(double) * (size_t)nnz), "%s: weights (subset %d)", name, subset);
    }
    /* The solvers' copy. */
    spia_stencils full;
    CHECK(spia__stencils_expand(s, &full, threads) == SPIA_OK, "%s: expand", name);
    CHECK(full.rows == n && full.nnz == nnz && full.plan == s->plan && full.boundary == s->boundary, "%s: expanded", name);
    CHECK(same(full.offsets, off0, sizeof(int64_t) * ((size_t)n + 1)) &&
              same(full.indices, idx0, sizeof(int32_t) * (size_t)nnz) && same(full.weights, w0, sizeof(double) * (size_t)nnz),
          "%s: the expanded arrays", name);
    spia__stencils_expanded_free(s, &full);

    /* The product, against the original rows summed in order. */
    uint64_t pseed = seed ^ 0x5eed;
    double *cage = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    double *out = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) cage[k] = (double)(next(&pseed) % 100000) / 3141.0 - 15.0;
    CHECK(spia_stencils_apply(s, cage, out) == SPIA_OK, "%s: apply", name);
    int64_t wrong = 0;
    for (int32_t r = 0; r < n; ++r) {
        double a = 0.0, b = 0.0, c = 0.0;
        for (int64_t k = off0[r]; k < off0[r + 1]; ++k) {
            const double *q = cage + 3 * (int64_t)idx0[k];
            a += w0[k] * q[0];
            b += w0[k] * q[1];
            c += w0[k] * q[2];
        }
        const double e[3] = {a, b, c};
        if (!same(e, out + 3 * (int64_t)r, sizeof e)) ++wrong;
    }
    CHECK(wrong == 0, "%s: %lld rows of the product differ", name, (long long)wrong);
    printf("%s: %d rows, %lld weights, %s%s%s, arrays %s\n", name, (int)n, (long long)nnz,
           !planned ? "no plan" : levels ? "levels" : "vertex order",
           !planned ? "" : s->plan->code8 ? ", 8-bit codes" : ", 16-bit codes",
           !planned ? "" : s->plan->delta16 ? ", 16-bit offsets" : ", 32-bit offsets", compact ? "rebuilt from the plan" : "kept");

    free(cage);
    free(out);
    free(off);
    free(idx);
    free(w);
    free(off0);
    free(idx0);
    free(w0);
    spia_stencils_free(s);
}

int main(void) {
    check_table("small", 3000, 40, 0, 1, 1);
    check_table("small, 300 weights", 3000, 300, 0, 1, 2); /* 16-bit codes */
    check_table("large, two threads", 60000, 40, 0, 2, 3);
    check_table("large, one thread", 60000, 300, 0, 1, 4);
    check_table("a row out of order", 3000, 40, 1, 1, 5);
    check_table("too many weights", 10000, 40000, 0, 1, 6);
    TEST_MAIN_END();
}
