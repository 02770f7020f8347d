// SPDX-License-Identifier: GPL-3.0-or-later
/* GS_PIA_FAST: Gauss-Seidel PIA on the table's sweep layout (plan.c).
 *
 * The update is GS-PIA's, V_i += (P_i - (L V)_i) / L_ii, row after row in
 * place, but
 *
 * - in the plan's order: vertex order on small tables; breadth-first levels
 *   of the stencils, each ordered by a colouring, on large ones, where
 *   several sweeps run at once, one behind the other, on the threads (a
 *   chunk is swept once the chunks before it that it refers to have had
 *   this sweep and those after it the sweep before: the sweeps do exactly
 *   what they would one after another, whatever the number of threads);
 * - on the correction Y to the first iterate S: the sweeps solve L Y = B,
 *   B = P - L S, in float32 with the weights' float32 copies, four floats a
 *   row (x, y, z and a zero lane, one vector operation per weight);
 * - with the residual and the stopping test in double: the residual of the
 *   cage as it will be stored, float(S + Y), with the table's exact
 *   weights (summed in one AVX register where the machine has AVX, to the
 *   same bits as in two SSE2 ones); the cage is written only once that
 *   meets the tolerance.
 *   Float32 sweeps hold Y to about 1e-7 of its own size, far below the
 *   rounding of the cage itself; where a tolerance asks for more (or the
 *   cage's coordinates are so far from the origin that float rounding of
 *   the cage misses it), the solve goes on with GS_PIA's double sweeps
 *   from where it got to.
 *
 * As GS-PIA, the error of an iteration (history, progress, the stopping
 * test's trigger) is the largest residual met during the sweep; the full
 * residual is computed when that reaches the tolerance.
 *
 * With SPIA_SOLVE_FIRST_STEP the first iterate is improved first by one
 * step of a local approximate inverse of the limit mask: Y_i = w_i sum_j
 * s_ij L_ij B_j, with s_ij = -1 where L_ij is one of the larger
 * off-diagonal weights of the row (at least half the largest: the edge
 * neighbours of a Catmull-Clark limit mask, 4 times a face corner's; the
 * plan codes them apart), +1 elsewhere, and w_i = 1.28 / L_ii^2.  On a
 * regular quad grid, whose limit mask has the symbol a(x) a(y) with
 * a(t) = (2 + cos t) / 3, that is 6.48 times the mask with alternating
 * signs, of symbol 6.48 a(x + pi) a(y + pi): the product of the two
 * symbols, 0.08 (4 - cos^2 x)(4 - cos^2 y), lies in [0.72, 1.28], so the
 * conditioning of L, 9, becomes 16/9.  It costs about a sweep and is not
 * counted as an iteration.
 */
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum {
    FAST_BLOCK = 2048,      /* rows per partial sum of the residual, as solve.c's BLOCK */
    PIECE_BLOCKS = 8,       /* blocks a thread takes at a time in the passes over all rows (taken as
                             * threads come free: a thread slowed down by other work holds back none) */
    FAST_WINDOW = 50,       /* solve.c's STAGNATION_WINDOW */
    FIRST_RUN = 4,          /* sweeps of the first run on a pipelined plan */
    LONGEST_RUN = 16,       /* the most sweeps run at once */
    FLOAT_FLOOR_CHECKS = 2  /* failed checks with the sweeps at the tolerance before handing over */
};
#define FAST_DIVERGENCE 1e4
#define FAST_DRIFT 50.0
#define FIRST_STEP_SCALE 1.28
/* The float32 sweeps are used when the tolerance is at least this much of
 * the first iterate's residual (about 30 float32 ulps of it). */
#define FLOAT_REACH 4e-6

enum { STUCK = 1, FROZEN = 2 };

/* The caller's rows, in table order, are fetched this many positions ahead
 * when gathered into the plan's order and when the cage is written back. */
enum { ROWS_AHEAD = 16 };
#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(address) __builtin_prefetch(address)
#define PREFETCH_WRITE(address) __builtin_prefetch((address), 1)
#else
#define PREFETCH(address) ((void)0)
#define PREFETCH_WRITE(address) ((void)0)
#endif

/* ------------------------------------------------------------------------ */
/* Four-lane vectors                                                         */
/* ------------------------------------------------------------------------ */

#if defined(__GNUC__) || defined(__clang__)
typedef float f4 __attribute__((vector_size(16)));
typedef double d4 __attribute__((vector_size(32)));
#define V4_SPLAT(T, a) ((T){(a), (a), (a), (a)})
#define V4_ZERO(T) ((T){0, 0, 0, 0})
#define V4_ADD(a, b) ((a) + (b))
#define V4_SUB(a, b) ((a) - (b))
#define V4_SCALE(a, s) ((a) * (s))
#define V4_MUL(a, b) ((a) * (b))
#define V4_LANE(a, i) ((a)[i])
#else
typedef struct f4 {
    float v[4];
} f4;
typedef struct d4 {
    double v[4];
} d4;
#define V4_LANE(a, i) ((a).v[i])
static inline f4 f4_make(float a, float b, float c, float d) {
    f4 r = {{a, b, c, d}};
    return r;
}
static inline d4 d4_make(double a, double b, double c, double d) {
    d4 r = {{a, b, c, d}};
    return r;
}
#define V4_SPLAT(T, a) T##_make((a), (a), (a), (a))
#define V4_ZERO(T) T##_make(0, 0, 0, 0)
static inline f4 f4_add(f4 a, f4 b) { return f4_make(a.v[0] + b.v[0], a.v[1] + b.v[1], a.v[2] + b.v[2], a.v[3] + b.v[3]); }
static inline f4 f4_sub(f4 a, f4 b) { return f4_make(a.v[0] - b.v[0], a.v[1] - b.v[1], a.v[2] - b.v[2], a.v[3] - b.v[3]); }
static inline f4 f4_scale(f4 a, float s) { return f4_make(a.v[0] * s, a.v[1] * s, a.v[2] * s, a.v[3] * s); }
static inline f4 f4_mul(f4 a, f4 b) { return f4_make(a.v[0] * b.v[0], a.v[1] * b.v[1], a.v[2] * b.v[2], a.v[3] * b.v[3]); }
static inline d4 d4_add(d4 a, d4 b) { return d4_make(a.v[0] + b.v[0], a.v[1] + b.v[1], a.v[2] + b.v[2], a.v[3] + b.v[3]); }
static inline d4 d4_sub(d4 a, d4 b) { return d4_make(a.v[0] - b.v[0], a.v[1] - b.v[1], a.v[2] - b.v[2], a.v[3] - b.v[3]); }
static inline d4 d4_scale(d4 a, double s) { return d4_make(a.v[0] * s, a.v[1] * s, a.v[2] * s, a.v[3] * s); }
#define V4_ADD(a, b) _Generic((a), f4: f4_add, d4: d4_add)((a), (b))
#define V4_SUB(a, b) _Generic((a), f4: f4_sub, d4: d4_sub)((a), (b))
#define V4_SCALE(a, s) _Generic((a), f4: f4_scale, d4: d4_scale)((a), (s))
#define V4_MUL(a, b) f4_mul((a), (b))
#endif


/* Sums in double of weights times float rows (x, y, z and a lane that is
 * dropped), for the residual: two SSE2 registers where there are some
 * (the generic 4-double vector would live on the stack there). */
