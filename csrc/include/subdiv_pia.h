// SPDX-License-Identifier: GPL-3.0-or-later
/*
 * subdiv_pia: subdivision surfaces that pass through the points you gave them.
 *
 * Given a polygon mesh, the library computes a new control cage (same
 * topology, new positions) whose subdivision LIMIT surface interpolates the
 * original vertices: the limit point of control vertex i is the original
 * position of vertex i.  It does so by progressive iterative approximation
 * (PIA) and related iterations on the limit stencils of the mesh.
 *
 * The Catmull-Clark limit stencils are those of Blender's Subdivision Surface
 * modifier with "Use Limit Surface" on (OpenSubdiv adaptive patches at the
 * modifier's quality level), so that the modifier on the returned cage shows
 * a surface through the original points.
 *
 * Conventions
 * -----------
 * - Plain data in, plain data out.  The mesh is described by a spia_mesh
 *   struct of counts and const pointers, laid out as Blender holds it; the
 *   library never copies what it only reads and never keeps a pointer to it
 *   after a call returns.
 * - Output buffers are owned and sized by the caller.  The one object the
 *   library owns, a stencil table, is an opaque handle with one create and
 *   one free.
 * - Every function that can fail returns a spia_result.  When the optional
 *   spia_status pointer is not NULL it receives the same code and a message
 *   in words.  The library never prints, never exits and never asserts on
 *   input.
 * - An options struct set to all zeros means the defaults
 *   (spia_options_default() is the same as memset to 0).
 * - No global state: every function is reentrant.  Progress and
 *   cancellation go through a callback with a user pointer.
 * - Indices are int32_t, as in Blender.  Positions are float (Blender's
 *   storage); all arithmetic is carried out in double.
 */
#ifndef SUBDIV_PIA_H
#define SUBDIV_PIA_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#if defined(_WIN32)
#  ifdef SPIA_BUILDING_LIBRARY
#    define SPIA_API __declspec(dllexport)
#  else
#    define SPIA_API __declspec(dllimport)
#  endif
#else
#  define SPIA_API __attribute__((visibility("default")))
#endif

#define SPIA_VERSION_MAJOR 0
#define SPIA_VERSION_MINOR 2
#define SPIA_VERSION_PATCH 0

/* ------------------------------------------------------------------------ */
/* Result codes                                                              */
/* ------------------------------------------------------------------------ */

typedef enum spia_result {
    SPIA_OK = 0,
    /* The solver stopped at max_iterations before reaching the tolerance.
     * The cage written is the last iterate and is usable.  Not a failure of
     * the call: the report tells how far it got. */
    SPIA_MAX_ITERATIONS = 1,
    /* Some vertices cannot reach their targets: no cage's limit surface
     * passes through all the points, because the limit matrix is singular
     * there (limit points tied together: the three vertices of a
     * double-sided triangle in a scan all have its centroid as limit point;
     * interior valence-2 vertices; faces folded back over their
     * neighbours).  The cage written is the least-squares cage (see
     * SPIA_METHOD_LEAST_SQUARES): the other vertices are within the
     * tolerance, these as close as the surface allows.  They are counted
     * in spia_report.unreachable_count and flagged in
     * spia_report.unreachable.  The cage is usable. */
    SPIA_STAGNATED = 2,

    /* Failures: nothing was written to the output buffers. */
    SPIA_ERROR_INVALID_ARGUMENT = -1, /* NULL pointer, negative count, bad option value */
    SPIA_ERROR_EMPTY_MESH = -2,       /* no vertices, or no faces                      */
    SPIA_ERROR_FACE_SIZE = -3,        /* a face with fewer than 3 vertices             */
    SPIA_ERROR_INDEX_RANGE = -4,      /* a face or edge index outside [0, vertex_count) */
    SPIA_ERROR_NONFINITE = -5,        /* a NaN or infinite position or crease          */
    SPIA_ERROR_DEGENERATE_FACE = -6,  /* a face that uses one vertex more than once    */
    SPIA_ERROR_TOPOLOGY = -7,         /* a topology the subdivision scheme rejects     */
    SPIA_ERROR_OUT_OF_MEMORY = -8,
    SPIA_ERROR_CANCELLED = -9,        /* the progress callback asked to stop           */
    SPIA_ERROR_DIVERGED = -10,        /* a NaN or infinity arose; nothing was written   */
    SPIA_ERROR_INTERNAL = -11         /* an unexpected failure inside the library      */
} spia_result;

/* Longest message, terminating NUL included. */
#define SPIA_MESSAGE_SIZE 256

typedef struct spia_status {
    spia_result code;
    /* The first offending element where one applies (face, vertex or edge
     * index), else -1. */
    int64_t index;
    char message[SPIA_MESSAGE_SIZE];
} spia_status;

/* A short constant name for a code, e.g. "SPIA_ERROR_FACE_SIZE".  Never NULL. */
SPIA_API const char *spia_result_name(spia_result code);

/* The library's version as major * 10000 + minor * 100 + patch. */
SPIA_API int spia_version(void);

/* ------------------------------------------------------------------------ */
/* The mesh                                                                  */
/* ------------------------------------------------------------------------ */

/*
 * A polygon mesh as Blender holds it.  Everything is read only and must stay
 * valid for the duration of the call it is passed to.
 *
 *   positions       vertex_count * 3 floats, x y z of each vertex.
 *   face_sizes      face_count ints, the number of corners of each face (>= 3).
 *   face_vertices   sum(face_sizes) ints: the vertex indices of each face's
 *                   corners, faces one after another in face order.
 *   edges           edge_count * 2 ints, the two vertices of each edge, or
 *                   NULL.  Edges used by no face are "loose edges".  Edges of
 *                   faces need not be listed; they are only needed here to
 *                   carry creases and to mark loose edges.  May be NULL when
 *                   edge_count is 0.
 *   edge_creases    edge_count floats in [0, 1] (Blender's edge crease), or
 *                   NULL for none.  An edge listed more than once (either
 *                   way round) takes its largest crease.
 *   vertex_creases  vertex_count floats in [0, 1] (Blender's vertex crease),
 *                   or NULL for none.
 *
 * Vertices used by no face and no edge ("loose vertices") are allowed; their
 * limit point is the vertex itself.
 */
