// SPDX-License-Identifier: GPL-3.0-or-later
/* A bounding volume hierarchy over triangles and the nearest-triangle query
 * (see bvh.h).
 *
 * Build: top-down, each node split where the binned surface-area heuristic
 * is cheapest (16 bins of triangle centroids on each axis), with small
 * leaves.  Ranges of more than SAMPLED_BINNING triangles bin an evenly
 * spaced sample of them (the split is chosen from the sample; the
 * partition and the children's boxes see every triangle), and ranges of
 * ONE_AXIS_RANGE or fewer bin only the axis along which their centroids
 * spread widest.  The first levels are split one node at a time; the
 * subtrees below them are then built each on one thread, side by side,
 * into their own arrays, and joined.  O(n log n).
 *
 * Query: depth first from the root, the nearer child first, any box farther
 * than the best triangle so far left out; the distances to triangles are
 * exact (double), those to the float boxes are rounded, so a box is left out
 * only when it is farther by more than any rounding could make up.  The
 * hit is then the one a search over every triangle makes. */
#include "bvh.h"

#include "internal.h"
#include "threads.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------------ */
/* The point-triangle distance                                               */
/* ------------------------------------------------------------------------ */

/* The closest point to p on segment ab, as the weight t of b. */
static double closest_on_segment(const double p[3], const double a[3], const double b[3]) {
    double ab[3], ap[3];
    for (int i = 0; i < 3; ++i) ab[i] = b[i] - a[i], ap[i] = p[i] - a[i];
    const double len2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
    if (!(len2 > 0.0)) return 0.0;
    const double t = (ab[0] * ap[0] + ab[1] * ap[1] + ab[2] * ap[2]) / len2;
    return t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
}

/* A triangle without area (two corners at one place, or in a line: an
 * unwelded or collapsed scan) is the union of its edges: the nearest point
 * of the three segments. */
static void closest_on_flat_triangle(const double p[3], const double *v[3], double bary[3]) {
    double best = INFINITY;
    for (int k = 0; k < 3; ++k) {
        const int k1 = (k + 1) % 3;
        const double t = closest_on_segment(p, v[k], v[k1]);
        double d2 = 0.0;
        for (int i = 0; i < 3; ++i) {
            const double x = (1.0 - t) * v[k][i] + t * v[k1][i] - p[i];
            d2 += x * x;
        }
        if (d2 < best) {
            best = d2;
            bary[k] = 1.0 - t, bary[k1] = t, bary[(k + 2) % 3] = 0.0;
        }
    }
}

/* The closest point to p on triangle (a, b, c), as barycentric weights
 * (u, v, w) of a, b, c; by the Voronoi regions of vertices, edges and face. */
static void closest_on_triangle(const double p[3], const double a[3], const double b[3], const double c[3],
                                double bary[3]) {
    double ab[3], ac[3], ap[3];
    for (int i = 0; i < 3; ++i) {
        ab[i] = b[i] - a[i];
        ac[i] = c[i] - a[i];
        ap[i] = p[i] - a[i];
    }
#define DOT(x, y) ((x)[0] * (y)[0] + (x)[1] * (y)[1] + (x)[2] * (y)[2])
    {
        const double n[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2],
                             ab[0] * ac[1] - ab[1] * ac[0]};
        if (!(DOT(n, n) > 1e-24 * DOT(ab, ab) * DOT(ac, ac))) {
            const double *v[3] = {a, b, c};
            closest_on_flat_triangle(p, v, bary);
            return;
        }
    }
    const double d1 = DOT(ab, ap), d2 = DOT(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        bary[0] = 1.0, bary[1] = 0.0, bary[2] = 0.0;
        return;
    }
    double bp[3], cp[3];
    for (int i = 0; i < 3; ++i) {
        bp[i] = p[i] - b[i];
        cp[i] = p[i] - c[i];
    }
    const double d3 = DOT(ab, bp), d4 = DOT(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
        bary[0] = 0.0, bary[1] = 1.0, bary[2] = 0.0;
        return;
    }
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        const double v = d1 / (d1 - d3);
        bary[0] = 1.0 - v, bary[1] = v, bary[2] = 0.0;
        return;
    }
    const double d5 = DOT(ab, cp), d6 = DOT(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) {
        bary[0] = 0.0, bary[1] = 0.0, bary[2] = 1.0;
        return;
    }
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        const double w = d2 / (d2 - d6);
        bary[0] = 1.0 - w, bary[1] = 0.0, bary[2] = w;
        return;
    }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        bary[0] = 0.0, bary[1] = 1.0 - w, bary[2] = w;
        return;
    }
    const double denom = va + vb + vc;
    const double v = vb / denom, w = vc / denom;
    bary[0] = 1.0 - v - w, bary[1] = v, bary[2] = w;
#undef DOT
}

