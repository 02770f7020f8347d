// SPDX-License-Identifier: GPL-3.0-or-later
/* The fit's fold guard and fold barrier: each sample's limit normal from
 * its grid against the scan's normal, the orientation, the folded samples,
 * the stiffening of their faces' vertices, and the barrier's pairs (its
 * constants in fit.h). */
#include "fit.h"
#include "threads.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The neighbours of sample l (of k x k in rows) along u and v, a[m] minus
 * b[m] (central, one-sided at the grid's edges), and the differences D[m]
 * of their positions in X from the block at `base`. */
void spia__fit_grid_differences(const double *X, int64_t base, int32_t l, int32_t k, int32_t a[2], int32_t b[2],
                                double D[2][3]) {
    const int32_t i = l % k, j = l / k;
    a[0] = j * k + (i < k - 1 ? i + 1 : i), b[0] = j * k + (i > 0 ? i - 1 : i);
    a[1] = (j < k - 1 ? j + 1 : j) * k + i, b[1] = (j > 0 ? j - 1 : j) * k + i;
    for (int m = 0; m < 2; ++m)
        for (int c = 0; c < 3; ++c) D[m][c] = X[3 * (base + a[m]) + c] - X[3 * (base + b[m]) + c];
}

/* Sample s's grid normal: the cross product of its neighbours' differences
 * along u and v (grid_differences), not normalised. */
static void differences_normal(const double D[2][3], double n[3]) {
    const double *du = D[0], *dv = D[1];
    n[0] = du[1] * dv[2] - du[2] * dv[1], n[1] = du[2] * dv[0] - du[0] * dv[2], n[2] = du[0] * dv[1] - du[1] * dv[0];
}

static void grid_normal(const double *X, int64_t s, int32_t k, double n[3]) {
    const int64_t per_face = (int64_t)k * k;
    int32_t a[2], b[2];
    double D[2][3];
    spia__fit_grid_differences(X, s - s % per_face, (int32_t)(s % per_face), k, a, b, D);
    differences_normal((const double(*)[3])D, n);
}

/* spia__fit_normal_agreement's work on the samples [begin, end). */
typedef struct agreement_pass {
    const double *X;
    const float *N;
    int32_t k;
    float *dots;
} agreement_pass;

static void agreement_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const agreement_pass *p = context;
    for (int64_t s = begin; s < end; ++s) {
        double n[3];
        grid_normal(p->X, s, p->k, n);
        const float *m = p->N + 3 * s;
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const double mlen = sqrt((double)m[0] * m[0] + (double)m[1] * m[1] + (double)m[2] * m[2]);
        p->dots[s] = len > 0.0 && mlen > 0.0 ? (float)((n[0] * m[0] + n[1] * m[1] + n[2] * m[2]) / (len * mlen)) : 0.0f;
    }
}

/* Per sample, the cosine between its limit normal and the scan's normal at
 * its closest point.  The normal is the cross product of the differences
 * to the neighbours along the ptex face's sample grid (grid_differences);
 * 0 where it or the scan's normal vanishes, and everywhere when the grid is
 * a single sample.  On `threads` threads, each sample on its own. */
void spia__fit_normal_agreement(const double *X, const float *N, int64_t S, int32_t k, float *dots, int threads) {
    if (k < 2) {
        memset(dots, 0, sizeof(float) * (size_t)S);
        return;
    }
    agreement_pass p = {X, N, k, dots};
    spia__parallel_for(threads, S, 65536, agreement_range, &p);
}

/* Per sample, the unit normal of the starting cage's surface where it
 * faced the scan as the cage does (sign), else zero (see facing_start), and
 * the lengths of its grid differences along u and v (the fold barrier's
 * least lengths); on `threads` threads, each sample on its own. */
typedef struct start_pass {
    const double *X;
    const float *dots;
    int32_t k;
    int sign;
    float *normals, *lengths;
} start_pass;