typedef struct spia_mesh {
    int32_t vertex_count;
    const float *positions;
    int32_t face_count;
    const int32_t *face_sizes;
    const int32_t *face_vertices;
    int32_t edge_count;
    const int32_t *edges;
    const float *edge_creases;
    const float *vertex_creases;
} spia_mesh;

/* ------------------------------------------------------------------------ */
/* Options                                                                   */
/* ------------------------------------------------------------------------ */

typedef enum spia_scheme {
    SPIA_SCHEME_CATMULL_CLARK = 0, /* Blender's Subdivision Surface modifier             */
    SPIA_SCHEME_LOOP = 1,          /* Loop, triangle meshes only (OpenSubdiv's, USD's)   */
    /* Two-phase Doo-Sabin (Cheng et al.): a shape parameter per face in the
     * first step, regular Doo-Sabin after; closed meshes, any face sizes. */
    SPIA_SCHEME_DOO_SABIN = 2
} spia_scheme;

/* Boundary rules for Loop (Catmull-Clark always follows Blender). */
typedef enum spia_boundary_rule {
    /* OpenSubdiv's (and USD's, RenderMan's): boundary edges are cubic
     * B-splines, limit (1/6, 2/3, 1/6); corners follow boundary_smooth;
     * creases and non-manifold parts as OpenSubdiv handles them. */
    SPIA_BOUNDARY_RULE_SMOOTH = 0,
    /* Hoppe et al. 1994, as in the open-mesh Loop PIA paper: a boundary
     * vertex is regular if its valence is 4, else extraordinary; boundary
     * edge points are midpoints unless the ends differ in type, then 5/8 on
     * the regular end and 3/8 on the extraordinary one.  boundary_smooth
     * and creases are ignored; non-manifold meshes are refused.  The six
     * limit masks are derived in csrc/src/loop.c. */
    SPIA_BOUNDARY_RULE_HOPPE = 1
} spia_boundary_rule;

typedef enum spia_boundary_smooth {
    SPIA_BOUNDARY_SMOOTH_ALL = 0,             /* Blender's "All" (its default)   */
    SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS = 1 /* Blender's "Keep Corners"        */
} spia_boundary_smooth;

typedef enum spia_method {
    /* On tables of 10,000 rows or more, GS_PIA_FAST with
     * SPIA_SOLVE_FIRST_STEP where every vertex has a positive weight on
     * itself (else as below).  On smaller ones, chosen before the first
     * step by how far one PIA step would shrink the residual: on smooth
     * targets, where it shrinks to under 0.15 of itself, CG where it
     * applies, else CHEBYSHEV; on rough ones (scans) GS_PIA_FAST with
     * SPIA_SOLVE_FIRST_STEP where every vertex has a positive weight on
     * itself, else CHEBYSHEV.  Staged solves choose as smaller tables do,
     * with GS_PIA for GS_PIA_FAST.  spia_report.method says which (PIA when
     * the first iterate was within the tolerance already). */
    SPIA_METHOD_AUTO = 0,
    SPIA_METHOD_PIA = 1,   /* V += P - L V (Jacobi-like, the papers' PIA)            */
    /* Gauss-Seidel PIA: vertex by vertex, in place, one stencil product per
     * iteration.  The error it reports after an iteration (history,
     * progress) is the largest one met during the sweep, just before each
     * vertex moved; the full residual is computed when that reaches the
     * tolerance, and the stopping test always uses the full residual. */
    SPIA_METHOD_GS_PIA = 2,
    /* PIA with Chebyshev acceleration over the spectrum of L, estimated from
     * the first PIA steps: one stencil product per iteration like PIA, and
     * far fewer iterations on rough targets. */
    SPIA_METHOD_CHEBYSHEV = 3,
    /* Weighted PIA: V += w (P - L V), with w = spia_options.weight or, when
     * that is 0, w = 2 / (lambda_min + lambda_max) estimated by power
     * iterations (the best weight when the spectrum is real). */
    SPIA_METHOD_WPIA = 4,
    /* Conjugate gradients on S V = D^-1 P where L = D S with D a positive
     * diagonal and S symmetric (closed meshes of every scheme here; for Loop
     * and Doo-Sabin the papers prove S positive definite; a breakdown falls
     * back to CHEBYSHEV); refused where L has no such form (boundaries). */
    SPIA_METHOD_CG = 5,
    /* GS-PIA's update on a layout of the stencils made for it (built with
     * the table): rows in vertex order on tables below 50,000 rows; from
     * there in the levels of a breadth-first search through the stencils,
     * each level ordered by a colouring so that rows swept one after
     * another are not neighbours, and several sweeps at once, one behind
     * the other, on `threads` threads.  The sweeps work in float32 (the
     * weights' float32 copies) on the correction to the first iterate; the
     * residual and the stopping test are in double, on the cage as it is
     * stored, so the cage meets the same tolerance as GS-PIA's (another
     * cage within it, the same whatever the thread count).  Where float32
     * cannot reach the tolerance (about 4e-6 of the first iterate's error,
     * or below the float rounding of the cage's coordinates), GS_PIA's
     * double sweeps take over and the report says GS_PIA.  The error of an
     * iteration is the largest met during the sweep, as for GS_PIA.
     * Needs every L_ii > 0, as GS_PIA. */
    SPIA_METHOD_GS_PIA_FAST = 6,
    /* Least squares: conjugate gradients on the normal equations
     * L^T L V = L^T P (CGLS), which converge for any L.  From the first
     * iterate they reach the least-squares cage nearest it: where no cage's
     * limit surface passes through every point (L singular: interior
     * valence-2 vertices, faces folded back over their neighbours,
     * double-sided faces), the points that can be reached are, within the
     * tolerance, and the others are as close as the surface allows.  Every
     * other method hands over to it by itself when it stagnates or
     * diverges; spia_report.method then says LEAST_SQUARES, the
     * iterations count both. */
    SPIA_METHOD_LEAST_SQUARES = 7
} spia_method;