#if defined(__SSE2__) || defined(_M_X64)
#include <emmintrin.h>
typedef struct sum3 {
    __m128d xy, zw;
} sum3;
static inline sum3 sum3_zero(void) {
    sum3 a = {_mm_setzero_pd(), _mm_setzero_pd()};
    return a;
}
/* a += w * (the row of 4 floats at x [+ the row at y]) */
static inline void sum3_add(sum3 *a, double w, const float *x, const float *y) {
    __m128 v = _mm_loadu_ps(x);
    if (y) v = _mm_add_ps(v, _mm_loadu_ps(y));
    const __m128d ww = _mm_set1_pd(w);
    a->xy = _mm_add_pd(a->xy, _mm_mul_pd(_mm_cvtps_pd(v), ww));
    a->zw = _mm_add_pd(a->zw, _mm_mul_pd(_mm_cvtps_pd(_mm_movehl_ps(v, v)), ww));
}
/* a += w * (the row of 4 doubles at x) */
static inline void sum3_add_d(sum3 *a, double w, const double *x) {
    const __m128d ww = _mm_set1_pd(w);
    a->xy = _mm_add_pd(a->xy, _mm_mul_pd(_mm_loadu_pd(x), ww));
    a->zw = _mm_add_pd(a->zw, _mm_mul_pd(_mm_loadu_pd(x + 2), ww));
}
static inline void sum3_get(sum3 a, sum3 b, double out[3]) {
    double xy[2], zw[2];
    _mm_storeu_pd(xy, _mm_add_pd(a.xy, b.xy));
    _mm_storeu_pd(zw, _mm_add_pd(a.zw, b.zw));
    out[0] = xy[0];
    out[1] = xy[1];
    out[2] = zw[0];
}
#else
typedef struct sum3 {
    double v[3];
} sum3;
static inline sum3 sum3_zero(void) {
    sum3 a = {{0.0, 0.0, 0.0}};
    return a;
}
static inline void sum3_add(sum3 *a, double w, const float *x, const float *y) {
    for (int c = 0; c < 3; ++c) a->v[c] += w * (double)(y ? x[c] + y[c] : x[c]);
}
static inline void sum3_add_d(sum3 *a, double w, const double *x) {
    for (int c = 0; c < 3; ++c) a->v[c] += w * x[c];
}
static inline void sum3_get(sum3 a, sum3 b, double out[3]) {
    for (int c = 0; c < 3; ++c) out[c] = a.v[c] + b.v[c];
}
#endif

/* The same sums in one AVX register, for the residual passes where the
 * processor and the system have AVX (SPIA_AVX_KERNELS): the lanes take the
 * same operations in the same order as sum3's two SSE2 registers (no fused
 * multiply-add), so the sums are the same to the bit, in fewer
 * instructions. */
#ifdef SPIA_AVX_KERNELS
#define SPIA_AVX_RESIDUALS 1
#include <immintrin.h>
#define AVX_TARGET __attribute__((target("avx")))
#define AVX_INLINE static inline __attribute__((always_inline, target("avx")))
typedef struct sumv {
    __m256d v;
} sumv;
AVX_INLINE sumv sumv_zero(void) {
    sumv a = {_mm256_setzero_pd()};
    return a;
}
AVX_INLINE void sumv_add(sumv *a, double w, const float *x, const float *y) {
    __m128 v = _mm_loadu_ps(x);
    if (y) v = _mm_add_ps(v, _mm_loadu_ps(y));
    a->v = _mm256_add_pd(a->v, _mm256_mul_pd(_mm256_cvtps_pd(v), _mm256_set1_pd(w)));
}
AVX_INLINE void sumv_get(sumv a, sumv b, double out[3]) {
    double xyzw[4];
    _mm256_storeu_pd(xyzw, _mm256_add_pd(a.v, b.v));
    out[0] = xyzw[0];
    out[1] = xyzw[1];
    out[2] = xyzw[2];
}

#endif

/* The sum of the square roots of x[0 .. count), two at a time where there
 * is SSE2 (no square root waits for the one before). */
static double sum_of_roots(const double *x, int32_t count) {
#if defined(__SSE2__) || defined(_M_X64)
    __m128d acc = _mm_setzero_pd();
    int32_t q = 0;
    for (; q + 1 < count; q += 2) acc = _mm_add_pd(acc, _mm_sqrt_pd(_mm_loadu_pd(x + q)));
    double pair[2];
    _mm_storeu_pd(pair, acc);
    double sum = pair[0] + pair[1];
    if (q < count) sum += sqrt(x[q]);
    return sum;
#else
    double even = 0.0, odd = 0.0;
    int32_t q = 0;
    for (; q + 1 < count; q += 2) {
        even += sqrt(x[q]);
        odd += sqrt(x[q + 1]);
    }
    double sum = even + odd;
    if (q < count) sum += sqrt(x[q]);
    return sum;
#endif
}

/* ------------------------------------------------------------------------ */
/* The solver's state                                                        */
/* ------------------------------------------------------------------------ */

typedef struct fast {
    const spia_plan *p;
    int32_t n;
    int threads;
    int wide;          /* double sweeps (SPIA_SOLVE_DOUBLE_SWEEPS) */
    float *P;          /* the targets by position, 3 floats a row */
    float *S;          /* the first iterate by position (P itself when none is given);
                        * a stuck row's is its target */
    void *Y, *B;       /* correction and right-hand side, 4 floats (or doubles) a row */
    unsigned char *flags;
    double *inverse;   /* wide: 1 / weight */
    f4 *weight4, *inverse4, *signed4; /* per code, in float32 in all four lanes: the weight, its inverse, the
                                       * first step's weight (signed_f) */
    int64_t blocks;
    int64_t *block_entry; /* blocks + 1: the first entry of each block of FAST_BLOCK rows */
    double *partial;   /* blocks * 4 */
} fast;

static inline int row_active(const fast *f, int32_t i) { return f->flags[i] == 0; }

/* The coordinate a of the cage as it will be stored: S + Y in float (a
 * stuck row has S = P and Y = 0). */
static inline float cage_value(const fast *f, int32_t i, int a) {
    if (f->wide) return (float)((double)f->S[3 * (int64_t)i + a] + ((const double *)f->Y)[4 * (int64_t)i + a]);
    return f->S[3 * (int64_t)i + a] + ((const float *)f->Y)[4 * (int64_t)i + a];
}

/* Sticky largest value: a NaN stays. */
static inline double keep_max(double worst, double d) { return (!(d <= worst) && worst == worst) ? d : worst; }

/* ------------------------------------------------------------------------ */
/* Kernels, for each width of codes and offsets                              */
/* ------------------------------------------------------------------------ */

/* One sweep over the rows of chunk c; returns the largest |g|^2 met. */
typedef double (*sweep_fn)(const fast *f, int32_t c);
/* The first step over the rows of chunk c. */
typedef void (*first_fn)(const fast *f, int32_t c);
/* Blocks [b0, b1) of FAST_BLOCK rows: R = P - L x, in double with the
 * exact weights, x the first iterate S (and then B = R) or the cage as
 * stored, S + Y; per block the largest |R| over all rows and over active
 * rows, the sum and the sum of squares (active rows) into f->partial. */
typedef void (*residual_fn)(fast *f, int64_t b0, int64_t b1);

