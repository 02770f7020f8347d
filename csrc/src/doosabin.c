// SPDX-License-Identifier: GPL-3.0-or-later
/* Two-phase Doo-Sabin subdivision (Cheng et al.): limit stencils and
 * refinement.
 *
 * Phase one moves each vertex V of each face F (f corners, centroid A) to
 *     W = w_F V + (1 - w_F) A,                                   (paper eq. 1)
 * with a shape parameter w_F in (0, 1) per face, and connects the new
 * points into F-faces (one per face), E-faces (one per edge) and V-faces
 * (one per vertex).  Later steps are regular Doo-Sabin.  The centroid of
 * every face of a Doo-Sabin mesh lies on the limit surface, so the limit
 * point of a control vertex V with n faces around it is the centroid of its
 * V-face after phase one (eq. 2):
 *     V_inf = 1/n sum_i (w_i V + (1 - w_i) A_i)
 * which weighs V by 1/n sum_i (w_i + (1 - w_i) / f_i) and every other
 * vertex U of face i by (1 - w_i) / (n f_i) (summed over the faces U shares
 * with V).  So L = diag(1/n) S with S symmetric (the weight of U in V's row
 * times n_V equals that of V in U's row times n_U), and S is positive
 * definite for w in (0, 1) (the paper's Proposition 1).  Hence PIA converges
 * (eigenvalues of L in (0, 1]); GS-PIA does too, since Gauss-Seidel on D S
 * sweeps exactly as on the SPD S; and CG applies to S, which AUTO uses.
 *
 * Open meshes are refused: the paper leaves them open.
 */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static double face_parameter(const spia_options *o, int32_t f) {
    return o->face_shape_parameters ? (double)o->face_shape_parameters[f] : o->shape_parameter;
}

/* Shape parameters in (0, 1), and no boundary edge. */
static spia_result check_input(const spia_mesh *m, const spia_adjacency *a, const spia_options *o,
                               spia_status *status) {
    int64_t bad = 0, first = -1;
    for (int32_t f = 0; f < m->face_count; ++f) {
        const double w = face_parameter(o, f);
        if (!(w > 0.0 && w < 1.0)) {
            if (first < 0) first = f;
            ++bad;
        }
    }
    if (bad)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, first,
                          "%lld faces have a shape parameter outside (0, 1) (first: face %lld, %g)", (long long)bad,
                          (long long)first, face_parameter(o, (int32_t)first));
    unsigned char *boundary = (unsigned char *)calloc((size_t)m->vertex_count, 1);
    if (!boundary || spia__boundary_vertices(m, a, boundary, o->threads) != SPIA_OK) {
        free(boundary);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory checking the mesh");
    }
    for (int32_t v = 0; v < m->vertex_count; ++v)
        if (boundary[v]) {
            if (first < 0) first = v;
            ++bad;
        }
    free(boundary);
    if (bad)
        return spia__fail(status, SPIA_ERROR_TOPOLOGY, first,
                          "two-phase Doo-Sabin interpolation needs a closed mesh: %lld vertices lie on a boundary "
                          "(first: vertex %lld); fill the holes first",
                          (long long)bad, (long long)first);
    return SPIA_OK;
}