/* spia_options.solve_flags: parts of the Gauss-Seidel solvers that can be
 * switched on, mostly to measure what each brings (bench/bench_solve.py). */
enum {
    /* GS_PIA, GS_PIA_FAST: before the first sweep, one step of a local
     * approximate inverse of the limit mask, V += M (P - L V), where row i
     * of M is L's row i with the signs of its larger off-diagonal weights
     * (a Catmull-Clark vertex's edge neighbours) flipped, times
     * 1.28 / L_ii^2: on a regular quad grid it brings the conditioning of L
     * from 9 to 16/9.  Costs about one sweep; not counted as an
     * iteration. */
    SPIA_SOLVE_FIRST_STEP = 1,
    /* GS_PIA: sweep in a multicolour order (a greedy colouring of the
     * stencils, no two rows of a colour in each other's stencil), the rows
     * of each colour shared among the threads. */
    SPIA_SOLVE_MULTICOLOUR = 2,
    /* GS_PIA_FAST: sweep in double instead of float32. */
    SPIA_SOLVE_DOUBLE_SWEEPS = 4,
    /* GS_PIA_FAST's residual passes and spia_fit's sample products in SSE2
     * even where the processor has AVX, as on one that has none.  The
     * results are the same to the bit (the same operations in the same
     * order); only the time differs. */
    SPIA_SOLVE_NO_AVX = 8
};

/*
 * Progress callback: called once per iteration (and once when the stencils
 * are ready, with iteration 0).  relative_error is the current largest
 * distance |P_i - (L V)_i| divided by the bounding-box diagonal.  Return
 * nonzero to cancel: the call then returns SPIA_ERROR_CANCELLED and writes
 * nothing.
 */
typedef int (*spia_progress_fn)(void *user_data, int32_t iteration, double relative_error);

/* All zeros means the defaults given in brackets. */
typedef struct spia_options {
    spia_scheme scheme;                   /* [CATMULL_CLARK] */
    spia_boundary_smooth boundary_smooth; /* [ALL] */
    int32_t ignore_creases;               /* nonzero: Blender's use_creases off [0: creases used] */
    int32_t quality;                      /* Blender's quality, 1..10 [3] */
    spia_method method;                   /* [AUTO] */
    double tolerance;                     /* stop when max |P - L V| <= tolerance * diagonal [1e-6] */
    int32_t max_iterations;               /* [1000] */
    spia_progress_fn progress;            /* [none] */
    void *progress_user_data;
    spia_boundary_rule boundary_rule;     /* Loop only [SMOOTH] */
    double weight;                        /* WPIA's weight; 0 = estimate it [0] */
    /* Nonzero: solve the boundary vertices first (their limit points depend
     * only on boundary vertices), then the interior with the boundary fixed,
     * as the open-mesh Loop paper does.  The report gives each stage's
     * iterations.  Reaches the same cage as solving everything at once. [0] */
    int32_t staged;
    /* Two-phase Doo-Sabin: the shape parameter of every face, in (0, 1)
     * [0.5], unless face_shape_parameters (face_count floats) is given. */
    double shape_parameter;
    const float *face_shape_parameters;
    /* Threads for building stencils, the solvers' sparse products and the
     * fits' closest points and least squares:
     * 0 = one per processor the system reports, 1 = the calling thread
     * only.  Results do not depend on it: every row and every sum is
     * computed in the same order whatever the count. [0] */
    int32_t threads;
    /* Catmull-Clark: the OpenSubdiv version (major * 10000 + minor * 100 +
     * patch, e.g. 30700 for 3.7.0) of the Blender whose modifier to match,
     * as Blender reports it in bpy.app.opensubdiv.version.  OpenSubdiv
     * versions differ in one rule that changes limit points: a non-manifold
     * vertex with exactly two non-manifold edges, no boundary edge and more
     * faces than edges is taken as a vertex on a non-manifold crease and
     * left smooth; up to 3.6.0 that is all, later versions (3.7.0, bundled
     * with Blender 5.1 and later) also require every manifold fan of faces
     * around it to run from one of the two edges to the other, and make
     * the vertex infinitely sharp (its limit point is itself) otherwise.
     * That happens where double-sided fins (a triangle and its reversed
     * twin) hang from two edges of a vertex, as in scans.  0, or any value
     * up to 30600: the rule of OpenSubdiv 3.5 and 3.6.0 (Blender 3.x to
     * 5.0); above 30600: the later rule.  Loop and Doo-Sabin ignore it.
     * [0] */
    int32_t opensubdiv_version;
    /* spia_solve and spia_interpolate: the first iterate, row_count * 3
     * finite floats (for example the cage solved before the mesh was edited
     * a little, which then needs fewer iterations to reach the same
     * tolerance); NULL: the targets, as PIA starts.  It may alias the cage
     * buffer.  spia_fit ignores it. [NULL] */
    const float *initial_cage;
    /* SPIA_SOLVE_* flags. [0] */
    int32_t solve_flags;
    /* The memory, in bytes, a call may use.  Every call first estimates
     * what the settings in force make it need (the stencil table of the
     * mesh, the faces refine and subdivide make at their levels, a fit's
     * samples at its samples_per_edge) and, where that is more, returns
     * SPIA_ERROR_OUT_OF_MEMORY at once with a message that names the
     * setting, the estimate and what would fit, having allocated nothing.
     * 0: what spia_available_memory() reports when the call starts; a
     * negative value: no check (allocations that fail are still reported
     * as SPIA_ERROR_OUT_OF_MEMORY). [0] */
    int64_t memory_budget;
} spia_options;