#define DEFINE_KERNELS(SUFFIX, CODE, DELTA)                                                                      \
    static double sweep_f_##SUFFIX(const fast *f, int32_t c) {                                                   \
        const spia_plan *p = f->p;                                                                               \
        f4 *Y = (f4 *)f->Y;                                                                                      \
        const f4 *B = (const f4 *)f->B;                                                                          \
        const f4 *w = f->weight4, *inverse = f->inverse4;                                                        \
        int64_t k = p->chunk_entry[c];                                                                           \
        double worst = 0.0;                                                                                      \
        for (int32_t i = p->chunk_start[c]; i < p->chunk_start[c + 1]; ++i) {                                    \
            const int32_t e = p->length[i];                                                                      \
            if (!row_active(f, i)) {                                                                             \
                k += e;                                                                                          \
                continue;                                                                                        \
            }                                                                                                    \
            const f4 *y = Y + i;                                                                                 \
            f4 a0, a1, a2;                                                                                       \
            if (e == 9) {                                                                                        \
                /* a regular quad mesh's rows: no loop */                                                        \
                a0 = V4_ADD(V4_ADD(V4_MUL(y[0], w[CODE[k]]), V4_MUL(y[DELTA[k + 1]], w[CODE[k + 1]])),           \
                            V4_MUL(y[DELTA[k + 2]], w[CODE[k + 2]]));                                            \
                a1 = V4_ADD(V4_ADD(V4_MUL(y[DELTA[k + 3]], w[CODE[k + 3]]), V4_MUL(y[DELTA[k + 4]], w[CODE[k + 4]])), \
                            V4_MUL(y[DELTA[k + 5]], w[CODE[k + 5]]));                                            \
                a2 = V4_ADD(V4_ADD(V4_MUL(y[DELTA[k + 6]], w[CODE[k + 6]]), V4_MUL(y[DELTA[k + 7]], w[CODE[k + 7]])), \
                            V4_MUL(y[DELTA[k + 8]], w[CODE[k + 8]]));                                            \
            } else {                                                                                             \
                a0 = V4_MUL(y[0], w[CODE[k]]);                                                                   \
                a1 = V4_ZERO(f4);                                                                                \
                a2 = V4_ZERO(f4);                                                                                \
                int32_t q = 1;                                                                                   \
                for (; q + 2 < e; q += 3) {                                                                      \
                    a0 = V4_ADD(a0, V4_MUL(y[DELTA[k + q]], w[CODE[k + q]]));                                    \
                    a1 = V4_ADD(a1, V4_MUL(y[DELTA[k + q + 1]], w[CODE[k + q + 1]]));                            \
                    a2 = V4_ADD(a2, V4_MUL(y[DELTA[k + q + 2]], w[CODE[k + q + 2]]));                            \
                }                                                                                                \
                for (; q < e; ++q) a0 = V4_ADD(a0, V4_MUL(y[DELTA[k + q]], w[CODE[k + q]]));                     \
            }                                                                                                    \
            const f4 g = V4_SUB(B[i], V4_ADD(a0, V4_ADD(a1, a2)));                                               \
            Y[i] = V4_ADD(Y[i], V4_MUL(g, inverse[CODE[k]]));                                                    \
            const float g0 = V4_LANE(g, 0), g1 = V4_LANE(g, 1), g2 = V4_LANE(g, 2);                              \
            worst = keep_max(worst, (double)(g0 * g0 + g1 * g1 + g2 * g2));                                      \
            k += e;                                                                                              \
        }                                                                                                        \
        return worst;                                                                                            \
    }                                                                                                            \
    static double sweep_d_##SUFFIX(const fast *f, int32_t c) {                                                   \
        const spia_plan *p = f->p;                                                                               \
        double *Y = (double *)f->Y;                                                                              \
        const double *B = (const double *)f->B, *w = p->weight;                                                  \
        int64_t k = p->chunk_entry[c];                                                                           \
        double worst = 0.0;                                                                                      \
        for (int32_t i = p->chunk_start[c]; i < p->chunk_start[c + 1]; ++i) {                                    \
            const int32_t e = p->length[i];                                                                      \
            if (!row_active(f, i)) {                                                                             \
                k += e;                                                                                          \
                continue;                                                                                        \
            }                                                                                                    \
            const double *y = Y + 4 * (int64_t)i;                                                                \
            sum3 a0 = sum3_zero(), a1 = sum3_zero(), a2 = sum3_zero();                                           \
            sum3_add_d(&a0, w[CODE[k]], y);                                                                      \
            int32_t q = 1;                                                                                       \
            for (; q + 2 < e; q += 3) {                                                                          \
                sum3_add_d(&a0, w[CODE[k + q]], y + 4 * (int64_t)DELTA[k + q]);                                  \
                sum3_add_d(&a1, w[CODE[k + q + 1]], y + 4 * (int64_t)DELTA[k + q + 1]);                          \
                sum3_add_d(&a2, w[CODE[k + q + 2]], y + 4 * (int64_t)DELTA[k + q + 2]);                          \
            }                                                                                                    \
            for (; q < e; ++q) sum3_add_d(&a0, w[CODE[k + q]], y + 4 * (int64_t)DELTA[k + q]);                   \
            double lx[3], m[3];                                                                                  \
            sum3_get(a0, a1, lx);                                                                                \
            sum3_get(a2, sum3_zero(), m);                                                                        \
            const double inv = f->inverse[CODE[k]];                                                              \
            double d2 = 0.0;                                                                                     \
            for (int a = 0; a < 3; ++a) {                                                                        \
                const double g = B[4 * (int64_t)i + a] - (lx[a] + m[a]);                                         \
                Y[4 * (int64_t)i + a] += g * inv;                                                                \
                d2 += g * g;                                                                                     \
            }                                                                                                    \
            worst = keep_max(worst, d2);                                                                         \
            k += e;                                                                                              \
        }                                                                                                        \
        return worst;                                                                                            \
    }                                                                                                            \
    static void first_##SUFFIX(const fast *f, int32_t c) {                                                       \
        const spia_plan *p = f->p;                                                                               \
        int64_t k = p->chunk_entry[c];                                                                           \
        for (int32_t i = p->chunk_start[c]; i < p->chunk_start[c + 1]; ++i) {                                    \
            const int32_t e = p->length[i];                                                                      \
            if (!row_active(f, i)) {                                                                             \
                k += e;                                                                                          \
                continue;                                                                                        \
            }                                                                                                    \
            const float own = p->inverse_f[CODE[k]];                                                             \
            if (f->wide) {                                                                                       \
                const d4 *B = (const d4 *)f->B + i;                                                              \
                d4 acc = V4_ZERO(d4);                                                                            \
                for (int32_t q = 0; q < e; ++q)                                                                  \
                    acc = V4_ADD(acc, V4_SCALE(B[DELTA[k + q]], (double)p->signed_f[CODE[k + q]]));              \
                ((d4 *)f->Y)[i] = V4_SCALE(acc, FIRST_STEP_SCALE * (double)own * (double)own);                   \
            } else {                                                                                             \
                const f4 *B = (const f4 *)f->B + i, *w = f->signed4;                                             \
                f4 acc = V4_MUL(B[0], w[CODE[k]]), acc2 = V4_ZERO(f4);                                           \
                int32_t q = 1;                                                                                   \
                for (; q + 1 < e; q += 2) {                                                                      \
                    acc = V4_ADD(acc, V4_MUL(B[DELTA[k + q]], w[CODE[k + q]]));                                  \
                    acc2 = V4_ADD(acc2, V4_MUL(B[DELTA[k + q + 1]], w[CODE[k + q + 1]]));                        \
                }                                                                                                \
                if (q < e) acc = V4_ADD(acc, V4_MUL(B[DELTA[k + q]], w[CODE[k + q]]));                           \
                ((f4 *)f->Y)[i] = V4_SCALE(V4_ADD(acc, acc2), (float)FIRST_STEP_SCALE * own * own);              \
            }                                                                                                    \
            k += e;                                                                                              \
        }                                                                                                        \
    }

/* The residual passes, for each width of codes and offsets and each way of
 * summing in double (S3: sum3, or sumv with AVX). */
