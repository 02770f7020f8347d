// SPDX-License-Identifier: GPL-3.0-or-later
/* Fitting a cage's limit surface to a scan.
 *
 * SURFACE: samples X = M V of the limit surface (M: the sample stencils) are
 * matched to their closest scan points T with the scan's normals N.  Each
 * round minimises, over the cage V,
 *
 *   sum_s w_s [ (N_s . (M_s V - T_s))^2 + a |M_s V - T_s|^2 ]
 *     + l sum_i |(Lap (V - V0))_i|^2
 *
 * (w_s = 0 beyond the cut-off, a the point-to-point weight, Lap the cage's
 * umbrella Laplacian, V0 the cage given, l the smoothing weight times the
 * number of counted samples per vertex), by conjugate gradients on the
 * normal equations with a 3x3 block-Jacobi preconditioner, warm started
 * from the previous round; then the closest points are found again.  The
 * point-to-plane term lets samples slide along the scan, which is why it
 * converges in a few rounds where plain closest-point least squares (LSPIA)
 * creeps; the Laplacian term keeps the cage fair and holds it in place over
 * holes.
 *
 * Each sample's weight w_s is a robust (Cauchy) kernel of its distance,
 * 1 / (1 + (d / c)^2) with c a multiple of the median distance, within the
 * cut-off and 0 beyond it or over a hole.  The fold guard: a sample whose
 * limit normal (differences along the sample grid) faces away from the
 * scan's normal weighs 0, and the vertices of its face are stiffened: the
 * fairness term is
 *
 *   l sum_i [ h_i |(Lap (V - V0))_i|^2 + (s_i - 1) |(Lap V)_i|^2 ],
 *
 * h_i, s_i from 1.  A fold lying on the scan (a pleat) raises s_i, which
 * irons the cage out there rather than holding it to the shape it was
 * given, often folded itself (a shrinkwrapped cage); a sample facing a
 * scan part farther off (a plate under a hole) raises h_i, which holds the
 * cage to its shape (see stiffen).  On the bench_fit.py cages, holding
 * every stiffened vertex to its shape left the bunny's level-3 surface
 * 0.17% of its points facing away, against 0.07%.
 *
 * VERTICES: the cage's limit points go to their closest scan points and the
 * cage is solved to interpolate them. */
#include "bvh.h"
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static spia_result resolve_fit(const spia_fit_options *in, spia_fit_options *out, spia_status *status) {
    spia_fit_options o;
    if (in)
        o = *in;
    else
        memset(&o, 0, sizeof o);
    if ((int)o.mode != SPIA_FIT_SURFACE && (int)o.mode != SPIA_FIT_VERTICES)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown fit mode %d", (int)o.mode);
    if (o.samples_per_edge == 0) o.samples_per_edge = 4;
    if (o.samples_per_edge < 1 || o.samples_per_edge > 64)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "samples_per_edge must be 1 to 64, got %d",
                          o.samples_per_edge);
    if (o.cutoff == 0.0) o.cutoff = 0.02;
    if (o.smoothing == 0.0) o.smoothing = 1e-5;
    if (o.point_weight == 0.0) o.point_weight = 1e-3;
    if (o.max_rounds == 0) o.max_rounds = 16;
    if (o.round_tolerance == 0.0) o.round_tolerance = 0.01;
    if (o.solver_iterations == 0) o.solver_iterations = 20;
    if (o.robust_scale == 0.0) o.robust_scale = 6.0;
    if (!isfinite(o.slide_weight) || o.slide_weight >= 1.0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "slide_weight must be below 1");
    if (o.slide_weight < 0.0) o.slide_weight = 0.0;
    if (!(o.robust_scale > 0.0) || !isfinite(o.robust_scale))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "robust_scale must be a positive number");
    const uint32_t known = SPIA_FIT_ALLOW_FOLDS | SPIA_FIT_HARD_CUTOFF | SPIA_FIT_NO_SCAN_DISTANCES | SPIA_FIT_SCAN_PULL |
                           SPIA_FIT_FREE_RIMS;
    if (o.flags & ~known)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown fit flags 0x%x", (unsigned)(o.flags & ~known));
    if ((o.flags & SPIA_FIT_SCAN_PULL) && (o.mode != SPIA_FIT_SURFACE || o.samples_per_edge < 2))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "the scan's pull (SPIA_FIT_SCAN_PULL) needs a Surface fit with samples_per_edge of 2 or more");
    if (!(o.cutoff > 0.0) || !isfinite(o.cutoff))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "cutoff must be a positive number");
    if (!isfinite(o.smoothing) || !isfinite(o.point_weight) || !isfinite(o.round_tolerance) ||
        o.round_tolerance < 0.0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "fit weights and tolerance must be finite");
    if (o.max_rounds < 0 || o.solver_iterations < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "max_rounds and solver_iterations must be positive");
    if (o.smoothing < 0.0) o.smoothing = 0.0;
    if (o.point_weight < 0.0) o.point_weight = 0.0;
    *out = o;
    return SPIA_OK;
}

/* Bytes a fit needs a sample at its peak: the sample's stencil, closest
 * point and normal, the fold guard's and the scan pull's buffers (547 measured
 * on the bunny's cage at 4 and 5 detail levels, python/spia's estimate). */
#define FIT_BYTES_PER_SAMPLE 600.0

/* The check before a fit or a table of surface samples: samples_per_edge
 * (k) and the most that fits.  Without surface samples (Loop, Doo-Sabin)
 * a fit takes the limit points alone. */
typedef struct samples_need {
    const spia_mesh *m;
    int surface;
} samples_need;
static double samples_bytes(const void *context, int32_t k) {
    const samples_need *n = (const samples_need *)context;
    const double samples = n->surface ? (double)spia_surface_sample_count(n->m, k) : (double)n->m->vertex_count;
    return spia__table_bytes(n->m) + FIT_BYTES_PER_SAMPLE * samples;
}
static spia_result samples_memory(const spia_mesh *m, const spia_options *o, int32_t k, int surface,
                                  const char *work, spia_status *status) {
    const samples_need context = {m, surface};
    char what[128];
    snprintf(what, sizeof what, "%s with %d samples per edge (%.0f samples)", work, (int)k,
             surface ? (double)spia_surface_sample_count(m, k) : (double)m->vertex_count);
    /* (without surface samples no number of them fits better) */
    return spia__memory_check_setting(o, samples_bytes, &context, surface ? k : 0, what,
                                      "at most %d samples per edge fit%.0s", "try a smaller cage", status);
}

spia_result spia_surface_stencils_create(const spia_mesh *mesh, const spia_options *options,
                                         int32_t samples_per_edge, spia_stencils **out, spia_status *status) {
    if (!out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "out must not be NULL");
    *out = NULL;
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme != SPIA_SCHEME_CATMULL_CLARK)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "surface samples are available for Catmull-Clark only");
    if (samples_per_edge < 1 || samples_per_edge > 64)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "samples_per_edge must be 1 to 64, got %d",
                          samples_per_edge);
    if ((r = spia_mesh_validate(mesh, status)) != SPIA_OK) return r;
    if ((r = samples_memory(mesh, &opt, samples_per_edge, 1, "a table of surface samples", status)) != SPIA_OK)
        return r;
    spia_adjacency adj;
    if ((r = spia__adjacency_build(mesh, &adj, status)) != SPIA_OK) return r;
    r = spia__osd_surface_stencils(mesh, &adj, &opt, samples_per_edge, out, status);
    spia__adjacency_free(&adj);
    return r;
}

/* ---- progress ------------------------------------------------------------- */

/* Besides after every round, the progress callback is called from the long steps once
 * PROGRESS_INTERVAL seconds have passed since the last call (the sample
 * stencils every BLOCK_TICK faces, closest points in chunks of QUERY_CHUNK,
 * each conjugate-gradient step, the surface's grid: its creation,
 * evaluation and build as a scan), so that a cancel is answered promptly
 * at every scale.  These calls repeat the last call's
 * figures (the rounds done and their mean distance, or the VERTICES
 * solve's last iteration and error; 0 and the cage given's mean before
 * any). */
#define PROGRESS_INTERVAL 0.1
#define QUERY_CHUNK 65536
typedef struct fit_clock {
    spia_progress_fn fn;
    void *user;
    double last, mean;
    int32_t round;
    int cancelled;
} fit_clock;

static int clock_tick(fit_clock *c) {
    if (!c->fn || c->cancelled) return c->cancelled;
    const double now = spia__now();
    if (now - c->last < PROGRESS_INTERVAL) return 0;
    c->last = now;
    if (c->fn(c->user, c->round, c->mean)) c->cancelled = 1;
    return c->cancelled;
}

/* The clock ticking from a build with a progress callback of its own (the
 * surface's grid as a scan): its phases and fractions are not passed on. */
static int clock_scan_tick(void *user, int32_t phase, double fraction) {
    (void)phase, (void)fraction;
    return clock_tick((fit_clock *)user);
}

/* The solver's progress, passed on and remembered (for the ticks to repeat). */
static int clock_forward(void *user, int32_t iteration, double value) {
    fit_clock *c = (fit_clock *)user;
    c->round = iteration, c->mean = value, c->last = spia__now();
    if (c->fn(c->user, iteration, value)) c->cancelled = 1;
    return c->cancelled;
}

/* ---- the samples as dense blocks ---------------------------------------- */

/* The samples of one ptex face combine the same cage vertices (the face's
 * patch points), so each ptex face's rows are kept as one dense block over
 * those vertices, column by column (a column's weights for all the face's
 * samples side by side), in float: a pass over a block gives its samples'
 * positions, or the whole normal-equation product M^T B M x of its samples
 * at once, reading each weight once, without an index per weight, in loops
 * the compiler vectorises, the sums in double.  On the 50k-vertex cage (800k
 * samples) a round's solve took 1.9 s as sparse rows and their transpose
 * in double, 1.1 s as double blocks and 0.8 to 1.1 s as float blocks (runs
 * one after another on a quiet machine).  Float
 * weights move a sample by at most 6e-8 of the cage's extent, well inside
 * the float32 the cage is read and written in.
 *
 * Blocks with equal weights share one copy of them.  Every regular face
 * has its patch points in the same order and the same weights, so a
 * quad-dominant cage has few distinct blocks: 170 for the 50k-vertex
 * voxel-remeshed dragon's 50,416 ptex faces (0.2 MB of weights against
 * 56 MB).  The products then read the columns and little else: its nine
 * rounds' solves took 1.9 s against 2.5 s, and the fit's peak fell by
 * 135 MB.
 *
 * The products run on up to two threads (the closest-point queries, the
 * bulk of a round, on every core: scan.c); on the 2-processor test machine
 * two measured no faster than one, the kernels being bound by arithmetic on
 * processors that seem to share a core. */
typedef struct sample_blocks {
    int64_t groups;   /* ptex faces */
    int32_t per;      /* samples per ptex face */
    int64_t *start;   /* groups + 1: the columns of block g are cols[start[g] .. start[g + 1]) */
    int32_t *cols;
    float *w;         /* block g at w + w_at[g]: column j's per weights at + per * j */
    int64_t *w_at;    /* groups: where each block's weights start; blocks of equal weights (the cage's
                         regular faces) share them */
    int64_t w_size;   /* floats in w */
    double *u;        /* BLOCK_PIECES * 6 * per: per piece, a block's samples' vectors (x, y, z apart; 6 for the
                         preconditioner's products) */
    double *extra;    /* (BLOCK_PIECES - 1) * 6 * columns: the later pieces' sums */
    int32_t columns;
    int threads;
    int avx;          /* the products' AVX kernels (SPIA_AVX_KERNELS) */
} sample_blocks;

/* The products run in this many pieces of the blocks, whatever the number
 * of threads, each piece summing into a vector of its own; the sums are
 * added in piece order, so the results do not depend on the threads. */
#define BLOCK_PIECES 2

static void blocks_free(sample_blocks *B) {
    free(B->start), free(B->cols), free(B->w), free(B->w_at), free(B->u), free(B->extra);
    memset(B, 0, sizeof *B);
}

/* The blocks as OpenSubdiv's part hands them over (spia__osd_surface_blocks),
 * the arrays grown as they come. */
typedef struct block_sink {
    sample_blocks *B;
    int64_t capacity;   /* columns cols has room for */
    int64_t w_capacity; /* floats w has room for */
    int32_t *kept;      /* a block's columns with a weight that is not zero */
    int32_t kept_capacity;
    /* The distinct blocks of weights: an open-addressed table of the first
     * block with each (-1: empty), and how many there are. */
    int64_t *table;
    int64_t table_size, distinct;
    int64_t next;     /* the ptex face expected next */
    fit_clock *clock; /* ticked every BLOCK_TICK faces */
} block_sink;

#define BLOCK_TICK 256

static inline int64_t block_width(const sample_blocks *B, int64_t g) { return B->start[g + 1] - B->start[g]; }

static uint64_t weights_hash(const float *w, int64_t count) {
    uint64_t h = 1469598103934665603ull ^ (uint64_t)count;
    for (int64_t i = 0; i < count; ++i) {
        uint32_t bits;
        memcpy(&bits, w + i, sizeof bits);
        h = (h ^ bits) * 1099511628211ull;
    }
    return h ^ (h >> 29);
}

/* Gives block g (its weights at the end of w) the weights of an earlier
 * block equal to it, if there is one, or keeps them. */
static int share_weights(block_sink *k, int64_t g, int64_t count) {
    sample_blocks *B = k->B;
    if (2 * (k->distinct + 1) > k->table_size) {
        const int64_t size = k->table_size ? 2 * k->table_size : 1024;
        int64_t *table = malloc(sizeof(int64_t) * (size_t)size);
        if (!table) return SPIA_ERROR_OUT_OF_MEMORY;
        for (int64_t i = 0; i < size; ++i) table[i] = -1;
        for (int64_t i = 0; i < k->table_size; ++i) {
            const int64_t e = k->table[i];
            if (e < 0) continue;
            uint64_t h = weights_hash(B->w + B->w_at[e], B->per * block_width(B, e)) & (uint64_t)(size - 1);
            while (table[h] >= 0) h = (h + 1) & (uint64_t)(size - 1);
            table[h] = e;
        }
        free(k->table);
        k->table = table;
        k->table_size = size;
    }
    const float *w = B->w + B->w_at[g];
    uint64_t h = weights_hash(w, count) & (uint64_t)(k->table_size - 1);
    for (; k->table[h] >= 0; h = (h + 1) & (uint64_t)(k->table_size - 1)) {
        const int64_t e = k->table[h];
        if (B->per * block_width(B, e) == count && !memcmp(B->w + B->w_at[e], w, sizeof(float) * (size_t)count)) {
            B->w_at[g] = B->w_at[e];
            return 0;
        }
    }
    k->table[h] = g;
    ++k->distinct;
    B->w_size += count;
    return 0;
}