/* The defaults, as a value (the same as an all-zero struct). */
SPIA_API spia_options spia_options_default(void);

/* The memory, in bytes, the machine can give a call now (the default
 * memory_budget): on Linux the kernel's MemAvailable, within a cgroup's
 * memory limit and the address space left under RLIMIT_AS (ulimit -v);
 * on Windows the available physical memory, within the process's virtual
 * address space; on macOS the machine's physical memory, within RLIMIT_AS.
 * -1 where it cannot be told (no check is made then). */
SPIA_API int64_t spia_available_memory(void);

/* ------------------------------------------------------------------------ */
/* Validation                                                                */
/* ------------------------------------------------------------------------ */

/*
 * Checks a mesh the way every other function does before it works on it:
 * counts, pointers, face sizes, index ranges, degenerate faces, finite
 * positions, creases.  Returns SPIA_OK or the first problem found.
 */
SPIA_API spia_result spia_mesh_validate(const spia_mesh *mesh, spia_status *status);

/* ------------------------------------------------------------------------ */
/* Limit stencils                                                            */
/* ------------------------------------------------------------------------ */

/*
 * A limit stencil table: one row per control vertex, in vertex order.  Row i
 * holds the weights w_ij over control vertices j such that sum_j w_ij V_j is
 * the limit point of vertex i.  Rows are stored as CSR (compressed sparse
 * rows): row i occupies entries offsets[i] .. offsets[i+1]-1 of indices and
 * weights; column indices within a row are increasing and unique.
 */
typedef struct spia_stencils spia_stencils;

/*
 * Builds the limit stencils of `mesh` under `options` (scheme,
 * boundary_smooth, ignore_creases, quality, boundary_rule and the shape
 * parameters are used; the solver fields are ignored; the progress callback
 * may cancel before the work starts and after it ends).  Loop needs
 * triangles and Doo-Sabin a closed mesh (SPIA_ERROR_TOPOLOGY, with counts,
 * otherwise).  On success *out receives a table to be freed with
 * spia_stencils_free.  On failure *out is set to NULL.
 */
SPIA_API spia_result spia_limit_stencils_create(const spia_mesh *mesh, const spia_options *options,
                                                spia_stencils **out, spia_status *status);

/* Frees a table from spia_limit_stencils_create.  NULL is allowed. */
SPIA_API void spia_stencils_free(spia_stencils *stencils);

/* Number of rows (control vertices) and of stored weights. */
SPIA_API int32_t spia_stencils_row_count(const spia_stencils *stencils);
SPIA_API int64_t spia_stencils_weight_count(const spia_stencils *stencils);

/*
 * Copies the table out as CSR arrays into caller buffers of sizes
 * row_count + 1 (offsets), weight_count (indices) and weight_count (weights).
 * Any of the three may be NULL to skip it.  The library keeps most tables
 * in the solver's compact layout alone (about 40 bytes a vertex on a quad
 * mesh, against 150 as CSR) and rebuilds the arrays from it, to the bit.
 * SPIA_ERROR_OUT_OF_MEMORY is possible only where offsets is NULL and
 * indices or weights are not (the library then makes the offsets itself).
 */
SPIA_API spia_result spia_stencils_copy_csr(const spia_stencils *stencils, int64_t *offsets,
                                            int32_t *indices, double *weights);

/*
 * Limit points of a cage: out[i] = sum_j w_ij cage[j], for row_count points of
 * 3 doubles each.  `cage` and `out` must not overlap.
 */
SPIA_API spia_result spia_stencils_apply(const spia_stencils *stencils, const double *cage, double *out);

/* ------------------------------------------------------------------------ */
/* Solving                                                                   */
/* ------------------------------------------------------------------------ */

typedef struct spia_report {
    spia_result result;        /* what the call returned                               */
    spia_method method;        /* the method actually used (AUTO resolved)             */
    int32_t iterations;        /* iterations carried out                               */
    double diagonal;           /* bounding-box diagonal of the targets                 */
    double max_error;          /* max_i |P_i - (L V)_i| for the cage written            */
    double mean_error;         /* mean of the same distances                           */
    double max_error_relative; /* max_error / diagonal                                 */
    double mean_error_relative;
    double initial_max_error_relative; /* the same before any iteration (the first iterate) */
    /* Vertices that cannot reach their targets (see SPIA_STAGNATED), and the
     * relative max error over all the others. */
    int32_t unreachable_count;
    double reachable_max_error_relative;
    double weight;             /* WPIA: the weight used, else 0                       */
    /* staged: iterations of the boundary stage and of the interior stage. */
    int32_t stage_iterations[2];
    double stencil_seconds;    /* wall time building stencils (spia_interpolate only)  */
    double solve_seconds;      /* wall time in the solver                              */
    /* Optional caller-owned buffer: the relative max error after each
     * iteration is written to history[k] for k < history_capacity. */
    double *history;
    int32_t history_capacity;
    int32_t history_count;     /* entries written */
    /* Optional caller-owned buffer of row_count flags: 1 for an unreachable
     * vertex, else 0.  Written whenever a cage is written. */
    uint8_t *unreachable;
} spia_report;

