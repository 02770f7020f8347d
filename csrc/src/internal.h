// SPDX-License-Identifier: GPL-3.0-or-later
/* Private declarations shared by the library's source files. */
#ifndef SPIA_INTERNAL_H
#define SPIA_INTERNAL_H

#include "subdiv_pia.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Kernels compiled a second time for AVX (__attribute__((target("avx"))),
 * without fused multiply-add, so that they give the same bits as the SSE2
 * ones) and chosen at run time where spia__have_avx() says so.  Not on
 * Windows, where GCC does not align the stack for spilled AVX registers
 * (GCC bug 54412). */
#if (defined(__GNUC__) || defined(__clang__)) && (defined(__x86_64__) || defined(__i386__)) && !defined(_WIN32)
#define SPIA_AVX_KERNELS 1
#define SPIA_TARGET_AVX __attribute__((target("avx")))
#endif
/* Whether the processor has AVX and the system saves its registers; 0
 * where the library has no AVX kernels. */
int spia__have_avx(void);

/* Tables of this many rows or more are solved on several threads (below
 * it a parallel region costs more than it saves). */
#define SPIA_PARALLEL_ROWS 50000

/* The table again, laid out for GS_PIA_FAST's sweeps (plan.c, fast.c).
 * Rows in the order they are swept: vertex order below SPIA_PARALLEL_ROWS
 * rows; from there the levels of a breadth-first search through the
 * stencils (from a far vertex of each connected part), each level's rows
 * ordered by a colouring of the level so that a row's neighbours are not
 * swept just before it.  Consecutive levels make up chunks of at least
 * SPIA_PLAN_CHUNK_ROWS rows; a row refers to rows at most `reach` chunks
 * away, which lets sweeps run one behind the other on several threads.
 *
 * The weights are those of the table, exactly: each row's entries are
 * codes into a dictionary of the table's distinct weights (in double, and
 * their float32 copies for the sweeps), with column positions as offsets
 * from the row's own; the row's own entry first, when it has one.  The
 * dictionary holds each weight twice: codes from words / 2 on are the
 * larger off-diagonal weights of their rows (at least half the largest:
 * the edge neighbours of a Catmull-Clark vertex), whose signs the first
 * step (SPIA_SOLVE_FIRST_STEP) flips.  Codes are 8 or 16 bits and offsets
 * 16 or 32 bits, the least that holds the table. */
enum { SPIA_PLAN_CHUNK_ROWS = 2048 };
typedef struct spia_plan {
    int32_t rows;
    int32_t *order;       /* position -> table row; NULL: vertex order */
    int32_t chunks;
    int32_t *chunk_start; /* chunks + 1 positions */
    int64_t *chunk_entry; /* chunks + 1: the first entry of each chunk */
    int32_t reach;
    uint16_t *length;     /* entries of the row at each position */
    uint8_t *code8;       /* one of code8, code16 */
    uint16_t *code16;
    int16_t *delta16;     /* one of delta16, delta32: column position - row position */
    int32_t *delta32;
    int32_t words;        /* codes: twice the distinct weights */
    double *weight;
    float *weight_f;
    float *inverse_f;     /* 1 / weight in float (for the rows' own entries) */
    float *signed_f;      /* weight_f, negative for the second half */
    /* Every row starts with its own entry, of a positive weight: what
     * Gauss-Seidel needs. */
    int diagonal_first;
    /* The table can be rebuilt from the plan, to the bit: every row's
     * columns strictly increase, so the row's own entry, placed first, goes
     * back before its first larger column (spia__plan_row). */
    int holds_table;
} spia_plan;

/* The stencil table behind the opaque handle: CSR rows, one per control
 * vertex.  offsets has rows + 1 entries.  Once spia_limit_stencils_create
 * is done, a table whose plan holds it keeps the plan alone (offsets,
 * indices and weights NULL; see spia__stencils_compact). */