static int block_sink_add(void *user, int64_t ptex, int32_t width, const int32_t *columns, const double *weights) {
    block_sink *k = user;
    sample_blocks *B = k->B;
    if (ptex != k->next || ptex >= B->groups) return SPIA_ERROR_INTERNAL;
    if (++k->next % BLOCK_TICK == 0 && clock_tick(k->clock)) return SPIA_ERROR_CANCELLED;
    const int64_t at = B->start[ptex], per = B->per;
    if (at + width > k->capacity) {
        int64_t cap = k->capacity > 0 ? k->capacity : 4096;
        while (cap < at + width) cap *= 2;
        int32_t *cols = realloc(B->cols, sizeof(int32_t) * (size_t)cap);
        if (!cols) return SPIA_ERROR_OUT_OF_MEMORY;
        B->cols = cols;
        k->capacity = cap;
    }
    if (B->w_size + per * width > k->w_capacity) {
        int64_t cap = k->w_capacity > 0 ? k->w_capacity : 4096 * per;
        while (cap < B->w_size + per * width) cap *= 2;
        float *w = realloc(B->w, sizeof(float) * (size_t)cap);
        if (!w) return SPIA_ERROR_OUT_OF_MEMORY;
        B->w = w;
        k->w_capacity = cap;
    }
    if (width > k->kept_capacity) {
        int32_t *kept = realloc(k->kept, sizeof(int32_t) * (size_t)width);
        if (!kept) return SPIA_ERROR_OUT_OF_MEMORY;
        k->kept = kept;
        k->kept_capacity = width;
    }
    /* The columns whose weights are not all zero, in the patch's order
     * (which is the same for every regular face, so their blocks share
     * one copy of the weights: the products then read little more than
     * the columns). */
    int32_t kept = 0;
    for (int32_t i = 0; i < width; ++i) {
        int any = 0;
        for (int64_t s = 0; s < per && !any; ++s) any = (float)weights[s * width + i] != 0.0f;
        if (any) k->kept[kept++] = i;
    }
    B->w_at[ptex] = B->w_size;
    for (int32_t j = 0; j < kept; ++j) {
        const int32_t i = k->kept[j];
        B->cols[at + j] = columns[i];
        float *col = B->w + B->w_size + per * j;
        for (int64_t s = 0; s < per; ++s) col[s] = (float)weights[s * width + i];
    }
    B->start[ptex + 1] = at + kept;
    return share_weights(k, ptex, per * kept);
}

/* The sample blocks of the cage (per ptex face, per_edge^2 samples; with
 * `corners`, a grid with per_edge points on each edge, from corner to
 * corner). */
static spia_result blocks_build(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                int32_t per_edge, int corners, sample_blocks *B, fit_clock *clock,
                                spia_status *status) {
    memset(B, 0, sizeof *B);
    B->per = per_edge * per_edge;
    B->columns = cage->vertex_count;
    B->threads = opt->threads > BLOCK_PIECES ? BLOCK_PIECES : opt->threads < 1 ? 1 : opt->threads;
    B->avx = !(opt->solve_flags & SPIA_SOLVE_NO_AVX) && spia__have_avx();
    B->groups = spia_surface_sample_count(cage, per_edge) / B->per;
    B->start = calloc((size_t)B->groups + 1, sizeof(int64_t));
    B->w_at = malloc(sizeof(int64_t) * (size_t)(B->groups > 0 ? B->groups : 1));
    B->u = malloc(sizeof(double) * 6 * BLOCK_PIECES * (size_t)B->per);
    B->extra = malloc(sizeof(double) * 6 * (BLOCK_PIECES - 1) * (size_t)(B->columns > 0 ? B->columns : 1));
    if (!B->start || !B->w_at || !B->u || !B->extra) {
        blocks_free(B);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
    }
    block_sink sink = {B, 0, 0, NULL, 0, NULL, 0, 0, 0, clock};
    spia_result r = spia__osd_surface_blocks(cage, adj, opt, per_edge, corners, block_sink_add, &sink, status);
    free(sink.kept);
    free(sink.table);
    if (r == SPIA_OK && sink.next != B->groups)
        r = spia__fail(status, SPIA_ERROR_INTERNAL, -1, "the sample stencils do not match the cage's faces");
    if (r != SPIA_OK) {
        blocks_free(B);
        return r;
    }
    return SPIA_OK;
}

/* The block products four samples at a time, in GCC's and Clang's vector
 * types: two SSE2 registers each by default, one AVX register in the
 * kernels compiled for AVX (SPIA_AVX_KERNELS).  Every lane does the
 * operations the scalar loops would, in their order, so both give the same
 * bits.  Loads and stores go through memcpy (any alignment). */
typedef double v4d __attribute__((vector_size(32)));
typedef float v4f __attribute__((vector_size(16)));
#define ALWAYS_INLINE static inline __attribute__((always_inline))

ALWAYS_INLINE void load4(v4d *out, const float *w) {
    v4f f;
    memcpy(&f, w, sizeof f);
    *out = __builtin_convertvector(f, v4d);
}

/* u = block g times the columns of x: its samples' positions.  Each sample
 * sums over the columns in order, eight (then four, then one) samples at a
 * time in registers. */
ALWAYS_INLINE void block_forward(const sample_blocks *B, int64_t g, const double *x, double *u) {
    const int32_t *cols = B->cols + B->start[g];
    const int64_t width = block_width(B, g);
    const int32_t per = B->per;
    const float *w = B->w + B->w_at[g];
    double *ux = u, *uy = u + per, *uz = u + 2 * per;
    int32_t s = 0;
    for (; s + 8 <= per; s += 8) {
        v4d x0 = {0.0, 0.0, 0.0, 0.0}, x1 = x0, y0 = x0, y1 = x0, z0 = x0, z1 = x0;
        for (int64_t j = 0; j < width; ++j) {
            const double *p = x + 3 * (int64_t)cols[j];
            const double px = p[0], py = p[1], pz = p[2];
            v4d m0, m1;
            load4(&m0, w + per * j + s);
            load4(&m1, w + per * j + s + 4);
            x0 += m0 * px, x1 += m1 * px;
            y0 += m0 * py, y1 += m1 * py;
            z0 += m0 * pz, z1 += m1 * pz;
        }
        memcpy(ux + s, &x0, sizeof x0), memcpy(ux + s + 4, &x1, sizeof x1);
        memcpy(uy + s, &y0, sizeof y0), memcpy(uy + s + 4, &y1, sizeof y1);
        memcpy(uz + s, &z0, sizeof z0), memcpy(uz + s + 4, &z1, sizeof z1);
    }
    for (; s + 4 <= per; s += 4) {
        v4d x0 = {0.0, 0.0, 0.0, 0.0}, y0 = x0, z0 = x0;
        for (int64_t j = 0; j < width; ++j) {
            const double *p = x + 3 * (int64_t)cols[j];
            v4d m;
            load4(&m, w + per * j + s);
            x0 += m * p[0], y0 += m * p[1], z0 += m * p[2];
        }
        memcpy(ux + s, &x0, sizeof x0), memcpy(uy + s, &y0, sizeof y0), memcpy(uz + s, &z0, sizeof z0);
    }
    for (; s < per; ++s) {
        double sx = 0.0, sy = 0.0, sz = 0.0;
        for (int64_t j = 0; j < width; ++j) {
            const double *p = x + 3 * (int64_t)cols[j];
            const double m = w[per * j + s];
            sx += m * p[0], sy += m * p[1], sz += m * p[2];
        }
        ux[s] = sx, uy[s] = sy, uz[s] = sz;
    }
}

/* out[cols] += block g transposed times u.  Four partial sums per axis, one
 * per lane (sample s in lane s mod 4; the samples after the last four in
 * lane 0), added pairwise at the end: the additions do not wait for each
 * other. */
ALWAYS_INLINE void block_backward(const sample_blocks *B, int64_t g, const double *u, double *out) {
    const int32_t *cols = B->cols + B->start[g];
    const int64_t width = block_width(B, g);
    const int32_t per = B->per;
    const float *w = B->w + B->w_at[g];
    const double *ux = u, *uy = u + per, *uz = u + 2 * per;
    for (int64_t j = 0; j < width; ++j) {
        const float *col = w + per * j;
        v4d a = {0.0, 0.0, 0.0, 0.0}, b = a, c = a;
        int32_t s = 0;
        for (; s + 4 <= per; s += 4) {
            v4d m, vx, vy, vz;
            load4(&m, col + s);
            memcpy(&vx, ux + s, sizeof vx), memcpy(&vy, uy + s, sizeof vy), memcpy(&vz, uz + s, sizeof vz);
            a += m * vx, b += m * vy, c += m * vz;
        }
        for (; s < per; ++s) {
            const double m = col[s];
            a[0] += m * ux[s], b[0] += m * uy[s], c[0] += m * uz[s];
        }
        double *p = out + 3 * (int64_t)cols[j];
        p[0] += (a[0] + a[1]) + (a[2] + a[3]);
        p[1] += (b[0] + b[1]) + (b[2] + b[3]);
        p[2] += (c[0] + c[1]) + (c[2] + c[3]);
    }
}

/* The pieces: a block product over [begin, end) of the blocks, as piece
 * number begin / grain. */
typedef void (*block_piece_fn)(const void *context, const sample_blocks *B, int64_t begin, int64_t end, double *u,
                               double *out);
typedef struct block_run {
    const sample_blocks *B;
    block_piece_fn fn;
    const void *context;
    double *out;
    int64_t grain;
    int stride; /* values per column in out */
} block_run;

static void block_run_piece(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const block_run *run = context;
    const int64_t piece = begin / run->grain;
    const sample_blocks *B = run->B;
    double *out = piece == 0 ? run->out : B->extra + run->stride * (piece - 1) * (int64_t)B->columns;
    if (piece > 0 && run->out) memset(out, 0, sizeof(double) * (size_t)run->stride * (size_t)B->columns);
    run->fn(run->context, B, begin, end, B->u + 6 * piece * B->per, out);
}

/* Runs fn over the blocks in BLOCK_PIECES pieces; `out` (stride values per
 * column, 3 or 6) gets the sum, or with stride 0 is written by piece 0
 * alone (fn writing only its own blocks' places). */
static void blocks_run(const sample_blocks *B, block_piece_fn fn, const void *context, double *out, int stride) {
    block_run run = {B, fn, context, out, (B->groups + BLOCK_PIECES - 1) / BLOCK_PIECES, stride};
    if (run.grain < 1) run.grain = 1;
    spia__parallel_for(B->threads, B->groups, run.grain, block_run_piece, &run);
    if (!stride) return;
    const int64_t pieces = (B->groups + run.grain - 1) / run.grain, size = stride * (int64_t)B->columns;
    for (int64_t piece = 1; piece < pieces; ++piece) {
        const double *e = B->extra + (piece - 1) * size;
        for (int64_t i = 0; i < size; ++i) out[i] += e[i];
    }
}

/* A piece function `name` around its body, and where the library has AVX
 * kernels its twin compiled for AVX (name##_avx); PIECE(B, name) is the
 * one B chose (B->avx). */
#define PIECE_ARGS const void *context, const sample_blocks *B, int64_t begin, int64_t end, double *u, double *out
#ifdef SPIA_AVX_KERNELS
#define DEFINE_PIECE(name, body)                                                   \
    static void name(PIECE_ARGS) { body(context, B, begin, end, u, out); }         \
    SPIA_TARGET_AVX static void name##_avx(PIECE_ARGS) { body(context, B, begin, end, u, out); }
#define PIECE(B, name) ((B)->avx ? name##_avx : name)
#else
#define DEFINE_PIECE(name, body) \
    static void name(PIECE_ARGS) { body(context, B, begin, end, u, out); }
#define PIECE(B, name) name
#endif

/* X = M x, 3 doubles per sample (or, into Xf, 3 floats). */
typedef struct apply_context {
    const double *x;
    double *X;
    float *Xf;
} apply_context;

ALWAYS_INLINE void positions_body(const void *context, const sample_blocks *B, int64_t begin, int64_t end,
                                  double *u, double *out) {
    (void)out;
    const apply_context *a = context;
    const int32_t per = B->per;
    for (int64_t g = begin; g < end; ++g) {
        block_forward(B, g, a->x, u);
        if (a->Xf) {
            float *X = a->Xf + 3 * g * per;
            for (int32_t s = 0; s < per; ++s)
                X[3 * s] = (float)u[s], X[3 * s + 1] = (float)u[per + s], X[3 * s + 2] = (float)u[2 * per + s];
            continue;
        }
        double *X = a->X + 3 * g * per;
        for (int32_t s = 0; s < per; ++s) X[3 * s] = u[s], X[3 * s + 1] = u[per + s], X[3 * s + 2] = u[2 * per + s];
    }
}

DEFINE_PIECE(positions_piece, positions_body)

static void blocks_apply(const sample_blocks *B, const double *x, double *X) {
    apply_context a = {x, X, NULL};
    blocks_run(B, PIECE(B, positions_piece), &a, NULL, 0);
}

static void blocks_apply_float(const sample_blocks *B, const double *x, float *X) {
    apply_context a = {x, NULL, X};
    blocks_run(B, PIECE(B, positions_piece), &a, NULL, 0);
}

/* ---- distances ------------------------------------------------------------ */

