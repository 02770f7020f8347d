// SPDX-License-Identifier: GPL-3.0-or-later
/* Entry points that tie validation, stencils and solvers together. */
#include "internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Scheme dispatch: one line per scheme and boundary rule.  Every builder
 * fills on_boundary (vertex_count entries, SPIA__BOUNDARY_UNKNOWN on entry):
 * OpenSubdiv's on the way, the others first. */
typedef spia_result (*stencil_builder)(const spia_mesh *, spia_adjacency *, const spia_options *, unsigned char *,
                                       spia_stencils **, spia_status *);
static spia_result classified(const spia_mesh *m, spia_adjacency *a, const spia_options *o, unsigned char *on_boundary,
                              spia_status *status) {
    if (spia__boundary_vertices(m, a, on_boundary, o->threads) == SPIA_OK) return SPIA_OK;
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory classifying boundary vertices");
}
static spia_result loop_hoppe(const spia_mesh *m, spia_adjacency *a, const spia_options *o, unsigned char *on_boundary,
                              spia_stencils **out, spia_status *status) {
    const spia_result r = classified(m, a, o, on_boundary, status);
    return r != SPIA_OK ? r : spia__loop_hoppe_limit_stencils(m, a, o, NULL, out, status);
}
static spia_result doo_sabin(const spia_mesh *m, spia_adjacency *a, const spia_options *o, unsigned char *on_boundary,
                             spia_stencils **out, spia_status *status) {
    const spia_result r = classified(m, a, o, on_boundary, status);
    return r != SPIA_OK ? r : spia__doosabin_limit_stencils(m, a, o, out, status);
}
static stencil_builder builder_for(const spia_options *o) {
    switch (o->scheme) {
    case SPIA_SCHEME_CATMULL_CLARK: return spia__osd_limit_stencils;
    case SPIA_SCHEME_LOOP: return o->boundary_rule == SPIA_BOUNDARY_RULE_HOPPE ? loop_hoppe : spia__osd_limit_stencils;
    case SPIA_SCHEME_DOO_SABIN: return doo_sabin;
    }
    return NULL;
}

static int cancelled(const spia_options *o) {
    return o->progress && o->progress(o->progress_user_data, 0, 0.0);
}

spia_result spia_limit_stencils_create(const spia_mesh *mesh, const spia_options *options, spia_stencils **out,
                                       spia_status *status) {
    if (!out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "out must not be NULL");
    *out = NULL;
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    r = spia_mesh_validate(mesh, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme == SPIA_SCHEME_LOOP && (r = spia__require_triangles(mesh, status)) != SPIA_OK) return r;
    char what[96];
    snprintf(what, sizeof what, "the limit stencils of %d vertices and %d faces", (int)mesh->vertex_count,
             (int)mesh->face_count);
    if ((r = spia__memory_check(&opt, spia__table_bytes(mesh), what, "try a smaller mesh", status)) != SPIA_OK)
        return r;
    if (cancelled(&opt)) return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled before computing stencils");
    spia_adjacency adj;
    r = spia__adjacency_build_threads(mesh, &adj, opt.threads, status);
    if (r != SPIA_OK) return r;
    unsigned char *on_boundary = (unsigned char *)malloc((size_t)mesh->vertex_count + 1);
    if (!on_boundary) {
        spia__adjacency_free(&adj);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory classifying boundary vertices");
    }
    memset(on_boundary, SPIA__BOUNDARY_UNKNOWN, (size_t)mesh->vertex_count + 1);
    r = builder_for(&opt)(mesh, &adj, &opt, on_boundary, out, status);
    if (r == SPIA_OK) spia__stencils_mark_boundary(*out, on_boundary);
    free(on_boundary);
    spia__adjacency_free(&adj);
    if (r == SPIA_OK && (r = spia__plan_build(*out, opt.threads, status)) != SPIA_OK) {
        spia_stencils_free(*out);
        *out = NULL;
    }
    if (r == SPIA_OK) spia__stencils_compact(*out);
    if (r == SPIA_OK && cancelled(&opt)) {
        spia_stencils_free(*out);
        *out = NULL;
        return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled after computing stencils");
    }
    return r;
}