#define DEFINE_RESIDUALS(SUFFIX, CODE, DELTA, S3, ATTR)                                                          \
    ATTR static void residual_first_##SUFFIX##S3(fast *f, int64_t b0, int64_t b1) {                              \
        const spia_plan *p = f->p;                                                                               \
        const int32_t n = f->n;                                                                                  \
        for (int64_t b = b0; b < b1; ++b) {                                                                      \
            double maxd = 0.0, maxa = 0.0, norm2 = 0.0, squares[FAST_BLOCK];                                     \
            const int32_t i0 = (int32_t)(b * FAST_BLOCK);                                                        \
            const int32_t i1 = (int32_t)((b + 1) * FAST_BLOCK < n ? (b + 1) * FAST_BLOCK : n);                   \
            int64_t k = f->block_entry[b];                                                                       \
            for (int32_t i = i0; i < i1; ++i) {                                                                  \
                const int32_t e = p->length[i];                                                                  \
                const float *S = f->S + 3 * (int64_t)i;                                                          \
                S3 a0 = S3##_zero(), a1 = S3##_zero();                                                           \
                int32_t q = 0;                                                                                   \
                for (; q + 1 < e; q += 2, k += 2) {                                                              \
                    S3##_add(&a0, p->weight[CODE[k]], S + 3 * (int64_t)DELTA[k], NULL);                          \
                    S3##_add(&a1, p->weight[CODE[k + 1]], S + 3 * (int64_t)DELTA[k + 1], NULL);                  \
                }                                                                                                \
                if (q < e) {                                                                                     \
                    S3##_add(&a0, p->weight[CODE[k]], S + 3 * (int64_t)DELTA[k], NULL);                          \
                    ++k;                                                                                         \
                }                                                                                                \
                double lx[3];                                                                                    \
                S3##_get(a0, a1, lx);                                                                            \
                const float *t = f->P + 3 * (int64_t)i;                                                          \
                const double r0 = (double)t[0] - lx[0], r1 = (double)t[1] - lx[1], r2 = (double)t[2] - lx[2];    \
                if (f->wide) {                                                                                   \
                    double *q4 = (double *)f->B + 4 * (int64_t)i;                                                \
                    q4[0] = r0;                                                                                  \
                    q4[1] = r1;                                                                                  \
                    q4[2] = r2;                                                                                  \
                    q4[3] = 0.0;                                                                                 \
                } else {                                                                                         \
                    float *q4 = (float *)f->B + 4 * (int64_t)i;                                                  \
                    q4[0] = (float)r0;                                                                           \
                    q4[1] = (float)r1;                                                                           \
                    q4[2] = (float)r2;                                                                           \
                    q4[3] = 0.0f;                                                                                \
                }                                                                                                \
                const double d2 = r0 * r0 + r1 * r1 + r2 * r2;                                                   \
                squares[i - i0] = d2;                                                                            \
                maxd = keep_max(maxd, d2);                                                                       \
                if (row_active(f, i)) {                                                                          \
                    maxa = keep_max(maxa, d2);                                                                   \
                    norm2 += d2;                                                                                 \
                }                                                                                                \
            }                                                                                                    \
            double *q4 = f->partial + 4 * b;                                                                     \
            q4[0] = sqrt(maxd);                                                                                  \
            q4[1] = sqrt(maxa);                                                                                  \
            q4[2] = sum_of_roots(squares, i1 - i0);                                                              \
            q4[3] = norm2;                                                                                       \
        }                                                                                                        \
    }                                                                                                            \
    ATTR static void residual_cage_##SUFFIX##S3(fast *f, int64_t b0, int64_t b1) {                               \
        const spia_plan *p = f->p;                                                                               \
        const int32_t n = f->n;                                                                                  \
        for (int64_t b = b0; b < b1; ++b) {                                                                      \
            double maxd = 0.0, maxa = 0.0, norm2 = 0.0, squares[FAST_BLOCK];                                     \
            const int32_t i0 = (int32_t)(b * FAST_BLOCK);                                                        \
            const int32_t i1 = (int32_t)((b + 1) * FAST_BLOCK < n ? (b + 1) * FAST_BLOCK : n);                   \
            int64_t k = f->block_entry[b];                                                                       \
            for (int32_t i = i0; i < i1; ++i) {                                                                  \
                const int32_t e = p->length[i];                                                                  \
                S3 a0 = S3##_zero(), a1 = S3##_zero();                                                           \
                if (f->wide) {                                                                                   \
                    for (int32_t q = 0; q < e; ++q, ++k) {                                                       \
                        const int32_t j = i + DELTA[k];                                                          \
                        const float x[4] = {cage_value(f, j, 0), cage_value(f, j, 1), cage_value(f, j, 2), 0.0f}; \
                        S3##_add(&a0, p->weight[CODE[k]], x, NULL);                                              \
                    }                                                                                            \
                } else {                                                                                         \
                    const float *S = f->S + 3 * (int64_t)i, *Y = (const float *)f->Y + 4 * (int64_t)i;           \
                    int32_t q = 0;                                                                               \
                    for (; q + 1 < e; q += 2, k += 2) {                                                          \
                        const int64_t j0 = DELTA[k], j1 = DELTA[k + 1];                                          \
                        S3##_add(&a0, p->weight[CODE[k]], S + 3 * j0, Y + 4 * j0);                               \
                        S3##_add(&a1, p->weight[CODE[k + 1]], S + 3 * j1, Y + 4 * j1);                           \
                    }                                                                                            \
                    if (q < e) {                                                                                 \
                        const int64_t j0 = DELTA[k];                                                             \
                        S3##_add(&a0, p->weight[CODE[k]], S + 3 * j0, Y + 4 * j0);                               \
                        ++k;                                                                                     \
                    }                                                                                            \
                }                                                                                                \
                double lx[3];                                                                                    \
                S3##_get(a0, a1, lx);                                                                            \
                const float *t = f->P + 3 * (int64_t)i;                                                          \
                const double r0 = (double)t[0] - lx[0], r1 = (double)t[1] - lx[1], r2 = (double)t[2] - lx[2];    \
                const double d2 = r0 * r0 + r1 * r1 + r2 * r2;                                                   \
                squares[i - i0] = d2;                                                                            \
                maxd = keep_max(maxd, d2);                                                                       \
                if (row_active(f, i)) {                                                                          \
                    maxa = keep_max(maxa, d2);                                                                   \
                    norm2 += d2;                                                                                 \
                }                                                                                                \
            }                                                                                                    \
            double *q4 = f->partial + 4 * b;                                                                     \
            q4[0] = sqrt(maxd);                                                                                  \
            q4[1] = sqrt(maxa);                                                                                  \
            q4[2] = sum_of_roots(squares, i1 - i0);                                                              \
            q4[3] = norm2;                                                                                       \
        }                                                                                                        \
    }

DEFINE_KERNELS(c8d16, p->code8, p->delta16)
DEFINE_KERNELS(c16d16, p->code16, p->delta16)
DEFINE_KERNELS(c8d32, p->code8, p->delta32)
DEFINE_KERNELS(c16d32, p->code16, p->delta32)
DEFINE_RESIDUALS(c8d16, p->code8, p->delta16, sum3, )
DEFINE_RESIDUALS(c16d16, p->code16, p->delta16, sum3, )
DEFINE_RESIDUALS(c8d32, p->code8, p->delta32, sum3, )
DEFINE_RESIDUALS(c16d32, p->code16, p->delta32, sum3, )
#ifdef SPIA_AVX_RESIDUALS
DEFINE_RESIDUALS(c8d16, p->code8, p->delta16, sumv, AVX_TARGET)
DEFINE_RESIDUALS(c16d16, p->code16, p->delta16, sumv, AVX_TARGET)
DEFINE_RESIDUALS(c8d32, p->code8, p->delta32, sumv, AVX_TARGET)
DEFINE_RESIDUALS(c16d32, p->code16, p->delta32, sumv, AVX_TARGET)
#endif

typedef struct kernels {
    sweep_fn sweep;
    first_fn first;
    residual_fn residual_first, residual_cage;
} kernels;

#define KERNELS(SUFFIX)                                                                                          \
    do {                                                                                                         \
        k.sweep = f->wide ? sweep_d_##SUFFIX : sweep_f_##SUFFIX;                                                 \
        k.first = first_##SUFFIX;                                                                                \
        k.residual_first = residual_first_##SUFFIX##sum3;                                                        \
        k.residual_cage = residual_cage_##SUFFIX##sum3;                                                          \
        AVX_RESIDUALS(SUFFIX);                                                                                   \
    } while (0)
