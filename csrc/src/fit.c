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
 * cage is solved to interpolate them.
 *
 * This file holds the options and the memory limits, the stages of a fit and
 * its rounds; fit.h lists the files that hold the rest. */
#include "fit.h"

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
                           SPIA_FIT_FREE_RIMS | SPIA_FIT_NO_SCAN_BEFORE;
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
spia_result spia__fit_samples_memory(const spia_mesh *m, const spia_options *o, int32_t k, int surface,
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
    if ((r = spia__fit_samples_memory(mesh, &opt, samples_per_edge, 1, "a table of surface samples", status)) !=
        SPIA_OK)
        return r;
    spia_adjacency adj;
    if ((r = spia__adjacency_build(mesh, &adj, status)) != SPIA_OK) return r;
    r = spia__osd_surface_stencils(mesh, &adj, &opt, samples_per_edge, out, status);
    spia__adjacency_free(&adj);
    return r;
}

/* The solver's progress, passed on and remembered (for the ticks to repeat). */
static int clock_forward(void *user, int32_t iteration, double value) {
    fit_clock *c = (fit_clock *)user;
    c->round = iteration, c->mean = value, c->last = spia__now();
    if (c->fn(c->user, iteration, value)) c->cancelled = 1;
    return c->cancelled;
}

/* ---- the entry point -------------------------------------------------------- */

/* The rounds' own buffers (the solver's, the weights, the fold guard's and
 * the scan's pull's, with its hierarchy over the samples), freed as soon as
 * the rounds are over, before the measures of the cage written: the scan's
 * then builds its grid's hierarchy where the cage given was not measured
 * (SPIA_FIT_NO_SCAN_BEFORE), and the peak stays that of the rounds. */
static void rounds_free(fit_buffers *b) {
    free(b->work), free(b->precond), free(b->tmp_n), free(b->tmp_diag), free(b->wts);
    free(b->hold), free(b->smooth), free(b->bar), free(b->bar_start), free(b->start_n), free(b->start_len);
    b->work = b->precond = b->tmp_n = b->tmp_diag = b->hold = b->smooth = NULL;
    b->wts = NULL, b->start_n = NULL, b->start_len = NULL;
    b->bar = NULL, b->bar_start = NULL, b->bar_capacity = 0;
    spia_scan_free(b->pull_surface);
    b->pull_surface = NULL;
    free(b->pull_pos), free(b->pull_d), free(b->pull_sizes), free(b->pull_quads), free(b->pull_near);
    free(b->pull_faces), free(b->pull_w), free(b->pull_off);
    b->pull_pos = b->pull_d = NULL;
    b->pull_sizes = b->pull_quads = b->pull_near = b->pull_faces = NULL;
    b->pull_w = b->pull_off = NULL;
}

/* Every buffer: the rounds' (rounds_free, a second time harmless) and the
 * rest. */
static void buffers_free(fit_buffers *b) {
    rounds_free(b);
    spia__fit_blocks_free(&b->blocks);
    spia_stencils_free(b->L);
    free(b->V0), free(b->V), free(b->best), free(b->X), free(b->near);
    free(b->T), free(b->N), free(b->d), free(b->scratch), free(b->targets), free(b->solved), free(b->on_boundary);
    free(b->nb_start), free(b->nb), free(b->free_vertex), free(b->sample_face);
    free(b->dots), free(b->folded), free(b->mark);
    spia__fit_blocks_free(&b->grid);
    spia_scan_free(b->surface);
    free(b->grid_pos), free(b->scan_d), free(b->scan_scratch), free(b->grid_sizes);
    free(b->grid_quads), free(b->scan_vertex), free(b->coarse_pos), free(b->scan_face);
    free(b->scan_near);
    free(b->scan_pts);
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
    spia__fit_blocks_apply(&b->blocks, V, b->X);
    if (!b->evaluated)
        for (int64_t s = 0; s < S; ++s) b->near[s] = -1;
    const int cancelled = spia__fit_closest_in_chunks(scan, S, b->X, b->near, b->T, b->N, b->d, NULL,
                                            b->on_boundary, threads, clock);
    b->evaluated = 1;
    *query_seconds += spia__now() - t0;
    return cancelled;
}