/*
 * Solves for a cage V with (L V)_i = targets_i, L the stencil table.
 *
 *   targets   row_count * 3 floats: the points the limit surface must pass
 *             through (usually the mesh's own positions).
 *   cage      row_count * 3 floats, written on success, SPIA_MAX_ITERATIONS
 *             and SPIA_STAGNATED; untouched on failure.  May alias targets.
 *   report    optional; filled in whatever the outcome.
 *
 * Uses options->method, tolerance, max_iterations, weight, staged and the
 * progress callback.  Where the method chosen stagnates or its error grows
 * without bound, least squares takes over (SPIA_METHOD_LEAST_SQUARES, with
 * up to max_iterations more iterations) and the result is SPIA_OK or
 * SPIA_STAGNATED; SPIA_ERROR_DIVERGED only if a NaN or infinity arises
 * even so.  GS-PIA refuses a table with a zero or negative diagonal
 * entry and CG one without the D S form, as SPIA_ERROR_INVALID_ARGUMENT.
 */
SPIA_API spia_result spia_solve(const spia_stencils *stencils, const float *targets,
                                const spia_options *options, float *cage, spia_report *report,
                                spia_status *status);

/*
 * The whole path: validate, build stencils, solve with the mesh's positions
 * as targets, write the cage (vertex_count * 3 floats).  Equivalent to
 * spia_limit_stencils_create + spia_solve + spia_stencils_free.
 */
SPIA_API spia_result spia_interpolate(const spia_mesh *mesh, const spia_options *options, float *cage,
                                      spia_report *report, spia_status *status);

/* ------------------------------------------------------------------------ */
/* Refinement (previews of surfaces Blender cannot show)                     */
/* ------------------------------------------------------------------------ */

/*
 * The surface of `mesh` (a cage) refined `levels` times (0 to 8), for the
 * schemes Blender's modifier cannot show:
 *   LOOP       triangles, every vertex moved to its limit position (uses
 *              boundary_rule, boundary_smooth, ignore_creases);
 *   DOO_SABIN  phase one with the shape parameters, then regular Doo-Sabin:
 *              the refined control mesh, whose face centroids lie on the
 *              limit surface (closed, consistently oriented manifold meshes).
 * Catmull-Clark is refused: Blender's modifier shows it.
 *
 * spia_refine_size writes the counts of vertices, faces and face corners
 * (in closed form: it costs a small part of the refinement, at most its
 * first Doo-Sabin step, which checks the mesh); spia_refine then fills
 * caller buffers of vertex_count * 3 floats, face_count ints (corners per
 * face) and corner_count ints (face vertices, faces one after another).
 * For LOOP, vertices 0 .. mesh->vertex_count - 1 are the limit points of
 * the control vertices (vertices no face uses stay where they are).
 *
 * spia_refine calls the options' progress callback on the calling thread
 * at the end of each level (the last one's once its positions are
 * computed, before anything is written) and in between about every 0.1 s
 * from its own loops.  Some steps are single calls that grow with the
 * faces made: OpenSubdiv's refinement of the topology for the LOOP rule
 * SMOOTH (one call for all levels, about 0.15 s per million faces made),
 * a level's adjacency and, for LOOP, its
 * interpolation, limit positions and the writing of the output.  Measured
 * on a 131k-triangle cage refined three times (8.4 million faces):
 * at most 0.11 s without a call for DOO_SABIN, 0.5 s for LOOP with
 * Hoppe's rule, 1.2 s for SMOOTH.  iteration is the level under way (1 to
 * levels; 0 for levels 0) and relative_error the share of the refinement
 * done, by face counts (each level four times the one before), 1 at the
 * last call.  Returning nonzero cancels: SPIA_ERROR_CANCELLED, nothing
 * written.
 */
SPIA_API spia_result spia_refine_size(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                      int32_t *vertex_count, int32_t *face_count, int64_t *corner_count,
                                      spia_status *status);
SPIA_API spia_result spia_refine(const spia_mesh *mesh, const spia_options *options, int32_t levels, float *positions,
                                 int32_t *face_sizes, int32_t *face_vertices, spia_status *status);


/*
 * The cage itself subdivided `levels` times (1 to 6) by Catmull-Clark: the
 * control mesh of the same limit surface with four times the faces a level,
 * as the levels of a Multires modifier are built.  Sharpness carries over as OpenSubdiv refines it
 * (one step softer a level), written back as Blender's creases so that the
 * refined mesh, read with the same options, has the cage's limit surface:
 * every edge of the last level with its crease, and every vertex's crease
 * (where Blender adds the smaller sharpness of a vertex's two edges, that
 * share is taken off the vertex crease first).  Catmull-Clark only.
 *
 * Vertex i of the result is the child of vertex i of the cage (vertices no
 * face uses stay where they are; loose edges are not carried, but the
 * vertex sharpness they gave their ends is); the vertices made on edges
 * and faces follow, in OpenSubdiv's order.  Every face is a quad.
 * spia_subdivide_size writes the counts in closed form; spia_subdivide then
 * fills caller buffers of vertex_count * 3 floats, face_count * 4 ints and,
 * where not NULL, edge_count * 2 ints, edge_count floats and vertex_count
 * floats.  The options' progress callback is called at the end of each
 * level (iteration: the level; relative_error: the share done), and
 * cancels as elsewhere.
 */
SPIA_API spia_result spia_subdivide_size(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                         int32_t *vertex_count, int32_t *face_count, int32_t *edge_count,
                                         spia_status *status);
SPIA_API spia_result spia_subdivide(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                    float *positions, int32_t *face_vertices, int32_t *edges, float *edge_creases,
                                    float *vertex_creases, spia_status *status);

/* ------------------------------------------------------------------------ */
/* Sharpness                                                                 */
/* ------------------------------------------------------------------------ */

/* spia_sharpness flags. */
enum {
    /* Leave Blender's two-edge rule out (a file for Blender, whose importer
     * applies it again when it reads the sharpness). */
    SPIA_SHARPNESS_NO_TWO_EDGE_RULE = 1
};