double spia__triangle_distance2(const double p[3], const float *a, const float *b, const float *c, double bary[3],
                                double point[3]) {
    const double v[3][3] = {{a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {c[0], c[1], c[2]}};
    closest_on_triangle(p, v[0], v[1], v[2], bary);
    double d2 = 0.0;
    for (int i = 0; i < 3; ++i) {
        point[i] = bary[0] * v[0][i] + bary[1] * v[1][i] + bary[2] * v[2][i];
        d2 += (point[i] - p[i]) * (point[i] - p[i]);
    }
    return d2;
}

/* ------------------------------------------------------------------------ */
/* Four floats at once                                                       */
/* ------------------------------------------------------------------------ */

/* The builder's boxes and the query's box distances take four floats at a
 * time: SSE, NEON or plain C, all with the same results (each lane is the
 * IEEE operation on its own; min and max see no NaN). */
#if defined(__SSE2__) || defined(_M_X64) || (defined(_M_IX86_FP) && _M_IX86_FP >= 2)
#include <emmintrin.h>
typedef __m128 v4;
static inline v4 v4_load(const float *p) { return _mm_loadu_ps(p); }
static inline void v4_store(float *p, v4 a) { _mm_storeu_ps(p, a); }
static inline v4 v4_set1(float x) { return _mm_set1_ps(x); }
static inline v4 v4_add(v4 a, v4 b) { return _mm_add_ps(a, b); }
static inline v4 v4_sub(v4 a, v4 b) { return _mm_sub_ps(a, b); }
static inline v4 v4_mul(v4 a, v4 b) { return _mm_mul_ps(a, b); }
static inline v4 v4_min(v4 a, v4 b) { return _mm_min_ps(a, b); }
static inline v4 v4_max(v4 a, v4 b) { return _mm_max_ps(a, b); }
/* Lane 3 cleared. */
static inline v4 v4_xyz(v4 a) { return _mm_and_ps(a, _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1))); }
#elif defined(__ARM_NEON) || defined(__aarch64__) || defined(_M_ARM64)
#include <arm_neon.h>
typedef float32x4_t v4;
static inline v4 v4_load(const float *p) { return vld1q_f32(p); }
static inline void v4_store(float *p, v4 a) { vst1q_f32(p, a); }
static inline v4 v4_set1(float x) { return vdupq_n_f32(x); }
static inline v4 v4_add(v4 a, v4 b) { return vaddq_f32(a, b); }
static inline v4 v4_sub(v4 a, v4 b) { return vsubq_f32(a, b); }
static inline v4 v4_mul(v4 a, v4 b) { return vmulq_f32(a, b); }
static inline v4 v4_min(v4 a, v4 b) { return vminq_f32(a, b); }
static inline v4 v4_max(v4 a, v4 b) { return vmaxq_f32(a, b); }
static inline v4 v4_xyz(v4 a) { return vsetq_lane_f32(0.0f, a, 3); }
#else
typedef struct v4 {
    float x[4];
} v4;
static inline v4 v4_load(const float *p) {
    v4 r;
    for (int i = 0; i < 4; ++i) r.x[i] = p[i];
    return r;
}
static inline void v4_store(float *p, v4 a) {
    for (int i = 0; i < 4; ++i) p[i] = a.x[i];
}
static inline v4 v4_set1(float x) {
    v4 r;
    for (int i = 0; i < 4; ++i) r.x[i] = x;
    return r;
}
#define V4_LANES(name, expr)                                                                                      \
    static inline v4 name(v4 a, v4 b) {                                                                        \
        v4 r;                                                                                                    \
        for (int i = 0; i < 4; ++i) r.x[i] = (expr);                                                             \
        return r;                                                                                                \
    }
V4_LANES(v4_add, a.x[i] + b.x[i])
V4_LANES(v4_sub, a.x[i] - b.x[i])
V4_LANES(v4_mul, a.x[i] * b.x[i])
V4_LANES(v4_min, a.x[i] < b.x[i] ? a.x[i] : b.x[i])
V4_LANES(v4_max, a.x[i] > b.x[i] ? a.x[i] : b.x[i])
#undef V4_LANES
static inline v4 v4_xyz(v4 a) {
    a.x[3] = 0.0f;
    return a;
}
#endif

/* ------------------------------------------------------------------------ */
/* Build                                                                     */
/* ------------------------------------------------------------------------ */

#define BINS 16
/* Leaves hold up to LEAF_MAX triangles; ranges of LEAF_MIN or fewer are
 * leaves without asking the heuristic. */
#ifndef LEAF_MIN
#define LEAF_MIN 2
#endif
#ifndef LEAF_MAX
#define LEAF_MAX 8
#endif
/* The heuristic's cost of a triangle against that of a box test. */
#ifndef TRIANGLE_COST
#define TRIANGLE_COST 2.0f
#endif
/* Beyond this depth ranges are halved instead (see SPIA__BVH_MAX_DEPTH). */
#define MEDIAN_DEPTH 64
#define MAX_PIECES 64
/* Ranges of more triangles than this bin a sample of between half and all
 * of this many.  On a dragon scan of 7.3M triangles the levels above the
 * subtrees took 0.30 to 0.35 s binning every triangle (on two threads)
 * and 0.13 to 0.18 s with the sample on one; the queries were as fast (the
 * top splits of a large range move little with the sample). */
#ifndef SAMPLED_BINNING
#define SAMPLED_BINNING 16384
#endif
/* Ranges of this many triangles or fewer bin only their widest axis: they
 * are most of the build's nodes, and the heuristic over three axes was
 * about a third of the build's time on scans. */
#ifndef ONE_AXIS_RANGE
#define ONE_AXIS_RANGE 64
#endif

/* A box; lane 3 of each corner is not used. */
typedef struct aabb {
    float lo[4], hi[4];
} aabb;

/* A triangle during the build: its box and its index (in lane 3 of hi,
 * cleared when loaded). */
typedef struct prim_ref {
    float lo[3], zero;
    float hi[3];
    uint32_t id;
} prim_ref;

typedef struct bins {
    aabb box[3][BINS];
    uint32_t count[3][BINS];
} bins;

/* A range of refs, its box and the box of its centroids (doubled: lo + hi),
 * and once planned how it splits: a leaf, or [begin, mid) and [mid, end). */
typedef struct range {
    uint32_t begin, end;
    int32_t depth; /* halvings from the root */
    int planned, leaf;
    uint32_t mid;
    aabb box, cbox;
    aabb half_box[2], half_cbox[2];
} range;

static const aabb empty_box = {{FLT_MAX, FLT_MAX, FLT_MAX, FLT_MAX}, {-FLT_MAX, -FLT_MAX, -FLT_MAX, -FLT_MAX}};

static inline void box_grow(aabb *b, v4 lo, v4 hi) {
    v4_store(b->lo, v4_min(v4_load(b->lo), lo));
    v4_store(b->hi, v4_max(v4_load(b->hi), hi));
}

static inline void box_merge(aabb *b, const aabb *c) { box_grow(b, v4_load(c->lo), v4_load(c->hi)); }

/* Half the surface area (0 for an empty box). */
static inline float box_area(const aabb *b) {
    const float x = b->hi[0] - b->lo[0], y = b->hi[1] - b->lo[1], z = b->hi[2] - b->lo[2];
    if (!(x >= 0.0f)) return 0.0f;
    return x * y + y * z + z * x;
}

static inline v4 ref_lo(const prim_ref *r) { return v4_load(r->lo); }
static inline v4 ref_hi(const prim_ref *r) { return v4_xyz(v4_load(r->hi)); }

/* Where centroids fall among the bins of each axis: bin
 * clamp((c - origin) * scale, 0, BINS - 1), truncated; an axis without
 * extent has scale 0. */