/* The k-th smallest of n floats (k < n), reordering a. */
static float select_kth(float *a, int64_t n, int64_t k) {
    int64_t lo = 0, hi = n - 1;
    while (lo < hi) {
        const float pivot = a[lo + (hi - lo) / 2];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (a[i] < pivot) ++i;
            while (a[j] > pivot) --j;
            if (i <= j) {
                const float t = a[i];
                a[i] = a[j], a[j] = t;
                ++i, --j;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            break;
    }
    return a[k];
}

/* Mean, 95th percentile and max of the distances within the cut-off,
 * relative to the diagonal; `scratch` holds count floats. */
static spia_fit_distances distance_stats(const float *d, int64_t count, double cutoff_abs, double diagonal,
                                         float *scratch) {
    spia_fit_distances s = {0.0, 0.0, 0.0, 0};
    int64_t n = 0;
    double sum = 0.0;
    for (int64_t i = 0; i < count; ++i) {
        if (d[i] > cutoff_abs) {
            s.ignored++;
            continue;
        }
        scratch[n++] = d[i];
        sum += d[i];
        if (d[i] > s.max) s.max = d[i];
    }
    if (n > 0) {
        /* The nearest-rank percentile, selected (a sort of the scan's
         * millions of distances took half a second). */
        int64_t rank = (int64_t)ceil(0.95 * (double)n);
        if (rank < 1) rank = 1;
        s.p95 = select_kth(scratch, n, rank - 1);
        s.mean = sum / (double)n;
    }
    const double unit = diagonal > 0.0 ? diagonal : 1.0;
    s.mean /= unit;
    s.p95 /= unit;
    s.max /= unit;
    return s;
}

/* The mean with every sample beyond the cut-off counted at the cut-off and,
 * given `folded`, every folded one FOLD_PENALTY of the cut-off farther than
 * it is: what picks the best cage, so that a round that pushes samples off
 * the scan or folds the surface does not look like a gain.  (Counted at the
 * whole cut-off, a folded sample outweighs a hundred good ones and the fit
 * stops rounds early: measured on the bunny, mean 1.35e-4 against 1.30e-4
 * at this penalty, with as many folds.) */
#define FOLD_PENALTY 0.03
static double mean_clamped(const float *d, const uint8_t *folded, int64_t count, double cutoff_abs) {
    double sum = 0.0;
    for (int64_t i = 0; i < count; ++i)
        sum += d[i] > cutoff_abs ? cutoff_abs : folded && folded[i] ? d[i] + FOLD_PENALTY * cutoff_abs : d[i];
    return count ? sum / (double)count : 0.0;
}

static double mean_within(const float *d, int64_t count, double cutoff_abs) {
    double sum = 0.0;
    int64_t n = 0;
    for (int64_t i = 0; i < count; ++i)
        if (d[i] <= cutoff_abs) sum += d[i], ++n;
    return n ? sum / (double)n : 0.0;
}

/* Sample weights: 1 within the cut-off, else 0; and 0 where the closest
 * point is on the scan's boundary.  Such a sample lies beyond the scan's
 * edge, over a hole: pulled, it drags the surface onto the rim (or, pulled
 * along the normal only, flattens it into the rim's tangent plane; pulled
 * only within a tenth of the cut-off of the rim, it draws a crease around
 * every hole), where smoothness fills the hole better. */
static void cutoff_weights(const float *d, const uint8_t *on_boundary, int64_t count, double cutoff_abs, float *w) {
    for (int64_t i = 0; i < count; ++i) w[i] = d[i] <= cutoff_abs && !on_boundary[i] ? 1.0f : 0.0f;
}

/* The median distance of the samples that pull (weight > 0); `scratch`
 * holds count floats.  0 when none does. */
static double median_pulling(const float *d, const float *w, int64_t count, float *scratch) {
    int64_t n = 0;
    for (int64_t i = 0; i < count; ++i)
        if (w[i] > 0.0f) scratch[n++] = d[i];
    return n ? (double)select_kth(scratch, n, n / 2) : 0.0;
}

/* Scales the weights by the robust kernel 1 / (1 + (d / c)^2). */
static void robust_weights(const float *d, int64_t count, double c, float *w) {
    if (!(c > 0.0)) return;
    const double inv = 1.0 / c;
    for (int64_t i = 0; i < count; ++i)
        if (w[i] > 0.0f) {
            const double r = d[i] * inv;
            w[i] = (float)(w[i] / (1.0 + r * r));
        }
}

/* Closest points in chunks, the clock ticking between them; returns 1 when
 * cancelled (the rest left undone). */
static int closest_in_chunks(const spia_scan *scan, int64_t count, const double *points, int32_t *near,
                             float *closest, float *normals, float *distances, int32_t *faces, uint8_t *on_boundary,
                             int threads, fit_clock *clock) {
    for (int64_t at = 0; at < count; at += QUERY_CHUNK) {
        const int64_t n = count - at < QUERY_CHUNK ? count - at : QUERY_CHUNK;
        spia__scan_closest_points_near(scan, n, points + 3 * at, near + at,
                                         closest ? closest + 3 * at : NULL, normals ? normals + 3 * at : NULL,
                                         distances + at, faces ? faces + at : NULL, on_boundary ? on_boundary + at : NULL,
                                         threads);
        if (clock_tick(clock)) return 1;
    }
    return 0;
}

/* Conjugate gradients stop early only when the residual has fallen this far:
 * in practice every round takes solver_iterations steps, which measured
 * better (for the same time) than looser tolerances with more rounds. */
#define CG_TOLERANCE 1e-10

/* ---- the least-squares rounds --------------------------------------------- */

/* A pair of samples of one block, neighbours along u or v, that the fold
 * barrier (barrier_pairs) holds apart: e . (X_a - X_b) is pulled to t. */
typedef struct fold_pair {
    int32_t a, b; /* the samples, within their block */
    float e[3], t;
} fold_pair;

typedef struct fit_system {
    const sample_blocks *blocks; /* the sample stencils */
    int32_t n;              /* cage vertices */
    int64_t S;              /* samples */
    const float *normals;   /* S * 3 */
    const float *dist;      /* S */
    const float *weight;    /* S: per-sample weights (0 beyond the cut-off) */
    const uint8_t *on_boundary; /* S */
    /* beta: the weight of each sample's tangential displacement within a
     * round (from X, the samples of the round's starting cage). */
    double cutoff_abs, alpha, beta, lambda, damping;
    const double *X;
    /* The fold barrier: block g's pairs are bar[bar_start[g] ..
     * bar_start[g + 1] - 1], each weighted bar_weight (bar NULL: none). */
    const fold_pair *bar;
    const int64_t *bar_start;
    double bar_weight;
    /* Umbrella Laplacian: neighbours of v are nb[nb_start[v] .. nb_start[v+1]-1]. */
    const int64_t *nb_start;
    const int32_t *nb;
    const unsigned char *free_vertex;
    /* The fold guard, per vertex (see stiffen): the hold h_i on the given
     * shape (the right-hand side's Lap^T H Lap V0) and the smoothing s_i;
     * the operator's Lap^T C Lap has c_i = h_i + s_i - 1. */
    const double *hold, *smooth;
    double *tmp_n;          /* n * 3 */
    double *tmp_diag;       /* n * 6 */
} fit_system;

/* g = B_s u with B_s = w_s (n n^T + alpha I). */
ALWAYS_INLINE void apply_b(const fit_system *f, int64_t s, const double u[3], double g[3]) {
    const double w = f->weight[s];
    if (w == 0.0) {
        g[0] = g[1] = g[2] = 0.0;
        return;
    }
    const float *nn = f->normals + 3 * s;
    const double dot = nn[0] * u[0] + nn[1] * u[1] + nn[2] * u[2];
    const double a = f->alpha + f->beta, keep = 1.0 - f->beta;
    for (int c = 0; c < 3; ++c) g[c] = w * (keep * nn[c] * dot + a * u[c]);
}

/* The right-hand side's share of sample s: B_s-weighted targets, the
 * tangential anchor at the sample's current place X_s. */
ALWAYS_INLINE void target_b(const fit_system *f, int64_t s, const float T[3], const double X[3], double g[3]) {
    const double w = f->weight[s];
    if (w == 0.0) {
        g[0] = g[1] = g[2] = 0.0;
        return;
    }
    const float *nn = f->normals + 3 * s;
    const double dt = nn[0] * T[0] + nn[1] * T[1] + nn[2] * T[2], dx = nn[0] * X[0] + nn[1] * X[1] + nn[2] * X[2];
    for (int c = 0; c < 3; ++c)
        g[c] = w * (nn[c] * dt + f->alpha * T[c] + f->beta * (X[c] - nn[c] * dx));
}

static void laplacian(const fit_system *f, const double *x, double *y) {
    for (int32_t v = 0; v < f->n; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        double *out = y + 3 * (int64_t)v;
        if (a == b) {
            out[0] = out[1] = out[2] = 0.0;
            continue;
        }
        double m[3] = {0.0, 0.0, 0.0};
        for (int64_t k = a; k < b; ++k)
            for (int c = 0; c < 3; ++c) m[c] += x[3 * (int64_t)f->nb[k] + c];
        for (int c = 0; c < 3; ++c) out[c] = x[3 * (int64_t)v + c] - m[c] / (double)(b - a);
    }
}

/* z += scale * Lap^T y (the neighbour relation is symmetric). */
static void laplacian_transpose_add(const fit_system *f, const double *y, double scale, double *z) {
    for (int32_t v = 0; v < f->n; ++v) {
        const int64_t a = f->nb_start[v], b = f->nb_start[v + 1];
        if (a == b) continue;
        double acc[3] = {y[3 * (int64_t)v], y[3 * (int64_t)v + 1], y[3 * (int64_t)v + 2]};
        for (int64_t k = a; k < b; ++k) {
            const int32_t j = f->nb[k];
            const double inv = 1.0 / (double)(f->nb_start[j + 1] - f->nb_start[j]);
            for (int c = 0; c < 3; ++c) acc[c] -= y[3 * (int64_t)j + c] * inv;
        }
        for (int c = 0; c < 3; ++c) z[3 * (int64_t)v + c] += scale * acc[c];
    }
}

static inline double stiffness(const fit_system *f, int32_t v) { return f->hold[v] + f->smooth[v] - 1.0; }

/* z += lambda Lap^T C Lap x (the operator's share), or with `held` the
 * right-hand side's lambda Lap^T H Lap x. */
static void fairness_add(const fit_system *f, const double *x, int held, double *z) {
    laplacian(f, x, f->tmp_n);
    for (int32_t v = 0; v < f->n; ++v) {
        const double k = held ? f->hold[v] : stiffness(f, v);
        for (int c = 0; c < 3; ++c) f->tmp_n[3 * (int64_t)v + c] *= k;
    }
    laplacian_transpose_add(f, f->tmp_n, f->lambda, z);
}

/* Whether any sample of block g pulls. */
ALWAYS_INLINE int block_pulls(const fit_system *f, int64_t g) {
    const float *w = f->weight + g * f->blocks->per;
    if (f->bar && f->bar_start[g + 1] > f->bar_start[g]) return 1;
    for (int32_t s = 0; s < f->blocks->per; ++s)
        if (w[s] != 0.0f) return 1;
    return 0;
}

typedef struct normal_context {
    const fit_system *f;
    const double *x;     /* system_apply's x */
    const float *T;      /* the right-hand side's targets */
} normal_context;

/* Block g's fold-barrier pairs into gx (3 per sample): with x (u, its
 * samples' positions) the operator's bar_weight e e^T (X_a - X_b), with
 * targets the right-hand side's bar_weight t e, at a and, negated, at b. */
ALWAYS_INLINE void barrier_body(const fit_system *f, int64_t g, int32_t per, const double *u, int targets,
                                double *gx) {
    memset(gx, 0, sizeof(double) * 3 * (size_t)per);
    for (int64_t i = f->bar_start[g]; i < f->bar_start[g + 1]; ++i) {
        const fold_pair *p = f->bar + i;
        const int32_t a = p->a, b = p->b;
        double r = targets ? p->t
                           : p->e[0] * (u[a] - u[b]) + p->e[1] * (u[per + a] - u[per + b]) +
                                 p->e[2] * (u[2 * per + a] - u[2 * per + b]);
        r *= f->bar_weight;
        for (int c = 0; c < 3; ++c) {
            gx[3 * a + c] += r * p->e[c];
            gx[3 * b + c] -= r * p->e[c];
        }
    }
}

/* Over blocks [begin, end): out += M^T B M x, or with targets T the
 * right-hand side's share, out += M^T (B-weighted targets); the fold
 * barrier's pairs with them (in u's second half). */
ALWAYS_INLINE void normal_body(const void *context, const sample_blocks *B, int64_t begin, int64_t end, double *u,
                               double *out) {
    const normal_context *c = context;
    const fit_system *f = c->f;
    const int32_t per = B->per;
    double *gx = u + 3 * per;
    for (int64_t g = begin; g < end; ++g) {
        if (!block_pulls(f, g)) continue;
        if (!c->T) block_forward(B, g, c->x, u);
        const int barrier = f->bar && f->bar_start[g + 1] > f->bar_start[g];
        if (barrier) barrier_body(f, g, per, u, c->T != NULL, gx);
        for (int32_t s = 0; s < per; ++s) {
            const int64_t q = g * per + s;
            double v[3];
            if (c->T) {
                target_b(f, q, c->T + 3 * q, f->X + 3 * q, v);
            } else {
                const double in[3] = {u[s], u[per + s], u[2 * per + s]};
                apply_b(f, q, in, v);
            }
            if (barrier) v[0] += gx[3 * s], v[1] += gx[3 * s + 1], v[2] += gx[3 * s + 2];
            u[s] = v[0], u[per + s] = v[1], u[2 * per + s] = v[2];
        }
        block_backward(B, g, u, out);
    }
}

DEFINE_PIECE(normal_piece, normal_body)

/* Over blocks [begin, end): out (6 per column: xx, xy, xz, yy, yz, zz) +=
 * sum_s m_sj^2 B_s, the diagonal 3x3 blocks of M^T B M.  Each sample's
 * B_s first (6 values apart in u), then per column the squared weights
 * against them, four samples at a time. */
ALWAYS_INLINE void diagonal_body(const void *context, const sample_blocks *B, int64_t begin, int64_t end, double *u,
                                 double *out) {
    const fit_system *f = context;
    const int32_t per = B->per;
    const double al = f->alpha + f->beta, kp = 1.0 - f->beta;
    for (int64_t g = begin; g < end; ++g) {
        if (!block_pulls(f, g)) continue;
        for (int32_t s = 0; s < per; ++s) {
            const int64_t q = g * per + s;
            const double w = f->weight[q];
            const float *nn = f->normals + 3 * q;
            const double e[6] = {kp * nn[0] * nn[0] + al, kp * nn[0] * nn[1], kp * nn[0] * nn[2],
                                 kp * nn[1] * nn[1] + al, kp * nn[1] * nn[2], kp * nn[2] * nn[2] + al};
            for (int c = 0; c < 6; ++c) u[c * per + s] = w * e[c];
        }
        const int32_t *cols = B->cols + B->start[g];
        const int64_t width = block_width(B, g);
        const float *w = B->w + B->w_at[g];
        for (int64_t j = 0; j < width; ++j) {
            const float *col = w + per * j;
            v4d acc[6];
            for (int c = 0; c < 6; ++c) acc[c] = (v4d){0.0, 0.0, 0.0, 0.0};
            int32_t s = 0;
            for (; s + 4 <= per; s += 4) {
                v4d m;
                load4(&m, col + s);
                m *= m;
                for (int c = 0; c < 6; ++c) {
                    v4d e;
                    memcpy(&e, u + c * per + s, sizeof e);
                    acc[c] += m * e;
                }
            }
            for (; s < per; ++s) {
                const double m = (double)col[s] * col[s];
                for (int c = 0; c < 6; ++c) acc[c][0] += m * u[c * per + s];
            }
            double *a = out + 6 * (int64_t)cols[j];
            for (int c = 0; c < 6; ++c) a[c] += (acc[c][0] + acc[c][1]) + (acc[c][2] + acc[c][3]);
        }
    }
}

DEFINE_PIECE(diagonal_piece, diagonal_body)

/* y = A x, the normal-equation matrix: M^T B M x block by block, then the
 * fairness and the damping. */
static void system_apply(const fit_system *f, const double *x, double *y) {
    memset(y, 0, sizeof(double) * 3 * (size_t)f->n);
    normal_context c = {f, x, NULL};
    blocks_run(f->blocks, PIECE(f->blocks, normal_piece), &c, y, 3);
    if (f->lambda > 0.0) {
        fairness_add(f, x, 0, y);
    }
    for (int32_t v = 0; v < f->n; ++v)
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            y[i] = f->free_vertex[v] ? y[i] + f->damping * x[i] : 0.0;
        }
}

/* Inverse of a symmetric 3x3 matrix (xx, xy, xz, yy, yz, zz), as 9 entries;
 * falls back to the inverse diagonal when it is near singular. */