spia_result spia__doosabin_limit_stencils(const spia_mesh *m, spia_adjacency *a, const spia_options *o,
                                          spia_stencils **out, spia_status *status) {
    *out = NULL;
    spia_result r = check_input(m, a, o, status);
    if (r != SPIA_OK) return r;
    int64_t nnz = 0;
    for (int32_t v = 0; v < m->vertex_count; ++v) {
        nnz += 1;
        for (int64_t i = a->first[v]; i < a->first[v + 1]; ++i) nnz += m->face_sizes[a->face_of_corner[a->corner_of[i]]];
    }
    spia_stencils *s = spia__stencils_alloc(m->vertex_count, nnz);
    if (!s) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for Doo-Sabin stencils");
    int64_t pos = 0;
    for (int32_t v = 0; v < m->vertex_count; ++v) {
        s->offsets[v] = pos;
        const int64_t n = a->first[v + 1] - a->first[v];
        const int64_t self = pos++;
        s->indices[self] = v;
        s->weights[self] = n ? 0.0 : 1.0; /* used by no face: stays put */
        for (int64_t i = a->first[v]; i < a->first[v + 1]; ++i) {
            const int32_t f = a->face_of_corner[a->corner_of[i]];
            const double w = face_parameter(o, f), k = (double)m->face_sizes[f];
            s->weights[self] += w / (double)n;
            for (int64_t c = a->corner_start[f]; c < a->corner_start[f + 1]; ++c) {
                s->indices[pos] = m->face_vertices[c];
                s->weights[pos++] = (1.0 - w) / (k * (double)n);
            }
        }
    }
    s->offsets[m->vertex_count] = pos;
    spia__stencils_canonicalize(s);
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

/* ------------------------------------------------------------------------ */
/* Refinement                                                                */
/* ------------------------------------------------------------------------ */

typedef struct poly_level {
    int32_t n, f;
    int64_t corners;
    double *P;      /* n * 3     */
    int32_t *sizes; /* f         */
    int32_t *fv;    /* corners   */
} poly_level;

static void poly_free(poly_level *l) {
    free(l->P);
    free(l->sizes);
    free(l->fv);
    memset(l, 0, sizeof *l);
}

/* The corner of v whose face continues around v after corner c: the face
 * across the edge (prev(c), v), where it runs v -> prev(c).  -1 if none. */
static int64_t next_around(const spia_mesh *m, const spia_adjacency *a, int64_t c) {
    const int32_t v = m->face_vertices[c], before = spia__corner_prev(m, a, c);
    for (int64_t i = a->first[v]; i < a->first[v + 1]; ++i) {
        const int64_t d = a->corner_of[i];
        if (d != c && spia__corner_next(m, a, d) == before) return d;
    }
    return -1;
}

/* The new points at face f's corners (from corner s0 on): eq. (1) in
 * phase one, else the regular Doo-Sabin rule (see ds_step). */
static void face_points(const poly_level *in, const spia_options *o, int phase_one, int32_t f, int64_t s0,
                        poly_level *out) {
    const int32_t size = in->sizes[f];
    double centroid[3] = {0.0, 0.0, 0.0};
    for (int32_t i = 0; i < size; ++i)
        for (int d = 0; d < 3; ++d) centroid[d] += in->P[3 * (int64_t)in->fv[s0 + i] + d] / size;
    for (int32_t i = 0; i < size; ++i) {
        double *q = out->P + 3 * (s0 + i);
        if (phase_one) {
            const double w = face_parameter(o, f);
            for (int d = 0; d < 3; ++d) q[d] = w * in->P[3 * (int64_t)in->fv[s0 + i] + d] + (1.0 - w) * centroid[d];
        } else {
            for (int d = 0; d < 3; ++d) q[d] = 0.0;
            for (int32_t j = 0; j < size; ++j) {
                const double alpha = i == j ? (size + 5.0) / (4.0 * size)
                                            : (3.0 + 2.0 * cos(2.0 * M_PI * (i - j) / size)) / (4.0 * size);
                for (int d = 0; d < 3; ++d) q[d] += alpha * in->P[3 * (int64_t)in->fv[s0 + j] + d];
            }
        }
    }
}

/* The twin of edge v -> w: its corner at w (*twin_w) and the next one, at v
 * (*twin_v); the last found where there are several. */
static void twin_corners(const spia_mesh *m, const spia_adjacency *a, int32_t v, int32_t w, int64_t *twin_w,
                         int64_t *twin_v) {
    for (int64_t i = a->first[w]; i < a->first[w + 1]; ++i) {
        const int64_t d = a->corner_of[i];
        if (spia__corner_next(m, a, d) == v) {
            *twin_w = d;
            const int32_t g = a->face_of_corner[d];
            *twin_v = d + 1 == a->corner_start[g + 1] ? a->corner_start[g] : d + 1;
        }
    }
}

/* One step.  New vertex i is corner i of the old mesh.  phase_one: eq. (1)
 * with options' parameters; else the regular Doo-Sabin rule
 * W_i = sum_j alpha_ij V_j, alpha_ii = (k + 5) / (4k),
 * alpha_ij = (3 + 2 cos(2 pi (i - j) / k)) / (4k). */
static spia_result ds_step(const poly_level *in, const spia_options *o, int phase_one, poly_level *out,
                           spia__refine_clock *clock, spia_status *status) {
    float *dummy = (float *)calloc(3 * (size_t)in->n + 3, sizeof(float));
    spia_adjacency a;
    memset(&a, 0, sizeof a);
    memset(out, 0, sizeof *out);
    spia_result r = SPIA_ERROR_OUT_OF_MEMORY;
    if (!dummy) goto fail;
    spia_mesh m = {in->n, dummy, in->f, in->sizes, in->fv, 0, NULL, NULL, NULL};
    if ((r = spia__adjacency_build(&m, &a, status)) != SPIA_OK) goto fail;
    /* Edges: each corner c starts edge (v, next); its twin runs back. */
    int64_t edges = 0, used = 0;
    for (int64_t c = 0; c < in->corners; ++c) {
        if (spia__refine_tick(clock, c)) goto cancelled;
        const int32_t v = in->fv[c], w = spia__corner_next(&m, &a, c);
        int twins = 0;
        for (int64_t i = a.first[w]; i < a.first[w + 1]; ++i) twins += spia__corner_next(&m, &a, a.corner_of[i]) == v;
        if (twins != 1) {
            r = spia__fail(status, SPIA_ERROR_TOPOLOGY, a.face_of_corner[c],
                           "Doo-Sabin refinement needs a closed, consistently oriented manifold mesh: edge %d-%d "
                           "has %d faces running the other way",
                           (int)v, (int)w, twins);
            goto fail;
        }
        edges += v < w;
    }
    for (int32_t v = 0; v < in->n; ++v) used += a.first[v + 1] > a.first[v];
    out->n = (int32_t)in->corners;
    out->f = in->f + (int32_t)edges + (int32_t)used;
    out->corners = in->corners + 4 * edges + in->corners;
    out->P = (double *)malloc(sizeof(double) * 3 * (size_t)out->n);
    out->sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)out->f);
    out->fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)out->corners);
    if (!out->P || !out->sizes || !out->fv) {
        r = spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
        goto fail;
    }
    /* Positions and F-faces. */
    int64_t k = 0;
    int32_t nf = 0;
    for (int32_t f = 0; f < in->f; ++f) {
        if (spia__refine_tick(clock, f)) goto cancelled;
        const int64_t s0 = a.corner_start[f];
        const int32_t size = in->sizes[f];
        face_points(in, o, phase_one, f, s0, out);
        for (int32_t i = 0; i < size; ++i) out->fv[k++] = (int32_t)(s0 + i);
        out->sizes[nf++] = size;
    }
    /* E-faces: edge v -> w in corner c's face, w -> v in its twin's. */
    for (int64_t c = 0; c < in->corners; ++c) {
        if (spia__refine_tick(clock, c)) goto cancelled;
        const int32_t v = in->fv[c], w = spia__corner_next(&m, &a, c);
        if (v > w) continue;
        int64_t cw = -1, twin_w = -1, twin_v = -1;
        const int32_t f = a.face_of_corner[c];
        cw = c + 1 == a.corner_start[f + 1] ? a.corner_start[f] : c + 1;
        twin_corners(&m, &a, v, w, &twin_w, &twin_v);
        out->fv[k++] = (int32_t)cw;
        out->fv[k++] = (int32_t)c;
        out->fv[k++] = (int32_t)twin_v;
        out->fv[k++] = (int32_t)twin_w;
        out->sizes[nf++] = 4;
    }
    /* V-faces: the corners of v in their order around v. */
    for (int32_t v = 0; v < in->n; ++v) {
        if (spia__refine_tick(clock, v)) goto cancelled;
        if (a.first[v + 1] == a.first[v]) continue;
        const int64_t start = a.corner_of[a.first[v]];
        int64_t c = start;
        int32_t size = 0;
        do {
            out->fv[k++] = (int32_t)c;
            ++size;
            c = next_around(&m, &a, c);
        } while (c >= 0 && c != start && size <= a.first[v + 1] - a.first[v]);
        if (c != start || size != a.first[v + 1] - a.first[v]) {
            r = spia__fail(status, SPIA_ERROR_TOPOLOGY, v,
                           "Doo-Sabin refinement needs a manifold mesh: the faces around vertex %d do not form one "
                           "fan",
                           (int)v);
            goto fail;
        }
        out->sizes[nf++] = size;
    }
    out->corners = k;
    spia__adjacency_free(&a);
    free(dummy);
    return SPIA_OK;