typedef struct binning {
    float origin[4], scale[4];
    int usable[3];
    int axis;       /* the one axis binned, or -1 for all three */
    int bins;       /* BINS, or fewer for a small range */
    float last_bin; /* bins - 1 */
} binning;

/* The bin on one axis, by the same operations as bins_fill's lanes. */
static inline int bin_of(const binning *g, const prim_ref *r, int axis) {
    float f = (r->lo[axis] + r->hi[axis] - g->origin[axis]) * g->scale[axis];
    f = f > 0.0f ? f : 0.0f;
    f = f < g->last_bin ? f : g->last_bin;
    return (int)f;
}

/* Bins the refs begin, begin + stride, ... before end: on g's one axis
 * when it has one, else on all three. */
static void bins_fill(bins *b, const binning *g, const prim_ref *refs, uint32_t begin, uint32_t end,
                      uint32_t stride) {
    for (int a = 0; a < 3; ++a)
        if (g->axis < 0 || a == g->axis)
            for (int i = 0; i < g->bins; ++i) {
                b->box[a][i] = empty_box;
                b->count[a][i] = 0;
            }
    if (g->axis >= 0) {
        const int a = g->axis;
        for (uint32_t i = begin; i < end; i += stride) {
            const int k = bin_of(g, refs + i, a);
            box_grow(&b->box[a][k], ref_lo(refs + i), ref_hi(refs + i));
            ++b->count[a][k];
        }
        return;
    }
    const v4 origin = v4_load(g->origin), scale = v4_load(g->scale), zero = v4_set1(0.0f),
             top = v4_set1(g->last_bin);
    for (uint32_t i = begin; i < end; i += stride) {
        const v4 lo = ref_lo(refs + i), hi = ref_hi(refs + i);
        float f[4];
        v4_store(f, v4_min(v4_max(v4_mul(v4_sub(v4_add(lo, hi), origin), scale), zero), top));
        for (int a = 0; a < 3; ++a) {
            const int k = (int)f[a];
            box_grow(&b->box[a][k], lo, hi);
            ++b->count[a][k];
        }
    }
}

typedef struct builder {
    const float *positions;
    const int32_t *triangles;
    prim_ref *refs;
    spia__build_progress *progress;
    spia__counter subtrees_done;
    int64_t subtree_count;
} builder;

int spia__build_poll(spia__build_progress *p, int thread, double fraction) {
    if (!p || !p->fn) return 0;
    if (spia__counter_get(&p->cancelled)) return 1;
    if (thread != 0) return 0;
    const double now = spia__now();
    if (now - p->last < p->interval) return 0;
    p->last = now;
    fraction = fraction < 0.0 ? 0.0 : (fraction > 1.0 ? 1.0 : fraction);
    if (p->fn(p->user_data, p->phase, p->from + (p->to - p->from) * fraction)) {
        spia__counter_set(&p->cancelled, 1);
        return 1;
    }
    return 0;
}

/* The share of the build's time that the subtrees take (the rest: boxes,
 * top levels, leaf order). */
#define SUBTREE_SHARE 0.8

static double subtree_fraction(builder *b) {
    return 0.1 + SUBTREE_SHARE * (double)spia__counter_get(&b->subtrees_done) /
                     (double)(b->subtree_count > 0 ? b->subtree_count : 1);
}

/* Halves the range (the fall-back where the heuristic cannot work: all
 * centroids at one place, or too deep). */
static void split_median(const builder *b, range *r) {
    r->leaf = 0;
    r->mid = r->begin + (r->end - r->begin) / 2;
    for (int side = 0; side < 2; ++side) {
        r->half_box[side] = r->half_cbox[side] = empty_box;
        const uint32_t from = side ? r->mid : r->begin, to = side ? r->end : r->mid;
        for (uint32_t i = from; i < to; ++i) {
            const v4 lo = ref_lo(b->refs + i), hi = ref_hi(b->refs + i), c = v4_add(lo, hi);
            box_grow(&r->half_box[side], lo, hi);
            box_grow(&r->half_cbox[side], c, c);
        }
    }
}

/* Decides whether r is a leaf, and if not splits it where the heuristic is
 * cheapest, moving its refs into the two halves. */