#ifdef SPIA_AVX_RESIDUALS
#define AVX_RESIDUALS(SUFFIX)                                                                                    \
    if (avx) {                                                                                                   \
        k.residual_first = residual_first_##SUFFIX##sumv;                                                        \
        k.residual_cage = residual_cage_##SUFFIX##sumv;                                                          \
    }
#else
#define AVX_RESIDUALS(SUFFIX) (void)avx
#endif

/* The kernels for the plan's widths; the residual passes with AVX unless
 * no_avx (SPIA_SOLVE_NO_AVX) or the machine has none. */
static kernels kernels_for(const fast *f, int no_avx) {
    const spia_plan *p = f->p;
    kernels k;
#ifdef SPIA_AVX_RESIDUALS
    const int avx = !no_avx && spia__have_avx();
#else
    const int avx = 0;
    (void)no_avx;
#endif
    if (p->code8 && p->delta16)
        KERNELS(c8d16);
    else if (p->delta16)
        KERNELS(c16d16);
    else if (p->code8)
        KERNELS(c8d32);
    else
        KERNELS(c16d32);
    return k;
}

/* Entry e's code and column offset, whatever their widths (the rare
 * passes). */
static inline int32_t code_at(const spia_plan *p, int64_t e) { return p->code8 ? p->code8[e] : p->code16[e]; }
static inline int32_t delta_at(const spia_plan *p, int64_t e) { return p->delta16 ? p->delta16[e] : p->delta32[e]; }

/* ------------------------------------------------------------------------ */
/* Residual passes                                                           */
/* ------------------------------------------------------------------------ */

typedef struct residual_task {
    fast *f;
    residual_fn fn;
} residual_task;

static void residual_blocks(void *context, int64_t b0, int64_t b1, int thread) {
    (void)thread;
    residual_task *t = (residual_task *)context;
    t->fn(t->f, b0, b1);
}

/* R of the first iterate (first: B written) or of the cage as stored:
 * returns the largest distance over all rows, writes the mean and the
 * largest over active rows; the partial sums are added in block order. */
static double residual_pass(fast *f, const kernels *k, int first, double *mean, double *max_active) {
    residual_task t = {f, first ? k->residual_first : k->residual_cage};
    spia__parallel_for(f->threads, f->blocks, PIECE_BLOCKS, residual_blocks, &t);
    double maxd = 0.0, maxa = 0.0, sum = 0.0;
    for (int64_t b = 0; b < f->blocks; ++b) {
        maxd = keep_max(maxd, f->partial[4 * b]);
        maxa = keep_max(maxa, f->partial[4 * b + 1]);
        sum += f->partial[4 * b + 2];
    }
    *mean = sum / f->n;
    *max_active = maxa;
    return maxd;
}

/* ------------------------------------------------------------------------ */
/* Pipelined sweeps                                                          */
/* ------------------------------------------------------------------------ */

typedef struct pipeline {
    fast *f;
    kernels k;
    int32_t stages;     /* sweeps, and the first step before them when first_step */
    int first_step;
    int32_t *pairs;     /* (chunk, stage) in the order they are handed out */
    int64_t pair_count;
    spia__counter next;
    spia__counter *done;     /* per chunk: stages done */
    spia__counter *finished; /* per stage: chunks done */
    spia__counter stop;
    double *worst;           /* per thread and stage */
    int threads;
    /* Reported by the calling thread as stages finish: */
    int32_t reported;
    double *estimate;        /* per stage: the sweep's error */
    int32_t iteration;       /* iterations before this run */
    double scale;
    const spia_options *opt;
    spia_report *report;
    int32_t cancelled; /* the iteration after which the callback cancelled, else 0 */
} pipeline;

/* Stages finished so far, in order, from the calling thread: each sweep's
 * error into the history and to the progress callback, which may cancel;
 * all but the last, which the caller reports once it knows whether the
 * residual in double follows it. */
static void report_finished(pipeline *u) {
    const int32_t chunks = u->f->p->chunks;
    while (u->reported < u->stages && spia__counter_get(&u->finished[u->reported]) == chunks) {
        const int32_t st = u->reported++;
        if (u->first_step && st == 0) continue;
        double w = 0.0;
        for (int t = 0; t < u->threads; ++t) w = keep_max(w, u->worst[(int64_t)t * u->stages + st]);
        const double err = sqrt(w);
        u->estimate[st] = err;
        if (st == u->stages - 1) continue;
        const int32_t it = u->iteration + st + (u->first_step ? 0 : 1);
        spia_report *rep = u->report;
        if (rep && rep->history && it <= rep->history_capacity) {
            rep->history[it - 1] = err / u->scale;
            rep->history_count = it;
        }
        if (!u->cancelled && u->opt->progress && u->opt->progress(u->opt->progress_user_data, it, err / u->scale)) {
            u->cancelled = it;
            spia__counter_set(&u->stop, 1);
        }
    }
}

static void pipeline_worker(void *context, int64_t piece0, int64_t piece1, int thread) {
    (void)piece0;
    (void)piece1;
    pipeline *u = (pipeline *)context;
    const spia_plan *p = u->f->p;
    const int32_t reach = p->reach, last = p->chunks - 1;
    for (;;) {
        if (spia__counter_get(&u->stop)) break;
        const int64_t ticket = spia__counter_add(&u->next, 1);
        if (ticket >= u->pair_count) break;
        const int32_t c = u->pairs[2 * ticket], st = u->pairs[2 * ticket + 1];
        /* As one sweep after another would have it: the chunks before this
         * one that it refers to have had this stage (and are done reading
         * it), those after it the stage before (and not yet this one: that
         * waits for this chunk). */
        const int32_t lo = c - reach > 0 ? c - reach : 0, hi = c + reach < last ? c + reach : last;
        for (int32_t j = lo; j <= hi; ++j) {
            int rounds = 0;
            while (spia__counter_get(&u->done[j]) < st + (j < c ? 1 : 0)) {
                if (spia__counter_get(&u->stop)) return;
                spia__wait(&rounds);
            }
        }
        if (u->first_step && st == 0) {
            u->k.first(u->f, c);
        } else {
            double *w = &u->worst[(int64_t)thread * u->stages + st];
            *w = keep_max(*w, u->k.sweep(u->f, c));
        }
        spia__counter_add(&u->done[c], 1);
        spia__counter_add(&u->finished[st], 1);
        if (thread == 0) report_finished(u);
    }
}

/* Runs `sweeps` sweeps (after the first step when first_step), their
 * errors into estimate[0 ..]; returns 0 when out of memory, -1 when
 * cancelled (after iteration *cancelled_at). */
