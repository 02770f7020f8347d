// SPDX-License-Identifier: GPL-3.0-or-later
/* What the files of the fit share (internal): the progress clock, the
 * samples as dense blocks, the least-squares system, the fold barrier's
 * pairs and constants, a fit's buffers and its stages' state, and the
 * functions one file calls in another.  The files, each calling only
 * those listed before it:
 *
 *   fit_progress.c    the progress clock
 *   fit_blocks.c      the samples as dense blocks and every product over
 *                     them (the plain and AVX kernels)
 *   fit_distances.c   distances, their statistics, weights, closest points
 *   fit_system.c      a round's least squares: normal equations, CG
 *   fit_folds.c       the fold guard and the fold barrier
 *   fit_scan_side.c   the scan's distances to the surface, the scan's pull
 *   fit.c             spia_fit: the options and memory limits, the stages,
 *                     the rounds; spia_surface_stencils_create
 *   flat_solve.c      the flat positions' least squares (spia__flat_solve),
 *                     spia_flat_positions' and the fit's
 *   flat_positions.c  spia_flat_positions */
#ifndef SPIA_FIT_H
#define SPIA_FIT_H

#include "internal.h"

/* ---- progress (fit_progress.c) --------------------------------------------- */

typedef struct fit_clock {
    spia_progress_fn fn;
    void *user;
    double last, mean;
    int32_t round;
    int cancelled;
} fit_clock;

int spia__fit_clock_tick(fit_clock *c);

/* ---- the samples as dense blocks (fit_blocks.c) ------------------------------ */

/* The samples of one ptex face as one dense block over the cage vertices
 * they combine, in float (fit_blocks.c tells why). */
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

/* ---- the least-squares system (fit_system.c) --------------------------------- */

/* A pair of samples of one block, neighbours along u or v, that the fold
 * barrier (barrier_pairs) holds apart: e . (X_a - X_b) is pulled to t. */
typedef struct fold_pair {
    int32_t a, b; /* the samples, within their block */
    float e[3], t;
} fold_pair;