static void plan(const builder *b, range *r) {
    const uint32_t n = r->end - r->begin;
    r->planned = 1;
    r->leaf = 1;
    if (n <= LEAF_MIN) return;
    if (r->depth >= MEDIAN_DEPTH) {
        if (n > LEAF_MAX) split_median(b, r);
        return;
    }
    binning g;
    int any = 0;
    g.origin[3] = g.scale[3] = 0.0f;
    g.bins = n < BINS ? (int)n : BINS; /* a bin a triangle is enough for a small range */
    g.last_bin = (float)(g.bins - 1);
    int widest = 0;
    for (int a = 1; a < 3; ++a)
        if (r->cbox.hi[a] - r->cbox.lo[a] > r->cbox.hi[widest] - r->cbox.lo[widest]) widest = a;
    g.axis = n <= ONE_AXIS_RANGE ? widest : -1;
    for (int a = 0; a < 3; ++a) {
        const float extent = r->cbox.hi[a] - r->cbox.lo[a];
        g.origin[a] = r->cbox.lo[a];
        g.usable[a] = extent > 0.0f && (float)g.bins / extent < FLT_MAX && (g.axis < 0 || a == g.axis);
        g.scale[a] = g.usable[a] ? (float)g.bins * (1.0f - 1e-6f) / extent : 0.0f;
        any |= g.usable[a];
    }
    if (!any) {
        if (n > LEAF_MAX) split_median(b, r);
        return;
    }
    bins all;
    if (n > SAMPLED_BINNING) {
        bins_fill(&all, &g, b->refs, r->begin, r->end, n / (SAMPLED_BINNING / 2));
    } else {
        bins_fill(&all, &g, b->refs, r->begin, r->end, 1);
    }
    /* The cheapest split: the bins left of bin i | bin i and those right. */
    float best = INFINITY;
    int best_axis = -1, best_bin = 0;
    for (int a = 0; a < 3; ++a) {
        if (!g.usable[a]) continue;
        float right_cost[BINS];
        aabb acc = empty_box;
        uint32_t count = 0;
        for (int i = g.bins - 1; i > 0; --i) {
            box_merge(&acc, &all.box[a][i]);
            count += all.count[a][i];
            right_cost[i] = count ? box_area(&acc) * (float)count : -1.0f;
        }
        acc = empty_box;
        count = 0;
        for (int i = 1; i < g.bins; ++i) {
            box_merge(&acc, &all.box[a][i - 1]);
            count += all.count[a][i - 1];
            if (count == 0 || right_cost[i] < 0.0f) continue;
            const float cost = box_area(&acc) * (float)count + right_cost[i];
            if (cost < best) best = cost, best_axis = a, best_bin = i;
        }
    }
    if (best_axis < 0) { /* cannot happen with an axis of extent; be safe */
        if (n > LEAF_MAX) split_median(b, r);
        return;
    }
    const float area = box_area(&r->box);
    if (n <= LEAF_MAX && TRIANGLE_COST * (float)n * area <= area + TRIANGLE_COST * best) return;
    /* Partition: refs whose centroid is in a bin left of best_bin first. */
    r->leaf = 0;
    v4 box_lo[2], box_hi[2], c_lo[2], c_hi[2];
    for (int side = 0; side < 2; ++side) {
        box_lo[side] = c_lo[side] = v4_load(empty_box.lo);
        box_hi[side] = c_hi[side] = v4_load(empty_box.hi);
    }
    prim_ref *refs = b->refs;
    uint32_t i = r->begin, j = r->end;
    while (i < j) {
        const v4 lo = ref_lo(refs + i), hi = ref_hi(refs + i), c = v4_add(lo, hi);
        if (bin_of(&g, refs + i, best_axis) < best_bin) {
            box_lo[0] = v4_min(box_lo[0], lo), box_hi[0] = v4_max(box_hi[0], hi);
            c_lo[0] = v4_min(c_lo[0], c), c_hi[0] = v4_max(c_hi[0], c);
            ++i;
        } else {
            --j;
            const prim_ref x = refs[i];
            refs[i] = refs[j];
            refs[j] = x;
            box_lo[1] = v4_min(box_lo[1], lo), box_hi[1] = v4_max(box_hi[1], hi);
            c_lo[1] = v4_min(c_lo[1], c), c_hi[1] = v4_max(c_hi[1], c);
        }
    }
    for (int side = 0; side < 2; ++side) {
        v4_store(r->half_box[side].lo, box_lo[side]), v4_store(r->half_box[side].hi, box_hi[side]);
        v4_store(r->half_cbox[side].lo, c_lo[side]), v4_store(r->half_cbox[side].hi, c_hi[side]);
    }
    r->mid = i;
    /* Both sides have the counts of their bins, so neither is empty; should
     * a compiler round the partition's centroids otherwise than the
     * binning's (excess precision), halve instead. */
    if (r->mid == r->begin || r->mid == r->end) split_median(b, r);
}

static range range_half(const range *r, int side) {
    range h;
    h.planned = h.leaf = 0;
    h.mid = 0;
    h.begin = side ? r->mid : r->begin;
    h.end = side ? r->end : r->mid;
    h.depth = r->depth + 1;
    h.box = r->half_box[side];
    h.cbox = r->half_cbox[side];
    return h;
}

/* The children of a node over range r (planned): r's halves, then the
 * halves of the child of largest area that is not a leaf, and so on up to
 * four.  Every child comes out planned. */
static int node_children(const builder *b, const range *r, range child[4]) {
    int n = 1;
    child[0] = *r;
    for (;;) {
        int at = -1;
        float largest = -1.0f;
        for (int i = 0; i < n; ++i) {
            if (child[i].planned && child[i].leaf) continue;
            const float a = box_area(&child[i].box);
            if (a > largest) largest = a, at = i;
        }
        if (at < 0) break;
        if (!child[at].planned) {
            plan(b, &child[at]);
            continue;
        }
        if (n == 4) break;
        const range split = child[at];
        child[at] = range_half(&split, 0);
        child[n++] = range_half(&split, 1);
    }
    for (int i = 0; i < n; ++i)
        if (!child[i].planned) plan(b, &child[i]);
    return n;
}

/* A growable array of nodes. */
typedef struct node_vec {
    spia__bvh_node *v;
    uint32_t n, cap;
} node_vec;

static int node_vec_push(node_vec *a, uint32_t *index) {
    if (a->n + 1 > a->cap) {
        const uint64_t want = a->cap ? 2 * (uint64_t)a->cap : 16;
        if (want > UINT32_MAX) return 0;
        spia__bvh_node *v = realloc(a->v, sizeof(spia__bvh_node) * (size_t)want);
        if (!v) return 0;
        a->v = v;
        a->cap = (uint32_t)want;
    }
    *index = a->n++;
    return 1;
}

/* A node to make: its range (planned, a split unless it is the root) and
 * where it goes. */
typedef struct task {
    range r;
    uint32_t slot;
    int32_t level; /* of nodes below the root */
} task;

/* Writes the node of task t (into->v[t->slot], or *root when not NULL) from
 * its children; those that are nodes get slots in `into` and become tasks
 * (at most 4, into `out`).  0 when out of memory. */
static int make_node(const builder *b, const task *t, node_vec *into, spia__bvh_node *root, task *out,
                     int *out_count) {
    range child[4];
    const int n = t->r.leaf ? 1 : node_children(b, &t->r, child);
    if (t->r.leaf) child[0] = t->r;
    uint32_t slot[4];
    for (int i = 0; i < n; ++i)
        if (!child[i].leaf && !node_vec_push(into, &slot[i])) return 0;
    /* Only now (the array may have moved) the node itself. */
    spia__bvh_node *node = root ? root : into->v + t->slot;
    memset(node, 0, sizeof *node);
    node->children = (uint32_t)n;
    for (int i = 0; i < 4; ++i) {
        const aabb *box = i < n ? &child[i].box : &empty_box;
        for (int k = 0; k < 3; ++k) node->lo[k][i] = box->lo[k], node->hi[k][i] = box->hi[k];
    }
    *out_count = 0;
    for (int i = 0; i < n; ++i) {
        if (child[i].leaf) {
            node->child[i] = child[i].begin;
            node->count[i] = (uint8_t)(child[i].end - child[i].begin);
        } else {
            node->child[i] = slot[i];
            node->count[i] = 0;
            task *c = &out[(*out_count)++];
            c->r = child[i];
            c->slot = slot[i];
            c->level = t->level + 1;
        }
    }
    return 1;
}