static void invert_sym3(const double a[6], double inv[9]) {
    const double c00 = a[3] * a[5] - a[4] * a[4], c01 = a[2] * a[4] - a[1] * a[5], c02 = a[1] * a[4] - a[2] * a[3];
    const double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
    const double scale = fabs(a[0]) + fabs(a[3]) + fabs(a[5]);
    memset(inv, 0, 9 * sizeof(double));
    if (!(fabs(det) > 1e-12 * scale * scale * scale)) {
        if (a[0] > 0.0) inv[0] = 1.0 / a[0];
        if (a[3] > 0.0) inv[4] = 1.0 / a[3];
        if (a[5] > 0.0) inv[8] = 1.0 / a[5];
        return;
    }
    const double c11 = a[0] * a[5] - a[2] * a[2], c12 = a[1] * a[2] - a[0] * a[4], c22 = a[0] * a[3] - a[1] * a[1];
    inv[0] = c00 / det, inv[1] = c01 / det, inv[2] = c02 / det;
    inv[3] = c01 / det, inv[4] = c11 / det, inv[5] = c12 / det;
    inv[6] = c02 / det, inv[7] = c12 / det, inv[8] = c22 / det;
}

/* z = P r with the 3x3 blocks of P (9 per vertex); returns z . r. */
static double precondition(int32_t n, const double *precond, const double *r, double *z) {
    double rz = 0.0;
    for (int32_t v = 0; v < n; ++v) {
        const double *P = precond + 9 * (int64_t)v, *rv = r + 3 * (int64_t)v;
        double *zv = z + 3 * (int64_t)v;
        for (int c = 0; c < 3; ++c) zv[c] = P[3 * c] * rv[0] + P[3 * c + 1] * rv[1] + P[3 * c + 2] * rv[2];
        rz += zv[0] * rv[0] + zv[1] * rv[1] + zv[2] * rv[2];
    }
    return rz;
}

/* One round: conjugate gradients on A V = b from the current V, with targets
 * T (S * 3 floats).  `work` holds 5 * 3n doubles, `precond` 9n. */
static int least_squares_round(fit_system *f, const float *T, const double *V0, double *V, int iterations,
                               double *work, double *precond, fit_clock *clock) {
    const int64_t N3 = 3 * (int64_t)f->n;
    double *b = work, *r = work + N3, *z = work + 2 * N3, *p = work + 3 * N3, *Ap = work + 4 * N3;
    /* b = M^T B T + lambda Lap^T H Lap V0 + damping V (the damping anchors the
     * current iterate, so it does not bias the fit). */
    const sample_blocks *B = f->blocks;
    memset(b, 0, sizeof(double) * (size_t)N3);
    normal_context c = {f, NULL, T};
    blocks_run(B, PIECE(B, normal_piece), &c, b, 3);
    if (f->lambda > 0.0) {
        fairness_add(f, V0, 1, b);
    }
    for (int64_t i = 0; i < N3; ++i) b[i] += f->damping * V[i];

    /* Block-Jacobi preconditioner: sum_s m_si^2 B_s + lambda (Lap^T Lap)_ii + damping. */
    double *diag = f->tmp_diag;
    memset(diag, 0, sizeof(double) * 6 * (size_t)f->n);
    blocks_run(B, PIECE(B, diagonal_piece), f, diag, 6);
    for (int32_t v = 0; v < f->n; ++v) {
        double *a = diag + 6 * (int64_t)v;
        const int64_t na = f->nb_start[v], nb = f->nb_start[v + 1];
        double lap = 0.0; /* (Lap^T C Lap)_vv */
        if (nb > na) {
            lap = stiffness(f, v);
            for (int64_t k = na; k < nb; ++k) {
                const int32_t j = f->nb[k];
                const double deg = (double)(f->nb_start[j + 1] - f->nb_start[j]);
                lap += stiffness(f, j) / (deg * deg);
            }
        }
        const double d = f->lambda * lap + f->damping;
        a[0] += d, a[3] += d, a[5] += d;
        if (f->free_vertex[v])
            invert_sym3(a, precond + 9 * (int64_t)v);
        else
            memset(precond + 9 * (int64_t)v, 0, 9 * sizeof(double));
    }

    system_apply(f, V, Ap);
    for (int64_t i = 0; i < N3; ++i) r[i] = f->free_vertex[i / 3] ? b[i] - Ap[i] : 0.0;
    double rz = precondition(f->n, precond, r, z);
    memcpy(p, z, sizeof(double) * (size_t)N3);
    const double rz0 = rz;
    int it = 0;
    for (; it < iterations && rz > CG_TOLERANCE * CG_TOLERANCE * rz0 && rz > 0.0 && !clock_tick(clock); ++it) {
        system_apply(f, p, Ap);
        double pAp = 0.0;
        for (int64_t i = 0; i < N3; ++i) pAp += p[i] * Ap[i];
        if (!(pAp > 0.0)) break;
        const double alpha = rz / pAp;
        for (int64_t i = 0; i < N3; ++i) {
            V[i] += alpha * p[i];
            r[i] -= alpha * Ap[i];
        }
        const double rz_new = precondition(f->n, precond, r, z);
        const double beta = rz_new / rz;
        rz = rz_new;
        for (int64_t i = 0; i < N3; ++i) p[i] = z[i] + beta * p[i];
    }
    return it;
}

/* ---- the entry point -------------------------------------------------------- */

typedef struct fit_buffers {
    spia_stencils *L;
    sample_blocks blocks;
    double *V0, *V, *best, *X, *work, *precond, *tmp_n, *tmp_diag;
    int32_t *near; /* S: each sample's scan triangle of the last query, or -1 */
    int evaluated;
    float *T, *N, *d, *scratch, *targets, *solved, *wts;
    uint8_t *on_boundary;
    int64_t *nb_start;
    int32_t *nb;
    unsigned char *free_vertex;
    int32_t *sample_face;
    /* The fold guard: per sample the normal agreement and whether it is
     * folded; per vertex the stiffness and a mark. */
    float *dots, *start_n; /* start_n: start_normals, S * 3 (with the fold guard) */
    float *start_len;      /* per sample, the starting cage's grid differences' lengths along u and v */
    uint8_t *folded, *mark;
    double *hold, *smooth;
    fold_pair *bar; /* the fold barrier's pairs (bar_capacity of them), by block from bar_start */
    int64_t bar_capacity, *bar_start;
    /* The scan side: the limit surface as a quad grid (its points' blocks,
     * their positions, its quads and their sizes, all 4), and the scan
     * vertices measured, in double. */
    sample_blocks grid;
    int32_t grid_vertices, grid_faces, grid_side;
    /* A grid of more than SCAN_GRID_FACES quads is searched through its
     * ptex faces' corners (coarse_pos, grid_quads one quad a ptex face),
     * then within the closest one's own quads (scan_face). */
    int coarse;
    spia_scan *surface; /* the grid as a scan: built by the first measure, moved by later ones */
    float *grid_pos, *coarse_pos, *scan_d, *scan_scratch;
    int32_t *grid_sizes, *grid_quads, *scan_vertex, *scan_near, *scan_face;
    double *scan_pts;
    int64_t scan_count;
    /* The scan's pull (SPIA_FIT_SCAN_PULL): the samples as the quads of
     * each ptex face's grid, as a scan to find each scan vertex's nearest
     * sample in; per sample the pull's weight and offset along the normal. */
    spia_scan *pull_surface;
    float *pull_pos, *pull_d;
    int32_t *pull_sizes, *pull_quads, *pull_near, *pull_faces;
    double *pull_w, *pull_off;
} fit_buffers;

static void buffers_free(fit_buffers *b) {
    blocks_free(&b->blocks);
    spia_stencils_free(b->L);
    free(b->V0), free(b->V), free(b->best), free(b->X), free(b->near), free(b->work), free(b->precond), free(b->tmp_diag);
    free(b->tmp_n), free(b->T), free(b->N), free(b->d), free(b->scratch), free(b->targets), free(b->solved);
    free(b->wts), free(b->on_boundary);
    free(b->nb_start), free(b->nb), free(b->free_vertex), free(b->sample_face);
    free(b->dots), free(b->start_n), free(b->start_len), free(b->folded), free(b->mark), free(b->hold), free(b->smooth), free(b->bar), free(b->bar_start);
    blocks_free(&b->grid);
    spia_scan_free(b->surface);
    free(b->grid_pos), free(b->scan_d), free(b->scan_scratch), free(b->grid_sizes);
    free(b->grid_quads), free(b->scan_vertex), free(b->coarse_pos), free(b->scan_face);
    free(b->scan_near);
    free(b->scan_pts);
    spia_scan_free(b->pull_surface);
    free(b->pull_pos), free(b->pull_d), free(b->pull_sizes), free(b->pull_quads), free(b->pull_near);
    free(b->pull_faces), free(b->pull_w), free(b->pull_off);
}

/* ---- folds ---------------------------------------------------------------- */

/* The neighbours of sample l (of k x k in rows) along u and v, a[m] minus
 * b[m] (central, one-sided at the grid's edges), and the differences D[m]
 * of their positions in X from the block at `base`. */
static void grid_differences(const double *X, int64_t base, int32_t l, int32_t k, int32_t a[2], int32_t b[2],
                             double D[2][3]) {
    const int32_t i = l % k, j = l / k;
    a[0] = j * k + (i < k - 1 ? i + 1 : i), b[0] = j * k + (i > 0 ? i - 1 : i);
    a[1] = (j < k - 1 ? j + 1 : j) * k + i, b[1] = (j > 0 ? j - 1 : j) * k + i;
    for (int m = 0; m < 2; ++m)
        for (int c = 0; c < 3; ++c) D[m][c] = X[3 * (base + a[m]) + c] - X[3 * (base + b[m]) + c];
}

/* Sample s's grid normal: the cross product of its neighbours' differences
 * along u and v (grid_differences), not normalised. */
static void grid_normal(const double *X, int64_t s, int32_t k, double n[3]) {
    const int64_t per_face = (int64_t)k * k;
    int32_t a[2], b[2];
    double D[2][3];
    grid_differences(X, s - s % per_face, (int32_t)(s % per_face), k, a, b, D);
    const double *du = D[0], *dv = D[1];
    n[0] = du[1] * dv[2] - du[2] * dv[1], n[1] = du[2] * dv[0] - du[0] * dv[2], n[2] = du[0] * dv[1] - du[1] * dv[0];
}

/* Per sample, the cosine between its limit normal and the scan's normal at
 * its closest point.  The normal is the cross product of the differences
 * to the neighbours along the ptex face's sample grid (grid_differences);
 * 0 where it or the scan's normal vanishes, and everywhere when the grid is
 * a single sample. */
static void normal_agreement(const double *X, const float *N, int64_t S, int32_t k, float *dots) {
    if (k < 2) {
        memset(dots, 0, sizeof(float) * (size_t)S);
        return;
    }
    for (int64_t s = 0; s < S; ++s) {
        double n[3];
        grid_normal(X, s, k, n);
        const float *m = N + 3 * s;
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const double mlen = sqrt((double)m[0] * m[0] + (double)m[1] * m[1] + (double)m[2] * m[2]);
        dots[s] = len > 0.0 && mlen > 0.0 ? (float)((n[0] * m[0] + n[1] * m[1] + n[2] * m[2]) / (len * mlen)) : 0.0f;
    }
}

/* Per sample, the unit normal of the starting cage's surface where it
 * faced the scan as the cage does (sign), else zero (see facing_start). */
static void start_normals(const double *X, const float *dots, int64_t S, int32_t k, int sign, float *out) {
    for (int64_t s = 0; s < S; ++s) {
        double n[3];
        grid_normal(X, s, k, n);
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const int keep = len > 0.0 && (double)sign * dots[s] > 0.0;
        for (int c = 0; c < 3; ++c) out[3 * s + c] = keep ? (float)(n[c] / len) : 0.0f;
    }
}

/* Lets go of the samples whose closest point lies on a part of the scan
 * facing against the starting cage's surface there (where that faced the
 * scan): the other side of a part thinner than the distance to it (a
 * blade, a finger), which would pull the sample through and turn the
 * surface over. */
static void facing_start(const float *start, const float *N, int64_t S, int sign, float *w) {
    for (int64_t s = 0; s < S; ++s) {
        const float *m = start + 3 * s, *n = N + 3 * s;
        if ((double)sign * ((double)m[0] * n[0] + (double)m[1] * n[1] + (double)m[2] * n[2]) < 0.0) w[s] = 0.0f;
    }
}

/* Whether samples that pull are counted facing along the scan's normals
 * (+1) or against them (-1): the cage's and the scan's orientation need
 * not agree, so the sign most of them agree on is the right one. */
static int orientation(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S, double cutoff_abs) {
    double sum = 0.0;
    for (int64_t s = 0; s < S; ++s)
        if (d[s] <= cutoff_abs && !on_boundary[s]) sum += dots[s];
    return sum < 0.0 ? -1 : 1;
}

/* Marks the folded samples (within the cut-off, not over a hole, facing
 * away); returns how many. */