static int run_sweeps(fast *f, const kernels *k, int first_step, int32_t sweeps, int32_t iteration, double scale,
                      const spia_options *opt, spia_report *report, double *estimate, int32_t *cancelled_at) {
    const spia_plan *p = f->p;
    pipeline u;
    memset(&u, 0, sizeof u);
    u.f = f;
    u.k = *k;
    u.first_step = first_step;
    u.stages = sweeps + (first_step ? 1 : 0);
    /* (no more threads than stages: a thread beyond them would only wait) */
    u.threads = f->threads < u.stages ? f->threads : u.stages;
    u.iteration = iteration;
    u.scale = scale;
    u.opt = opt;
    u.report = report;
    const int32_t chunks = p->chunks, lag = p->reach + 1;
    u.pair_count = (int64_t)chunks * u.stages;
    u.pairs = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)u.pair_count);
    u.done = (spia__counter *)malloc(sizeof(spia__counter) * (size_t)chunks);
    u.finished = (spia__counter *)malloc(sizeof(spia__counter) * (size_t)u.stages);
    u.worst = (double *)calloc((size_t)u.threads * (size_t)u.stages, sizeof(double));
    u.estimate = (double *)calloc((size_t)u.stages, sizeof(double));
    if (!u.pairs || !u.done || !u.finished || !u.worst || !u.estimate) {
        free(u.pairs);
        free(u.done);
        free(u.finished);
        free(u.worst);
        free(u.estimate);
        return 0;
    }
    /* Chunk c of stage s at step c + lag * s: everything it waits for
     * (the chunk before it in its stage, the chunk `reach` after it in the
     * stage before) comes at an earlier step, and the pairs of one step
     * are lag chunks apart, too far to touch each other's rows. */
    int64_t m = 0;
    const int64_t steps = (int64_t)chunks + (int64_t)lag * (u.stages - 1);
    for (int64_t t = 0; t < steps; ++t)
        for (int32_t s = 0; s < u.stages; ++s) {
            const int64_t c = t - (int64_t)lag * s;
            if (c < 0 || c >= chunks) continue;
            u.pairs[2 * m] = (int32_t)c;
            u.pairs[2 * m + 1] = s;
            ++m;
        }
    for (int32_t c = 0; c < chunks; ++c) spia__counter_set(&u.done[c], 0);
    for (int32_t s = 0; s < u.stages; ++s) spia__counter_set(&u.finished[s], 0);
    spia__counter_set(&u.next, 0);
    spia__counter_set(&u.stop, 0);
    spia__parallel_for(u.threads, u.threads, 0, pipeline_worker, &u);
    if (!u.cancelled) report_finished(&u);
    for (int32_t s = 0; s < sweeps; ++s) estimate[s] = u.estimate[s + (first_step ? 1 : 0)];
    const int cancelled = u.cancelled != 0;
    *cancelled_at = u.cancelled;
    free(u.pairs);
    free(u.done);
    free(u.finished);
    free(u.worst);
    free(u.estimate);
    return cancelled ? -1 : 1;
}

/* ------------------------------------------------------------------------ */
/* Unreachable rows                                                          */
/* ------------------------------------------------------------------------ */

typedef struct mark_task {
    fast *f;
    double *distances; /* 2 per row: the cage's, and the first iterate's */
} mark_task;

static void mark_blocks(void *context, int64_t b0, int64_t b1, int thread) {
    (void)thread;
    mark_task *t = (mark_task *)context;
    fast *f = t->f;
    const spia_plan *p = f->p;
    for (int64_t b = b0; b < b1; ++b) {
        const int64_t i1 = (b + 1) * FAST_BLOCK < f->n ? (b + 1) * FAST_BLOCK : f->n;
        int64_t k = f->block_entry[b];
        for (int64_t i = b * FAST_BLOCK; i < i1; ++i) {
            double s[3] = {0.0, 0.0, 0.0}, s0[3] = {0.0, 0.0, 0.0};
            for (int32_t q = 0; q < p->length[i]; ++q, ++k) {
                const double w = p->weight[code_at(p, k)];
                const int32_t j = (int32_t)i + delta_at(p, k);
                for (int a = 0; a < 3; ++a) {
                    s[a] += w * (double)cage_value(f, j, a);
                    s0[a] += w * (double)f->S[3 * (int64_t)j + a];
                }
            }
            double d = 0.0, d0 = 0.0;
            for (int a = 0; a < 3; ++a) {
                const double t0 = (double)f->P[3 * i + a];
                d += (t0 - s[a]) * (t0 - s[a]);
                d0 += (t0 - s0[a]) * (t0 - s0[a]);
            }
            t->distances[2 * i] = sqrt(d);
            t->distances[2 * i + 1] = sqrt(d0);
        }
    }
}

/* solve.c's mark_stuck on the plan's rows: a row whose residual has not
 * fallen below half its first iterate's, or whose cage vertex has drifted
 * DRIFT_FACTOR times the largest first distance, is put back on its target
 * (S = P, Y = 0) and left there; B follows the new S.  Returns the number
 * marked, -1 when out of memory. */
static int32_t mark_stuck(fast *f, const kernels *k, double threshold) {
    const int32_t n = f->n;
    double *dist = (double *)malloc(sizeof(double) * 2 * (size_t)n);
    if (!dist) return -1;
    mark_task t = {f, dist};
    spia__parallel_for(f->threads, f->blocks, PIECE_BLOCKS, mark_blocks, &t);
    double initial_max = threshold;
    for (int32_t i = 0; i < n; ++i)
        if (row_active(f, i) && dist[2 * (int64_t)i + 1] > initial_max) initial_max = dist[2 * (int64_t)i + 1];
    int32_t count = 0;
    for (int32_t i = 0; i < n; ++i) {
        if (!row_active(f, i)) continue;
        double moved2 = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double m = (double)cage_value(f, i, a) - (double)f->S[3 * (int64_t)i + a];
            moved2 += m * m;
        }
        const double d = dist[2 * (int64_t)i], d0 = dist[2 * (int64_t)i + 1];
        if ((d > threshold && d > 0.5 * d0) || sqrt(moved2) > FAST_DRIFT * initial_max) {
            f->flags[i] |= STUCK;
            ++count;
        }
    }
    free(dist);
    if (count > 0) {
        for (int32_t i = 0; i < n; ++i) {
            if (!(f->flags[i] & STUCK)) continue;
            for (int a = 0; a < 3; ++a) {
                f->S[3 * (int64_t)i + a] = f->P[3 * (int64_t)i + a];
                if (f->wide)
                    ((double *)f->Y)[4 * (int64_t)i + a] = 0.0;
                else
                    ((float *)f->Y)[4 * (int64_t)i + a] = 0.0f;
            }
        }
        double mean, err;
        residual_pass(f, k, 1, &mean, &err);
    }
    return count;
}

/* ------------------------------------------------------------------------ */
/* The solve                                                                 */
/* ------------------------------------------------------------------------ */

typedef struct stage_result {
    double err_all, mean, err; /* the last residual pass */
    int current;               /* that pass is of the cage as it is now */
    int float_floor;           /* the double sweeps should take over */
} stage_result;

/* The contraction of a sweep's error from the last two (1 while there are
 * fewer), between 0.05 and 1. */
static double contraction(const double *recent, int32_t known) {
    if (known < 2 || !(recent[0] > 0.0) || !(recent[1] > 0.0) || !isfinite(recent[1])) return 1.0;
    const double rho = recent[1] / recent[0];
    return rho >= 0.05 ? (rho < 1.0 ? rho : 1.0) : 0.05;
}

/* The residual after a sweep is near the sweep's error (the largest met
 * before each row moved) times the contraction: the residual in double is
 * taken once that expects to be within this part of the tolerance. */
#define EXPECTED_MARGIN 0.9

/* The next run's length: on a pipelined plan, as many sweeps as the last
 * two errors' ratio says are still needed for the expected residual to be
 * within the margin (at least one, at most LONGEST_RUN; FIRST_RUN before
 * there is a ratio); one at a time on a plan of one chunk. */
static int32_t run_length(const fast *f, const double *recent, int32_t known, double threshold) {
    if (f->p->chunks == 1) return 1;
    if (known < 2) return FIRST_RUN;
    const double rho = contraction(recent, known);
    if (!(rho < 0.95)) return 1;
    /* The least n with rho^n <= target, by multiplying: libm's log is
     * GLIBC_2.29, newer than the glibc official Blender runs on (2.28). */
    const double target = EXPECTED_MARGIN * threshold / (recent[1] * rho);
    if (!(target < 1.0)) return 1;
    double power = rho;
    int32_t n = 1;
    while (power > target && n < LONGEST_RUN) {
        power *= rho;
        ++n;
    }
    return n;
}

/* One stage (all of the solve unless staged): sweeps until the tolerance,
 * max_iterations, stagnation or the float32 floor.  known_stats: the
 * residual statistics of the cage as it is (err_all, mean, err), or NULL
 * to measure them. */