/* A subtree built on one thread: its root goes to *root, the rest into
 * nodes (the indices in them local to it until joined). */
typedef struct subtree {
    task root_task;
    spia__bvh_node *root;
    node_vec nodes;
    int32_t level;
    int failed; /* 1: out of memory; 2: cancelled */
} subtree;

#define BUILD_STACK (3 * SPIA__BVH_MAX_DEPTH + 4)

static void build_subtree(builder *b, subtree *st, int thread) {
    task *stack = malloc(sizeof(task) * BUILD_STACK);
    if (!stack) {
        st->failed = 1;
        return;
    }
    int top = 0;
    stack[top++] = st->root_task;
    st->level = st->root_task.level;
    int root = 1;
    uint32_t made = 0;
    while (top > 0) {
        if ((++made & 1023) == 0 && spia__build_poll(b->progress, thread, subtree_fraction(b))) {
            st->failed = 2;
            break;
        }
        const task t = stack[--top];
        task children[4];
        int count;
        if (!make_node(b, &t, &st->nodes, root ? st->root : NULL, children, &count)) {
            st->failed = 1;
            break;
        }
        root = 0;
        if (t.level > st->level) st->level = t.level;
        for (int i = count - 1; i >= 0; --i) stack[top++] = children[i];
    }
    free(stack);
}

typedef struct subtree_job {
    builder *b;
    subtree *subtrees;
} subtree_job;

static void subtree_range(void *context, int64_t begin, int64_t end, int thread) {
    const subtree_job *j = (const subtree_job *)context;
    for (int64_t i = begin; i < end; ++i) {
        if (spia__build_poll(j->b->progress, thread, subtree_fraction(j->b))) {
            j->subtrees[i].failed = 2;
            continue;
        }
        build_subtree(j->b, &j->subtrees[i], thread);
        spia__counter_add(&j->b->subtrees_done, 1);
    }
}

typedef struct refs_job {
    const builder *b;
    int64_t grain;
    aabb *box, *cbox; /* per piece */
} refs_job;

static void refs_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const refs_job *j = (const refs_job *)context;
    aabb box = empty_box, cbox = empty_box;
    for (int64_t t = begin; t < end; ++t) {
        prim_ref *r = j->b->refs + t;
        const int32_t *tri = j->b->triangles + 3 * t;
        const float *v0 = j->b->positions + 3 * (int64_t)tri[0], *v1 = j->b->positions + 3 * (int64_t)tri[1],
                    *v2 = j->b->positions + 3 * (int64_t)tri[2];
        for (int k = 0; k < 3; ++k) {
            const float lo = v0[k] < v1[k] ? v0[k] : v1[k], hi = v0[k] > v1[k] ? v0[k] : v1[k];
            r->lo[k] = v2[k] < lo ? v2[k] : lo;
            r->hi[k] = v2[k] > hi ? v2[k] : hi;
        }
        r->zero = 0.0f;
        r->id = (uint32_t)t;
        const v4 lo = ref_lo(r), hi = ref_hi(r), c = v4_add(lo, hi);
        box_grow(&box, lo, hi);
        box_grow(&cbox, c, c);
    }
    j->box[begin / j->grain] = box;
    j->cbox[begin / j->grain] = cbox;
}

/* The join: each subtree's nodes copied to their place in the one array,
 * with the indices of their inner children (and of the subtree root's,
 * among the top nodes) moved by that place. */
typedef struct join_job {
    const builder *b;
    const subtree *subtrees;
    const uint32_t *base; /* each subtree's first node in the array */
    spia__bvh_node *nodes;
    const spia__bvh_node *top;
    int64_t count;
} join_job;

static void join_range(void *context, int64_t begin, int64_t end, int thread) {
    const join_job *j = (const join_job *)context;
    for (int64_t i = begin; i < end; ++i) {
        if (spia__build_poll(j->b->progress, thread, 0.1 + SUBTREE_SHARE + 0.03 * (double)i / (double)j->count))
            return; /* cancelled: the poll after the join reports it */
        const subtree *st = &j->subtrees[i];
        const uint32_t base = j->base[i];
        spia__bvh_node *dst = j->nodes + base;
        if (st->nodes.n) memcpy(dst, st->nodes.v, sizeof(spia__bvh_node) * st->nodes.n);
        for (uint32_t k = 0; k <= st->nodes.n; ++k) {
            spia__bvh_node *node = k < st->nodes.n ? dst + k : j->nodes + (st->root - j->top);
            for (uint32_t c = 0; c < node->children; ++c)
                if (node->count[c] == 0) node->child[c] += base;
        }
    }
}

typedef struct order_job {
    const prim_ref *refs;
    uint32_t *order;
    const int32_t *from;
    int32_t *to;
} order_job;

static void order_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const order_job *j = (const order_job *)context;
    for (int64_t i = begin; i < end; ++i) j->order[i] = j->refs[i].id;
}

static void permute_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const order_job *j = (const order_job *)context;
    for (int64_t i = begin; i < end; ++i)
        for (int k = 0; k < 3; ++k) j->to[3 * i + k] = j->from[3 * (int64_t)j->order[i] + k];
}

void spia__bvh_free(spia__bvh *bvh) {
    if (!bvh) return;
    free(bvh->node_memory);
    free(bvh->order);
    memset(bvh, 0, sizeof *bvh);
}

/* The boxes of node `index`'s children from its triangles and its child
 * nodes' boxes, and its own box (their union) into lo, hi. */
static void refit_node(spia__bvh *bvh, uint32_t index, float lo[3], float hi[3]) {
    spia__bvh_node *node = bvh->nodes + index;
    for (int k = 0; k < 3; ++k) lo[k] = FLT_MAX, hi[k] = -FLT_MAX;
    for (uint32_t i = 0; i < node->children; ++i) {
        float clo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, chi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
        if (node->count[i] == 0) {
            refit_node(bvh, node->child[i], clo, chi);
        } else {
            for (uint32_t t = node->child[i]; t < node->child[i] + node->count[i]; ++t)
                for (int c = 0; c < 3; ++c) {
                    const float *v = bvh->positions + 3 * (int64_t)bvh->triangles[3 * (int64_t)t + c];
                    for (int k = 0; k < 3; ++k) {
                        clo[k] = v[k] < clo[k] ? v[k] : clo[k];
                        chi[k] = v[k] > chi[k] ? v[k] : chi[k];
                    }
                }
        }
        for (int k = 0; k < 3; ++k) {
            node->lo[k][i] = clo[k], node->hi[k][i] = chi[k];
            lo[k] = clo[k] < lo[k] ? clo[k] : lo[k];
            hi[k] = chi[k] > hi[k] ? chi[k] : hi[k];
        }
    }
}

