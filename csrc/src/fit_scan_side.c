// SPDX-License-Identifier: GPL-3.0-or-later
/* The scan side of a fit: the scan's vertices measured against the limit
 * surface (a quad grid of limit points, searched as a scan of its own, or
 * through its ptex faces' corners when too large), and the scan's pull
 * (SPIA_FIT_SCAN_PULL), which searches the samples from the scan. */
#include "bvh.h"
#include "fit.h"
#include "threads.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The clock ticking from a build with a progress callback of its own (the
 * surface's grid as a scan): its phases and fractions are not passed on. */
static int clock_scan_tick(void *user, int32_t phase, double fraction) {
    (void)phase, (void)fraction;
    return spia__fit_clock_tick((fit_clock *)user);
}

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
 * of the face it found (coarse_range). */
#define SCAN_GRID_FACES (2 << 20)
static int32_t grid_levels(int64_t ptex, int32_t per_edge) {
    int32_t levels = 1;
    while ((1 << levels) < per_edge) ++levels;
    ++levels;
    while (levels > 1 && (ptex << (2 * levels)) > SCAN_GRID_FACES) --levels;
    return levels;
}

int32_t spia__fit_scan_grid_side(const spia_mesh *cage, int32_t per_edge) {
    return (1 << grid_levels(spia_surface_sample_count(cage, 1), per_edge)) + 1;
}

spia_result spia__fit_scan_side_prepare(const spia_mesh *cage, int32_t per_edge, const spia_scan *scan, fit_buffers *b,
                                        fit_clock *clock, spia_status *status) {
    const int64_t ptex = spia_surface_sample_count(cage, 1);
    const int32_t levels = grid_levels(ptex, per_edge);
    const int32_t side = (1 << levels) + 1; /* points along a ptex face's edge */
    if (ptex * side * side > INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "the cage has too many faces (%lld ptex faces) to measure the scan's distances to its "
                          "surface; leave that measure out (SPIA_FIT_NO_SCAN_DISTANCES)",
                          (long long)ptex);
    /* The grid's blocks are made with the samples' (sample_surface). */
    if (!b->grid.start || b->grid.per != side * side)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "the surface's grid does not match the cage's faces");
    if (spia__fit_clock_tick(clock)) return scan_side_cancelled(status);
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
spia_result spia__fit_scan_side_measure(fit_buffers *b, const double *V, double cutoff_abs, double diagonal,
                                        int threads, int warm, fit_clock *clock, spia_fit_distances *out,
                                        spia_status *status) {
    spia_result r;
    spia__fit_blocks_apply_float(&b->grid, V, b->grid_pos);
    if (b->coarse) coarse_corners(b);
    if (spia__fit_clock_tick(clock)) return scan_side_cancelled(status);
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
    const int cancelled = spia__fit_clock_tick(clock) ||
                          spia__fit_closest_in_chunks(b->surface, b->scan_count, b->scan_pts, b->scan_near, NULL, NULL,
                                            b->scan_d, b->scan_face, NULL, threads, clock);
    if (cancelled) return scan_side_cancelled(status);
    if (b->coarse) spia__parallel_for(threads, b->scan_count, 4096, coarse_range, b);
    *out = spia__fit_distance_stats(b->scan_d, b->scan_count, cutoff_abs, diagonal, b->scan_scratch);
    return SPIA_OK;
}

/* The scan's pull weighs its vertices as a whole like the samples as a whole
 * (each vertex by the samples per pulling scan vertex), within these bounds. */
#define SCAN_PULL_MIN_RATIO 1.0
#define SCAN_PULL_MAX_RATIO 64.0

static spia_result scan_pull_prepare(fit_run *u) {
    fit_buffers *b = &u->b;
    const int64_t S = u->S, k = u->fo.samples_per_edge;
    if (scan_points_prepare(u->scan, b) != SPIA_OK) return spia__fit_oom(u);
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
        return spia__fit_oom(u);
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

/* The pull's passes over the samples and the scan's vertices that are
 * independent item by item, on the fit's threads. */
typedef struct pull_pass {
    fit_buffers *b;
    double cutoff_abs;
} pull_pass;

#define PULL_GRAIN 65536

/* The samples' positions in float, for the pull's hierarchy. */
static void pull_positions(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    fit_buffers *b = ((const pull_pass *)context)->b;
    for (int64_t i = 3 * begin; i < 3 * end; ++i) b->pull_pos[i] = (float)b->X[i];
}

/* Each scan vertex's nearest corner of its closest quad, kept in
 * pull_faces (-1: it does not pull). */
static void pull_corners(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const pull_pass *p = context;
    fit_buffers *b = p->b;
    for (int64_t v = begin; v < end; ++v) {
        const int32_t f = b->pull_faces[v];
        int32_t pick = -1;
        if (f >= 0 && b->pull_d[v] <= p->cutoff_abs) {
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
    }
}

/* Each pulled sample's plane target moved by its pull, its weight grown. */
static void pull_targets(void *context, int64_t begin, int64_t end, int thread) {
    (void)thread;
    fit_buffers *b = ((const pull_pass *)context)->b;
    for (int64_t i = begin; i < end; ++i) {
        if (b->pull_w[i] <= 0.0) continue;
        const double shift = b->pull_off[i] / ((double)b->wts[i] + b->pull_w[i]);
        for (int a = 0; a < 3; ++a) b->T[3 * i + a] += (float)(shift * b->N[3 * i + a]);
        b->wts[i] = (float)((double)b->wts[i] + b->pull_w[i]);
    }
}

/* SPIA_FIT_SCAN_PULL: each scan vertex within the cut-off pulls the
 * surface's nearest pulling sample along the scan's normal at that
 * sample's closest point, with the robust kernel's weight: the sample's
 * plane target and weight become those of its own pull and the scan
 * vertices' together (the same least squares as a row for each). */
spia_result spia__fit_scan_pull(fit_run *u) {
    fit_buffers *b = &u->b;
    const int64_t S = u->S, k = u->fo.samples_per_edge;
    spia_result r;
    if (!b->pull_quads && (r = scan_pull_prepare(u)) != SPIA_OK) return r;
    pull_pass pass = {b, u->cutoff_abs};
    spia__parallel_for(u->opt.threads, S, PULL_GRAIN, pull_positions, &pass);
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
    if (spia__fit_closest_in_chunks(b->pull_surface, b->scan_count, b->scan_pts, b->pull_near, NULL, NULL, b->pull_d,
                          b->pull_faces, NULL, u->opt.threads, &u->clock))
        return spia__fit_cancelled(u);
    int64_t pulling_samples = 0, pulling_scan = 0;
    for (int64_t i = 0; i < S; ++i) pulling_samples += b->wts[i] > 0.0f;
    spia__parallel_for(u->opt.threads, b->scan_count, PULL_GRAIN, pull_corners, &pass);
    for (int64_t v = 0; v < b->scan_count; ++v) pulling_scan += b->pull_faces[v] >= 0;
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
    spia__parallel_for(u->opt.threads, S, PULL_GRAIN, pull_targets, &pass);
    return SPIA_OK;
}