cancelled:
    r = spia__refine_cancelled(status, clock);
fail:
    spia__adjacency_free(&a);
    free(dummy);
    poly_free(out);
    return r == SPIA_ERROR_OUT_OF_MEMORY ? spia__fail(status, r, -1, "out of memory refining the surface") : r;
}

spia_result spia__doosabin_refine(const spia_mesh *m, const spia_options *o, int32_t levels, int32_t *vertex_count,
                                  int32_t *face_count, int64_t *corner_count, float *positions, int32_t *face_sizes,
                                  int32_t *face_vertices, spia__refine_clock *clock, spia_status *status) {
    spia_adjacency a;
    spia_result r = spia__adjacency_build(m, &a, status);
    if (r != SPIA_OK) return r;
    r = check_input(m, &a, o, status);
    /* A vertex on two faces becomes a two-sided face in the first step,
     * which the second cannot refine (two of its edges join the same two
     * vertices): refused here, before any counting or allocating. */
    int64_t on_two = 0, first_on_two = -1;
    for (int32_t v = 0; r == SPIA_OK && levels >= 2 && v < m->vertex_count; ++v)
        if (a.first[v + 1] - a.first[v] == 2) {
            if (first_on_two < 0) first_on_two = v;
            ++on_two;
        }
    spia__adjacency_free(&a);
    if (r != SPIA_OK) return r;
    if (on_two)
        return spia__fail(status, SPIA_ERROR_TOPOLOGY, first_on_two,
                          "Doo-Sabin refinement beyond one level needs every vertex on three or more faces: %lld "
                          "vertices are on two (first: vertex %lld); dissolve them or show one level",
                          (long long)on_two, (long long)first_on_two);
    poly_level cur;
    cur.n = m->vertex_count;
    cur.f = m->face_count;
    cur.corners = 0;
    for (int32_t f = 0; f < m->face_count; ++f) cur.corners += m->face_sizes[f];
    /* The counts: the first step's (which checks the mesh), then in closed
     * form: after a step every vertex is a corner of a closed manifold mesh
     * (E = C / 2 edges), and a step makes a vertex of every corner and a
     * face of every face, edge and vertex, with C + 4 E + C corners. */
    int64_t nv = cur.n, nf = cur.f, nc = cur.corners;
    const int counts_only = positions == NULL;
    if (counts_only && levels == 0) goto counted;
    cur.P = (double *)malloc(sizeof(double) * 3 * (size_t)cur.n);
    cur.sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)cur.f);
    cur.fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)cur.corners);
    if (!cur.P || !cur.sizes || !cur.fv) {
        poly_free(&cur);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
    }
    for (int64_t k = 0; k < 3 * (int64_t)cur.n; ++k) cur.P[k] = m->positions[k];
    memcpy(cur.sizes, m->face_sizes, sizeof(int32_t) * (size_t)cur.f);
    memcpy(cur.fv, m->face_vertices, sizeof(int32_t) * (size_t)cur.corners);
    for (int32_t l = 0; l < levels; ++l) {
        poly_level next;
        if (cur.corners * 3 > INT32_MAX) {
            poly_free(&cur);
            return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "%d levels make too many faces", (int)levels);
        }
        r = ds_step(&cur, o, l == 0, &next, clock, status);
        poly_free(&cur);
        if (r != SPIA_OK) return r;
        cur = next;
        if (l == 0) {
            nv = cur.n, nf = cur.f, nc = cur.corners;
            for (int32_t k = 1; k < levels; ++k) {
                if (nc * 3 > INT32_MAX) {
                    poly_free(&cur);
                    return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "%d levels make too many faces",
                                      (int)levels);
                }
                nf += nc / 2 + nv;
                nv = nc;
                nc *= 4;
            }
            if (counts_only) {
                poly_free(&cur);
                goto counted;
            }
        }
        if (l + 1 < levels && spia__refine_level_done(clock, l + 1)) {
            poly_free(&cur);
            return spia__refine_cancelled(status, clock);
        }
    }
    if (cur.n != nv || cur.f != nf || cur.corners != nc) {
        poly_free(&cur);
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1,
                          "refined to %d vertices, %d faces and %lld corners, not the %lld, %lld and %lld counted",
                          (int)cur.n, (int)cur.f, (long long)cur.corners, (long long)nv, (long long)nf, (long long)nc);
    }
    if (spia__refine_level_done(clock, levels)) {
        poly_free(&cur);
        return spia__refine_cancelled(status, clock);
    }
    for (int64_t k = 0; k < 3 * (int64_t)cur.n; ++k) positions[k] = (float)cur.P[k];
    memcpy(face_sizes, cur.sizes, sizeof(int32_t) * (size_t)cur.f);
    memcpy(face_vertices, cur.fv, sizeof(int32_t) * (size_t)cur.corners);
    poly_free(&cur);
counted:
    *vertex_count = (int32_t)nv;
    *face_count = (int32_t)nf;
    *corner_count = nc;
    spia__ok(status);
    return SPIA_OK;
}