void spia__bvh_refit(spia__bvh *bvh) {
    if (!bvh || bvh->node_count < 1) return;
    float lo[3], hi[3];
    refit_node(bvh, 0, lo, hi);
    double extent = 0.0;
    for (int k = 0; k < 3; ++k) {
        extent = fabs(lo[k]) > extent ? fabs(lo[k]) : extent;
        extent = fabs(hi[k]) > extent ? fabs(hi[k]) : extent;
    }
    bvh->extent = extent;
}

size_t spia__bvh_bytes(const spia__bvh *bvh) {
    return sizeof(spia__bvh_node) * (size_t)bvh->node_count + sizeof(uint32_t) * (size_t)bvh->triangle_count;
}

static spia_result out_of_memory(spia_status *status, int64_t triangle_count) {
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1,
                      "out of memory for the bounding volume hierarchy of %lld triangles",
                      (long long)triangle_count);
}

/* Open tasks of the top levels, at most this many. */
#define MAX_TOP_TASKS 256

static uint32_t task_size(const subtree *s) { return s->root_task.r.end - s->root_task.r.begin; }

static spia_result cancelled(spia_status *status) {
    return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled while building the scan's hierarchy");
}

spia_result spia__bvh_build(spia__bvh *bvh, const float *positions, int32_t *triangles, int64_t triangle_count,
                            int threads, spia_status *status) {
    return spia__bvh_build_progress(bvh, positions, triangles, triangle_count, threads, NULL, status);
}

spia_result spia__bvh_build_progress(spia__bvh *bvh, const float *positions, int32_t *triangles,
                                     int64_t triangle_count, int threads, spia__build_progress *progress,
                                     spia_status *status) {
    return spia__bvh_build_keep(bvh, positions, triangles, triangle_count, threads, progress, NULL, NULL, status);
}

/* What the stages of a build share. */
typedef struct build_run {
    builder b;
    spia__bvh *bvh;
    int threads;
    uint32_t n;
    int64_t triangle_count;
    node_vec top;       /* the top levels' nodes */
    subtree *subtrees;  /* MAX_TOP_TASKS */
    int open;           /* subtrees in use */
    spia_status *status;
} build_run;

/* The triangles' boxes, and the root's, planned as the first subtree's
 * task; bvh->extent the largest coordinate. */
static void root_task(build_run *u, aabb *piece_box, uint32_t root_slot) {
    const uint32_t n = u->n;
    int64_t pieces = u->threads > 1 ? 4 * (int64_t)u->threads : 1;
    if (pieces > MAX_PIECES) pieces = MAX_PIECES;
    const int64_t grain = ((int64_t)n + pieces - 1) / pieces;
    pieces = ((int64_t)n + grain - 1) / grain;
    refs_job job = {&u->b, grain, piece_box, piece_box + MAX_PIECES};
    spia__parallel_for(u->threads, n, grain, refs_range, &job);
    range all;
    memset(&all, 0, sizeof all);
    all.end = n;
    all.box = all.cbox = empty_box;
    for (int64_t p = 0; p < pieces; ++p) {
        box_merge(&all.box, &piece_box[p]);
        box_merge(&all.cbox, &piece_box[MAX_PIECES + p]);
    }
    double extent = 0.0;
    for (int k = 0; k < 3; ++k) {
        extent = fabs(all.box.lo[k]) > extent ? fabs(all.box.lo[k]) : extent;
        extent = fabs(all.box.hi[k]) > extent ? fabs(all.box.hi[k]) : extent;
    }
    u->bvh->extent = extent;
    plan(&u->b, &all);
    u->subtrees[0].root_task.r = all;
    u->subtrees[0].root_task.slot = root_slot;
    u->subtrees[0].root_task.level = 0;
}

/* The top levels: make the node of the largest open task until there are
 * enough for the threads to share. */
static spia_result top_levels(build_run *u) {
    subtree *subtrees = u->subtrees;
    const uint32_t n = u->n;
    const int threads = u->threads;
    const uint32_t small = n / (8 * (uint32_t)threads) > 4096 ? n / (8 * (uint32_t)threads) : 4096;
    while (u->open + 3 <= MAX_TOP_TASKS) {
        if (spia__build_poll(u->b.progress, 0, 0.1 * (double)u->open / MAX_TOP_TASKS)) return cancelled(u->status);
        int largest = 0;
        for (int i = 1; i < u->open; ++i)
            if (task_size(&subtrees[i]) > task_size(&subtrees[largest])) largest = i;
        if (task_size(&subtrees[largest]) <= small || subtrees[largest].root_task.r.leaf) break;
        const task t = subtrees[largest].root_task;
        task children[4];
        int count;
        if (!make_node(&u->b, &t, &u->top, NULL, children, &count)) return out_of_memory(u->status, u->triangle_count);
        /* The largest's place goes to its last child, or to the last
         * open task when all its children were leaves. */
        if (count > 0) {
            subtrees[largest].root_task = children[count - 1];
            for (int i = 0; i + 1 < count; ++i) subtrees[u->open++].root_task = children[i];
        } else {
            subtrees[largest] = subtrees[--u->open];
            if (u->open == 0) break;
        }
    }
    return SPIA_OK;
}

/* The subtrees, largest first, each on one thread; *total receives the
 * nodes of the whole hierarchy and *level its depth. */
