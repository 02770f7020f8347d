// SPDX-License-Identifier: GPL-3.0-or-later
/* The samples of a fit as dense blocks, one a ptex face: their build from
 * OpenSubdiv's stencils (weights shared between equal blocks), and every
 * product over them, in the plain kernels and their twins compiled for AVX
 * (SPIA_AVX_KERNELS): the samples' positions, and the normal equations'
 * products and diagonal blocks of the least-squares rounds (fit_system.c).
 *
 * The samples of one ptex face combine the same cage vertices (the face's
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
#include "fit.h"
#include "threads.h"

#include <stdlib.h>
#include <string.h>

/* The products run in this many pieces of the blocks, whatever the number
 * of threads, each piece summing into a vector of its own; the sums are
 * added in piece order, so the results do not depend on the threads. */
#define BLOCK_PIECES 2

void spia__fit_blocks_free(sample_blocks *B) {
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

/* FNV-1a in four lanes (weight i in lane i mod 4), which do not wait for
 * one another: a block of the 3 x 3 grid has 144 weights, and a level of
 * 3.2M faces hashes one a face. */
static uint64_t weights_hash(const float *w, int64_t count) {
    uint64_t h[4] = {1469598103934665603ull ^ (uint64_t)count, 1469598103934665603ull, 1469598103934665603ull,
                     1469598103934665603ull};
    int64_t i = 0;
    for (; i + 4 <= count; i += 4) {
        uint32_t bits[4];
        memcpy(bits, w + i, sizeof bits);
        for (int k = 0; k < 4; ++k) h[k] = (h[k] ^ bits[k]) * 1099511628211ull;
    }
    for (; i < count; ++i) {
        uint32_t bits;
        memcpy(&bits, w + i, sizeof bits);
        h[0] = (h[0] ^ bits) * 1099511628211ull;
    }
    const uint64_t m = ((h[0] * 31 + h[1]) * 31 + h[2]) * 31 + h[3];
    return m ^ (m >> 29);
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
    if (++k->next % BLOCK_TICK == 0 && spia__fit_clock_tick(k->clock)) return SPIA_ERROR_CANCELLED;
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

/* Sample blocks of the cage for `count` sets of points at once (one
 * OpenSubdiv topology and one surface a face for all): set i has
 * per_edge[i]^2 points per ptex face, at the centres of a grid's cells, or
 * with corners[i] a grid of per_edge[i] points on each edge, from corner
 * to corner. */
spia_result spia__fit_blocks_build_sets(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                        int count, const int32_t *per_edge, const int *corners, sample_blocks **B,
                                        fit_clock *clock, spia_status *status) {
    block_sink sink[FIT_BLOCK_SETS];
    spia__block_points points[FIT_BLOCK_SETS];
    if (count < 1 || count > FIT_BLOCK_SETS)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "%d sets of sample stencils", count);
    memset(sink, 0, sizeof sink);
    for (int i = 0; i < count; ++i) memset(B[i], 0, sizeof *B[i]);
    spia_result r = SPIA_OK;
    for (int i = 0; i < count && r == SPIA_OK; ++i) {
        sample_blocks *b = B[i];
        b->per = per_edge[i] * per_edge[i];
        b->columns = cage->vertex_count;
        b->threads = opt->threads > BLOCK_PIECES ? BLOCK_PIECES : opt->threads < 1 ? 1 : opt->threads;
        b->avx = !(opt->solve_flags & SPIA_SOLVE_NO_AVX) && spia__have_avx();
        b->groups = spia_surface_sample_count(cage, per_edge[i]) / b->per;
        b->start = calloc((size_t)b->groups + 1, sizeof(int64_t));
        b->w_at = malloc(sizeof(int64_t) * (size_t)(b->groups > 0 ? b->groups : 1));
        b->u = malloc(sizeof(double) * 6 * BLOCK_PIECES * (size_t)b->per);
        b->extra = malloc(sizeof(double) * 6 * (BLOCK_PIECES - 1) * (size_t)(b->columns > 0 ? b->columns : 1));
        if (!b->start || !b->w_at || !b->u || !b->extra)
            r = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
        sink[i] = (block_sink){b, 0, 0, NULL, 0, NULL, 0, 0, 0, clock};
        points[i] = (spia__block_points){per_edge[i], corners[i], block_sink_add, &sink[i]};
    }
    if (r == SPIA_OK) r = spia__osd_surface_blocks(cage, adj, opt, points, count, status);
    for (int i = 0; i < count; ++i)
        if (r == SPIA_OK && sink[i].next != B[i]->groups)
            r = spia__fail(status, SPIA_ERROR_INTERNAL, -1, "the sample stencils do not match the cage's faces");
    for (int i = 0; i < count; ++i) {
        free(sink[i].kept), free(sink[i].table);
        if (r != SPIA_OK) spia__fit_blocks_free(B[i]);
    }
    return r;
}

/* The sample blocks of the cage (per ptex face, per_edge^2 samples; with
 * `corners`, a grid with per_edge points on each edge, from corner to
 * corner). */
spia_result spia__fit_blocks_build(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                   int32_t per_edge, int corners, sample_blocks *B, fit_clock *clock,
                                   spia_status *status) {
    return spia__fit_blocks_build_sets(cage, adj, opt, 1, &per_edge, &corners, &B, clock, status);
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

void spia__fit_blocks_apply(const sample_blocks *B, const double *x, double *X) {
    apply_context a = {x, X, NULL};
    blocks_run(B, PIECE(B, positions_piece), &a, NULL, 0);
}

void spia__fit_blocks_apply_float(const sample_blocks *B, const double *x, float *X) {
    apply_context a = {x, NULL, X};
    blocks_run(B, PIECE(B, positions_piece), &a, NULL, 0);
}


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

/* out += M^T B M x over all the blocks, or with targets T (x NULL) the
 * right-hand side's share M^T (B-weighted targets); the fold barrier's
 * pairs with them. */
void spia__fit_blocks_normal(const fit_system *f, const double *x, const float *T, double *out) {
    normal_context c = {f, x, T};
    blocks_run(f->blocks, PIECE(f->blocks, normal_piece), &c, out, 3);
}

/* out (6 per column) += the diagonal 3x3 blocks of M^T B M. */
void spia__fit_blocks_diagonal(const fit_system *f, double *out) {
    blocks_run(f->blocks, PIECE(f->blocks, diagonal_piece), f, out, 6);
}