static spia_result fast_stage(fast *f, const kernels *k, const spia_options *opt, double threshold, double scale,
                              int first_step, const double *known_stats, int32_t *it, int32_t *stuck_count,
                              stage_result *out, spia_report *report, spia_status *status) {
    double mean, err, err_all;
    if (known_stats) {
        err_all = known_stats[0];
        mean = known_stats[1];
        err = known_stats[2];
    } else {
        err_all = residual_pass(f, k, 0, &mean, &err);
    }
    out->current = 1;
    const double initial = err;
    double best = err, recent[2] = {0.0, 0.0};
    int32_t it_best = *it, known = 0, failed_checks = 0;
    int stuck_checked = 0;
    spia_result res = SPIA_OK;
    double estimate[LONGEST_RUN];
    while (!(err <= threshold)) {
        if (*it >= opt->max_iterations) {
            res = SPIA_MAX_ITERATIONS;
            break;
        }
        int32_t sweeps = run_length(f, recent, known, threshold);
        if (sweeps > opt->max_iterations - *it) sweeps = opt->max_iterations - *it;
        if (sweeps > it_best + FAST_WINDOW - *it) sweeps = it_best + FAST_WINDOW - *it;
        if (sweeps < 1) sweeps = 1;
        int32_t cancelled_at = 0;
        const int ran = run_sweeps(f, k, first_step, sweeps, *it, scale, opt, report, estimate, &cancelled_at);
        first_step = 0;
        if (ran == 0) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver");
        if (ran < 0) {
            *it = cancelled_at;
            return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after %d iterations", (int)*it);
        }
        out->current = 0;
        for (int32_t s = 0; s < sweeps; ++s) {
            ++*it;
            err = err_all = estimate[s];
            if (!isfinite(err) || err > FAST_DIVERGENCE * (initial > threshold ? initial : threshold))
                return spia__fail(status, SPIA_ERROR_DIVERGED, -1,
                                  "the iteration diverged after %d iterations (max error %g of the diagonal)", (int)*it,
                                  err / scale);
            if (err < best * (1.0 - 1e-3)) {
                best = err;
                it_best = *it;
            }
            recent[0] = recent[1];
            recent[1] = err;
            if (known < 2) ++known;
        }
        const int expected = err * contraction(recent, known) <= EXPECTED_MARGIN * threshold;
        const int at_tolerance = err <= threshold;
        if (at_tolerance || expected || *it - it_best >= FAST_WINDOW) {
            /* The sweeps say the tolerance is reached (or soon will be), or
             * the error has not fallen for a while: the residual in double,
             * which the history and the progress callback then give for
             * this iteration, as GS_PIA does. */
            err_all = residual_pass(f, k, 0, &mean, &err);
            out->current = 1;
        }
        if (report && report->history && *it <= report->history_capacity) {
            report->history[*it - 1] = err_all / scale;
            report->history_count = *it;
        }
        if (opt->progress && opt->progress(opt->progress_user_data, *it, err_all / scale))
            return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after %d iterations", (int)*it);
        if (!out->current) continue;
        if (err <= threshold) break;
        if (at_tolerance && ++failed_checks >= FLOAT_FLOOR_CHECKS) {
            out->float_floor = 1;
            break;
        }
        if (err < best * (1.0 - 1e-3)) {
            best = err;
            it_best = *it;
        } else if (*it - it_best >= FAST_WINDOW) {
            if (stuck_checked) {
                res = SPIA_STAGNATED;
                break;
            }
            stuck_checked = 1;
            const int32_t found = mark_stuck(f, k, threshold);
            if (found < 0) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver");
            if (found == 0) {
                res = SPIA_STAGNATED;
                break;
            }
            *stuck_count += found;
            err_all = residual_pass(f, k, 0, &mean, &err);
            best = err;
            it_best = *it;
            known = 0;
        }
    }
    out->err_all = err_all;
    out->mean = mean;
    out->err = err;
    return res;
}

typedef struct write_task {
    fast *f;
    float *cage;
} write_task;

static void write_rows(void *context, int64_t i0, int64_t i1, int thread) {
    (void)thread;
    write_task *t = (write_task *)context;
    const fast *f = t->f;
    const int32_t *order = f->p->order;
    for (int64_t i = i0; i < i1; ++i) {
        const int64_t r = order ? order[i] : i;
        if (order && i + ROWS_AHEAD < i1) PREFETCH_WRITE(t->cage + 3 * (int64_t)order[i + ROWS_AHEAD]);
        for (int a = 0; a < 3; ++a) t->cage[3 * r + a] = cage_value(f, (int32_t)i, a);
    }
}

typedef struct gather_task {
    fast *f;
    const float *targets, *start;
} gather_task;

/* Rows [i0, i1): the targets and the first iterate into the plan's order,
 * and the correction Y set to zero. */
static void gather_rows(void *context, int64_t i0, int64_t i1, int thread) {
    (void)thread;
    gather_task *t = (gather_task *)context;
    fast *f = t->f;
    const int32_t *order = f->p->order;
    const size_t row = 4 * (f->wide ? sizeof(double) : sizeof(float));
    memset((char *)f->Y + row * (size_t)i0, 0, row * (size_t)(i1 - i0));
    for (int64_t i = i0; i < i1; ++i) {
        const int64_t r = order ? order[i] : i;
        if (order && i + ROWS_AHEAD < i1) {
            PREFETCH(t->targets + 3 * (int64_t)order[i + ROWS_AHEAD]);
            if (f->S != f->P) PREFETCH(t->start + 3 * (int64_t)order[i + ROWS_AHEAD]);
        }
        for (int a = 0; a < 3; ++a) {
            f->P[3 * i + a] = t->targets[3 * r + a];
            if (f->S != f->P) f->S[3 * i + a] = t->start[3 * r + a];
        }
    }
}

/* The solver's arrays (f->p, n, wide and blocks set); 0 when out of
 * memory (fast_free frees what was allocated). */
static int fast_alloc(fast *f, const spia_options *opt, size_t lane) {
    /* P and S with a float to spare: rows are read four lanes at a time. */
    f->P = (float *)spia__alloc_large(sizeof(float) * (3 * (size_t)f->n + 1));
    f->S = opt->initial_cage ? (float *)spia__alloc_large(sizeof(float) * (3 * (size_t)f->n + 1)) : f->P;
    f->Y = spia__alloc_large(4 * (size_t)f->n * lane); /* zeroed by gather_rows, on the threads */
    f->B = spia__alloc_large(4 * (size_t)f->n * lane);
    f->flags = (unsigned char *)calloc((size_t)f->n, 1);
    f->partial = (double *)malloc(sizeof(double) * 4 * (size_t)f->blocks);
    f->block_entry = (int64_t *)malloc(sizeof(int64_t) * ((size_t)f->blocks + 1));
    if (f->wide) f->inverse = (double *)malloc(sizeof(double) * (size_t)(f->p->words > 0 ? f->p->words : 1));
    f->weight4 = (f4 *)malloc(sizeof(f4) * (size_t)(f->p->words > 0 ? f->p->words : 1));
    f->inverse4 = (f4 *)malloc(sizeof(f4) * (size_t)(f->p->words > 0 ? f->p->words : 1));
    f->signed4 = (f4 *)malloc(sizeof(f4) * (size_t)(f->p->words > 0 ? f->p->words : 1));
    return f->P && f->S && f->Y && f->B && f->flags && f->partial && f->block_entry && (!f->wide || f->inverse) &&
           f->weight4 && f->inverse4 && f->signed4;
}

static void fast_free(fast *f) {
    free(f->P);
    if (f->S != f->P) free(f->S);
    free(f->Y);
    free(f->B);
    free(f->flags);
    free(f->partial);
    free(f->block_entry);
    free(f->inverse);
    free(f->weight4);
    free(f->inverse4);
    free(f->signed4);
}