static spia_result build_subtrees(build_run *u, uint64_t *total, int32_t *level) {
    subtree *subtrees = u->subtrees;
    const int open = u->open;
    for (int i = 1; i < open; ++i)
        for (int j = i; j > 0 && task_size(&subtrees[j]) > task_size(&subtrees[j - 1]); --j) {
            const subtree x = subtrees[j];
            subtrees[j] = subtrees[j - 1];
            subtrees[j - 1] = x;
        }
    for (int i = 0; i < open; ++i) subtrees[i].root = u->top.v + subtrees[i].root_task.slot;
    u->b.subtree_count = open;
    {
        subtree_job job = {&u->b, subtrees};
        spia__parallel_for(u->threads, open, 1, subtree_range, &job);
    }
    for (int i = 0; i < open; ++i)
        if (subtrees[i].failed == 2) return cancelled(u->status);
    *total = u->top.n;
    *level = 0;
    for (int i = 0; i < open; ++i) {
        if (subtrees[i].failed) return out_of_memory(u->status, u->triangle_count);
        *total += subtrees[i].nodes.n;
        *level = subtrees[i].level > *level ? subtrees[i].level : *level;
    }
    return SPIA_OK;
}

/* Join: the top nodes, then each subtree's with its indices moved. */
static spia_result join_nodes(build_run *u, uint64_t total, int32_t level) {
    spia__bvh *bvh = u->bvh;
    bvh->node_memory = malloc(sizeof(spia__bvh_node) * (size_t)total + 64);
    if (!bvh->node_memory) return out_of_memory(u->status, u->triangle_count);
    bvh->nodes = (spia__bvh_node *)(((uintptr_t)bvh->node_memory + 63) & ~(uintptr_t)63);
    memcpy(bvh->nodes, u->top.v, sizeof(spia__bvh_node) * u->top.n);
    {
        uint32_t base[MAX_TOP_TASKS];
        base[0] = u->top.n;
        for (int i = 1; i < u->open; ++i) base[i] = base[i - 1] + u->subtrees[i - 1].nodes.n;
        join_job job = {&u->b, u->subtrees, base, bvh->nodes, u->top.v, u->open};
        spia__parallel_for(u->threads, u->open, 1, join_range, &job);
    }
    bvh->node_count = (int64_t)total;
    bvh->depth = level;
    return SPIA_OK;
}

/* Leaf order: the triangles sorted as the refs, through the refs' memory
 * (28 bytes a triangle, more than the 12 needed). */
static spia_result leaf_order(build_run *u, uint32_t *order, int32_t *triangles) {
    order_job job = {u->b.refs, order, triangles, NULL};
    spia__parallel_for(u->threads, u->n, 65536, order_range, &job);
    if (spia__build_poll(u->b.progress, 0, 0.1 + SUBTREE_SHARE + 0.05)) return cancelled(u->status);
    int32_t *copy = (int32_t *)(void *)u->b.refs;
    memcpy(copy, triangles, sizeof(int32_t) * 3 * (size_t)u->n);
    job.from = copy;
    job.to = triangles;
    spia__parallel_for(u->threads, u->n, 65536, permute_range, &job);
    return SPIA_OK;
}

spia_result spia__bvh_build_keep(spia__bvh *bvh, const float *positions, int32_t *triangles, int64_t triangle_count,
                                 int threads, spia__build_progress *progress, void **scratch, size_t *scratch_bytes,
                                 spia_status *status) {
    if (scratch) *scratch = NULL;
    if (scratch_bytes) *scratch_bytes = 0;
    memset(bvh, 0, sizeof *bvh);
    if (triangle_count < 1 || triangle_count > (int64_t)(UINT32_MAX / 3))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "cannot build a hierarchy of %lld triangles",
                          (long long)triangle_count);
    if (threads < 1) threads = 1;
    const uint32_t n = (uint32_t)triangle_count;
    build_run u;
    memset(&u, 0, sizeof u);
    u.bvh = bvh;
    u.threads = threads;
    u.n = n;
    u.triangle_count = triangle_count;
    u.status = status;
    builder *b = &u.b;
    b->positions = positions;
    b->triangles = triangles;
    b->refs = malloc(sizeof(prim_ref) * (size_t)n);
    b->progress = progress;
    spia__counter_set(&b->subtrees_done, 0);
    b->subtree_count = 1;
    aabb *piece_box = malloc(sizeof(aabb) * 2 * MAX_PIECES);
    u.subtrees = calloc(MAX_TOP_TASKS, sizeof(subtree));
    uint32_t *order = malloc(sizeof(uint32_t) * (size_t)n);
    uint32_t root_slot = 0;
    spia_result result = SPIA_OK;
    uint64_t total = 0;
    int32_t level = 0;
    if (!b->refs || !piece_box || !u.subtrees || !order || !node_vec_push(&u.top, &root_slot)) {
        result = out_of_memory(status, triangle_count);
        goto done;
    }
    root_task(&u, piece_box, root_slot);
    u.open = 1;
    if (threads > 1 && (result = top_levels(&u)) != SPIA_OK) goto done;
    if ((result = build_subtrees(&u, &total, &level)) != SPIA_OK) goto done;
    /* The join and the leaf order take a few tenths of a second on scans
     * of millions of triangles, the join up to 0.8 s in a process whose
     * fresh pages come slowly (Blender's, on a scan of 7.3M triangles): a
     * poll before and after each, and the join spread over the threads,
     * polling between subtrees. */
    if (spia__build_poll(progress, 0, 0.1 + SUBTREE_SHARE)) {
        result = cancelled(status);
        goto done;
    }
    if ((result = join_nodes(&u, total, level)) != SPIA_OK) goto done;
    if (spia__build_poll(progress, 0, 0.1 + SUBTREE_SHARE + 0.03)) {
        result = cancelled(status);
        goto done;
    }
    if ((result = leaf_order(&u, order, triangles)) != SPIA_OK) goto done;
    bvh->order = order;
    order = NULL;
    bvh->positions = positions;
    bvh->triangles = triangles;
    bvh->triangle_count = triangle_count;

done:
    for (int i = 0; i < MAX_TOP_TASKS && u.subtrees; ++i) free(u.subtrees[i].nodes.v);
    free(u.subtrees);
    free(u.top.v);
    free(order);
    free(piece_box);
    if (result == SPIA_OK && scratch && scratch_bytes) {
        *scratch = b->refs;
        *scratch_bytes = sizeof(prim_ref) * (size_t)n;
    } else {
        free(b->refs);
    }
    if (result != SPIA_OK) spia__bvh_free(bvh);
    return result;
}

/* ------------------------------------------------------------------------ */
/* Query                                                                     */
/* ------------------------------------------------------------------------ */