/*
 * The sharpness the library hands OpenSubdiv for `mesh` under `options`
 * (scheme and ignore_creases are used), in the mesh's own numbering, for
 * writing the mesh where the same surface is to be rebuilt (USD):
 *   - creases c in [0, 1] become sharpness c * c * 10 (float); face edges
 *     below 1e-6 are left out; an edge listed more than once takes its
 *     largest; edges used by no face carry none;
 *   - Catmull-Clark (Blender's rules): the ends of edges used by no face
 *     are infinitely sharp (10), and a vertex with exactly two face edges
 *     gets the smaller of their sharpnesses added to its own, capped at 10
 *     (unless flags has SPIA_SHARPNESS_NO_TWO_EDGE_RULE).
 * Writes *crease_count, the creased face edges; where not NULL,
 * crease_pairs (2 * count ints: each edge's smaller vertex index, then its
 * larger, edges sorted by them) and crease_sharpness (count floats) must
 * have room for them (call once with both NULL for the count), and
 * vertex_sharpness receives vertex_count floats (0 for vertices no face
 * uses).
 */
SPIA_API spia_result spia_sharpness(const spia_mesh *mesh, const spia_options *options, int32_t flags,
                                    int32_t *crease_count, int32_t *crease_pairs, float *crease_sharpness,
                                    float *vertex_sharpness, spia_status *status);

/* ------------------------------------------------------------------------ */
/* Limit surface samples                                                     */
/* ------------------------------------------------------------------------ */

/*
 * Limit stencils at points inside the faces of `mesh`, Catmull-Clark only,
 * on the patches Blender's modifier builds (same quality, creases and
 * boundary settings as spia_limit_stencils_create).  Every ptex face (a
 * quad, or the sub-quad at each corner of a triangle or n-gon, corners in
 * face order) gets samples_per_edge^2 samples (1 to 64) at the centres of a
 * regular grid: sample  (ptex * k + j) * k + i  (k = samples_per_edge) lies
 * at (s, t) = ((i + 0.5) / k, (j + 0.5) / k).  spia_surface_sample_count
 * gives the number of rows without building them.  Row r of the table
 * holds the weights over control vertices whose sum is sample r; free the
 * table with spia_stencils_free.
 */
SPIA_API spia_result spia_surface_stencils_create(const spia_mesh *mesh, const spia_options *options,
                                                  int32_t samples_per_edge, spia_stencils **out,
                                                  spia_status *status);
SPIA_API int64_t spia_surface_sample_count(const spia_mesh *mesh, int32_t samples_per_edge);

/* ------------------------------------------------------------------------ */
/* Scans: closest points                                                     */
/* ------------------------------------------------------------------------ */

/*
 * A scan (any polygon mesh, usually a dense triangle mesh) prepared for
 * closest-point queries: the library's own bounding volume hierarchy over
 * its triangles (polygons are cut into fans; faces that repeat a vertex are
 * left out), built on every processor, about 40 bytes a triangle, and smooth
 * vertex normals (area-weighted).  The positions are copied; `mesh` need
 * not outlive the call.  Only vertex_count, positions, face_count,
 * face_sizes and face_vertices are read.  Fails with SPIA_ERROR_EMPTY_MESH
 * for a scan without faces.  Free with spia_scan_free.
 */
typedef struct spia_scan spia_scan;
SPIA_API spia_result spia_scan_create(const spia_mesh *mesh, spia_scan **out, spia_status *status);
/* spia_scan_create with a progress callback, called on the calling thread
 * about every 0.1 s of the build and once at its end: iteration is the
 * phase (1 checking the mesh, 2 triangles and normals, 3 the hierarchy, 4
 * the boundary) and relative_error the fraction of the whole build done,
 * 0 to 1.  Returning nonzero cancels: SPIA_ERROR_CANCELLED, within a
 * fraction of a second (every thread stops at its next check), with
 * nothing left allocated and *out NULL.  progress may be NULL. */
SPIA_API spia_result spia_scan_create_progress(const spia_mesh *mesh, spia_progress_fn progress,
                                               void *progress_user_data, spia_scan **out, spia_status *status);
SPIA_API void spia_scan_free(spia_scan *scan);
/* The bounding-box diagonal of the scan's faces, the unit of every relative
 * distance the fitting reports. */
SPIA_API double spia_scan_diagonal(const spia_scan *scan);

/*
 * For each of `count` points (3 floats each), the closest point on the scan
 * and, into whichever of these caller buffers are not NULL: closest
 * (count * 3 floats), normals (count * 3 floats: the scan's smooth unit
 * normal there), distances (count floats), faces (count ints: the scan
 * polygon it lies on) and on_boundary (count bytes: 1 when the closest point
 * is on the scan's boundary, an edge only one triangle uses or one of its
 * vertices: the query point is then beyond the scan's edge, over a hole).
 * The closest point is the one a search over every triangle finds: the
 * least distance (computed in double), and of triangles at equal distance
 * the first (in the order of the faces and their fans), whatever the
 * number of threads.
 * Safe to call from several threads on one scan.
 */
SPIA_API spia_result spia_scan_closest_points(const spia_scan *scan, int64_t count, const float *points,
                                              float *closest, float *normals, float *distances, int32_t *faces,
                                              uint8_t *on_boundary, spia_status *status);
/* spia_scan_closest_points with a progress callback, called on the calling
 * thread about every 0.1 s and once at the end: iteration 1, and
 * relative_error the fraction of the points done (roughly: points are
 * taken in pieces).  Nonzero cancels within a fraction of a second:
 * SPIA_ERROR_CANCELLED, with the buffers partly written.  progress may be
 * NULL. */
SPIA_API spia_result spia_scan_closest_points_progress(const spia_scan *scan, int64_t count, const float *points,
                                                       float *closest, float *normals, float *distances,
                                                       int32_t *faces, uint8_t *on_boundary,
                                                       spia_progress_fn progress, void *progress_user_data,
                                                       spia_status *status);