static int64_t find_folds(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S, double cutoff_abs,
                          int sign, uint8_t *folded) {
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
static void stiffen(const spia_mesh *cage, const spia_adjacency *adj, const uint8_t *folded, const float *d,
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

/* The fold barrier: the guard above lets a folded sample go and stiffens
 * its face, but a pleat lying on the scan costs the samples around it
 * nothing (point-to-plane lets them slide), so it stays.  Its samples'
 * grid, though, is turned over: the difference D_u of a sample's
 * neighbours along u has a negative component along e_u = sign (D_v x N)
 * (N the scan's normal at its closest point), the direction D_u has on an
 * unfolded grid, and likewise D_v along e_v = sign (N x D_u).  Each round,
 * every pair whose component falls below FOLD_BARRIER_SHEAR of its length
 * gets the term FOLD_BARRIER_WEIGHT (e . D - t)^2, t that share of its
 * length, with e as the round starts (linear in the cage).  Only where
 * both samples lie on the scan, within FOLD_BARRIER_REACH times the
 * kernel's scale (at most the cut-off) and not over a hole: a sample
 * facing a scan part farther away (a base plate under a hole) is no
 * pleat, and turning it to that part's normal would pull the surface.
 *
 * Measured on bench_fit.py's four scans (share of Blender's level-3
 * points facing away; mean distance): the guard alone left 0.065%, 0.211%,
 * 0.269% and 0.204% (bunny, dragon, armadillo, Chinese dragon); with the
 * barrier 0.019%, 0.181%, 0.081% and 0.081%, the means within 0.6% except
 * the bunny's (+2.5%, from the surface over the scan's holes, which
 * reaches farther out: tests/python/test_fit_quality.py compares the
 * means off the rims).
 * Weights 0.005 to 0.03 and shares 0.45 to 0.6 gave 0.08% to 0.13% on the
 * two new scans; 0.1 and more fight the samples' pull (more folds).  A
 * reach of 4 left the armadillo 0.12%, 6 and 8 0.08%; at 16 the base plate
 * of test_a_base_plate_does_not_pull pulls the surface 25% off.  A barrier
 * without the guard left 0.16% to 0.36%; one only at samples facing more
 * than 60 degrees from the scan, or holding sheared pairs where they are
 * instead of pushing them to t, removed fewer. */
#define FOLD_BARRIER_WEIGHT 0.02
#define FOLD_BARRIER_SHEAR 0.5
#define FOLD_BARRIER_REACH 6.0

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
static int barrier_pairs(const double *X, const float *N, const float *d, const uint8_t *on_boundary, int64_t S,
                         int32_t k, int sign, double reach, const float *start_len, fold_pair **bar, int64_t *capacity,
                         int64_t *bar_start) {
    const int32_t per = k * k;
    int64_t count = 0;
    for (int64_t g = 0; g * per < S; ++g) {
        bar_start[g] = count;
        const int64_t base = g * per;
        int over_hole = 0;
        for (int32_t l = 0; l < per && !over_hole; ++l) over_hole = on_boundary[base + l];
        if (over_hole) continue;
        for (int32_t l = 0; l < per; ++l) {
            const int64_t q = base + l;
            if (!(d[q] <= reach)) continue;
            int32_t pa[2], pb[2];
            double D[2][3];
            grid_differences(X, base, l, k, pa, pb, D);
            const float *n = N + 3 * q;
            const double e[2][3] = {
                {D[1][1] * n[2] - D[1][2] * n[1], D[1][2] * n[0] - D[1][0] * n[2], D[1][0] * n[1] - D[1][1] * n[0]},
                {n[1] * D[0][2] - n[2] * D[0][1], n[2] * D[0][0] - n[0] * D[0][2], n[0] * D[0][1] - n[1] * D[0][0]}};
            for (int m = 0; m < 2; ++m) {
                if (!(d[base + pa[m]] <= reach) || !(d[base + pb[m]] <= reach)) continue;
                /* along = sign e . D / |e| below FOLD_BARRIER_SHEAR |D|, squared where it is positive */
                const double e2 = e[m][0] * e[m][0] + e[m][1] * e[m][1] + e[m][2] * e[m][2];
                const double d2 = D[m][0] * D[m][0] + D[m][1] * D[m][1] + D[m][2] * D[m][2];
                const double ed = (double)sign * (e[m][0] * D[m][0] + e[m][1] * D[m][1] + e[m][2] * D[m][2]);
                if (!(e2 > 0.0) || !(d2 > 0.0)) continue;
                const double least = start_len ? FOLD_BARRIER_COMPRESS * start_len[2 * q + m] : 0.0;
                if (ed > 0.0 && ed * ed >= FOLD_BARRIER_SHEAR * FOLD_BARRIER_SHEAR * e2 * d2 && d2 >= least * least)
                    continue;
                const double el = sqrt(e2), dl = sqrt(d2) > least / FOLD_BARRIER_SHEAR ? sqrt(d2) : least / FOLD_BARRIER_SHEAR;
                if (count == *capacity) {
                    const int64_t grown = *capacity > 0 ? 2 * *capacity : 4096;
                    fold_pair *more = realloc(*bar, sizeof(fold_pair) * (size_t)grown);
                    if (!more) return 1;
                    *bar = more, *capacity = grown;
                }
                fold_pair *p = *bar + count++;
                p->a = pa[m], p->b = pb[m];
                for (int c = 0; c < 3; ++c) p->e[c] = (float)((double)sign * e[m][c] / el);
                p->t = (float)(FOLD_BARRIER_SHEAR * dl);
            }
        }
    }
    bar_start[(S + per - 1) / per] = count;
    return 0;
}

/* ---- the scan side ------------------------------------------------------ */

static spia_result scan_side_cancelled(spia_status *status) {
    return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled measuring the scan's distances to the surface");
}

/* The scan vertices its faces use, in double, and the buffers of their
 * distances (once: the scan side's measure and the scan's pull share them). */
static spia_result scan_points_prepare(const spia_scan *scan, fit_buffers *b) {
    if (b->scan_pts) return SPIA_OK;
    int32_t scan_n = 0;
    const int32_t *original = NULL;
    const float *P = spia__scan_positions(scan, &scan_n, &original);
    uint8_t *used = malloc((size_t)scan_n + 1);
    if (!used) return SPIA_ERROR_OUT_OF_MEMORY;
    spia__scan_used_vertices(scan, used);
    int64_t count = 0;
    for (int32_t v = 0; v < scan_n; ++v) count += used[v];
    b->scan_count = count;
    b->scan_vertex = malloc(sizeof(int32_t) * (size_t)(count + 1));
    b->scan_pts = malloc(sizeof(double) * 3 * (size_t)(count + 1));
    b->scan_d = malloc(sizeof(float) * (size_t)(count + 1));
    b->scan_scratch = malloc(sizeof(float) * (size_t)(count + 1));
    b->scan_near = malloc(sizeof(int32_t) * (size_t)(count + 1));
    if (!b->scan_vertex || !b->scan_pts || !b->scan_d || !b->scan_scratch || !b->scan_near) {
        free(used);
        return SPIA_ERROR_OUT_OF_MEMORY;
    }
    int64_t k = 0;
    for (int32_t v = 0; v < scan_n; ++v)
        if (used[v]) {
            b->scan_vertex[k] = original ? original[v] : v;
            for (int c = 0; c < 3; ++c) b->scan_pts[3 * k + c] = P[3 * (int64_t)v + c];
            ++k;
        }
    free(used);
    return SPIA_OK;
}

/* The limit surface's grid and the scan vertices to measure.  The grid
 * has 2^levels quads along each edge of a ptex face, levels one more than
 * the samples' (ceil(log2 per_edge) + 1), so that its flat quads stay
 * within a sixteenth of a sample spacing's curvature sag of the surface,
 * and one fewer at a time while it would have more than SCAN_GRID_FACES
 * quads (at least one level).  Its points are limit points of the cage, in
 * blocks like the samples' (each ptex face's own, so the points along its
 * edges repeat those of its neighbour: the grid is not welded, which a
 * distance does not see), made face by face between progress calls; each
 * cage's grid is then one pass over them.  A grid still larger than
 * SCAN_GRID_FACES (a detail level's millions of faces) gets no hierarchy
 * of its own: the search runs over the ptex faces' corners, one quad a
 * face, and each scan vertex then takes its distance to the grid's quads
 * of the face it found (coarse_measure). */
#define SCAN_GRID_FACES (2 << 20)
static spia_result scan_side_prepare(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                     int32_t per_edge, const spia_scan *scan, fit_buffers *b, fit_clock *clock,
                                     spia_status *status) {
    int32_t levels = 1;
    while ((1 << levels) < per_edge) ++levels;
    ++levels;
    const int64_t ptex = spia_surface_sample_count(cage, 1);
    while (levels > 1 && (ptex << (2 * levels)) > SCAN_GRID_FACES) --levels;
    const int32_t side = (1 << levels) + 1; /* points along a ptex face's edge */
    if (ptex * side * side > INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "the cage has too many faces (%lld ptex faces) to measure the scan's distances to its "
                          "surface; leave that measure out (SPIA_FIT_NO_SCAN_DISTANCES)",
                          (long long)ptex);
    spia_result r = blocks_build(cage, adj, opt, side, 1, &b->grid, clock, status);
    if (r != SPIA_OK) return r == SPIA_ERROR_CANCELLED ? scan_side_cancelled(status) : r;
    if (clock_tick(clock)) return scan_side_cancelled(status);
    const int32_t gv = (int32_t)(ptex * side * side);
    b->coarse = (ptex << (2 * levels)) > SCAN_GRID_FACES;
    /* The quads searched: the grid's, or one a ptex face through its corners. */
    const int32_t gf = (int32_t)(b->coarse ? ptex : ptex << (2 * levels));
    const int32_t cells = b->coarse ? 1 : side - 1, row = b->coarse ? 2 : side;
    b->grid_vertices = gv, b->grid_faces = gf, b->grid_side = side;
    b->grid_quads = malloc(sizeof(int32_t) * 4 * (size_t)gf);
    if (!b->grid_quads) return SPIA_ERROR_OUT_OF_MEMORY;
    {
        int32_t *q = b->grid_quads;
        for (int64_t g = 0; g < ptex; ++g)
            for (int32_t j = 0; j < cells; ++j)
                for (int32_t i = 0; i < cells; ++i) {
                    const int32_t v = (int32_t)(g * row * row) + j * row + i;
                    q[0] = v, q[1] = v + 1, q[2] = v + row + 1, q[3] = v + row;
                    q += 4;
                }
    }
    b->grid_pos = malloc(sizeof(float) * 3 * (size_t)(gv > 0 ? gv : 1));
    b->grid_sizes = malloc(sizeof(int32_t) * (size_t)(gf > 0 ? gf : 1));
    if (!b->grid_pos || !b->grid_sizes) return SPIA_ERROR_OUT_OF_MEMORY;
    for (int32_t f = 0; f < gf; ++f) b->grid_sizes[f] = 4;
    if (b->coarse) {
        b->coarse_pos = malloc(sizeof(float) * 12 * (size_t)(ptex > 0 ? ptex : 1));
        if (!b->coarse_pos) return SPIA_ERROR_OUT_OF_MEMORY;
    }
    const spia_result r2 = scan_points_prepare(scan, b);
    if (r2 != SPIA_OK || !b->coarse) return r2;
    b->scan_face = malloc(sizeof(int32_t) * (size_t)(b->scan_count + 1));
    return b->scan_face ? SPIA_OK : SPIA_ERROR_OUT_OF_MEMORY;
}

/* The corners of each ptex face's grid, the coarse search's quads. */
static void coarse_corners(fit_buffers *b) {
    const int64_t side = b->grid_side, per = side * side;
    const int64_t corner[4] = {0, side - 1, per - side, per - 1}; /* in grid_quads' order: (0,0) (1,0) (0,1) (1,1) */
    for (int64_t g = 0; g < b->grid_faces; ++g)
        for (int c = 0; c < 4; ++c)
            memcpy(b->coarse_pos + 12 * g + 3 * c, b->grid_pos + 3 * (g * per + corner[c]), sizeof(float) * 3);
}

/* Each scan vertex's distance to the grid's quads of the ptex face its
 * coarse search found (each quad as the scan triangulates it, across its
 * first corner). */
static void coarse_range(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const fit_buffers *b = (const fit_buffers *)context;
    const int32_t side = b->grid_side;
    for (int64_t k = begin; k < end; ++k) {
        const int64_t g = b->scan_face[k];
        if (g < 0) continue;
        const float *P = b->grid_pos + 3 * g * side * side;
        double best = INFINITY, bary[3], point[3];
        for (int32_t j = 0; j + 1 < side; ++j)
            for (int32_t i = 0; i + 1 < side; ++i) {
                const float *q0 = P + 3 * (j * side + i), *q1 = q0 + 3, *q3 = q0 + 3 * side, *q2 = q3 + 3;
                const double d0 = spia__triangle_distance2(b->scan_pts + 3 * k, q0, q1, q2, bary, point);
                const double d1 = spia__triangle_distance2(b->scan_pts + 3 * k, q0, q2, q3, bary, point);
                if (d0 < best) best = d0;
                if (d1 < best) best = d1;
            }
        b->scan_d[k] = (float)sqrt(best);
    }
}

/* The distances of the scan vertices to the limit surface of cage V.  The
 * first measure builds the grid's hierarchy and keeps each vertex's closest
 * grid triangle; a later one moves the grid (refitting the hierarchy: on
 * the 50k-vertex cage's 0.8M quads a build took 0.38 to 0.43 s, a move
 * 0.04) and starts each search from that triangle on the new surface. */
static spia_result scan_side_measure(fit_buffers *b, const double *V, double cutoff_abs, double diagonal, int threads,
                                     int warm, fit_clock *clock, spia_fit_distances *out, spia_status *status) {
    spia_result r;
    blocks_apply_float(&b->grid, V, b->grid_pos);
    if (b->coarse) coarse_corners(b);
    if (clock_tick(clock)) return scan_side_cancelled(status);
    if (!warm)
        for (int64_t k = 0; k < b->scan_count; ++k) b->scan_near[k] = -1;
    float *searched = b->coarse ? b->coarse_pos : b->grid_pos;
    if (!b->surface) {
        spia_mesh view;
        memset(&view, 0, sizeof view);
        view.vertex_count = b->coarse ? 4 * b->grid_faces : b->grid_vertices;
        view.positions = searched;
        view.face_count = b->grid_faces;
        view.face_sizes = b->grid_sizes;
        view.face_vertices = b->grid_quads;
        r = spia__scan_create_bare(&view, clock->fn ? clock_scan_tick : NULL, clock, &b->surface, status);
        if (r != SPIA_OK) return r == SPIA_ERROR_CANCELLED ? scan_side_cancelled(status) : r;
    } else if ((r = spia__scan_move(b->surface, searched)) != SPIA_OK) {
        return spia__fail(status, r, -1, "%s moving the surface's grid to the fitted cage",
                          r == SPIA_ERROR_NONFINITE ? "non-finite positions" : "out of memory");
    }
    const int cancelled = clock_tick(clock) ||
                          closest_in_chunks(b->surface, b->scan_count, b->scan_pts, b->scan_near, NULL, NULL,
                                            b->scan_d, b->scan_face, NULL, threads, clock);
    if (cancelled) return scan_side_cancelled(status);
    if (b->coarse) spia__parallel_for(threads, b->scan_count, 4096, coarse_range, b);
    *out = distance_stats(b->scan_d, b->scan_count, cutoff_abs, diagonal, b->scan_scratch);
    return SPIA_OK;
}

/* The umbrella neighbours of every vertex, from the faces. */
static spia_result build_neighbours(const spia_mesh *mesh, const spia_adjacency *adj, fit_buffers *b) {
    const int32_t n = mesh->vertex_count;
    const int32_t cap = 2 * spia__max_corners_per_vertex(adj) + 2;
    int32_t *nb = malloc(sizeof(int32_t) * (size_t)cap), *faces_on = malloc(sizeof(int32_t) * (size_t)cap);
    b->nb_start = malloc(sizeof(int64_t) * ((size_t)n + 1));
    b->nb = malloc(sizeof(int32_t) * (size_t)(2 * adj->corner_count + 1));
    b->free_vertex = malloc((size_t)n + 1);
    if (!nb || !faces_on || !b->nb_start || !b->nb || !b->free_vertex) {
        free(nb), free(faces_on);
        return SPIA_ERROR_OUT_OF_MEMORY;
    }
    int64_t k = 0;
    for (int32_t v = 0; v < n; ++v) {
        b->nb_start[v] = k;
        b->free_vertex[v] = adj->first[v + 1] > adj->first[v];
        const int32_t count = spia__vertex_neighbours(mesh, adj, v, nb, faces_on, cap);
        for (int32_t i = 0; i < count && i < cap; ++i) b->nb[k++] = nb[i];
    }
    b->nb_start[n] = k;
    free(nb), free(faces_on);
    return SPIA_OK;
}

/* Sample -> face, from the ptex layout. */
static spia_result build_sample_faces(const spia_mesh *mesh, int32_t per_edge, int64_t S, fit_buffers *b) {
    b->sample_face = malloc(sizeof(int32_t) * (size_t)(S > 0 ? S : 1));
    if (!b->sample_face) return SPIA_ERROR_OUT_OF_MEMORY;
    int64_t s = 0;
    const int64_t per_ptex = (int64_t)per_edge * per_edge;
    for (int32_t f = 0; f < mesh->face_count; ++f)
        for (int64_t k = 0; k < spia__ptex_of_face(mesh->face_sizes[f]) * per_ptex && s < S; ++k) b->sample_face[s++] = f;
    return s == S ? SPIA_OK : SPIA_ERROR_INTERNAL;
}

/* Samples of the cage V and their closest points.  After the first call,
 * each search starts from the bound "previous distance + how far the sample
 * moved", which prunes most of the scan's hierarchy. */
static spia_result nothing_to_fit(spia_status *status, const char *what, double cutoff) {
    return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                      "no %s lies within the cut-off (%g of the scan's diagonal) of the scan, so there is "
                      "nothing to fit: check that the cage lies on the scan, or raise the cut-off",
                      what, cutoff);
}

static int evaluate(const spia_scan *scan, fit_buffers *b, const double *V, int64_t S, int threads,
                    double *query_seconds, fit_clock *clock) {
    const double t0 = spia__now();
    blocks_apply(&b->blocks, V, b->X);
    if (!b->evaluated)
        for (int64_t s = 0; s < S; ++s) b->near[s] = -1;
    const int cancelled = closest_in_chunks(scan, S, b->X, b->near, b->T, b->N, b->d, NULL,
                                            b->on_boundary, threads, clock);
    b->evaluated = 1;
    *query_seconds += spia__now() - t0;
    return cancelled;
}

/* What the stages of a fit share: the arguments resolved, the buffers and
 * the progress clock. */
typedef struct fit_run {
    const spia_mesh *cage;
    const spia_scan *scan;
    spia_options opt;
    spia_options surface_opt; /* opt for Catmull-Clark: the samples' and the grid's */
    spia_fit_options fo;
    spia_fit_report *report;
    spia_status *status;
    fit_buffers b;
    spia_adjacency adj;
    fit_clock clock;
    int32_t n;
    int64_t N3, S;
    double diagonal, cutoff_abs;
    int sign;          /* see orientation */
    double kernel_scale; /* the round's robust kernel scale (round_weights) */
    int measured_best; /* the samples' last measure is of the best cage */
    /* The samples serve the report in both modes; for Loop and Doo-Sabin
     * (VERTICES only) there are none, and the limit points are measured. */
    int surface_samples;
} fit_run;

static spia_result fit_oom(fit_run *u) {
    return spia__fail(u->status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory fitting the cage");
}

static spia_result fit_cancelled(fit_run *u) {
    return spia__fail(u->status, SPIA_ERROR_CANCELLED, -1, "cancelled during fitting round %d", u->clock.round + 1);
}

/* Every field of the report but the caller's buffers starts afresh. */
static void report_start(spia_fit_report *report) {
    spia_fit_report fresh;
    memset(&fresh, 0, sizeof fresh);
    fresh.vertex_distances = report->vertex_distances;
    fresh.history = report->history;
    fresh.history_capacity = report->history_capacity;
    fresh.scan_distances = report->scan_distances;
    *report = fresh;
}

/* The arguments checked and the options resolved into u (report->result
 * set where the check follows the options). */
static spia_result fit_arguments(const spia_mesh *cage, const spia_scan *scan, const spia_options *options,
                                 const spia_fit_options *fit_options, const float *cage_out, fit_run *u) {
    spia_status *status = u->status;
    spia_fit_report *report = u->report;
    if (!scan) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the scan must not be NULL");
    if (!cage_out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "cage_out must not be NULL");
    spia_result r = spia__resolve_options(options, &u->opt, status);
    if (r != SPIA_OK) return r;
    u->opt.initial_cage = NULL; /* each round's solve starts from its own targets */
    if ((r = resolve_fit(fit_options, &u->fo, status)) != SPIA_OK) return report->result = r;
    report->mode = u->fo.mode;
    if (u->fo.mode == SPIA_FIT_SURFACE && u->opt.scheme != SPIA_SCHEME_CATMULL_CLARK)
        return report->result = spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                                           "fitting the surface is available for Catmull-Clark only; "
                                           "use the VERTICES fit for Loop and Doo-Sabin");
    if ((r = spia_mesh_validate(cage, status)) != SPIA_OK) return report->result = r;
    if (u->opt.scheme == SPIA_SCHEME_LOOP && (r = spia__require_triangles(cage, status)) != SPIA_OK)
        return report->result = r;
    return SPIA_OK;
}

/* Sampling: the sample stencils (Catmull-Clark), and the cage given as the
 * first iterate and the best so far. */
static spia_result sample_surface(fit_run *u) {
    fit_buffers *b = &u->b;
    const double t0 = spia__now();
    if (u->surface_samples) {
        const spia_result r = blocks_build(u->cage, &u->adj, &u->surface_opt, u->fo.samples_per_edge, 0, &b->blocks,
                                           &u->clock, u->status);
        if (r != SPIA_OK) return r;
        u->S = b->blocks.groups * b->blocks.per;
    }
    u->report->sample_count = u->S;
    u->report->stencil_seconds += spia__now() - t0;

    const int64_t N3 = u->N3;
    b->V0 = malloc(sizeof(double) * (size_t)N3);
    b->V = malloc(sizeof(double) * (size_t)N3);
    b->best = malloc(sizeof(double) * (size_t)N3);
    if (!b->V0 || !b->V || !b->best) return fit_oom(u);
    for (int64_t i = 0; i < N3; ++i) b->V0[i] = b->V[i] = b->best[i] = u->cage->positions[i];
    return SPIA_OK;
}

/* The scan's vertices measured against the cage given's surface (see
 * scan_side_prepare). */
static spia_result measure_scan_given(fit_run *u) {
    fit_buffers *b = &u->b;
    const double t0 = spia__now();
    spia_result r = scan_side_prepare(u->cage, &u->adj, &u->surface_opt, u->fo.samples_per_edge, u->scan, b,
                                      &u->clock, u->status);
    if (r != SPIA_OK) return r == SPIA_ERROR_OUT_OF_MEMORY ? fit_oom(u) : r;
    if ((r = scan_side_measure(b, b->V0, u->cutoff_abs, u->diagonal, u->opt.threads, 0, &u->clock,
                               &u->report->scan_before, u->status)) != SPIA_OK)
        return r;
    u->report->scan_point_count = b->scan_count;
    u->report->query_seconds += spia__now() - t0;
    return SPIA_OK;
}

/* Closest points of the cage given's samples: its distances, folds and
 * orientation, and the scan side's first measure. */
static spia_result measure_given(fit_run *u) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const int64_t S = u->S;
    b->X = malloc(sizeof(double) * 3 * (size_t)S);
    b->T = malloc(sizeof(float) * 3 * (size_t)S);
    b->N = malloc(sizeof(float) * 3 * (size_t)S);
    b->d = malloc(sizeof(float) * (size_t)S);
    b->scratch = malloc(sizeof(float) * (size_t)S);
    b->on_boundary = malloc((size_t)S);
    b->near = malloc(sizeof(int32_t) * (size_t)S);
    if (!b->X || !b->T || !b->N || !b->d || !b->scratch || !b->on_boundary || !b->near) return fit_oom(u);
    spia_result r = build_sample_faces(u->cage, u->fo.samples_per_edge, S, b);
    if (r != SPIA_OK) {
        if (r == SPIA_ERROR_OUT_OF_MEMORY) return fit_oom(u);
        return spia__fail(u->status, SPIA_ERROR_INTERNAL, -1, "the samples do not match the cage's faces");
    }
    if (evaluate(u->scan, b, b->V, S, u->opt.threads, &report->query_seconds, &u->clock)) return fit_cancelled(u);
    report->before = distance_stats(b->d, S, u->cutoff_abs, u->diagonal, b->scratch);
    u->measured_best = 1;
    u->clock.mean = report->before.mean;
    if (report->before.ignored >= S) return nothing_to_fit(u->status, "sample of the cage's limit surface", u->fo.cutoff);
    b->dots = malloc(sizeof(float) * (size_t)S);
    b->folded = malloc((size_t)S);
    if (!b->dots || !b->folded) return fit_oom(u);
    normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots);
    u->sign = orientation(b->dots, b->d, b->on_boundary, S, u->cutoff_abs);
    report->folded_before = find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
    if (u->fo.samples_per_edge < 2) report->folded_before = -1;
    if (u->fo.samples_per_edge >= 2 && !(u->fo.flags & SPIA_FIT_ALLOW_FOLDS)) {
        b->start_n = malloc(sizeof(float) * 3 * (size_t)S);
        if (!b->start_n) return fit_oom(u);
        start_normals(b->X, b->dots, S, u->fo.samples_per_edge, u->sign, b->start_n);
        b->start_len = malloc(sizeof(float) * 2 * (size_t)S);
        if (!b->start_len) return fit_oom(u);
        const int64_t per_face = (int64_t)u->fo.samples_per_edge * u->fo.samples_per_edge;
        for (int64_t q = 0; q < S; ++q) {
            int32_t pa[2], pb[2];
            double D[2][3];
            grid_differences(b->X, q - q % per_face, (int32_t)(q % per_face), u->fo.samples_per_edge, pa, pb, D);
            for (int m = 0; m < 2; ++m)
                b->start_len[2 * q + m] = (float)sqrt(D[m][0] * D[m][0] + D[m][1] * D[m][1] + D[m][2] * D[m][2]);
        }
    }
    if (!(u->fo.flags & SPIA_FIT_NO_SCAN_DISTANCES)) return measure_scan_given(u);
    return SPIA_OK;
}