#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(p) __builtin_prefetch(p)
#else
#define PREFETCH(p) ((void)0)
#endif

/* The squared box distance (as the query rounds it, in float) beyond which
 * no triangle in the box can be within best_d2: the float query point and
 * the float arithmetic are off by a few units in the last place of the
 * largest coordinate (margin, 2^-20 of it) and of the distance; 2^-20 is
 * 16 of float's units.  Never below FLT_MIN, where float squares vanish. */
static inline float prune_bound(double best_d2, double margin) {
    if (!(best_d2 < INFINITY)) return INFINITY;
    const double r = sqrt(best_d2) * (1.0 + 0x1p-20) + margin;
    const float bound = (float)(r * r);
    return bound > FLT_MIN ? bound : FLT_MIN;
}

/* Squared distances from (x, y, z) to a node's four boxes, in float. */
static inline void box_distances(const spia__bvh_node *node, v4 x, v4 y, v4 z, float d[4]) {
    const v4 zero = v4_set1(0.0f);
    v4 dx = v4_max(v4_sub(v4_load(node->lo[0]), x), v4_sub(x, v4_load(node->hi[0])));
    v4 dy = v4_max(v4_sub(v4_load(node->lo[1]), y), v4_sub(y, v4_load(node->hi[1])));
    v4 dz = v4_max(v4_sub(v4_load(node->lo[2]), z), v4_sub(z, v4_load(node->hi[2])));
    dx = v4_max(dx, zero);
    dy = v4_max(dy, zero);
    dz = v4_max(dz, zero);
    v4_store(d, v4_add(v4_add(v4_mul(dx, dx), v4_mul(dy, dy)), v4_mul(dz, dz)));
}

typedef struct stack_entry {
    uint32_t child, count; /* a node (count 0) or a leaf */
    float d2;
} stack_entry;

typedef struct query {
    const spia__bvh *bvh;
    const double *p;
    double margin;
    double best_d2;
    uint32_t best_order;
    int64_t best;
    float bound;
    spia__bvh_hit *hit;
} query;

static void test_leaf(query *q, uint32_t first, uint32_t count) {
    const float *pos = q->bvh->positions;
    const int32_t *tris = q->bvh->triangles;
    const uint32_t *order = q->bvh->order;
    for (uint32_t i = first, end = first + count; i < end; ++i) {
        const int32_t *t = tris + 3 * (int64_t)i;
        double bary[3], point[3];
        const double d2 = spia__triangle_distance2(q->p, pos + 3 * (int64_t)t[0], pos + 3 * (int64_t)t[1],
                                                   pos + 3 * (int64_t)t[2], bary, point);
        if (d2 < q->best_d2 || (d2 == q->best_d2 && order[i] < q->best_order)) {
            q->best_d2 = d2;
            q->best_order = order[i];
            q->best = i;
            memcpy(q->hit->bary, bary, sizeof bary);
            memcpy(q->hit->point, point, sizeof point);
            q->bound = prune_bound(d2, q->margin);
        }
    }
}

/* One search; best_d2 bounds it (the hint squared, or INFINITY), and
 * triangle `start` (when not negative) is its first candidate. */
static void search(const spia__bvh *bvh, const double p[3], double best_d2, int64_t start, spia__bvh_hit *hit) {
    const spia__bvh_node *nodes = bvh->nodes;
    const v4 x = v4_set1((float)p[0]), y = v4_set1((float)p[1]), z = v4_set1((float)p[2]);
    double extent = bvh->extent;
    for (int k = 0; k < 3; ++k) extent = fabs(p[k]) > extent ? fabs(p[k]) : extent;
    query q;
    q.bvh = bvh;
    q.p = p;
    q.margin = extent * 0x1p-20;
    q.best_d2 = best_d2;
    q.best_order = UINT32_MAX;
    q.best = -1;
    q.bound = prune_bound(best_d2, q.margin);
    q.hit = hit;
    if (start >= 0) test_leaf(&q, (uint32_t)start, 1);
    stack_entry stack[3 * SPIA__BVH_MAX_DEPTH + 4];
    int top = 0;
    uint32_t at = 0;
    for (;;) {
        const spia__bvh_node *node = nodes + at;
        float d[4];
        box_distances(node, x, y, z, d);
        /* The children within the bound, nearest first. */
        int hits[4], k = 0;
        for (int i = 0; i < (int)node->children; ++i) {
            if (!(d[i] <= q.bound)) continue;
            int j = k++;
            for (; j > 0 && d[hits[j - 1]] > d[i]; --j) hits[j] = hits[j - 1];
            hits[j] = i;
            if (node->count[i] == 0) {
                PREFETCH(nodes + node->child[i]);
                PREFETCH((const char *)(nodes + node->child[i]) + 64);
            } else {
                PREFETCH(bvh->triangles + 3 * (int64_t)node->child[i]);
            }
        }
        for (int j = k - 1; j > 0; --j) {
            stack[top].child = node->child[hits[j]];
            stack[top].count = node->count[hits[j]];
            stack[top].d2 = d[hits[j]];
            ++top;
        }
        if (k > 0) {
            if (node->count[hits[0]] == 0) {
                at = node->child[hits[0]];
                continue;
            }
            test_leaf(&q, node->child[hits[0]], node->count[hits[0]]);
        }
        /* The next on the stack still within the bound. */
        for (;;) {
            if (top == 0) goto done;
            const stack_entry e = stack[--top];
            if (!(e.d2 <= q.bound)) continue;
            if (e.count == 0) {
                at = e.child;
                break;
            }
            test_leaf(&q, e.child, e.count);
        }
    }
done:
    hit->triangle = q.best;
    hit->d2 = q.best_d2;
}

void spia__bvh_closest(const spia__bvh *bvh, const double p[3], double radius, spia__bvh_hit *hit) {
    hit->triangle = -1;
    if (radius >= 0.0 && radius < INFINITY) {
        search(bvh, p, radius * radius, -1, hit);
        if (hit->triangle >= 0) return;
    }
    search(bvh, p, INFINITY, -1, hit);
}

void spia__bvh_closest_from(const spia__bvh *bvh, const double p[3], int64_t start, spia__bvh_hit *hit) {
    hit->triangle = -1;
    search(bvh, p, INFINITY, start >= 0 && start < bvh->triangle_count ? start : -1, hit);
}