/* ------------------------------------------------------------------------ */
/* Fitting a cage to a scan                                                  */
/* ------------------------------------------------------------------------ */

typedef enum spia_fit_mode {
    /* The limit surface as a whole: samples of it (spia_surface_stencils)
     * are pulled to their closest points on the scan, by point-to-plane
     * least squares along the scan's normals with a small point-to-point
     * term, a fairness term on the cage, and closest points found again
     * after every round.  Catmull-Clark only. */
    SPIA_FIT_SURFACE = 0,
    /* The cage's limit points only: each is moved to its closest point on
     * the scan, and the cage is solved to interpolate them (spia_solve with
     * the spia_options given).  One projection is enough: the solved limit
     * points lie on the scan, so projecting again changes nothing.  Any
     * scheme. */
    SPIA_FIT_VERTICES = 1
} spia_fit_mode;

/* All zeros means the defaults given in brackets. */
typedef struct spia_fit_options {
    spia_fit_mode mode;        /* [SURFACE] */
    int32_t samples_per_edge;  /* samples per ptex face edge, 1 to 64 [4] (16 per quad)              */
    /* A sample (or, for VERTICES, a limit point) whose closest scan point is
     * farther than cutoff * scan diagonal is over a hole or off the scan: it
     * does not pull.  Nor does one whose closest point is on the scan's
     * boundary (over a hole, however near its rim).  [0.02] */
    double cutoff;
    /* Fairness: weight of |Laplacian(cage - initial cage)|^2 per cage vertex
     * against the squared distances of the samples, per sample.  Keeps the
     * cage's shape where samples say nothing (holes) and stops ripples;
     * larger is smoother and farther from the scan.  Negative for none.
     * [1e-5] */
    double smoothing;
    /* Weight of the point-to-point distance next to the point-to-plane one
     * (1 = both alike); it lets samples slide along the scan less.
     * Negative for none.  [1e-3] */
    double point_weight;
    int32_t max_rounds;        /* projection + least-squares rounds [16]                             */
    /* Stop after two rounds in a row that lowered the best mean distance by
     * less than this fraction (the cage written is the best one seen). [0.01] */
    double round_tolerance;
    int32_t solver_iterations; /* conjugate gradient steps per round [20]                            */
    /* SURFACE: how far a sample may be before it pulls less, as a multiple
     * of the median distance of the samples within the cut-off (the
     * robust kernel's scale): a sample at distance d pulls with weight
     * 1 / (1 + (d / (robust_scale * median))^2), so stray scan parts,
     * noise blobs and a base plate that the surface does not belong to
     * lose their pull as the fit closes in.  [6] */
    double robust_scale;
    /* SURFACE: weight, next to the point-to-plane one, of each sample's
     * sideways move (along the scan's tangent plane) within a round.
     * Point-to-plane lets samples slide, which is what makes the fit
     * converge in few rounds, but lets neighbouring samples slide over
     * one another into a pleat whose middle layer faces away from the
     * scan; this holds them back a little each round, at a price in
     * accuracy (on the bunny, 0.01 halves the folds left by the fold guard
     * and raises the mean distance by a sixth).  Below 1.  [0: none] */
    double slide_weight;
    uint32_t flags;            /* spia_fit_flags, or-ed [0]                                          */
} spia_fit_options;

typedef enum spia_fit_flags {
    /* SURFACE: no fold guard.  By default a sample whose limit normal faces
     * away from the scan's normal at its closest point (a fold, or a
     * sample caught by the wrong side of a thin part) does not pull, and
     * the cage around it is smoothed, twice as firmly for every round in
     * which it stays folded; and neighbouring samples on the scan whose
     * grid starts to turn over (one sliding past the other along the
     * scan) are pushed apart by a small extra term. */
    SPIA_FIT_ALLOW_FOLDS = 1,
    /* SURFACE: the cut-off alone decides which samples pull (weight 1
     * within it, 0 beyond), with no robust kernel. */
    SPIA_FIT_HARD_CUTOFF = 2,
    /* Leave out the scan-to-surface distances (scan_before, scan_after),
     * which cost a grid of limit points, a hierarchy over it and a query
     * per scan vertex. */
    SPIA_FIT_NO_SCAN_DISTANCES = 4,
    /* SURFACE (samples_per_edge 2 or more): the scan pulls too.  Every
     * round, each scan vertex within the cut-off pulls the surface's
     * nearest sample (one that pulls itself) along the scan's normal at
     * that sample's closest point, weighted by the robust kernel, and all
     * of them together as much as all the samples: the surface meets the
     * scan from both sides, reaching into the scan's detail between the
     * samples' closest points (its vertices, its ridges) instead of
     * cutting across it.  For fits that start on the scan (detail
     * levels). */
    SPIA_FIT_SCAN_PULL = 8,
    /* SURFACE with the fold guard: leave the cage's rims free.  By default
     * the vertices of every face with a vertex on the cage's boundary
     * start ten times as smooth as the others: a rim has samples on one
     * side only to hold it, and a fit curls it over onto the scan beyond
     * it (on an open cage of a holed scan, 0.7% of the level-3 surface
     * turned over against the cage given, 0.1% with the rims held).  For
     * fits that start on the scan (detail levels), whose rims have no
     * fold to make and reach the scan's edge closer free. */
    SPIA_FIT_FREE_RIMS = 16,
    /* Measure the scan-to-surface distances of the cage written only
     * (scan_after; scan_before stays zero): one measure of every scan
     * vertex fewer, where the distances to the cage given are known or
     * not wanted (a finest detail level starts on the surface of the level
     * above: on a 50k-vertex cage's third level, 3.2M faces, its queries
     * took 1.3 s less). */
    SPIA_FIT_NO_SCAN_BEFORE = 32
} spia_fit_flags;