/* The plan's weights as the sweeps read them, and each block's first entry. */
static void fast_weights(fast *f) {
    if (f->wide)
        for (int32_t c = 0; c < f->p->words; ++c) f->inverse[c] = 1.0 / f->p->weight[c];
    for (int32_t c = 0; c < f->p->words; ++c) {
        f->weight4[c] = V4_SPLAT(f4, f->p->weight_f[c]);
        f->inverse4[c] = V4_SPLAT(f4, f->p->inverse_f[c]);
        f->signed4[c] = V4_SPLAT(f4, f->p->signed_f[c]);
    }
    {
        int64_t e = 0;
        for (int64_t b = 0; b < f->blocks; ++b) {
            f->block_entry[b] = e;
            const int32_t i1 = (b + 1) * FAST_BLOCK < f->n ? (int32_t)((b + 1) * FAST_BLOCK) : f->n;
            int32_t sum = 0;
            for (int32_t i = (int32_t)(b * FAST_BLOCK); i < i1; ++i) sum += f->p->length[i];
            e += sum;
        }
        f->block_entry[f->blocks] = e;
    }
}

/* The sweeps done (res >= 0, no hand-over): the cage written out, the
 * result's status and the report's errors; returns the result. */
static spia_result fast_finish(fast *f, const kernels *k, const spia_options *opt, spia_result res, int32_t it,
                               int32_t stuck_count, stage_result *sr, double scale, float *cage, spia_report *report,
                               spia_status *status) {
    const int32_t n = f->n;
    if (!sr->current) sr->err_all = residual_pass(f, k, 0, &sr->mean, &sr->err);
    write_task w = {f, cage};
    spia__parallel_for(f->threads, n, PIECE_BLOCKS * FAST_BLOCK, write_rows, &w);
    if (stuck_count > 0 && res == SPIA_OK) res = SPIA_STAGNATED;
    if (res == SPIA_OK)
        spia__ok(status);
    else if (res == SPIA_MAX_ITERATIONS)
        spia__fail(status, res, -1,
                   "stopped at max_iterations (%d) with max error %.3g of the diagonal, above the tolerance %.3g",
                   (int)it, sr->err_all / scale, opt->tolerance);
    else if (stuck_count > 0)
        spia__fail(status, res, -1,
                   "%d vertices cannot reach their targets (their limit points are tied to other vertices'), "
                   "with max error %.3g of the diagonal. The other vertices reach %.3g",
                   (int)stuck_count, sr->err_all / scale, sr->err / scale);
    else
        spia__fail(status, res, -1,
                   "the error stopped falling after %d iterations at %.3g of the diagonal, above the tolerance %.3g",
                   (int)it, sr->err_all / scale, opt->tolerance);
    if (report) {
        report->max_error = sr->err_all;
        report->mean_error = sr->mean;
        report->max_error_relative = sr->err_all / scale;
        report->mean_error_relative = sr->mean / scale;
        report->reachable_max_error_relative = sr->err / scale;
        report->unreachable_count = stuck_count;
        if (report->unreachable)
            for (int32_t i = 0; i < n; ++i)
                report->unreachable[f->p->order ? f->p->order[i] : i] = (uint8_t)((f->flags[i] & STUCK) != 0);
    }
    return res;
}

spia_result spia__solve_fast(const spia_stencils *L, const float *targets, const spia_options *opt, double diagonal,
                             int automatic, float *cage, float **handover, int32_t *handover_iterations,
                             spia_report *report, spia_status *status) {
    const int32_t n = L->rows;
    const spia_plan *p = L->plan;
    const double scale = diagonal > 0.0 ? diagonal : 1.0;
    const double threshold = opt->tolerance * scale;
    *handover = NULL;
    *handover_iterations = 0;
    if (report) report->diagonal = diagonal;
    fast f;
    memset(&f, 0, sizeof f);
    f.p = p;
    f.n = n;
    f.threads = opt->threads > 0 && n >= SPIA_PARALLEL_ROWS ? opt->threads : 1;
    f.wide = (opt->solve_flags & SPIA_SOLVE_DOUBLE_SWEEPS) != 0;
    const size_t lane = f.wide ? sizeof(double) : sizeof(float);
    f.blocks = ((int64_t)n + FAST_BLOCK - 1) / FAST_BLOCK;
    spia_result res;
    int32_t it = 0, stuck_count = 0;
    stage_result sr;
    memset(&sr, 0, sizeof sr);
    if (!fast_alloc(&f, opt, lane)) {
        res = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver (%d vertices)", (int)n);
        goto done;
    }
    fast_weights(&f);
    {
        gather_task g = {&f, targets, opt->initial_cage ? opt->initial_cage : targets};
        spia__parallel_for(f.threads, n, PIECE_BLOCKS * FAST_BLOCK, gather_rows, &g);
        f.P[3 * (size_t)n] = 0.0f;
        f.S[3 * (size_t)n] = 0.0f;
    }
    const kernels k = kernels_for(&f, (opt->solve_flags & SPIA_SOLVE_NO_AVX) != 0);
    double mean, err;
    const double err_all0 = residual_pass(&f, &k, 1, &mean, &err);
    const double stats0[3] = {err_all0, mean, err};
    if (report) {
        report->initial_max_error_relative = err_all0 / scale;
        report->method = automatic && err <= threshold ? SPIA_METHOD_PIA : SPIA_METHOD_GS_PIA_FAST;
    }
    if (!(err <= threshold) && !f.wide && threshold < FLOAT_REACH * err) {
        /* Beyond what float32 sweeps hold: GS-PIA from the start. */
        res = SPIA__HAND_OVER;
        goto done;
    }
    const int first_step = (opt->solve_flags & SPIA_SOLVE_FIRST_STEP) != 0;
    const int staged = opt->staged && L->boundary_count > 0 && L->boundary_count < n;
    if (staged) {
        for (int32_t i = 0; i < n; ++i) f.flags[i] = L->boundary[p->order ? p->order[i] : i] ? 0 : FROZEN;
        res = fast_stage(&f, &k, opt, threshold, scale, first_step, NULL, &it, &stuck_count, &sr, report, status);
        if (report) report->stage_iterations[0] = it;
        if (res == SPIA_OK && !sr.float_floor) {
            for (int32_t i = 0; i < n; ++i)
                f.flags[i] = (unsigned char)((f.flags[i] & STUCK) | (L->boundary[p->order ? p->order[i] : i] ? FROZEN : 0));
            res = fast_stage(&f, &k, opt, threshold, scale, 0, NULL, &it, &stuck_count, &sr, report, status);
            for (int32_t i = 0; i < n; ++i) f.flags[i] &= STUCK;
            sr.current = 0;
        }
        if (report) report->stage_iterations[1] = it - report->stage_iterations[0];
    } else {
        res = fast_stage(&f, &k, opt, threshold, scale, first_step, stats0, &it, &stuck_count, &sr, report, status);
    }
    if (res >= 0 && sr.float_floor) {
        /* The cage's own rounding (or the sweeps' float32) stands between it
         * and the tolerance: GS-PIA's double sweeps go on from here. */
        *handover = (float *)malloc(sizeof(float) * 3 * (size_t)n);
        if (!*handover) {
            res = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the solver (%d vertices)", (int)n);
            goto done;
        }
        write_task w = {&f, *handover};
        spia__parallel_for(f.threads, n, PIECE_BLOCKS * FAST_BLOCK, write_rows, &w);
        *handover_iterations = it;
        res = SPIA__HAND_OVER;
        goto done;
    }
    if (res >= 0) res = fast_finish(&f, &k, opt, res, it, stuck_count, &sr, scale, cage, report, status);
    if (report) report->iterations = it;
    if (res == SPIA_STAGNATED || res == SPIA_ERROR_DIVERGED) *handover_iterations = it;
done:
    fast_free(&f);
    return res;
}