static void start_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const start_pass *p = context;
    const int64_t per_face = (int64_t)p->k * p->k;
    for (int64_t s = begin; s < end; ++s) {
        int32_t a[2], b[2];
        double D[2][3];
        spia__fit_grid_differences(p->X, s - s % per_face, (int32_t)(s % per_face), p->k, a, b, D);
        double n[3];
        differences_normal((const double(*)[3])D, n);
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const int keep = len > 0.0 && (double)p->sign * p->dots[s] > 0.0;
        for (int c = 0; c < 3; ++c) p->normals[3 * s + c] = keep ? (float)(n[c] / len) : 0.0f;
        for (int m = 0; m < 2; ++m)
            p->lengths[2 * s + m] = (float)sqrt(D[m][0] * D[m][0] + D[m][1] * D[m][1] + D[m][2] * D[m][2]);
    }
}

void spia__fit_start_normals(const double *X, const float *dots, int64_t S, int32_t k, int sign, float *normals,
                             float *lengths, int threads) {
    start_pass p = {X, dots, k, sign, normals, lengths};
    spia__parallel_for(threads, S, 65536, start_range, &p);
}

/* Lets go of the samples whose closest point lies on a part of the scan
 * facing against the starting cage's surface there (where that faced the
 * scan): the other side of a part thinner than the distance to it (a
 * blade, a finger), which would pull the sample through and turn the
 * surface over. */
void spia__fit_facing_start(const float *start, const float *N, int64_t S, int sign, float *w) {
    for (int64_t s = 0; s < S; ++s) {
        const float *m = start + 3 * s, *n = N + 3 * s;
        if ((double)sign * ((double)m[0] * n[0] + (double)m[1] * n[1] + (double)m[2] * n[2]) < 0.0) w[s] = 0.0f;
    }
}

/* Whether samples that pull are counted facing along the scan's normals
 * (+1) or against them (-1): the cage's and the scan's orientation need
 * not agree, so the sign most of them agree on is the right one. */
int spia__fit_orientation(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S, double cutoff_abs) {
    double sum = 0.0;
    for (int64_t s = 0; s < S; ++s)
        if (d[s] <= cutoff_abs && !on_boundary[s]) sum += dots[s];
    return sum < 0.0 ? -1 : 1;
}

/* Marks the folded samples (within the cut-off, not over a hole, facing
 * away); returns how many. */
int64_t spia__fit_find_folds(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S,
                             double cutoff_abs, int sign, uint8_t *folded) {
    int64_t count = 0;
    for (int64_t s = 0; s < S; ++s) {
        folded[s] = d[s] <= cutoff_abs && !on_boundary[s] && (double)sign * dots[s] < 0.0;
        count += folded[s];
    }
    return count;
}

/* The fold guard's stiffness, per vertex of a face holding a folded
 * sample, once per round: a fold lying on the scan (the sample within
 * FOLD_NEAR times `near`, the robust kernel's scale, of its closest point:
 * a pleat) doubles the vertex's smoothing s_i; a sample facing a scan part
 * farther away (a base plate under a hole) quadruples its hold h_i on the
 * shape given.  Both stop at STIFFNESS_MAX.
 *
 * Measured on the bench_fit.py cages (Blender's level-3 surface; share of
 * its points facing away from the scan, mean distance) and the base-plate
 * test (tests/python/test_fit_quality.py): smoothing every folded part
 * (FOLD_NEAR infinite) brought the bunny from 0.17% to 0.05% but let a
 * plate facing up pull the fit 15% off (held, 7%); FOLD_NEAR 1, 2, 4, 6
 * left the bunny 0.070, 0.087, 0.069, 0.069% and the dragon 0.246, 0.220,
 * 0.213, 0.196%, the plate at +5 to +8%.  The smoothing's growth: 1.5 left
 * three times the bunny's folds; 3, 4 and 16 cost accuracy (the dragon's
 * mean 6.4, 6.5 and 7.0e-5 against 6.3e-5) for no fewer folds. */