spia_result spia_interpolate(const spia_mesh *mesh, const spia_options *options, float *cage, spia_report *report,
                             spia_status *status) {
    if (!cage) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "cage must not be NULL");
    const double t0 = spia__now();
    spia_stencils *L = NULL;
    spia_result r = spia_limit_stencils_create(mesh, options, &L, status);
    const double t1 = spia__now();
    if (r != SPIA_OK) {
        if (report) {
            report->result = r;
            report->stencil_seconds = t1 - t0;
        }
        return r;
    }
    r = spia_solve(L, mesh->positions, options, cage, report, status);
    if (report) report->stencil_seconds = t1 - t0;
    spia_stencils_free(L);
    return r;
}

/* ---- refinement ------------------------------------------------------------ */

/* Faces of the last level of `levels` refinement steps: Loop splits each
 * triangle in four; a Doo-Sabin step makes a face of every face, edge and
 * vertex (about as many as the corners), four times as many each step after;
 * Catmull-Clark makes a quad of every corner, then four of each quad. */
static double refined_faces(const spia_mesh *m, spia_scheme scheme, int32_t levels) {
    double corners = 0.0;
    for (int32_t f = 0; f < m->face_count; ++f) corners += (double)m->face_sizes[f];
    double faces = scheme == SPIA_SCHEME_LOOP ? (double)m->face_count : corners;
    for (int32_t l = scheme == SPIA_SCHEME_LOOP ? 0 : 1; l < levels; ++l) faces *= 4.0;
    return levels > 0 ? faces : (double)m->face_count;
}

/* Bytes a refinement needs at its peak per face of its last level
 * (OpenSubdiv's topology of every level, the points of every level in
 * double, the caller's output), measured from the peak resident size at
 * two levels (bench/bench_creases.py): Loop 257, Catmull-Clark's
 * subdivision with its edges and creases 356, Doo-Sabin 70; a tenth more. */
static double refine_bytes_per_face(spia_scheme scheme) {
    switch (scheme) {
    case SPIA_SCHEME_LOOP: return 290.0;
    case SPIA_SCHEME_DOO_SABIN: return 80.0;
    default: return 400.0;
    }
}

/* The check before a refinement: the levels asked for, and the most that fit. */
typedef struct refine_need {
    const spia_mesh *m;
    spia_scheme scheme;
} refine_need;
static double refine_bytes(const void *context, int32_t levels) {
    const refine_need *r = (const refine_need *)context;
    return refine_bytes_per_face(r->scheme) * refined_faces(r->m, r->scheme, levels);
}
static spia_result refine_memory(const spia_mesh *m, const spia_options *o, int32_t levels, const char *work,
                                 spia_status *status) {
    const refine_need context = {m, o->scheme};
    char what[128];
    snprintf(what, sizeof what, "%s %d level%s (%.0f faces)", work, (int)levels, levels == 1 ? "" : "s",
             refined_faces(m, o->scheme, levels));
    return spia__memory_check_setting(o, refine_bytes, &context, levels, what, "at most %d level%s fit",
                                      "not one level fits", status);
}

static spia_result refine_dispatch(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                   int32_t *vertex_count, int32_t *face_count, int64_t *corner_count,
                                   float *positions, int32_t *face_sizes, int32_t *faces, spia_status *status) {
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme == SPIA_SCHEME_CATMULL_CLARK)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "refinement is for Loop and Doo-Sabin; Blender's modifier shows Catmull-Clark itself");
    if (levels < 0 || levels > 8)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "levels must be 0 to 8, got %d", (int)levels);
    r = spia_mesh_validate(mesh, status);
    if (r != SPIA_OK) return r;
    if ((r = refine_memory(mesh, &opt, levels, "refining", status)) != SPIA_OK) return r;
    spia__refine_clock clock;
    spia__refine_clock_start(&clock, &opt, levels);
    spia__refine_clock *tick = positions ? &clock : NULL;
    if (opt.scheme == SPIA_SCHEME_DOO_SABIN)
        return spia__doosabin_refine(mesh, &opt, levels, vertex_count, face_count, corner_count, positions,
                                     face_sizes, faces, tick, status);
    if ((r = spia__require_triangles(mesh, status)) != SPIA_OK) return r;
    if (opt.boundary_rule == SPIA_BOUNDARY_RULE_HOPPE) {
        r = spia__loop_hoppe_refine_limit(mesh, &opt, levels, vertex_count, face_count, positions, faces, tick,
                                          status);
    } else {
        spia_adjacency adj;
        r = spia__adjacency_build(mesh, &adj, status);
        if (r != SPIA_OK) return r;
        r = spia__osd_refine_limit(mesh, &adj, &opt, levels, vertex_count, face_count, positions, faces, tick,
                                   status);
        spia__adjacency_free(&adj);
    }
    if (r == SPIA_OK) {
        *corner_count = 3 * (int64_t)*face_count;
        if (face_sizes)
            for (int32_t f = 0; f < *face_count; ++f) face_sizes[f] = 3;
    }
    return r;
}