typedef struct spia_fit_distances {
    double mean, p95, max;     /* over the samples within the cutoff, relative to the scan diagonal  */
    int64_t ignored;           /* samples beyond the cutoff                                          */
} spia_fit_distances;

typedef struct spia_fit_report {
    spia_result result;
    spia_fit_mode mode;
    int32_t rounds;            /* rounds carried out (VERTICES: 1)                                   */
    int64_t sample_count;
    double diagonal;           /* of the scan                                                        */
    /* Distances of the limit surface (the samples) to the scan, for the
     * cage given and for the cage written.  Loop and Doo-Sabin (VERTICES
     * only) have no samples: their limit points are measured instead, and
     * sample_count is the vertex count. */
    spia_fit_distances before, after;
    /* VERTICES: the interpolation's report (iterations, errors). */
    int32_t iterations;
    double max_error_relative;
    double stencil_seconds, query_seconds, solve_seconds;
    /* Optional caller-owned buffer of cage vertex_count floats: for each
     * vertex, the largest relative distance to the scan of the samples on
     * the faces around it (after the fit; 0 where no sample counts); for
     * Loop and Doo-Sabin, the distance of its limit point. */
    float *vertex_distances;
    /* Optional caller-owned buffer: the mean relative distance after each
     * round, history[0] being the cage given. */
    double *history;
    int32_t history_capacity;
    int32_t history_count;
    /* Catmull-Clark: samples within the cut-off, not over a hole, whose limit normal (from
     * their neighbours on the sample grid) faces away from the scan's
     * normal at the closest point, the orientation being the one most of
     * the cage given agrees on; -1 when samples_per_edge is 1. */
    int64_t folded_before, folded_after;
    /* Distances the other way: from each scan vertex that a face uses to
     * the limit surface (as a grid of its points with 2^levels quads along
     * each ptex face's edge, levels = ceil(log2 samples_per_edge) + 1, one
     * fewer at a time while that would make more than 2M quads, down to
     * one level; a grid still larger is searched through its ptex faces'
     * corners, each scan vertex then measured against the grid's quads of
     * the face found), relative to the scan's diagonal, for the cage given
     * and the cage written.  `ignored` counts the scan vertices farther
     * than the cut-off: scan parts the surface does not reach.  Catmull-Clark only; all zero with
     * SPIA_FIT_NO_SCAN_DISTANCES, scan_before zero with SPIA_FIT_NO_SCAN_BEFORE. */
    int64_t scan_point_count;
    spia_fit_distances scan_before, scan_after;
    /* Optional caller-owned buffer of the scan's vertex_count floats: each
     * scan vertex's relative distance to the limit surface of the cage
     * written (-1 for vertices no scan face uses).  For a heat map. */
    float *scan_distances;
    /* Optional caller-owned buffer of cage vertex_count * 3 floats: for a
     * Catmull-Clark cage of quads (a subdivided cage, a detail level),
     * spia_flat_positions of the cage written, computed from the grid of
     * limit points that measured the scan's distances (so not with
     * SPIA_FIT_NO_SCAN_DISTANCES) instead of stencils of its own: a fifth
     * of spia_flat_positions' time, and less memory.  flat_positions_written
     * is 1 when it was written; 0 otherwise (another cage, or they could
     * not be made: too little memory left, say), and spia_flat_positions
     * gives them, or says why not.  A cancel while they are made cancels
     * the fit. */
    float *flat_positions;
    int32_t flat_positions_written;
} spia_fit_report;

/*
 * Moves the vertices of `cage` so that its limit surface lies on `scan`.
 * `options` gives the subdivision settings (scheme, quality, creases,
 * boundary) and, for VERTICES, the solver settings; its progress callback
 * is called after every round with the round and the mean relative
 * distance (VERTICES: the solve's iterations), and also at least every
 * 0.1 s within the long steps, repeating the last call's figures (0 and
 * the cage given's mean before any), and cancels as elsewhere.
 *
 * Returns SPIA_OK; or SPIA_MAX_ITERATIONS when SURFACE used max_rounds with
 * the distances still falling, or the VERTICES solve stopped short of its
 * tolerance (SPIA_STAGNATED likewise): the cage written is usable then.
 * Fails with SPIA_ERROR_INVALID_ARGUMENT when no sample (no limit point) is
 * within the cut-off: the cage does not lie on the scan.  `cage_out`
 * (vertex_count * 3 floats) is written unless the call fails.  It may alias
 * cage->positions.  Vertices no face uses keep their positions.
 */
SPIA_API spia_result spia_fit(const spia_mesh *cage, const spia_scan *scan, const spia_options *options,
                              const spia_fit_options *fit, float *cage_out, spia_fit_report *report,
                              spia_status *status);

/*
 * Positions for the vertices of a quad mesh `mesh` (a cage subdivided: every
 * face a quad) such that its faces drawn flat, as Blender's Multires draws
 * its finest level, lie as close as they can to the mesh's Catmull-Clark
 * limit surface: the limit points at each quad's corners, edge midpoints and
 * centre against the bilinear quad through the new positions, in least
 * squares (the corners weighted a sixteenth, which keeps a checkerboard of
 * the vertices determined).  The limit points of the
 * vertices themselves draw flat faces that cut inside convex parts and
 * outside concave ones by their sagitta; these straddle the surface
 * instead.  `out` holds vertex_count * 3 floats; vertices no face uses keep
 * their positions.  options as for spia_limit_stencils_create (Catmull-Clark
 * only); its progress callback is called about every 0.1 s with iteration 0
 * and relative_error 0, and cancels.  Fails with SPIA_ERROR_FACE_SIZE for a
 * face that is not a quad.
 */
SPIA_API spia_result spia_flat_positions(const spia_mesh *mesh, const spia_options *options, float *out,
                                         spia_status *status);

#ifdef __cplusplus
}
#endif

#endif /* SUBDIV_PIA_H */