#define FOLD_NEAR 4.0
#define SMOOTHING_GROWTH 2.0
#define HOLD_GROWTH 4.0
#define STIFFNESS_MAX 65536.0
void spia__fit_stiffen(const spia_mesh *cage, const spia_adjacency *adj, const uint8_t *folded, const float *d,
                       double near, const int32_t *sample_face, int64_t S, uint8_t *mark, double *hold,
                       double *smooth) {
    memset(mark, 0, (size_t)cage->vertex_count);
    for (int64_t s = 0; s < S; ++s)
        if (folded[s]) {
            const int32_t f = sample_face[s];
            const uint8_t kind = d[s] <= FOLD_NEAR * near ? 1 : 2;
            for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c) mark[cage->face_vertices[c]] |= kind;
        }
    for (int32_t v = 0; v < cage->vertex_count; ++v) {
        if ((mark[v] & 1) && smooth[v] < STIFFNESS_MAX) smooth[v] *= SMOOTHING_GROWTH;
        if ((mark[v] & 2) && hold[v] < STIFFNESS_MAX) hold[v] *= HOLD_GROWTH;
    }
}

/* Fills bar (growing it as needed) and bar_start (groups + 1) for the
 * samples X with closest-point normals N; returns 0, or 1 out of memory.
 * No pairs in a ptex face with a sample over a hole of the scan: there the
 * barrier pushed the surface out over the hole (bunny, mean 1.387e-4 with
 * them, 1.353e-4 without, and 0.032% against 0.019% of the level-3 points
 * facing away; the other three scans' fits are the same to the bit). */
/* The barrier also holds a pair whose samples have come closer than
 * FOLD_BARRIER_COMPRESS of their distance on the starting cage: a grid
 * squeezed to a tenth of its size is where a pleat forms (the armadillo's
 * turned points had a median tenth of their starting normal's length),
 * before it turns over.  Its target is then that share of the starting
 * distance.  Measured with bench_fit_folds.py (level-3 points turned
 * against the starting cage: bunny, dragon, armadillo, Chinese dragon),
 * together with facing_start: without it 0.086, 0.128, 0.204, 0.041%; with
 * 0.25, 0.4, 0.5, 0.6 and 0.7: 0.088/0.072/0.072/0.075/0.079% (bunny),
 * 0.100/0.104/0.104/0.107/0.127% (dragon), 0.171/0.097/0.100/0.075/0.100%
 * (armadillo), 0.011/0.004/0.004/0.003/0.008% (Chinese dragon); at 0.5 the
 * mean distances moved by -0.2% to +1.4%. */
#define FOLD_BARRIER_COMPRESS 0.5
/* The pairs of the ptex faces [g0, g1) into a list of their own, and each
 * face's first pair's place in it into bar_start; returns 1 out of memory. */
typedef struct barrier_list {
    fold_pair *v;
    int64_t count, capacity;
    int failed;
} barrier_list;

typedef struct barrier_pass {
    const double *X;
    const float *N, *d, *start_len;
    const uint8_t *on_boundary;
    int32_t k;
    int sign;
    double reach;
    int64_t groups, chunk;
    int64_t *bar_start;
    barrier_list *lists; /* one a chunk of `chunk` faces */
} barrier_pass;