/* VERTICES: the targets, each limit point's closest scan point (within the
 * cut-off, not on the scan's boundary; else the limit point itself). */
static spia_result vertex_targets(fit_run *u) {
    fit_buffers *b = &u->b;
    const int32_t n = u->n;
    const int64_t N3 = u->N3;
    double *Y = malloc(sizeof(double) * (size_t)N3);
    b->targets = malloc(sizeof(float) * (size_t)N3);
    b->solved = malloc(sizeof(float) * (size_t)N3);
    float *closest = malloc(sizeof(float) * (size_t)N3), *dist = malloc(sizeof(float) * (size_t)(n + 1));
    uint8_t *edge = malloc((size_t)n + 1);
    if (!Y || !b->targets || !b->solved || !closest || !dist || !edge) {
        free(Y), free(closest), free(dist), free(edge);
        return fit_oom(u);
    }
    const double t0 = spia__now();
    spia_stencils_apply(b->L, b->V0, Y);
    spia__scan_closest_points_double(u->scan, n, Y, NULL, closest, NULL, dist, NULL, edge, u->opt.threads);
    u->report->query_seconds += spia__now() - t0;
    int32_t pulled = 0;
    for (int32_t v = 0; v < n; ++v) {
        const int keep = u->adj.first[v + 1] == u->adj.first[v] || dist[v] > u->cutoff_abs || edge[v];
        pulled += !keep;
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            b->targets[i] = keep ? (float)Y[i] : closest[i];
        }
    }
    if (!pulled) {
        free(Y), free(closest), free(dist), free(edge);
        return nothing_to_fit(u->status, "limit point of the cage", u->fo.cutoff);
    }
    if (!u->surface_samples) { /* Loop, Doo-Sabin: the limit points are what is measured */
        float *scratch = malloc(sizeof(float) * (size_t)(n + 1));
        if (!scratch) {
            free(Y), free(closest), free(dist), free(edge);
            return fit_oom(u);
        }
        u->report->before = distance_stats(dist, n, u->cutoff_abs, u->diagonal, scratch);
        free(scratch);
    }
    free(Y), free(closest), free(dist), free(edge);
    return SPIA_OK;
}

/* VERTICES: the cage interpolating the targets; returns the solve's result
 * (SPIA_MAX_ITERATIONS and SPIA_STAGNATED go on to the report). */
static spia_result fit_vertices(fit_run *u) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    double t0 = spia__now();
    spia_result r = spia_limit_stencils_create(u->cage, &u->opt, &b->L, u->status);
    report->stencil_seconds += spia__now() - t0;
    if (r != SPIA_OK) return r;
    if ((r = vertex_targets(u)) != SPIA_OK) return r;
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    t0 = spia__now();
    spia_options solve_opt = u->opt;
    if (u->opt.progress) solve_opt.progress = clock_forward, solve_opt.progress_user_data = &u->clock;
    r = spia_solve(b->L, b->targets, &solve_opt, b->solved, &rep, u->status);
    report->solve_seconds += spia__now() - t0;
    report->iterations = rep.iterations;
    report->max_error_relative = rep.max_error_relative;
    if (r < 0) return r;
    /* Vertices no face uses stay where they are (the solve keeps their
     * limit points, which loose edges tie to moving vertices). */
    for (int32_t v = 0; v < u->n; ++v)
        for (int c = 0; c < 3; ++c) {
            const int64_t i = 3 * (int64_t)v + c;
            b->best[i] = u->adj.first[v + 1] > u->adj.first[v] ? (double)b->solved[i] : b->V0[i];
        }
    u->measured_best = 0;
    report->rounds = 1;
    return r;
}

/* The fold guard's rims: the vertices of every face with a vertex on the
 * cage's boundary start with their smoothing s_i at RIM_SMOOTHING.  A rim
 * has samples on one side only to hold it, and there the fit curled it
 * over onto the scan.  Measured with bench/bench_fit_folds.py (level-3
 * points turned against the starting cage where it faced the scan and now
 * facing away from the scan or off it; mean distance): on the elephant's
 * cage (1,218 boundary edges) 0.684% -> 0.101%, mean -0.9%; the dragon's
 * (392) 0.005% -> 0.001% (all turned points 0.104% -> 0.094%), mean +0.5%;
 * the bunny's (40) 0.002% -> 0.004%, mean +0.5%.  3 left the elephant at
 * 0.336% and the dragon's turned points at 0.108%; 30 cost the bunny and
 * the dragon 4% of their mean for the elephant's 0.094%.  Closed cages are
 * untouched.  Detail levels leave their rims free (SPIA_FIT_FREE_RIMS):
 * held, they left the scan 4 to 5% farther from the bunny's and dragon's
 * finest levels (the elephant's 5%) for no fewer folds. */
#define RIM_SMOOTHING 10.0
static spia_result rim_smoothing(const fit_run *u, double *smooth) {
    const spia_mesh *cage = u->cage;
    const int32_t n = cage->vertex_count;
    unsigned char *boundary = malloc((size_t)n + 1), *rim = calloc((size_t)n + 1, 1);
    spia_result r = boundary && rim ? spia__boundary_vertices(cage, &u->adj, boundary, u->opt.threads)
                                    : SPIA_ERROR_OUT_OF_MEMORY;
    if (r == SPIA_OK)
        for (int32_t f = 0; f < cage->face_count; ++f) {
            const int64_t a = u->adj.corner_start[f], b = u->adj.corner_start[f + 1];
            int touches = 0;
            for (int64_t c = a; c < b; ++c) touches |= boundary[cage->face_vertices[c]];
            if (touches)
                for (int64_t c = a; c < b; ++c) rim[cage->face_vertices[c]] = 1;
        }
    if (r == SPIA_OK)
        for (int32_t v = 0; v < n; ++v)
            if (rim[v]) smooth[v] = RIM_SMOOTHING;
    free(boundary), free(rim);
    return r;
}