/* Every field of the report but the caller's buffers starts afresh. */
static void report_start(spia_fit_report *report) {
    spia_fit_report fresh;
    memset(&fresh, 0, sizeof fresh);
    fresh.vertex_distances = report->vertex_distances;
    fresh.history = report->history;
    fresh.history_capacity = report->history_capacity;
    fresh.scan_distances = report->scan_distances;
    fresh.flat_positions = report->flat_positions;
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
        /* With the scan's distances to measure, the grid they are measured
         * on too: the two from one OpenSubdiv topology and one surface a
         * face (on a detail level of 3.2M faces, 1.6 s and 0.6 s saved). */
        sample_blocks *sets[2] = {&b->blocks, &b->grid};
        const int32_t per_edge[2] = {u->fo.samples_per_edge, spia__fit_scan_grid_side(u->cage, u->fo.samples_per_edge)};
        const int corners[2] = {0, 1};
        const int count = u->fo.flags & SPIA_FIT_NO_SCAN_DISTANCES ? 1 : 2;
        const spia_result r = spia__fit_blocks_build_sets(u->cage, &u->adj, &u->surface_opt, count, per_edge, corners,
                                                          sets, &u->clock, u->status);
        if (r != SPIA_OK) return r;
        u->S = b->blocks.groups * b->blocks.per;
    }
    u->report->sample_count = u->S;
    u->report->stencil_seconds += spia__now() - t0;

    const int64_t N3 = u->N3;
    b->V0 = malloc(sizeof(double) * (size_t)N3);
    b->V = malloc(sizeof(double) * (size_t)N3);
    b->best = malloc(sizeof(double) * (size_t)N3);
    if (!b->V0 || !b->V || !b->best) return spia__fit_oom(u);
    for (int64_t i = 0; i < N3; ++i) b->V0[i] = b->V[i] = b->best[i] = u->cage->positions[i];
    return SPIA_OK;
}

/* The scan's vertices measured against the cage given's surface (see
 * scan_side_prepare); only prepared for the cage written's measure with
 * SPIA_FIT_NO_SCAN_BEFORE. */