struct spia_stencils {
    int32_t rows;
    int64_t nnz;
    int64_t *offsets;
    int32_t *indices;
    double *weights;
    /* Per row: 1 for a boundary vertex whose stencil refers to boundary
     * vertices only (what a staged solve does first). */
    unsigned char *boundary;
    int32_t boundary_count;
    /* The sweep layout (spia_limit_stencils_create makes it); NULL where the
     * table does not fit one (more than 32768 distinct weights, or a row of
     * more than 65535 entries). */
    spia_plan *plan;
};

/* out = (row r of s) applied to points x (3 doubles each). */
static inline void spia__row_product(const spia_stencils *s, int32_t r, const double *x, double out[3]) {
    double a = 0.0, b = 0.0, c = 0.0;
    for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k) {
        const double w = s->weights[k];
        const double *p = x + 3 * (int64_t)s->indices[k];
        a += w * p[0];
        b += w * p[1];
        c += w * p[2];
    }
    out[0] = a;
    out[1] = b;
    out[2] = c;
}

/* Writes code and a printf-style message into status (if not NULL) and
 * returns code, so that failures read `return spia__fail(...)`. */
spia_result spia__fail(spia_status *status, spia_result code, int64_t index, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
void spia__ok(spia_status *status);

/* Options with every zero field replaced by its default, or an error for
 * out-of-range values. */
spia_result spia__resolve_options(const spia_options *in, spia_options *out, spia_status *status);
/* memory.c: the budget in force (spia_options.memory_budget resolved; -1
 * for none), the check before a call allocates what its settings make
 * grow (need in bytes; what: the work and its setting, fits: what would
 * fit, or NULL), and the bytes of a mesh's limit stencil table with the
 * solvers' working arrays. */
int64_t spia__memory_budget(const spia_options *o);
spia_result spia__memory_check(const spia_options *o, double need, const char *what, const char *fits,
                               spia_status *status);
double spia__table_bytes(const spia_mesh *m);
/* The check for a setting that makes the need grow (levels, samples per
 * edge): need(context, k) in bytes at setting k; where `setting` does not
 * fit, the message says the largest that does, fits_format taking it and
 * an "s" for the plural ("at most %d level%s fit"), or nothing_fits. */
typedef double (*spia__need_fn)(const void *context, int32_t setting);
spia_result spia__memory_check_setting(const spia_options *o, spia__need_fn need, const void *context, int32_t setting,
                                       const char *what, const char *fits_format, const char *nothing_fits,
                                       spia_status *status);

/* Monotonic wall clock in seconds. */
double spia__now(void);

/* A table with room for `rows` rows and `nnz` weights (offsets zeroed). */
spia_stencils *spia__stencils_alloc(int32_t rows, int64_t nnz);

/* Gives back the room of the arrays beyond nnz weights. */
void spia__stencils_shrink(spia_stencils *s);

/* Sorts the column indices of every row, adds up repeated columns and drops
 * exact zeros, compacting the arrays in place. */
void spia__stencils_canonicalize(spia_stencils *s);

/* Per-vertex adjacency derived from the faces: for vertex v, the corners
 * (face-vertex slots) that use it are corner_of[first[v] .. first[v+1]-1],
 * in face order.  face_of_corner maps a corner to its face and
 * corner_start[f] is the first corner of face f. */
typedef struct spia_adjacency {
    int32_t vertex_count;
    int32_t face_count;
    int64_t corner_count;
    int64_t *corner_start;   /* face_count + 1 */
    int32_t *face_of_corner; /* corner_count   */
    int64_t *first;          /* vertex_count + 1 */
    int32_t *corner_of;      /* corner_count (at most INT32_MAX corners, as in Blender) */
} spia_adjacency;

spia_result spia__adjacency_build(const spia_mesh *mesh, spia_adjacency *adj, spia_status *status);
/* The same on up to `threads` threads (the lists are the same). */
spia_result spia__adjacency_build_threads(const spia_mesh *mesh, spia_adjacency *adj, int threads, spia_status *status);
void spia__adjacency_free(spia_adjacency *adj);
/* Frees face_of_corner, first and corner_of (a builder that no longer needs
 * them makes room for the table); corner_start stays. */
void spia__adjacency_release_vertex_lists(spia_adjacency *adj);

/* The vertices before and after corner c within its face. */
static inline int32_t spia__corner_prev(const spia_mesh *m, const spia_adjacency *a, int64_t c) {
    int32_t f = a->face_of_corner[c];
    int64_t s = a->corner_start[f];
    return m->face_vertices[c == s ? a->corner_start[f + 1] - 1 : c - 1];
}
static inline int32_t spia__corner_next(const spia_mesh *m, const spia_adjacency *a, int64_t c) {
    int32_t f = a->face_of_corner[c];
    int64_t e = a->corner_start[f + 1];
    return m->face_vertices[c + 1 == e ? a->corner_start[f] : c + 1];
}

/* boundary[v] = 1 for vertices on an edge that only one face uses, else 0
 * (threads as spia_options.threads, resolved).  The _unknown form fills only
 * the entries that are SPIA__BOUNDARY_UNKNOWN, leaving those a builder has
 * already learnt. */
enum { SPIA__BOUNDARY_UNKNOWN = 0xff };
spia_result spia__boundary_vertices(const spia_mesh *mesh, const spia_adjacency *adj, unsigned char *boundary,
                                    int threads);
spia_result spia__boundary_vertices_unknown(const spia_mesh *mesh, const spia_adjacency *adj,
                                            unsigned char *boundary, int threads);

/* The most corners any vertex has (its valence bound: neighbours <= 2x). */
int32_t spia__max_corners_per_vertex(const spia_adjacency *adj);

/* The distinct neighbours of v along face edges, and for each the number of
 * faces on that edge; returns their number (at most cap are written; a cap
 * of 2 * corners of v always suffices). */
int32_t spia__vertex_neighbours(const spia_mesh *mesh, const spia_adjacency *adj, int32_t v, int32_t *nb,
                                int32_t *faces_on_edge, int32_t cap);

/* Builds s->plan (plan.c) on `threads` threads.  SPIA_OK also when the
 * table does not fit a plan (s->plan stays NULL); SPIA_ERROR_OUT_OF_MEMORY
 * when memory runs out.  The plan does not depend on the thread count. */
spia_result spia__plan_build(spia_stencils *s, int threads, spia_status *status);
void spia__plan_free(spia_plan *p);
/* Where p->holds_table: the table's CSR arrays rebuilt from the plan, the
 * same to the bit: offsets (rows + 1) and, where not NULL, indices and
 * weights; on up to `threads` threads. */
void spia__plan_table(const spia_plan *p, int64_t *offsets, int32_t *indices, double *weights, int threads);
/* Where p->holds_table: spia_stencils_apply from the plan, each row summed
 * in the table's order (so to the same bits). */
void spia__plan_apply(const spia_plan *p, const double *cage, double *out);

/* Once the plan is built: where it holds the table, the CSR arrays go (the
 * table is then 40 to 50 bytes a vertex, not 150) and offsets, indices and
 * weights are NULL.  Whatever needs the arrays asks spia__stencils_expand
 * for them. */
void spia__stencils_compact(spia_stencils *s);
/* *full = *s with its CSR arrays: s's own, or rebuilt from the plan into
 * new ones (then SPIA_ERROR_OUT_OF_MEMORY is possible).  full shares s's
 * other arrays: give it back with spia__stencils_expanded_free, never
 * spia_stencils_free. */
spia_result spia__stencils_expand(const spia_stencils *s, spia_stencils *full, int threads);
void spia__stencils_expanded_free(const spia_stencils *s, spia_stencils *full);

/* GS_PIA_FAST (fast.c), called by spia_solve once the arguments are checked
 * and L->plan found fit (every row's own weight positive): writes the cage
 * and fills the report (method, iterations, errors, history) as spia_solve
 * documents.  `options` is resolved; `diagonal` is the targets'
 * bounding-box diagonal; `automatic`: chosen by AUTO (a first iterate
 * already within the tolerance is then reported as PIA's).  Returns
 * SPIA__HAND_OVER, with nothing written, when float32 sweeps cannot reach
 * the tolerance: GS_PIA is to go on from *handover (a cage the caller
 * frees; NULL: from the first iterate), after *handover_iterations.  On
 * SPIA_STAGNATED and SPIA_ERROR_DIVERGED, where least squares goes on,
 * *handover_iterations is the sweeps' count as well. */
#define SPIA__HAND_OVER ((spia_result)100)
spia_result spia__solve_fast(const spia_stencils *L, const float *targets, const spia_options *options,
                             double diagonal, int automatic, float *cage, float **handover,
                             int32_t *handover_iterations, spia_report *report, spia_status *status);

/* Least squares (least_squares.c): moves cage (row_count * 3 doubles, the
 * first iterate on entry) towards the least-squares cage of L V = targets,
 * until every row is within options->tolerance * scale, the least-squares
 * residual is reached, or max_steps steps; *it counts the steps, which go
 * into the report's history and the progress callback as iterations.  L
 * must hold its CSR arrays.  Returns SPIA_OK, or SPIA_ERROR_CANCELLED,
 * _OUT_OF_MEMORY or _DIVERGED (a NaN or infinity met). */
spia_result spia__least_squares(const spia_stencils *L, const float *targets, double *cage, const spia_options *options,
                                double scale, int32_t *it, int32_t max_steps, spia_report *report,
                                spia_status *status);

/* Fills s->boundary and s->boundary_count from the boundary vertices
 * (spia__boundary_vertices). */
void spia__stencils_mark_boundary(spia_stencils *s, const unsigned char *on_boundary);

/* Limit stencils through OpenSubdiv (osd_limit_stencils.cpp): Catmull-Clark exactly
 * as Blender's modifier, and Loop with OpenSubdiv's boundary rules.  Frees
 * the adjacency's vertex lists once it no longer needs them.  on_boundary
 * (vertex_count entries, SPIA__BOUNDARY_UNKNOWN) receives the boundary
 * vertices as spia__boundary_vertices finds them: the closed-form rows
 * learn most of them on the way. */
spia_result spia__osd_limit_stencils(const spia_mesh *mesh, spia_adjacency *adj, const spia_options *options,
                                     unsigned char *on_boundary, spia_stencils **out, spia_status *status);

/* Catmull-Clark rows with a closed form (catmark_closed.c).  Sharpness as
 * OpenSubdiv is given it, in the mesh's vertex numbering: vertex[v] after
 * Blender's rules (0 for vertices no face uses), and the creased face edges
 * of each vertex as a list (crease_first NULL when there are none). */
#define SPIA__SHARPNESS_INFINITE 10.0f
typedef struct spia_catmark_sharpness {
    const float *vertex;
    const int64_t *crease_first; /* vertex_count + 1 */
    const int32_t *crease_other;
    const float *crease_sharpness;
    int preserve_corners; /* boundary vertices with one face are corners */
} spia_catmark_sharpness;

/* Sharpness of face edge (v, w): 0 when not creased. */
float spia__catmark_edge_sharpness(const spia_catmark_sharpness *sh, int32_t v, int32_t w);

typedef struct spia_row_entry {
    int32_t column;
    double weight;
} spia_row_entry;

/* Per-thread room for one row, grown as needed; zero it to start.  With
 * build 0, spia__catmark_closed_row only classifies and returns a bound on
 * the row's length. */
typedef struct spia_fan_corner {
    int64_t corner, start; /* v's corner, and its face's first */
    int32_t size, next, prev, succ;
    double inverse_size;
} spia_fan_corner;
typedef struct spia_row_scratch {
    spia_row_entry *entries;
    spia_fan_corner *fan;
    int64_t capacity;
    int build;
    int on_boundary; /* set by each call: 1 or 0 once v's fan is known to be one, else -1 */
} spia_row_scratch;
void spia__row_scratch_free(spia_row_scratch *s);

enum { SPIA__ROW_NOT_CLOSED = -1, SPIA__ROW_OUT_OF_MEMORY = -2 };

/* The closed-form limit row of vertex v: its length, with the entries in
 * scratch->entries sorted by column, repeats added up and zeros dropped
 * (with scratch->build 0: a bound on it, and no entries);
 * SPIA__ROW_NOT_CLOSED when v needs OpenSubdiv's patches, or
 * SPIA__ROW_OUT_OF_MEMORY. */
int32_t spia__catmark_closed_row(const spia_mesh *mesh, const spia_adjacency *adj, const spia_catmark_sharpness *sh,
                                 int32_t v, spia_row_scratch *scratch);

/* spia_refine's progress (refine.c): the options' callback at the end
 * of each level (the last one's once its limit positions are computed,
 * before any output is written; levels 0: once) and, from
 * spia__refine_tick, once REFINE_INTERVAL seconds have passed since the
 * last call; iteration is the level under way (1 to levels) and
 * relative_error the share of the refinement done (a level's share by its
 * face count: four times the one before).  Once it has asked to stop,
 * every later call says so without calling it again. */
typedef struct spia__refine_clock {
    spia_progress_fn fn;
    void *user;
    double last;
    int32_t level, levels;
    int cancelled;
} spia__refine_clock;
void spia__refine_clock_start(spia__refine_clock *clock, const spia_options *options, int32_t levels);
/* Nonzero when cancelled; looks at the time only when k is a multiple of 1024. */
int spia__refine_tick(spia__refine_clock *clock, int64_t k);
/* Level `level` finished: the callback is called; nonzero when cancelled. */
int spia__refine_level_done(spia__refine_clock *clock, int32_t level);
spia_result spia__refine_cancelled(spia_status *status, const spia__refine_clock *clock);

/* Loop refinement with every vertex at its limit (OpenSubdiv's rules, in
 * osd_refine.cpp; Hoppe's, in loop.c).  Counts only when positions is
 * NULL, without refining; otherwise the refinement's progress goes to
 * clock. */
spia_result spia__osd_refine_limit(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                   int32_t levels, int32_t *vertex_count, int32_t *face_count, float *positions,
                                   int32_t *faces, spia__refine_clock *clock, spia_status *status);
spia_result spia__loop_hoppe_refine_limit(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                          int32_t *vertex_count, int32_t *face_count, float *positions,
                                          int32_t *faces, spia__refine_clock *clock, spia_status *status);

/* Catmull-Clark refinement of the control mesh (spia_subdivide), in
 * osd_refine.cpp.  Counts only when positions is NULL. */
/* spia_sharpness's work (osd_sharpness.cpp): the sharpness handed to
 * OpenSubdiv, in the mesh's numbering; two_edge_rule 0 leaves Blender's
 * two-edge rule out. */
spia_result spia__osd_sharpness(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                int two_edge_rule, int32_t *count, int32_t *pairs, float *edge_sharpness,
                                float *vertex_sharpness, spia_status *status);
spia_result spia__osd_subdivide(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                int32_t levels, int32_t *vertex_count, int32_t *face_count, int32_t *edge_count,
                                float *positions, int32_t *face_vertices, int32_t *edges, float *edge_creases,
                                float *vertex_creases, spia__refine_clock *clock, spia_status *status);

/* Two-phase Doo-Sabin (doosabin.c): limit stencils (paper eq. 2) and
 * refinement (phase one, then regular Doo-Sabin); counts only when
 * positions is NULL (the first step's checks, then the counts in closed
 * form). */
spia_result spia__doosabin_limit_stencils(const spia_mesh *mesh, spia_adjacency *adj,
                                          const spia_options *options, spia_stencils **out, spia_status *status);
spia_result spia__doosabin_refine(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                  int32_t *vertex_count, int32_t *face_count, int64_t *corner_count, float *positions,
                                  int32_t *face_sizes, int32_t *face_vertices, spia__refine_clock *clock,
                                  spia_status *status);

/* Loop limit stencils with Hoppe et al.'s boundary rules (loop.c); clock
 * (may be NULL): a refinement's, ticked row by row. */
spia_result spia__loop_hoppe_limit_stencils(const spia_mesh *mesh, spia_adjacency *adj,
                                            const spia_options *options, spia__refine_clock *clock,
                                            spia_stencils **out, spia_status *status);

/* Rejects Loop input that is not all triangles, naming how many faces are not. */
spia_result spia__require_triangles(const spia_mesh *mesh, spia_status *status);

/* Ptex faces of a face: 1 for a quad, else one per corner. */
static inline int32_t spia__ptex_of_face(int32_t size) { return size == 4 ? 1 : size; }

/* Catmull-Clark limit stencils at samples inside faces (osd_samples.cpp). */
spia_result spia__osd_surface_stencils(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                       int32_t samples_per_edge, spia_stencils **out, spia_status *status);
/* The same rows face by face, for one set of points or several at once
 * (one topology and one surface a face for all): for each ptex face in
 * order, each set's emit gets its columns (mesh numbering, each once) and
 * its points' weights over them, per_edge^2 rows of `width` (point j's at
 * weights + j * width).  A set's points are at the centres of a grid of
 * per_edge^2 cells over the ptex face, or with `corners` a grid of
 * per_edge (at least 2) points on each edge from 0 to 1, corners included.
 * The surfaces are made on options->threads; emit is called on the calling
 * thread, each set's in ptex order, the same whatever the threads.  A
 * nonzero return stops it: SPIA_ERROR_CANCELLED or SPIA_ERROR_INTERNAL
 * with that result, anything else with SPIA_ERROR_OUT_OF_MEMORY. */
typedef int (*spia__sample_block_fn)(void *user, int64_t ptex, int32_t width, const int32_t *columns,
                                     const double *weights);
typedef struct spia__block_points {
    int32_t per_edge;
    int32_t corners;
    spia__sample_block_fn emit;
    void *user;
} spia__block_points;
spia_result spia__osd_surface_blocks(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                     const spia__block_points *sets, int32_t set_count, spia_status *status);

/* The scan's own copy of its positions (scan.c), in its own order, with
 * (original, when not NULL) each vertex's index in the mesh it was made
 * from; and which of them its triangles use (used: vertex_count bytes). */
const float *spia__scan_positions(const spia_scan *scan, int32_t *vertex_count, const int32_t **original);
void spia__scan_used_vertices(const spia_scan *scan, uint8_t *used);

/* A scan for distances alone (scan.c): no normals, no boundary, so that
 * only closest points, distances and faces may be asked of it. */
spia_result spia__scan_create_bare(const spia_mesh *mesh, spia_progress_fn progress, void *progress_user_data,
                                   spia_scan **out, spia_status *status);

/* Moves the scan's vertices to `positions` (3 floats per vertex of the
 * mesh it was made from, in that mesh's order), its faces staying: its
 * normals (when it has them), diagonal (over the vertices its triangles use) and hierarchy
 * (refitted, not rebuilt: spia__bvh_refit) follow.  Fails, changing
 * nothing, with SPIA_ERROR_NONFINITE or SPIA_ERROR_OUT_OF_MEMORY. */
spia_result spia__scan_move(spia_scan *s, const float *positions);

/* Closest points for points in double (scan.c); no argument checks.  radius,
 * when not NULL, bounds each point's distance from above (a search hint;
 * a bound that proves too small falls back to a full search).  threads as
 * spia_options.threads, resolved (at least 1). */
void spia__scan_closest_points_double(const spia_scan *scan, int64_t count, const double *points, const float *radius,
                                      float *closest, float *normals, float *distances, int32_t *faces,
                                      uint8_t *on_boundary, int threads);

/* The same, each point's search starting from near[i]: its triangle in the
 * scan's own numbering as an earlier call wrote it (-1 for none), which is
 * overwritten with the triangle found.  For points that moved a little
 * since (a fit's next round), that triangle's distance is nearly the
 * answer: a tighter bound than any radius known beforehand.  The results
 * are those of spia__scan_closest_points_double. */
void spia__scan_closest_points_near(const spia_scan *scan, int64_t count, const double *points, int32_t *near,
                                    float *closest, float *normals, float *distances, int32_t *faces,
                                    uint8_t *on_boundary, int threads);

#ifdef __cplusplus
}
#endif

#endif