/* SURFACE: the buffers of the rounds and the system f they solve. */
static spia_result surface_system(fit_run *u, int guard, fit_system *f) {
    fit_buffers *b = &u->b;
    const int32_t n = u->n;
    const int64_t N3 = u->N3, S = u->S;
    b->work = malloc(sizeof(double) * 5 * (size_t)N3);
    b->precond = malloc(sizeof(double) * 9 * (size_t)n);
    b->tmp_n = malloc(sizeof(double) * (size_t)N3);
    b->tmp_diag = malloc(sizeof(double) * 6 * (size_t)(n > 0 ? n : 1));
    b->wts = malloc(sizeof(float) * (size_t)S);
    b->hold = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    b->smooth = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    b->mark = malloc((size_t)n + 1);
    if (!b->work || !b->precond || !b->tmp_n || !b->tmp_diag || !b->wts || !b->hold || !b->smooth || !b->mark)
        return fit_oom(u);
    for (int32_t v = 0; v < n; ++v) b->hold[v] = b->smooth[v] = 1.0;
    if (guard && !(u->fo.flags & SPIA_FIT_FREE_RIMS) && rim_smoothing(u, b->smooth) != SPIA_OK) return fit_oom(u);
    if (build_neighbours(u->cage, &u->adj, b) != SPIA_OK) return fit_oom(u);
    int64_t counted = S - u->report->before.ignored;
    int32_t free_count = 0;
    for (int32_t v = 0; v < n; ++v) free_count += b->free_vertex[v];
    f->blocks = &b->blocks, f->n = n, f->S = S, f->normals = b->N, f->dist = b->d, f->weight = b->wts;
    f->on_boundary = b->on_boundary, f->cutoff_abs = u->cutoff_abs;
    f->alpha = u->fo.point_weight;
    f->beta = u->fo.slide_weight;
    f->X = b->X;
    f->bar = NULL, f->bar_start = NULL, f->bar_weight = FOLD_BARRIER_WEIGHT;
    if (guard) {
        b->bar_start = malloc(sizeof(int64_t) * ((size_t)b->blocks.groups + 1));
        if (!b->bar_start) return fit_oom(u);
    }
    f->lambda = u->fo.smoothing * (double)(counted > 0 ? counted : S) / (double)(free_count > 0 ? free_count : 1);
    /* A whisper of damping towards the current iterate keeps vertices no
     * sample reaches (and global drift) determined. */
    f->damping = 1e-6 * (1.0 + f->lambda) * (double)S / (double)(free_count > 0 ? free_count : 1);
    f->nb_start = b->nb_start, f->nb = b->nb, f->free_vertex = b->free_vertex;
    f->hold = b->hold, f->smooth = b->smooth;
    f->tmp_n = b->tmp_n, f->tmp_diag = b->tmp_diag;
    return SPIA_OK;
}

/* A round's weights: the cut-off's and the robust kernel's, and with the
 * fold guard the folded samples let go, their faces stiffened and the
 * barrier's pairs. */
static spia_result round_weights(fit_run *u, int guard, fit_system *f) {
    fit_buffers *b = &u->b;
    const int64_t S = u->S;
    cutoff_weights(b->d, b->on_boundary, S, u->cutoff_abs, b->wts);
    const double kernel_scale = u->fo.robust_scale * median_pulling(b->d, b->wts, S, b->scratch);
    u->kernel_scale = kernel_scale;
    if (!(u->fo.flags & SPIA_FIT_HARD_CUTOFF)) robust_weights(b->d, S, kernel_scale, b->wts);
    if (guard) {
        for (int64_t q = 0; q < S; ++q)
            if (b->folded[q]) b->wts[q] = 0.0f;
        if (b->start_n) facing_start(b->start_n, b->N, S, u->sign, b->wts);
        stiffen(u->cage, &u->adj, b->folded, b->d, kernel_scale, b->sample_face, S, b->mark, b->hold, b->smooth);
        const double reach = FOLD_BARRIER_REACH * kernel_scale < u->cutoff_abs ? FOLD_BARRIER_REACH * kernel_scale
                                                                               : u->cutoff_abs;
        if (barrier_pairs(b->X, b->N, b->d, b->on_boundary, S, u->fo.samples_per_edge, u->sign, reach, b->start_len, &b->bar,
                          &b->bar_capacity, b->bar_start))
            return fit_oom(u);
        f->bar = b->bar, f->bar_start = b->bar_start;
    }
    return SPIA_OK;
}

/* The scan's pull weighs its vertices as a whole like the samples as a whole
 * (each vertex by the samples per pulling scan vertex), within these bounds. */
#define SCAN_PULL_MIN_RATIO 1.0
#define SCAN_PULL_MAX_RATIO 64.0

static spia_result scan_pull_prepare(fit_run *u) {
    fit_buffers *b = &u->b;
    const int64_t S = u->S, k = u->fo.samples_per_edge;
    if (scan_points_prepare(u->scan, b) != SPIA_OK) return fit_oom(u);
    const int64_t ptex = S / (k * k), quads = ptex * (k - 1) * (k - 1);
    if (quads > INT32_MAX || S > INT32_MAX)
        return spia__fail(u->status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "too many samples (%lld) for the scan's pull", (long long)S);
    const int64_t n = b->scan_count + 1;
    b->pull_quads = malloc(sizeof(int32_t) * 4 * (size_t)(quads + 1));
    b->pull_sizes = malloc(sizeof(int32_t) * (size_t)(quads + 1));
    b->pull_pos = malloc(sizeof(float) * 3 * (size_t)S);
    b->pull_near = malloc(sizeof(int32_t) * (size_t)n);
    b->pull_faces = malloc(sizeof(int32_t) * (size_t)n);
    b->pull_d = malloc(sizeof(float) * (size_t)n);
    b->pull_w = malloc(sizeof(double) * (size_t)S);
    b->pull_off = malloc(sizeof(double) * (size_t)S);
    if (!b->pull_quads || !b->pull_sizes || !b->pull_pos || !b->pull_near || !b->pull_faces || !b->pull_d ||
        !b->pull_w || !b->pull_off)
        return fit_oom(u);
    int32_t *q = b->pull_quads;
    for (int64_t g = 0; g < ptex; ++g)
        for (int64_t j = 0; j + 1 < k; ++j)
            for (int64_t i = 0; i + 1 < k; ++i) {
                const int32_t v = (int32_t)(g * k * k + j * k + i);
                q[0] = v, q[1] = v + 1, q[2] = (int32_t)(v + k + 1), q[3] = (int32_t)(v + k);
                q += 4;
            }
    for (int64_t f = 0; f < quads; ++f) b->pull_sizes[f] = 4;
    for (int64_t i = 0; i < b->scan_count; ++i) b->pull_near[i] = -1;
    return SPIA_OK;
}

/* SPIA_FIT_SCAN_PULL: each scan vertex within the cut-off pulls the
 * surface's nearest pulling sample along the scan's normal at that
 * sample's closest point, with the robust kernel's weight: the sample's
 * plane target and weight become those of its own pull and the scan
 * vertices' together (the same least squares as a row for each). */
static spia_result scan_pull(fit_run *u) {
    fit_buffers *b = &u->b;
    const int64_t S = u->S, k = u->fo.samples_per_edge;
    spia_result r;
    if (!b->pull_quads && (r = scan_pull_prepare(u)) != SPIA_OK) return r;
    for (int64_t i = 0; i < 3 * S; ++i) b->pull_pos[i] = (float)b->X[i];
    if (!b->pull_surface) {
        spia_mesh view;
        memset(&view, 0, sizeof view);
        view.vertex_count = (int32_t)S;
        view.positions = b->pull_pos;
        view.face_count = (int32_t)((S / (k * k)) * (k - 1) * (k - 1));
        view.face_sizes = b->pull_sizes;
        view.face_vertices = b->pull_quads;
        r = spia__scan_create_bare(&view, NULL, NULL, &b->pull_surface, u->status);
        if (r != SPIA_OK) return r;
    } else if ((r = spia__scan_move(b->pull_surface, b->pull_pos)) != SPIA_OK) {
        return spia__fail(u->status, r, -1, "%s moving the samples for the scan's pull",
                          r == SPIA_ERROR_NONFINITE ? "non-finite positions" : "out of memory");
    }
    if (closest_in_chunks(b->pull_surface, b->scan_count, b->scan_pts, b->pull_near, NULL, NULL, b->pull_d,
                          b->pull_faces, NULL, u->opt.threads, &u->clock))
        return fit_cancelled(u);
    int64_t pulling_samples = 0, pulling_scan = 0;
    for (int64_t i = 0; i < S; ++i) pulling_samples += b->wts[i] > 0.0f;
    /* Each scan vertex's nearest corner of its closest quad, kept in
     * pull_faces (-1: it does not pull). */
    for (int64_t v = 0; v < b->scan_count; ++v) {
        const int32_t f = b->pull_faces[v];
        int32_t pick = -1;
        if (f >= 0 && b->pull_d[v] <= u->cutoff_abs) {
            double best = INFINITY;
            for (int c = 0; c < 4; ++c) {
                const int32_t i = b->pull_quads[4 * (int64_t)f + c];
                double d2 = 0.0;
                for (int a = 0; a < 3; ++a) {
                    const double x = b->X[3 * (int64_t)i + a] - b->scan_pts[3 * v + a];
                    d2 += x * x;
                }
                if (d2 < best) best = d2, pick = i;
            }
            if (b->wts[pick] <= 0.0f) pick = -1;
        }
        b->pull_faces[v] = pick;
        pulling_scan += pick >= 0;
    }
    if (!pulling_scan) return SPIA_OK;
    double ratio = (double)pulling_samples / (double)pulling_scan;
    ratio = ratio < SCAN_PULL_MIN_RATIO ? SCAN_PULL_MIN_RATIO : ratio > SCAN_PULL_MAX_RATIO ? SCAN_PULL_MAX_RATIO : ratio;
    memset(b->pull_w, 0, sizeof(double) * (size_t)S);
    memset(b->pull_off, 0, sizeof(double) * (size_t)S);
    const int hard = (u->fo.flags & SPIA_FIT_HARD_CUTOFF) != 0;
    for (int64_t v = 0; v < b->scan_count; ++v) {
        const int32_t i = b->pull_faces[v];
        if (i < 0) continue;
        const double d = b->pull_d[v], t = u->kernel_scale > 0.0 ? d / u->kernel_scale : 0.0;
        const double w = ratio * (hard ? 1.0 : 1.0 / (1.0 + t * t));
        const float *nn = b->N + 3 * (int64_t)i;
        const float *T = b->T + 3 * (int64_t)i;
        double off = 0.0;
        for (int a = 0; a < 3; ++a) off += nn[a] * (b->scan_pts[3 * v + a] - T[a]);
        b->pull_w[i] += w;
        b->pull_off[i] += w * off;
    }
    for (int64_t i = 0; i < S; ++i) {
        if (b->pull_w[i] <= 0.0) continue;
        const double shift = b->pull_off[i] / ((double)b->wts[i] + b->pull_w[i]);
        for (int a = 0; a < 3; ++a) b->T[3 * i + a] += (float)(shift * b->N[3 * i + a]);
        b->wts[i] = (float)((double)b->wts[i] + b->pull_w[i]);
    }
    return SPIA_OK;
}

static double relative(const fit_run *u, double distance) {
    return distance / (u->diagonal > 0.0 ? u->diagonal : 1.0);
}

/* A round's new closest points, folds and mean distance, into the report,
 * the history and the progress callback. */
static spia_result round_measure(fit_run *u, int32_t round) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const int64_t S = u->S;
    if (evaluate(u->scan, b, b->V, S, u->opt.threads, &report->query_seconds, &u->clock)) return fit_cancelled(u);
    normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots);
    find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
    const double mean = mean_within(b->d, S, u->cutoff_abs);
    report->rounds = round;
    if (report->history && round < report->history_capacity) {
        report->history[round] = relative(u, mean);
        report->history_count = round + 1;
    }
    u->clock.mean = relative(u, mean);
    u->clock.round = round;
    u->clock.last = spia__now();
    if (u->opt.progress && u->opt.progress(u->opt.progress_user_data, round, u->clock.mean))
        return spia__fail(u->status, SPIA_ERROR_CANCELLED, -1, "cancelled after fitting round %d", round);
    return SPIA_OK;
}

/* SURFACE: the rounds (weights, one least-squares solve, new closest
 * points), keeping the best cage; SPIA_MAX_ITERATIONS when they had not
 * settled by max_rounds. */
static spia_result fit_surface(fit_run *u) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const int64_t S = u->S;
    const int guard = !(u->fo.flags & SPIA_FIT_ALLOW_FOLDS) && u->fo.samples_per_edge >= 2;
    fit_system f;
    spia_result r = surface_system(u, guard, &f);
    if (r != SPIA_OK) return r;
    double best_score = mean_clamped(b->d, guard ? b->folded : NULL, S, u->cutoff_abs);
    if (report->history && report->history_capacity > 0) {
        report->history[0] = relative(u, mean_within(b->d, S, u->cutoff_abs));
        report->history_count = 1;
    }
    int stale = 0, settled = 0;
    for (int round = 1; round <= u->fo.max_rounds; ++round) {
        const double t0 = spia__now();
        if ((r = round_weights(u, guard, &f)) != SPIA_OK) return r;
        if ((u->fo.flags & SPIA_FIT_SCAN_PULL) && (r = scan_pull(u)) != SPIA_OK) return r;
        report->iterations +=
            least_squares_round(&f, b->T, b->V0, b->V, u->fo.solver_iterations, b->work, b->precond, &u->clock);
        if (u->clock.cancelled) return fit_cancelled(u);
        report->solve_seconds += spia__now() - t0;
        if ((r = round_measure(u, round)) != SPIA_OK) return r;
        /* The distances do not fall monotonically (new closest points,
         * new planes): keep the best cage, and stop after two rounds in
         * a row that improved it by less than round_tolerance. */
        const double score = mean_clamped(b->d, guard ? b->folded : NULL, S, u->cutoff_abs);
        const double gain = best_score > 0.0 ? (best_score - score) / best_score : 0.0;
        u->measured_best = score < best_score;
        if (u->measured_best) {
            best_score = score;
            memcpy(b->best, b->V, sizeof(double) * (size_t)u->N3);
        }
        stale = gain < u->fo.round_tolerance ? stale + 1 : 0;
        if (stale >= 2) {
            settled = 1;
            break;
        }
    }
    if (!settled && u->fo.max_rounds > 0) {
        r = SPIA_MAX_ITERATIONS;
        spia__fail(u->status, SPIA_MAX_ITERATIONS, -1,
                   "stopped after max_rounds (%d) rounds with the distances still falling by more than "
                   "round_tolerance; the best cage so far is written",
                   u->fo.max_rounds);
    }
    return r;
}