spia_result spia_refine_size(const spia_mesh *mesh, const spia_options *options, int32_t levels, int32_t *vertex_count,
                             int32_t *face_count, int64_t *corner_count, spia_status *status) {
    if (!vertex_count || !face_count || !corner_count)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the count pointers must not be NULL");
    return refine_dispatch(mesh, options, levels, vertex_count, face_count, corner_count, NULL, NULL, NULL, status);
}

spia_result spia_refine(const spia_mesh *mesh, const spia_options *options, int32_t levels, float *positions,
                        int32_t *face_sizes, int32_t *face_vertices, spia_status *status) {
    if (!positions || !face_sizes || !face_vertices)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "positions, face_sizes and face_vertices must not be NULL");
    int32_t nv = 0, nf = 0;
    int64_t nc = 0;
    return refine_dispatch(mesh, options, levels, &nv, &nf, &nc, positions, face_sizes, face_vertices, status);
}

/* ---- subdivision of the cage ---------------------------------------------- */

static spia_result subdivide_dispatch(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                      int32_t *vertex_count, int32_t *face_count, int32_t *edge_count,
                                      float *positions, int32_t *face_vertices, int32_t *edges, float *edge_creases,
                                      float *vertex_creases, spia_status *status) {
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme != SPIA_SCHEME_CATMULL_CLARK)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "subdivision of the cage is for Catmull-Clark; spia_refine refines Loop and Doo-Sabin");
    if (levels < 1 || levels > 6)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "levels must be 1 to 6, got %d", (int)levels);
    r = spia_mesh_validate(mesh, status);
    if (r != SPIA_OK) return r;
    if ((r = refine_memory(mesh, &opt, levels, "subdividing", status)) != SPIA_OK) return r;
    spia__refine_clock clock;
    spia__refine_clock_start(&clock, &opt, levels);
    spia_adjacency adj;
    r = spia__adjacency_build(mesh, &adj, status);
    if (r != SPIA_OK) return r;
    r = spia__osd_subdivide(mesh, &adj, &opt, levels, vertex_count, face_count, edge_count, positions, face_vertices,
                            edges, edge_creases, vertex_creases, positions ? &clock : NULL, status);
    spia__adjacency_free(&adj);
    return r;
}

spia_result spia_subdivide_size(const spia_mesh *mesh, const spia_options *options, int32_t levels,
                                int32_t *vertex_count, int32_t *face_count, int32_t *edge_count, spia_status *status) {
    if (!vertex_count || !face_count || !edge_count)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "the count pointers must not be NULL");
    return subdivide_dispatch(mesh, options, levels, vertex_count, face_count, edge_count, NULL, NULL, NULL, NULL, NULL,
                              status);
}

spia_result spia_subdivide(const spia_mesh *mesh, const spia_options *options, int32_t levels, float *positions,
                           int32_t *face_vertices, int32_t *edges, float *edge_creases, float *vertex_creases,
                           spia_status *status) {
    if (!positions || !face_vertices)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "positions and face_vertices must not be NULL");
    int32_t nv = 0, nf = 0, ne = 0;
    return subdivide_dispatch(mesh, options, levels, &nv, &nf, &ne, positions, face_vertices, edges, edge_creases,
                              vertex_creases, status);
}

/* ---- sharpness ------------------------------------------------------------ */

spia_result spia_sharpness(const spia_mesh *mesh, const spia_options *options, int32_t flags, int32_t *crease_count,
                           int32_t *crease_pairs, float *crease_sharpness, float *vertex_sharpness,
                           spia_status *status) {
    if (!crease_count) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "crease_count must not be NULL");
    if (flags & ~SPIA_SHARPNESS_NO_TWO_EDGE_RULE)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown sharpness flags 0x%x", (unsigned)flags);
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if ((r = spia_mesh_validate(mesh, status)) != SPIA_OK) return r;
    spia_adjacency adj;
    if ((r = spia__adjacency_build(mesh, &adj, status)) != SPIA_OK) return r;
    r = spia__osd_sharpness(mesh, &adj, &opt, !(flags & SPIA_SHARPNESS_NO_TWO_EDGE_RULE), crease_count, crease_pairs,
                            crease_sharpness, vertex_sharpness, status);
    spia__adjacency_free(&adj);
    return r;
}