typedef struct fit_system {
    const sample_blocks *blocks; /* the sample stencils */
    int threads;            /* of the passes over the vertices */
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

/* The fold barrier (fit_folds.c): the fold guard (stiffen) lets a folded sample go and stiffens
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

/* ---- a fit's buffers and its stages' state (fit.c) ---------------------------- */

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

static inline spia_result spia__fit_oom(fit_run *u) {
    return spia__fail(u->status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory fitting the cage");
}

static inline spia_result spia__fit_cancelled(fit_run *u) {
    return spia__fail(u->status, SPIA_ERROR_CANCELLED, -1, "cancelled during fitting round %d", u->clock.round + 1);
}

/* ---- fit_blocks.c ------------------------------------------------------------- */

void spia__fit_blocks_free(sample_blocks *B);
#define FIT_BLOCK_SETS 2
spia_result spia__fit_blocks_build_sets(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                        int count, const int32_t *per_edge, const int *corners, sample_blocks **B,
                                        fit_clock *clock, spia_status *status);
spia_result spia__fit_blocks_build(const spia_mesh *cage, const spia_adjacency *adj, const spia_options *opt,
                                   int32_t per_edge, int corners, sample_blocks *B, fit_clock *clock,
                                   spia_status *status);
void spia__fit_blocks_apply(const sample_blocks *B, const double *x, double *X);
void spia__fit_blocks_apply_float(const sample_blocks *B, const double *x, float *X);
void spia__fit_blocks_normal(const fit_system *f, const double *x, const float *T, double *out);
void spia__fit_blocks_diagonal(const fit_system *f, double *out);

/* ---- fit_distances.c ---------------------------------------------------------- */

spia_fit_distances spia__fit_distance_stats(const float *d, int64_t count, double cutoff_abs, double diagonal,
                                            float *scratch);
double spia__fit_mean_clamped(const float *d, const uint8_t *folded, int64_t count, double cutoff_abs);
double spia__fit_mean_within(const float *d, int64_t count, double cutoff_abs);
void spia__fit_cutoff_weights(const float *d, const uint8_t *on_boundary, int64_t count, double cutoff_abs,
                              float *w);
double spia__fit_median_pulling(const float *d, const float *w, int64_t count, float *scratch);
void spia__fit_robust_weights(const float *d, int64_t count, double c, float *w);
int spia__fit_closest_in_chunks(const spia_scan *scan, int64_t count, const double *points, int32_t *near,
                                float *closest, float *normals, float *distances, int32_t *faces,
                                uint8_t *on_boundary, int threads, fit_clock *clock);

/* ---- fit_system.c ------------------------------------------------------------- */

int spia__fit_least_squares_round(fit_system *f, const float *T, const double *V0, double *V, int iterations,
                                  double *work, double *precond, fit_clock *clock);

/* ---- fit_folds.c -------------------------------------------------------------- */

void spia__fit_grid_differences(const double *X, int64_t base, int32_t l, int32_t k, int32_t a[2], int32_t b[2],
                                double D[2][3]);
void spia__fit_normal_agreement(const double *X, const float *N, int64_t S, int32_t k, float *dots, int threads);
void spia__fit_start_normals(const double *X, const float *dots, int64_t S, int32_t k, int sign, float *normals,
                             float *lengths, int threads);
void spia__fit_facing_start(const float *start, const float *N, int64_t S, int sign, float *w);
int spia__fit_orientation(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S,
                          double cutoff_abs);
int64_t spia__fit_find_folds(const float *dots, const float *d, const uint8_t *on_boundary, int64_t S,
                             double cutoff_abs, int sign, uint8_t *folded);
void spia__fit_stiffen(const spia_mesh *cage, const spia_adjacency *adj, const uint8_t *folded, const float *d,
                       double near, const int32_t *sample_face, int64_t S, uint8_t *mark, double *hold,
                       double *smooth);
int spia__fit_barrier_pairs(const double *X, const float *N, const float *d, const uint8_t *on_boundary, int64_t S,
                            int32_t k, int sign, double reach, const float *start_len, fold_pair **bar,
                            int64_t *capacity, int64_t *bar_start, int threads);

/* ---- fit_scan_side.c ---------------------------------------------------------- */

/* Points along each edge of a ptex face of the grid the scan's vertices are
 * measured against, for samples_per_edge per_edge: its blocks' side. */
int32_t spia__fit_scan_grid_side(const spia_mesh *cage, int32_t per_edge);
/* The scan side's grid and buffers, over the grid's blocks the fit made
 * with its samples' (spia__fit_scan_grid_side's side) in b->grid. */
spia_result spia__fit_scan_side_prepare(const spia_mesh *cage, int32_t per_edge, const spia_scan *scan, fit_buffers *b,
                                        fit_clock *clock, spia_status *status);
spia_result spia__fit_scan_side_measure(fit_buffers *b, const double *V, double cutoff_abs, double diagonal,
                                        int threads, int warm, fit_clock *clock, spia_fit_distances *out,
                                        spia_status *status);
spia_result spia__fit_scan_pull(fit_run *u);

/* ---- flat_solve.c ------------------------------------------------------------- */

/* The flat positions of quad mesh m (its positions: where vertices no face
 * uses stay) from X, each face's side x side grid of limit points in the
 * order of spia__fit_blocks_build's (side odd, 3 or more: the 3 x 3 grid
 * taken is its corners, edge midpoints and centre). */
spia_result spia__flat_solve(const spia_mesh *m, const float *X, int32_t side, float *out, fit_clock *clock,
                             spia_status *status);

/* ---- fit.c -------------------------------------------------------------------- */

spia_result spia__fit_samples_memory(const spia_mesh *m, const spia_options *o, int32_t k, int surface,
                                     const char *work, spia_status *status);

#endif