/* The scan's vertices measured against the written cage's surface, into
 * the report and its per-vertex buffer. */
static spia_result measure_scan_written(fit_run *u) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const double t0 = spia__now();
    const spia_result r = scan_side_measure(b, b->best, u->cutoff_abs, u->diagonal, u->opt.threads, 1, &u->clock,
                                            &report->scan_after, u->status);
    if (r != SPIA_OK) return r;
    report->query_seconds += spia__now() - t0;
    if (report->scan_distances) {
        int32_t scan_n = 0;
        spia__scan_positions(u->scan, &scan_n, NULL);
        const double unit = u->diagonal > 0.0 ? u->diagonal : 1.0;
        for (int32_t v = 0; v < scan_n; ++v) report->scan_distances[v] = -1.0f;
        for (int64_t k = 0; k < b->scan_count; ++k)
            report->scan_distances[b->scan_vertex[k]] = (float)(b->scan_d[k] / unit);
    }
    return SPIA_OK;
}

/* Per cage vertex, the largest relative distance of the samples within the
 * cut-off on the faces around it. */
static void sample_vertex_distances(fit_run *u) {
    const fit_buffers *b = &u->b;
    float *vd = u->report->vertex_distances;
    memset(vd, 0, sizeof(float) * (size_t)u->n);
    const double unit = u->diagonal > 0.0 ? u->diagonal : 1.0;
    for (int64_t s = 0; s < u->S; ++s) {
        if (b->d[s] > u->cutoff_abs) continue;
        const int32_t face = b->sample_face[s];
        const float rel = (float)(b->d[s] / unit);
        for (int64_t c = u->adj.corner_start[face]; c < u->adj.corner_start[face + 1]; ++c) {
            const int32_t v = u->cage->face_vertices[c];
            if (rel > vd[v]) vd[v] = rel;
        }
    }
}

/* Distances of the cage written: measured already when it is the last
 * cage measured (the samples, their closest points, their normals'
 * agreement are those of the best cage).  Returns r, or what the scan
 * side's measure returns when there is one. */
static spia_result measure_samples_written(fit_run *u, spia_result r) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const int64_t S = u->S;
    if (!u->measured_best) {
        if (evaluate(u->scan, b, b->best, S, u->opt.threads, &report->query_seconds, &u->clock))
            return fit_cancelled(u);
        normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots);
    }
    report->after = distance_stats(b->d, S, u->cutoff_abs, u->diagonal, b->scratch);
    report->folded_after = u->fo.samples_per_edge < 2
                               ? -1
                               : find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
    if (b->grid.groups) {
        const spia_result m = measure_scan_written(u);
        if (m != SPIA_OK) return m;
    }
    if (report->vertex_distances) sample_vertex_distances(u);
    return r;
}

/* Loop and Doo-Sabin: the limit points of the cage written. */
static spia_result measure_limit_points_written(fit_run *u) {
    spia_fit_report *report = u->report;
    const int32_t n = u->n;
    double *Y = malloc(sizeof(double) * (size_t)u->N3);
    float *dist = malloc(sizeof(float) * (size_t)(n + 1)), *scratch = malloc(sizeof(float) * (size_t)(n + 1));
    if (!Y || !dist || !scratch) {
        free(Y), free(dist), free(scratch);
        return fit_oom(u);
    }
    const double t0 = spia__now();
    spia_stencils_apply(u->b.L, u->b.best, Y);
    spia__scan_closest_points_double(u->scan, n, Y, NULL, NULL, NULL, dist, NULL, NULL, u->opt.threads);
    report->query_seconds += spia__now() - t0;
    report->after = distance_stats(dist, n, u->cutoff_abs, u->diagonal, scratch);
    report->sample_count = n;
    if (report->vertex_distances)
        for (int32_t v = 0; v < n; ++v)
            report->vertex_distances[v] = dist[v] <= u->cutoff_abs ? (float)relative(u, dist[v]) : 0.0f;
    free(Y), free(dist), free(scratch);
    return SPIA_OK;
}

spia_result spia_fit(const spia_mesh *cage, const spia_scan *scan, const spia_options *options,
                     const spia_fit_options *fit_options, float *cage_out, spia_fit_report *report,
                     spia_status *status) {
    spia_fit_report local;
    if (!report) {
        memset(&local, 0, sizeof local);
        report = &local;
    }
    report_start(report);
    report->result = SPIA_ERROR_INVALID_ARGUMENT;
    fit_run u;
    memset(&u, 0, sizeof u);
    u.report = report;
    u.status = status;
    spia_result r = fit_arguments(cage, scan, options, fit_options, cage_out, &u);
    if (r != SPIA_OK) return r;
    r = samples_memory(cage, &u.opt, u.fo.samples_per_edge, u.opt.scheme == SPIA_SCHEME_CATMULL_CLARK, "the fit",
                       status);
    if (r != SPIA_OK) return report->result = r;
    u.cage = cage;
    u.scan = scan;
    u.n = cage->vertex_count;
    u.N3 = 3 * (int64_t)u.n;
    u.diagonal = spia_scan_diagonal(scan);
    u.cutoff_abs = u.fo.cutoff * u.diagonal;
    report->diagonal = u.diagonal;
    report->stencil_seconds = report->query_seconds = report->solve_seconds = 0.0;
    if ((r = spia__adjacency_build(cage, &u.adj, status)) != SPIA_OK) return report->result = r;
    u.sign = 1;
    u.clock = (fit_clock){u.opt.progress, u.opt.progress_user_data, spia__now(), 0.0, 0, 0};
    u.surface_opt = u.opt;
    u.surface_opt.scheme = SPIA_SCHEME_CATMULL_CLARK;
    u.surface_samples = u.opt.scheme == SPIA_SCHEME_CATMULL_CLARK;

    /* A negative result stops the fit; SPIA_MAX_ITERATIONS and
     * SPIA_STAGNATED go on to the cage written. */
    if ((r = sample_surface(&u)) < 0) goto done;
    if (u.S > 0 && (r = measure_given(&u)) < 0) goto done;
    r = u.fo.mode == SPIA_FIT_VERTICES ? fit_vertices(&u) : fit_surface(&u);
    if (r < 0) goto done;
    if (u.S > 0)
        r = measure_samples_written(&u, r);
    else if (u.b.L) {
        const spia_result m = measure_limit_points_written(&u);
        if (m != SPIA_OK) r = m;
    }
    if (r < 0) goto done;
    for (int64_t i = 0; i < u.N3; ++i) cage_out[i] = (float)u.b.best[i];
    if (r == SPIA_OK) spia__ok(status);
done:
    buffers_free(&u.b);
    spia__adjacency_free(&u.adj);
    report->result = r;
    return r;
}

/* ---- the limit surface as flat quads ------------------------------------- */

/* spia_flat_positions: each quad's 3 x 3 grid of limit points (corners, edge
 * midpoints, centre) against the bilinear quad through its corners' new
 * positions, in least squares, the corner points weighted FLAT_CORNER_WEIGHT
 * (measured on the bunny's level 3: 0, 1/16, 1/4 and 1 left the scan's
 * vertices a median 2.5, 2.6, 2.9 and 3.5e-5 of the diagonal from the flat
 * faces, against 4.4e-5 from those through the limit points; with none a
 * checkerboard of the vertices would not be determined); conjugate
 * gradients with a Jacobi preconditioner, from the limit points. */
#define FLAT_CORNER_WEIGHT 0.0625
#define FLAT_MAX_ITERATIONS 200
#define FLAT_TOLERANCE 1e-8

/* Bilinear weights of grid point (i, j), i along the first edge, at (i / 2, j / 2). */
static void flat_weights(int i, int j, double w[4]) {
    const double s = 0.5 * i, t = 0.5 * j;
    w[0] = (1 - s) * (1 - t), w[1] = s * (1 - t), w[2] = s * t, w[3] = (1 - s) * t;
}

/* y = A x: the quads' 4 x 4 normal block M (the same for every quad), and
 * an identity row for each vertex no quad uses (extra 1). */
static void flat_apply(const spia_mesh *m, const double M[16], const double *extra, const double *x, double *y) {
    memset(y, 0, sizeof(double) * 3 * (size_t)m->vertex_count);
    for (int32_t f = 0; f < m->face_count; ++f) {
        const int32_t *q = m->face_vertices + 4 * (int64_t)f;
        for (int c = 0; c < 4; ++c)
            for (int a = 0; a < 3; ++a) {
                double sum = 0.0;
                for (int d = 0; d < 4; ++d) sum += M[4 * c + d] * x[3 * (int64_t)q[d] + a];
                y[3 * (int64_t)q[c] + a] += sum;
            }
    }
    for (int64_t i = 0; i < 3 * (int64_t)m->vertex_count; ++i) y[i] += extra[i / 3] * x[i];
}

static spia_result flat_oom(spia_status *status) {
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the flat positions");
}

static spia_result flat_solve(const spia_mesh *m, const float *X, float *out, fit_clock *clock, spia_status *status) {
    const int32_t n = m->vertex_count;
    const int64_t N3 = 3 * (int64_t)n;
    double M[16] = {0}, w[4];
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) {
            const double k = ((i == 1) || (j == 1)) ? 1.0 : FLAT_CORNER_WEIGHT;
            flat_weights(i, j, w);
            for (int c = 0; c < 4; ++c)
                for (int d = 0; d < 4; ++d) M[4 * c + d] += k * w[c] * w[d];
        }
    double *buf = malloc(sizeof(double) * (6 * (size_t)N3 + 2 * (size_t)n + 1));
    unsigned char *seen = calloc((size_t)n + 1, 1);
    if (!buf || !seen) {
        free(buf), free(seen);
        return flat_oom(status);
    }
    double *x = buf, *b = buf + N3, *r = buf + 2 * N3, *z = buf + 3 * N3, *p = buf + 4 * N3, *Ap = buf + 5 * N3;
    double *extra = buf + 6 * N3, *pre = extra + n;
    memset(b, 0, sizeof(double) * (size_t)N3);
    memset(extra, 0, sizeof(double) * 2 * (size_t)n);
    /* The right-hand side, the preconditioner, and the start: each vertex at
     * its limit point (its corner point in its first quad's grid). */
    static const int corner_point[4] = {0, 2, 8, 6};
    for (int32_t f = 0; f < m->face_count; ++f) {
        const int32_t *q = m->face_vertices + 4 * (int64_t)f;
        const float *G = X + 27 * (int64_t)f;
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) {
                const double k = ((i == 1) || (j == 1)) ? 1.0 : FLAT_CORNER_WEIGHT;
                flat_weights(i, j, w);
                for (int c = 0; c < 4; ++c)
                    for (int a = 0; a < 3; ++a) b[3 * (int64_t)q[c] + a] += k * w[c] * G[3 * (3 * j + i) + a];
            }
        for (int c = 0; c < 4; ++c) {
            pre[q[c]] += M[5 * c];
            if (!seen[q[c]]) {
                seen[q[c]] = 1;
                for (int a = 0; a < 3; ++a) x[3 * (int64_t)q[c] + a] = G[3 * corner_point[c] + a];
            }
        }
    }
    for (int32_t v = 0; v < n; ++v)
        if (!seen[v]) {
            extra[v] = 1.0, pre[v] = 1.0;
            for (int a = 0; a < 3; ++a) b[3 * (int64_t)v + a] = x[3 * (int64_t)v + a] = m->positions[3 * (int64_t)v + a];
        }
    free(seen);
    flat_apply(m, M, extra, x, Ap);
    double rz = 0.0, bb = 0.0;
    for (int64_t i = 0; i < N3; ++i) {
        r[i] = b[i] - Ap[i];
        z[i] = r[i] / pre[i / 3];
        p[i] = z[i];
        rz += r[i] * z[i];
        bb += b[i] * b[i];
    }
    for (int it = 0; it < FLAT_MAX_ITERATIONS && rz > FLAT_TOLERANCE * FLAT_TOLERANCE * bb; ++it) {
        if (clock_tick(clock)) {
            free(buf);
            return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the flat positions");
        }
        flat_apply(m, M, extra, p, Ap);
        double pAp = 0.0;
        for (int64_t i = 0; i < N3; ++i) pAp += p[i] * Ap[i];
        if (!(pAp > 0.0)) break;
        const double alpha = rz / pAp;
        double rz_new = 0.0;
        for (int64_t i = 0; i < N3; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * Ap[i];
            z[i] = r[i] / pre[i / 3];
            rz_new += r[i] * z[i];
        }
        const double beta = rz_new / rz;
        rz = rz_new;
        for (int64_t i = 0; i < N3; ++i) p[i] = z[i] + beta * p[i];
    }
    for (int64_t i = 0; i < N3; ++i)
        if (!isfinite(x[i])) {
            free(buf);
            return spia__fail(status, SPIA_ERROR_DIVERGED, -1, "the flat positions are not finite");
        }
    for (int64_t i = 0; i < N3; ++i) out[i] = (float)x[i];
    free(buf);
    return SPIA_OK;
}

spia_result spia_flat_positions(const spia_mesh *mesh, const spia_options *options, float *out, spia_status *status) {
    if (!out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "out must not be NULL");
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme != SPIA_SCHEME_CATMULL_CLARK)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "flat positions are for Catmull-Clark cages");
    if ((r = spia_mesh_validate(mesh, status)) != SPIA_OK) return r;
    for (int32_t f = 0; f < mesh->face_count; ++f)
        if (mesh->face_sizes[f] != 4)
            return spia__fail(status, SPIA_ERROR_FACE_SIZE, f,
                              "face %d has %d corners: flat positions are for quad meshes (a subdivided cage)",
                              (int)f, (int)mesh->face_sizes[f]);
    if ((r = samples_memory(mesh, &opt, 3, 1, "the flat positions", status)) != SPIA_OK) return r;
    spia_adjacency adj;
    if ((r = spia__adjacency_build(mesh, &adj, status)) != SPIA_OK) return r;
    fit_clock clock = {opt.progress, opt.progress_user_data, spia__now(), 0.0, 0, 0};
    sample_blocks B;
    r = blocks_build(mesh, &adj, &opt, 3, 1, &B, &clock, status);
    spia__adjacency_free(&adj);
    if (r != SPIA_OK) return r;
    const int64_t points = 9 * (int64_t)mesh->face_count, N3 = 3 * (int64_t)mesh->vertex_count;
    float *X = malloc(sizeof(float) * 3 * (size_t)(points > 0 ? points : 1));
    double *V = malloc(sizeof(double) * (size_t)(N3 > 0 ? N3 : 1));
    if (!X || !V) {
        free(X), free(V), blocks_free(&B);
        return flat_oom(status);
    }
    for (int64_t i = 0; i < N3; ++i) V[i] = mesh->positions[i];
    blocks_apply_float(&B, V, X);
    free(V);
    blocks_free(&B);
    r = clock.cancelled ? spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the flat positions")
                        : flat_solve(mesh, X, out, &clock, status);
    free(X);
    if (r == SPIA_OK) spia__ok(status);
    return r;
}