static int barrier_faces(const barrier_pass *p, int64_t g0, int64_t g1, barrier_list *out) {
    const int32_t k = p->k, per = k * k;
    const float *d = p->d;
    for (int64_t g = g0; g < g1; ++g) {
        p->bar_start[g] = out->count;
        const int64_t base = g * per;
        int over_hole = 0;
        for (int32_t l = 0; l < per && !over_hole; ++l) over_hole = p->on_boundary[base + l];
        if (over_hole) continue;
        for (int32_t l = 0; l < per; ++l) {
            const int64_t q = base + l;
            if (!(d[q] <= p->reach)) continue;
            int32_t pa[2], pb[2];
            double D[2][3];
            spia__fit_grid_differences(p->X, base, l, k, pa, pb, D);
            const float *n = p->N + 3 * q;
            const double e[2][3] = {
                {D[1][1] * n[2] - D[1][2] * n[1], D[1][2] * n[0] - D[1][0] * n[2], D[1][0] * n[1] - D[1][1] * n[0]},
                {n[1] * D[0][2] - n[2] * D[0][1], n[2] * D[0][0] - n[0] * D[0][2], n[0] * D[0][1] - n[1] * D[0][0]}};
            for (int m = 0; m < 2; ++m) {
                if (!(d[base + pa[m]] <= p->reach) || !(d[base + pb[m]] <= p->reach)) continue;
                /* along = sign e . D / |e| below FOLD_BARRIER_SHEAR |D|, squared where it is positive */
                const double e2 = e[m][0] * e[m][0] + e[m][1] * e[m][1] + e[m][2] * e[m][2];
                const double d2 = D[m][0] * D[m][0] + D[m][1] * D[m][1] + D[m][2] * D[m][2];
                const double ed = (double)p->sign * (e[m][0] * D[m][0] + e[m][1] * D[m][1] + e[m][2] * D[m][2]);
                if (!(e2 > 0.0) || !(d2 > 0.0)) continue;
                const double least = p->start_len ? FOLD_BARRIER_COMPRESS * p->start_len[2 * q + m] : 0.0;
                if (ed > 0.0 && ed * ed >= FOLD_BARRIER_SHEAR * FOLD_BARRIER_SHEAR * e2 * d2 && d2 >= least * least)
                    continue;
                const double el = sqrt(e2), dl = sqrt(d2) > least / FOLD_BARRIER_SHEAR ? sqrt(d2) : least / FOLD_BARRIER_SHEAR;
                if (out->count == out->capacity) {
                    const int64_t grown = out->capacity > 0 ? 2 * out->capacity : 256;
                    fold_pair *more = realloc(out->v, sizeof(fold_pair) * (size_t)grown);
                    if (!more) return 1;
                    out->v = more, out->capacity = grown;
                }
                fold_pair *f = out->v + out->count++;
                f->a = pa[m], f->b = pb[m];
                for (int c = 0; c < 3; ++c) f->e[c] = (float)((double)p->sign * e[m][c] / el);
                f->t = (float)(FOLD_BARRIER_SHEAR * dl);
            }
        }
    }
    return 0;
}

static void barrier_range(void *context, int64_t c0, int64_t c1, int thread) {
    (void)thread;
    const barrier_pass *p = context;
    for (int64_t c = c0; c < c1; ++c) {
        const int64_t g0 = c * p->chunk, g1 = p->groups - g0 < p->chunk ? p->groups : g0 + p->chunk;
        p->lists[c].failed = barrier_faces(p, g0, g1, &p->lists[c]);
    }
}

/* Ptex faces a chunk of the pairs' search takes. */
#define BARRIER_CHUNK 16384

/* The pairs, chunk by chunk on the threads, each chunk's list then put
 * after the one before: the same list as one pass over the faces. */
int spia__fit_barrier_pairs(const double *X, const float *N, const float *d, const uint8_t *on_boundary, int64_t S,
                            int32_t k, int sign, double reach, const float *start_len, fold_pair **bar,
                            int64_t *capacity, int64_t *bar_start, int threads) {
    const int32_t per = k * k;
    const int64_t groups = (S + per - 1) / per, chunks = (groups + BARRIER_CHUNK - 1) / BARRIER_CHUNK;
    barrier_list *lists = calloc((size_t)(chunks > 0 ? chunks : 1), sizeof(barrier_list));
    if (!lists) return 1;
    barrier_pass p = {X, N, d, start_len, on_boundary, k, sign, reach, groups, BARRIER_CHUNK, bar_start, lists};
    spia__parallel_for(threads, chunks, 1, barrier_range, &p);
    int64_t count = 0;
    int failed = 0;
    for (int64_t c = 0; c < chunks; ++c) count += lists[c].count, failed |= lists[c].failed;
    if (!failed && count > *capacity) {
        fold_pair *more = realloc(*bar, sizeof(fold_pair) * (size_t)count);
        if (more)
            *bar = more, *capacity = count;
        else
            failed = 1;
    }
    int64_t at = 0;
    for (int64_t c = 0; c < chunks; ++c) {
        if (!failed) {
            if (lists[c].count) memcpy(*bar + at, lists[c].v, sizeof(fold_pair) * (size_t)lists[c].count);
            const int64_t g0 = c * BARRIER_CHUNK, g1 = groups - g0 < BARRIER_CHUNK ? groups : g0 + BARRIER_CHUNK;
            for (int64_t g = g0; g < g1; ++g) bar_start[g] += at;
            at += lists[c].count;
        }
        free(lists[c].v);
    }
    free(lists);
    if (failed) return 1;
    bar_start[groups] = count;
    return 0;
}