static spia_result measure_scan_given(fit_run *u) {
    fit_buffers *b = &u->b;
    const double t0 = spia__now();
    spia_result r = spia__fit_scan_side_prepare(u->cage, u->fo.samples_per_edge, u->scan, b, &u->clock, u->status);
    if (r != SPIA_OK) return r == SPIA_ERROR_OUT_OF_MEMORY ? spia__fit_oom(u) : r;
    if (!(u->fo.flags & SPIA_FIT_NO_SCAN_BEFORE) &&
        (r = spia__fit_scan_side_measure(b, b->V0, u->cutoff_abs, u->diagonal, u->opt.threads, 0, &u->clock,
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
    if (!b->X || !b->T || !b->N || !b->d || !b->scratch || !b->on_boundary || !b->near) return spia__fit_oom(u);
    spia_result r = build_sample_faces(u->cage, u->fo.samples_per_edge, S, b);
    if (r != SPIA_OK) {
        if (r == SPIA_ERROR_OUT_OF_MEMORY) return spia__fit_oom(u);
        return spia__fail(u->status, SPIA_ERROR_INTERNAL, -1, "the samples do not match the cage's faces");
    }
    if (evaluate(u->scan, b, b->V, S, u->opt.threads, &report->query_seconds, &u->clock)) return spia__fit_cancelled(u);
    report->before = spia__fit_distance_stats(b->d, S, u->cutoff_abs, u->diagonal, b->scratch);
    u->measured_best = 1;
    u->clock.mean = report->before.mean;
    if (report->before.ignored >= S) return nothing_to_fit(u->status, "sample of the cage's limit surface", u->fo.cutoff);
    b->dots = malloc(sizeof(float) * (size_t)S);
    b->folded = malloc((size_t)S);
    if (!b->dots || !b->folded) return spia__fit_oom(u);
    spia__fit_normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots, u->opt.threads);
    u->sign = spia__fit_orientation(b->dots, b->d, b->on_boundary, S, u->cutoff_abs);
    report->folded_before = spia__fit_find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
    if (u->fo.samples_per_edge < 2) report->folded_before = -1;
    if (u->fo.samples_per_edge >= 2 && !(u->fo.flags & SPIA_FIT_ALLOW_FOLDS)) {
        b->start_n = malloc(sizeof(float) * 3 * (size_t)S);
        b->start_len = malloc(sizeof(float) * 2 * (size_t)S);
        if (!b->start_n || !b->start_len) return spia__fit_oom(u);
        spia__fit_start_normals(b->X, b->dots, S, u->fo.samples_per_edge, u->sign, b->start_n, b->start_len,
                                u->opt.threads);
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
        return spia__fit_oom(u);
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
            return spia__fit_oom(u);
        }
        u->report->before = spia__fit_distance_stats(dist, n, u->cutoff_abs, u->diagonal, scratch);
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
        return spia__fit_oom(u);
    for (int32_t v = 0; v < n; ++v) b->hold[v] = b->smooth[v] = 1.0;
    if (guard && !(u->fo.flags & SPIA_FIT_FREE_RIMS) && rim_smoothing(u, b->smooth) != SPIA_OK) return spia__fit_oom(u);
    if (build_neighbours(u->cage, &u->adj, b) != SPIA_OK) return spia__fit_oom(u);
    int64_t counted = S - u->report->before.ignored;
    int32_t free_count = 0;
    for (int32_t v = 0; v < n; ++v) free_count += b->free_vertex[v];
    f->blocks = &b->blocks, f->threads = u->opt.threads, f->n = n, f->S = S;
    f->normals = b->N, f->dist = b->d, f->weight = b->wts;
    f->on_boundary = b->on_boundary, f->cutoff_abs = u->cutoff_abs;
    f->alpha = u->fo.point_weight;
    f->beta = u->fo.slide_weight;
    f->X = b->X;
    f->bar = NULL, f->bar_start = NULL, f->bar_weight = FOLD_BARRIER_WEIGHT;
    if (guard) {
        b->bar_start = malloc(sizeof(int64_t) * ((size_t)b->blocks.groups + 1));
        if (!b->bar_start) return spia__fit_oom(u);
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
    spia__fit_cutoff_weights(b->d, b->on_boundary, S, u->cutoff_abs, b->wts);
    const double kernel_scale = u->fo.robust_scale * spia__fit_median_pulling(b->d, b->wts, S, b->scratch);
    u->kernel_scale = kernel_scale;
    if (!(u->fo.flags & SPIA_FIT_HARD_CUTOFF)) spia__fit_robust_weights(b->d, S, kernel_scale, b->wts);
    if (guard) {
        for (int64_t q = 0; q < S; ++q)
            if (b->folded[q]) b->wts[q] = 0.0f;
        if (b->start_n) spia__fit_facing_start(b->start_n, b->N, S, u->sign, b->wts);
        spia__fit_stiffen(u->cage, &u->adj, b->folded, b->d, kernel_scale, b->sample_face, S, b->mark, b->hold, b->smooth);
        const double reach = FOLD_BARRIER_REACH * kernel_scale < u->cutoff_abs ? FOLD_BARRIER_REACH * kernel_scale
                                                                               : u->cutoff_abs;
        if (spia__fit_barrier_pairs(b->X, b->N, b->d, b->on_boundary, S, u->fo.samples_per_edge, u->sign, reach, b->start_len, &b->bar,
                          &b->bar_capacity, b->bar_start, u->opt.threads))
            return spia__fit_oom(u);
        f->bar = b->bar, f->bar_start = b->bar_start;
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
    if (evaluate(u->scan, b, b->V, S, u->opt.threads, &report->query_seconds, &u->clock)) return spia__fit_cancelled(u);
    spia__fit_normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots, u->opt.threads);
    spia__fit_find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
    const double mean = spia__fit_mean_within(b->d, S, u->cutoff_abs);
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
    double best_score = spia__fit_mean_clamped(b->d, guard ? b->folded : NULL, S, u->cutoff_abs);
    if (report->history && report->history_capacity > 0) {
        report->history[0] = relative(u, spia__fit_mean_within(b->d, S, u->cutoff_abs));
        report->history_count = 1;
    }
    int stale = 0, settled = 0;
    for (int round = 1; round <= u->fo.max_rounds; ++round) {
        const double t0 = spia__now();
        if ((r = round_weights(u, guard, &f)) != SPIA_OK) return r;
        if ((u->fo.flags & SPIA_FIT_SCAN_PULL) && (r = spia__fit_scan_pull(u)) != SPIA_OK) return r;
        report->iterations +=
            spia__fit_least_squares_round(&f, b->T, b->V0, b->V, u->fo.solver_iterations, b->work, b->precond, &u->clock);
        if (u->clock.cancelled) return spia__fit_cancelled(u);
        report->solve_seconds += spia__now() - t0;
        if ((r = round_measure(u, round)) != SPIA_OK) return r;
        /* The distances do not fall monotonically (new closest points,
         * new planes): keep the best cage, and stop after two rounds in
         * a row that improved it by less than round_tolerance. */
        const double score = spia__fit_mean_clamped(b->d, guard ? b->folded : NULL, S, u->cutoff_abs);
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
 * the report and its per-vertex buffer (each search starting from the
 * closest point on the cage given's surface, where that was measured). */
static spia_result measure_scan_written(fit_run *u) {
    fit_buffers *b = &u->b;
    spia_fit_report *report = u->report;
    const double t0 = spia__now();
    const int warm = !(u->fo.flags & SPIA_FIT_NO_SCAN_BEFORE);
    /* Its own status: the grid's hierarchy, built here where the cage
     * given was not measured, says OK on success, and the fit's own word
     * (max_rounds reached) stands. */
    spia_status measured;
    const spia_result r = spia__fit_scan_side_measure(b, b->best, u->cutoff_abs, u->diagonal, u->opt.threads, warm,
                                                      &u->clock, &report->scan_after, &measured);
    if (r != SPIA_OK) {
        if (u->status) *u->status = measured;
        return r;
    }
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
            return spia__fit_cancelled(u);
        spia__fit_normal_agreement(b->X, b->N, S, u->fo.samples_per_edge, b->dots, u->opt.threads);
    }
    report->after = spia__fit_distance_stats(b->d, S, u->cutoff_abs, u->diagonal, b->scratch);
    report->folded_after = u->fo.samples_per_edge < 2
                               ? -1
                               : spia__fit_find_folds(b->dots, b->d, b->on_boundary, S, u->cutoff_abs, u->sign, b->folded);
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
        return spia__fit_oom(u);
    }
    const double t0 = spia__now();
    spia_stencils_apply(u->b.L, u->b.best, Y);
    spia__scan_closest_points_double(u->scan, n, Y, NULL, NULL, NULL, dist, NULL, NULL, u->opt.threads);
    report->query_seconds += spia__now() - t0;
    report->after = spia__fit_distance_stats(dist, n, u->cutoff_abs, u->diagonal, scratch);
    report->sample_count = n;
    if (report->vertex_distances)
        for (int32_t v = 0; v < n; ++v)
            report->vertex_distances[v] = dist[v] <= u->cutoff_abs ? (float)relative(u, dist[v]) : 0.0f;
    free(Y), free(dist), free(scratch);
    return SPIA_OK;
}

/* report->flat_positions: the grid of limit points (the scan side's) of
 * the cage written, taken from the buffers to outlive them, or NULL where
 * there is none or the cage has a face that is not a quad. */
static float *flat_grid_written(fit_run *u, const float *cage_out) {
    fit_buffers *b = &u->b;
    if (!u->report->flat_positions || !u->surface_samples || !b->grid.groups || !b->grid_pos) return NULL;
    for (int32_t f = 0; f < u->cage->face_count; ++f)
        if (u->cage->face_sizes[f] != 4) return NULL;
    /* The cage as written, in float, as spia_flat_positions would read it
     * (b->best is not used again). */
    for (int64_t i = 0; i < u->N3; ++i) b->best[i] = cage_out[i];
    spia__fit_blocks_apply_float(&b->grid, b->best, b->grid_pos);
    float *grid = b->grid_pos;
    b->grid_pos = NULL;
    return grid;
}

/* The flat positions from the grid, once the fit's buffers are freed (their
 * solve's time counts as the fit's solves').  Where they cannot be made
 * (short of memory, say) they are not written, and the fit's result
 * stands: spia_flat_positions says why.  Cancelled, the fit is. */
static spia_result flat_written(fit_run *u, const float *cage_out, const float *grid, spia_result r) {
    spia_mesh written = *u->cage;
    written.positions = (float *)cage_out;
    spia_status flat_status;
    const double t0 = spia__now();
    const spia_result f = spia__flat_solve(&written, grid, u->b.grid_side, u->report->flat_positions, &u->clock,
                                           &flat_status);
    u->report->solve_seconds += spia__now() - t0;
    if (f == SPIA_OK) u->report->flat_positions_written = 1;
    return f == SPIA_ERROR_CANCELLED ? spia__fail(u->status, f, -1, "cancelled computing the flat positions") : r;
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
    float *flat_grid = NULL;
    u.report = report;
    u.status = status;
    spia_result r = fit_arguments(cage, scan, options, fit_options, cage_out, &u);
    if (r != SPIA_OK) return r;
    r = spia__fit_samples_memory(cage, &u.opt, u.fo.samples_per_edge, u.opt.scheme == SPIA_SCHEME_CATMULL_CLARK, "the fit",
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
    rounds_free(&u.b);
    if (u.S > 0)
        r = measure_samples_written(&u, r);
    else if (u.b.L) {
        const spia_result m = measure_limit_points_written(&u);
        if (m != SPIA_OK) r = m;
    }
    if (r < 0) goto done;
    for (int64_t i = 0; i < u.N3; ++i) cage_out[i] = (float)u.b.best[i];
    flat_grid = flat_grid_written(&u, cage_out);
    if (r == SPIA_OK) spia__ok(status);
done:
    buffers_free(&u.b);
    spia__adjacency_free(&u.adj);
    if (flat_grid) {
        r = flat_written(&u, cage_out, flat_grid, r);
        free(flat_grid);
    }
    report->result = r;
    return r;
}
