// SPDX-License-Identifier: GPL-3.0-or-later
/* Loop limit stencils with the boundary rules of Hoppe et al. 1994, as the
 * open-mesh Loop PIA paper uses them.
 *
 * Interior vertex of valence n (the papers' eq. 3, equal to OpenSubdiv's
 * Loop limit):
 *     V_inf = beta_n V + (1 - beta_n) / n * sum of the n neighbours,
 *     beta_n = 3 / (11 - 8 (3/8 + (3/8 + cos(2 pi / n) / 4)^2)).
 * Its limit only involves its own ring, whatever the rules on the boundary.
 *
 * Boundary.  A boundary vertex is regular (R) if its valence is 4, else
 * extraordinary (E).  Subdivision on the boundary involves boundary vertices
 * only:
 *     vertex point  1/8 V_prev + 3/4 V + 1/8 V_next           (R and E alike)
 *     edge point    1/2, 1/2 when both ends have the same type,
 *                   5/8 on the R end, 3/8 on the E end otherwise.
 * The limit of V depends on (V_prev, V, V_next) only.  Every new edge point
 * on the boundary has valence 4, so after one step V keeps its type and its
 * two neighbours are regular: the configuration (R, t, R) then reproduces
 * itself, with the 3 x 3 local subdivision matrix S_t (rows: the new
 * V_prev-side edge point, V's new vertex point, the V_next-side edge point)
 *     S_R = [1/2 1/2 0; 1/8 3/4 1/8; 0 1/2 1/2]
 *     S_E = [5/8 3/8 0; 1/8 3/4 1/8; 0 3/8 5/8]
 * whose left eigenvectors for eigenvalue 1, normalized to sum 1, are the
 * limit masks l_R = (1/6, 2/3, 1/6) and l_E = (1/5, 3/5, 1/5)
 * (check: (1/5)(5/8) + (3/5)(1/8) = 1/5 and (1/5)(3/8) 2 + (3/5)(3/4) = 3/5).
 * For any neighbour types the mask is l_t times the first step's matrix F,
 * whose edge rows depend on the neighbours' types:
 *     edge row to an R neighbour of an R vertex: (1/2 on the neighbour, 1/2 on V)
 *     edge row to an E neighbour of an R vertex: (3/8, 5/8)
 *     edge row to an R neighbour of an E vertex: (5/8, 3/8)
 *     edge row to an E neighbour of an E vertex: (1/2, 1/2)
 * which gives, per side of V:
 *     V regular       (l = 1/6, 2/3, 1/6):  V gets 1/2 = 24/48 plus, per side,
 *         R neighbour: 8/48 on it, 4/48 on V;   E neighbour: 7/48 on it, 5/48 on V
 *     V extraordinary (l = 1/5, 3/5, 1/5):  V gets 9/20 = 18/40 plus, per side,
 *         R neighbour: 8/40 on it, 3/40 on V;   E neighbour: 7/40 on it, 4/40 on V
 * so the six configurations are
 *     R between R, R:  (8, 32, 8) / 48 = (1/6, 2/3, 1/6)
 *     R between E, R:  (7, 33, 8) / 48
 *     R between E, E:  (7, 34, 7) / 48
 *     E between R, R:  (8, 24, 8) / 40 = (1/5, 3/5, 1/5)
 *     E between E, R:  (7, 25, 8) / 40
 *     E between E, E:  (7, 26, 7) / 40
 * The tests check them against refining a boundary many times.
 */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static double loop_beta(int32_t n) {
    const double c = 0.375 + 0.25 * cos(2.0 * M_PI / (double)n);
    return 3.0 / (11.0 - 8.0 * (0.375 + c * c));
}

/* Corners of v that share an edge lie in one fan: counts the fans. */
static int32_t fan_count(const spia_mesh *m, const spia_adjacency *a, int32_t v, int32_t *parent) {
    const int64_t first = a->first[v], count = a->first[v + 1] - first;
    for (int64_t i = 0; i < count; ++i) parent[i] = (int32_t)i;
    for (int64_t i = 0; i < count; ++i) {
        int64_t ci = a->corner_of[first + i];
        int32_t pi = spia__corner_prev(m, a, ci), ni = spia__corner_next(m, a, ci);
        for (int64_t j = i + 1; j < count; ++j) {
            int64_t cj = a->corner_of[first + j];
            int32_t pj = spia__corner_prev(m, a, cj), nj = spia__corner_next(m, a, cj);
            if (pi == pj || pi == nj || ni == pj || ni == nj) {
                int32_t ri = (int32_t)i, rj = (int32_t)j;
                while (parent[ri] != ri) ri = parent[ri];
                while (parent[rj] != rj) rj = parent[rj];
                parent[ri] = rj;
            }
        }
    }
    int32_t fans = 0;
    for (int64_t i = 0; i < count; ++i) fans += parent[i] == (int32_t)i;
    return fans;
}

/* Vertex v's limit row written into s from entry pos on (nb, fe: room for
 * cap neighbours); returns the entry after it. */
static int64_t hoppe_row(const spia_mesh *m, const spia_adjacency *a, int32_t v, const int32_t *valence,
                         const unsigned char *boundary, int32_t *nb, int32_t *fe, int32_t cap, spia_stencils *s,
                         int64_t pos) {
    if (a->first[v + 1] == a->first[v]) { /* used by no face: stays put */
        s->indices[pos] = v;
        s->weights[pos++] = 1.0;
        return pos;
    }
    int32_t k = spia__vertex_neighbours(m, a, v, nb, fe, cap);
    if (!boundary[v]) {
        const double beta = loop_beta(k);
        s->indices[pos] = v;
        s->weights[pos++] = beta;
        for (int32_t i = 0; i < k; ++i) {
            s->indices[pos] = nb[i];
            s->weights[pos++] = (1.0 - beta) / k;
        }
        return pos;
    }
    const int regular = valence[v] == 4;
    const double denominator = regular ? 48.0 : 40.0;
    double centre = regular ? 24.0 : 18.0;
    const int64_t centre_at = pos++;
    for (int32_t i = 0; i < k; ++i) {
        if (fe[i] != 1) continue;
        const int side_regular = valence[nb[i]] == 4;
        centre += regular ? (side_regular ? 4.0 : 5.0) : (side_regular ? 3.0 : 4.0);
        s->indices[pos] = nb[i];
        s->weights[pos++] = (side_regular ? 8.0 : 7.0) / denominator;
    }
    s->indices[centre_at] = v;
    s->weights[centre_at] = centre / denominator;
    return pos;
}

spia_result spia__loop_hoppe_limit_stencils(const spia_mesh *m, spia_adjacency *a, const spia_options *opt,
                                            spia__refine_clock *clock, spia_stencils **out, spia_status *status) {
    (void)opt;
    *out = NULL;
    const int32_t n = m->vertex_count;
    const int32_t cap = 2 * spia__max_corners_per_vertex(a) + 2;
    int32_t *nb = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)cap);
    int32_t *valence = (int32_t *)malloc(sizeof(int32_t) * (size_t)n);
    unsigned char *boundary = (unsigned char *)calloc((size_t)n, 1);
    if (!nb || !valence || !boundary) {
        free(nb);
        free(valence);
        free(boundary);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for Loop stencils");
    }
    int32_t *fe = nb + cap, *parent = nb + 2 * cap;

    /* Valence, boundary, and the manifold test the boundary rules need. */
    int64_t nonmanifold = 0, first_bad = -1, nnz = 0;
    for (int32_t v = 0; v < n; ++v) {
        if (spia__refine_tick(clock, v)) {
            free(nb);
            free(valence);
            free(boundary);
            return spia__refine_cancelled(status, clock);
        }
        const int64_t faces = a->first[v + 1] - a->first[v];
        int32_t k = spia__vertex_neighbours(m, a, v, nb, fe, cap), boundary_edges = 0, bad = 0;
        for (int32_t i = 0; i < k; ++i) {
            if (fe[i] == 1) ++boundary_edges;
            if (fe[i] > 2) bad = 1;
        }
        valence[v] = k;
        boundary[v] = boundary_edges > 0;
        /* An interior vertex on two triangles: they share all three corners
         * (a doubled triangle, closed on itself), and its edges are not the
         * two-sided edges the rules need. */
        if (faces > 0 && (bad || (boundary_edges != 0 && boundary_edges != 2) || (boundary_edges == 0 && k == 2) ||
                          fan_count(m, a, v, parent) != 1)) {
            if (first_bad < 0) first_bad = v;
            ++nonmanifold;
        }
        nnz += boundary[v] ? 3 : k + 1;
    }
    if (nonmanifold) {
        free(nb);
        free(valence);
        free(boundary);
        return spia__fail(status, SPIA_ERROR_TOPOLOGY, first_bad,
                          "Hoppe's boundary rules need a manifold mesh: %lld vertices are non-manifold or on a "
                          "doubled triangle (first: vertex %lld); use the SMOOTH boundary rule or clean the mesh",
                          (long long)nonmanifold, (long long)first_bad);
    }

    spia_stencils *s = spia__stencils_alloc(n, nnz);
    if (!s) {
        free(nb);
        free(valence);
        free(boundary);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for Loop stencils");
    }
    int64_t pos = 0;
    for (int32_t v = 0; v < n; ++v) {
        if (spia__refine_tick(clock, v)) {
            spia_stencils_free(s);
            free(nb);
            free(valence);
            free(boundary);
            return spia__refine_cancelled(status, clock);
        }
        s->offsets[v] = pos;
        pos = hoppe_row(m, a, v, valence, boundary, nb, fe, cap, s, pos);
    }
    s->offsets[n] = pos;
    free(nb);
    free(valence);
    free(boundary);
    spia__stencils_canonicalize(s);
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

/* ------------------------------------------------------------------------ */
/* Refinement with Hoppe's rules, for previews of the limit surface.         */
/* ------------------------------------------------------------------------ */

/* Loop's vertex rule weight on each neighbour of an interior vertex. */
static double loop_refine_beta(int32_t n) {
    const double c = 0.375 + 0.25 * cos(2.0 * M_PI / (double)n);
    return (0.625 - c * c) / (double)n;
}

typedef struct tri_level {
    int32_t n, f;
    double *P;   /* n * 3 */
    int32_t *F;  /* f * 3 */
} tri_level;

/* A step's new points at the old vertices (Hoppe's boundary rule, Loop's
 * beta inside); nonzero when cancelled. */
static int vertex_points(const tri_level *in, tri_level *out, const spia_mesh *m, const spia_adjacency *adj,
                         const int32_t *valence, const int32_t *bnd, int32_t *nb, int32_t *cnt, int32_t cap,
                         spia__refine_clock *clock) {
    for (int32_t v = 0; v < in->n; ++v) {
        if (spia__refine_tick(clock, v)) return 1;
        double *q = out->P + 3 * (int64_t)v;
        const double *p = in->P + 3 * (int64_t)v;
        if (valence[v] == 0) {
            for (int a = 0; a < 3; ++a) q[a] = p[a];
        } else if (bnd[2 * v] >= 0) {
            const double *x = in->P + 3 * (int64_t)bnd[2 * v], *y = in->P + 3 * (int64_t)bnd[2 * v + 1];
            for (int a = 0; a < 3; ++a) q[a] = 0.75 * p[a] + 0.125 * (x[a] + y[a]);
        } else {
            int32_t k = spia__vertex_neighbours(m, adj, v, nb, cnt, cap);
            const double beta = loop_refine_beta(k);
            for (int a = 0; a < 3; ++a) q[a] = (1.0 - k * beta) * p[a];
            for (int32_t i = 0; i < k; ++i)
                for (int a = 0; a < 3; ++a) q[a] += beta * in->P[3 * (int64_t)nb[i] + a];
        }
    }
    return 0;
}

/* A step's edge points, numbered after the old vertices. */
static void edge_points(const tri_level *in, tri_level *out, const int64_t *first_edge, const int64_t *edge_other,
                        const int64_t *edge_opp, const int64_t *edge_faces, const int32_t *valence) {
    for (int32_t v = 0; v < in->n; ++v)
        for (int64_t e = first_edge[v]; e < first_edge[v + 1]; ++e) {
            const int32_t w = (int32_t)edge_other[e];
            const double *x = in->P + 3 * (int64_t)v, *y = in->P + 3 * (int64_t)w;
            double *q = out->P + 3 * (int64_t)(in->n + e);
            if (edge_faces[e] >= 2) {
                const double *c = in->P + 3 * edge_opp[2 * e], *d = in->P + 3 * edge_opp[2 * e + 1];
                for (int a = 0; a < 3; ++a) q[a] = 0.375 * (x[a] + y[a]) + 0.125 * (c[a] + d[a]);
            } else {
                const int rv = valence[v] == 4, rw = valence[w] == 4;
                const double wv = rv == rw ? 0.5 : rv ? 0.625 : 0.375;
                for (int a = 0; a < 3; ++a) q[a] = wv * x[a] + (1.0 - wv) * y[a];
            }
        }
}

/* Each triangle split in four. */
static void split_faces(const tri_level *in, tri_level *out, const int64_t *edge_of_corner) {
    for (int32_t f = 0; f < in->f; ++f) {
        const int32_t a = in->F[3 * f], b = in->F[3 * f + 1], c = in->F[3 * f + 2];
        const int32_t ab = in->n + (int32_t)edge_of_corner[3 * (int64_t)f], bc = in->n + (int32_t)edge_of_corner[3 * (int64_t)f + 1],
                      ca = in->n + (int32_t)edge_of_corner[3 * (int64_t)f + 2];
        const int32_t tris[12] = {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca};
        memcpy(out->F + 12 * (int64_t)f, tris, sizeof tris);
    }
}

/* One subdivision step: old vertices keep their indices, edge points follow. */
static spia_result hoppe_step(const tri_level *in, tri_level *out, spia__refine_clock *clock) {
    spia_result r = SPIA_ERROR_OUT_OF_MEMORY;
    int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * ((size_t)in->f + 1));
    float *dummy = (float *)calloc(3 * (size_t)in->n + 3, sizeof(float));
    int64_t *edge_of_corner = (int64_t *)malloc(sizeof(int64_t) * 3 * ((size_t)in->f + 1));
    spia_adjacency adj;
    memset(&adj, 0, sizeof adj);
    int32_t *nb = NULL, *cnt = NULL, *valence = NULL, *bnd = NULL;
    int64_t *first_edge = NULL, *edge_other = NULL, *edge_opp = NULL, *edge_faces = NULL;
    memset(out, 0, sizeof *out);
    if (!sizes || !dummy || !edge_of_corner) goto done;
    for (int32_t f = 0; f < in->f; ++f) sizes[f] = 3;
    spia_mesh m = {in->n, dummy, in->f, sizes, in->F, 0, NULL, NULL, NULL};
    if (spia__adjacency_build(&m, &adj, NULL) != SPIA_OK) goto done;
    const int32_t cap = 2 * spia__max_corners_per_vertex(&adj) + 2;
    nb = (int32_t *)malloc(sizeof(int32_t) * (size_t)cap);
    cnt = (int32_t *)malloc(sizeof(int32_t) * (size_t)cap);
    valence = (int32_t *)malloc(sizeof(int32_t) * (size_t)in->n);
    bnd = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)in->n);
    first_edge = (int64_t *)malloc(sizeof(int64_t) * ((size_t)in->n + 1));
    if (!nb || !cnt || !valence || !bnd || !first_edge) goto done;
    /* Edges (v, w) with v < w, numbered vertex by vertex. */
    int64_t edges = 0;
    for (int32_t v = 0; v < in->n; ++v) {
        if (spia__refine_tick(clock, v)) goto cancelled;
        int32_t k = spia__vertex_neighbours(&m, &adj, v, nb, cnt, cap);
        valence[v] = k;
        bnd[2 * v] = bnd[2 * v + 1] = -1;
        first_edge[v] = edges;
        for (int32_t i = 0; i < k; ++i) {
            if (cnt[i] == 1) bnd[2 * v + (bnd[2 * v] >= 0)] = nb[i];
            if (nb[i] > v) ++edges;
        }
    }
    first_edge[in->n] = edges;
    edge_other = (int64_t *)malloc(sizeof(int64_t) * (size_t)(edges + 1));
    edge_opp = (int64_t *)malloc(sizeof(int64_t) * 2 * (size_t)(edges + 1));
    edge_faces = (int64_t *)calloc((size_t)edges + 1, sizeof(int64_t));
    if (!edge_other || !edge_opp || !edge_faces) goto done;
    for (int32_t v = 0; v < in->n; ++v) {
        if (spia__refine_tick(clock, v)) goto cancelled;
        int32_t k = spia__vertex_neighbours(&m, &adj, v, nb, cnt, cap);
        int64_t e = first_edge[v];
        for (int32_t i = 0; i < k; ++i)
            if (nb[i] > v) edge_other[e++] = nb[i];
    }
    for (int32_t f = 0; f < in->f; ++f)
        for (int c = 0; c < 3; ++c) {
            if (c == 0 && spia__refine_tick(clock, f)) goto cancelled;
            int32_t a = in->F[3 * f + c], b = in->F[3 * f + (c + 1) % 3], opp = in->F[3 * f + (c + 2) % 3];
            int32_t lo = a < b ? a : b, hi = a < b ? b : a;
            int64_t e = first_edge[lo];
            while (edge_other[e] != hi) ++e;
            edge_of_corner[3 * (int64_t)f + c] = e;
            if (edge_faces[e] < 2) edge_opp[2 * e + edge_faces[e]] = opp;
            edge_faces[e]++;
        }
    out->n = in->n + (int32_t)edges;
    out->f = 4 * in->f;
    out->P = (double *)malloc(sizeof(double) * 3 * (size_t)out->n);
    out->F = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)out->f);
    if (!out->P || !out->F) goto done;
    if (vertex_points(in, out, &m, &adj, valence, bnd, nb, cnt, cap, clock)) goto cancelled;
    edge_points(in, out, first_edge, edge_other, edge_opp, edge_faces, valence);
    split_faces(in, out, edge_of_corner);
    r = SPIA_OK;
    goto done;
cancelled:
    r = SPIA_ERROR_CANCELLED;
done:
    if (r != SPIA_OK) {
        free(out->P);
        free(out->F);
        memset(out, 0, sizeof *out);
    }
    spia__adjacency_free(&adj);
    free(sizes);
    free(dummy);
    free(edge_of_corner);
    free(nb);
    free(cnt);
    free(valence);
    free(bnd);
    free(first_edge);
    free(edge_other);
    free(edge_opp);
    free(edge_faces);
    return r;
}

/* The mesh's edges counted into *edges; 0 when out of memory. */
static int count_edges(const spia_mesh *m, const spia_adjacency *adj, int64_t *edges) {
    const int32_t cap = 2 * spia__max_corners_per_vertex(adj) + 2;
    int32_t *nb = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)cap);
    if (!nb) return 0;
    for (int32_t v = 0; v < m->vertex_count; ++v) {
        int32_t k = spia__vertex_neighbours(m, adj, v, nb, nb + cap, cap);
        for (int32_t i = 0; i < k; ++i) *edges += nb[i] > v;
    }
    free(nb);
    return 1;
}

spia_result spia__loop_hoppe_refine_limit(const spia_mesh *m, const spia_options *opt, int32_t levels,
                                          int32_t *vertex_count, int32_t *face_count, float *positions,
                                          int32_t *faces, spia__refine_clock *clock, spia_status *status) {
    /* The manifold test and the limit masks of the control mesh first. */
    spia_adjacency adj;
    spia_result r = spia__adjacency_build(m, &adj, status);
    if (r != SPIA_OK) return r;
    spia_stencils *check = NULL;
    r = spia__loop_hoppe_limit_stencils(m, &adj, opt, NULL, &check, status);
    spia_stencils_free(check);
    if (r != SPIA_OK) {
        spia__adjacency_free(&adj);
        return r;
    }
    /* Sizes: V' = V + E, E' = 2 E + 3 F, F' = 4 F (closed form, no refinement). */
    int64_t edges = 0;
    if (!count_edges(m, &adj, &edges)) {
        spia__adjacency_free(&adj);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
    }
    spia__adjacency_free(&adj);
    int64_t nv = m->vertex_count, ne = edges, nf = m->face_count;
    for (int32_t l = 0; l < levels; ++l) {
        nv += ne;
        ne = 2 * ne + 3 * nf;
        nf *= 4;
    }
    if (nv > INT32_MAX || 3 * nf > INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "%d levels make %lld faces, too many", (int)levels,
                          (long long)nf);
    *vertex_count = (int32_t)nv;
    *face_count = (int32_t)nf;
    if (!positions) return SPIA_OK;

    tri_level cur;
    cur.n = m->vertex_count;
    cur.f = m->face_count;
    cur.P = (double *)malloc(sizeof(double) * 3 * (size_t)cur.n);
    cur.F = (int32_t *)malloc(sizeof(int32_t) * 3 * (size_t)cur.f);
    if (!cur.P || !cur.F) {
        free(cur.P);
        free(cur.F);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
    }
    for (int64_t k = 0; k < 3 * (int64_t)cur.n; ++k) cur.P[k] = m->positions[k];
    memcpy(cur.F, m->face_vertices, sizeof(int32_t) * 3 * (size_t)cur.f);
    for (int32_t l = 0; l < levels; ++l) {
        tri_level next;
        r = hoppe_step(&cur, &next, clock);
        free(cur.P);
        free(cur.F);
        if (r == SPIA_ERROR_CANCELLED) return spia__refine_cancelled(status, clock);
        if (r != SPIA_OK) return spia__fail(status, r, -1, "out of memory refining the surface");
        cur = next;
        if (l + 1 < levels && spia__refine_level_done(clock, l + 1)) {
            free(cur.P);
            free(cur.F);
            return spia__refine_cancelled(status, clock);
        }
    }
    if (cur.n != nv || cur.f != nf) {
        free(cur.P);
        free(cur.F);
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "refined to %d vertices and %d faces, not the %lld and %lld "
                          "counted", (int)cur.n, (int)cur.f, (long long)nv, (long long)nf);
    }
    /* Limit positions of the refined mesh: its own Hoppe masks. */
    int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)cur.f);
    float *fpos = (float *)malloc(sizeof(float) * 3 * (size_t)cur.n);
    double *lim = (double *)malloc(sizeof(double) * 3 * (size_t)cur.n);
    spia_stencils *s = NULL;
    r = SPIA_ERROR_OUT_OF_MEMORY;
    if (sizes && fpos && lim) {
        for (int32_t f = 0; f < cur.f; ++f) sizes[f] = 3;
        for (int64_t k = 0; k < 3 * (int64_t)cur.n; ++k) fpos[k] = (float)cur.P[k];
        spia_mesh fine = {cur.n, fpos, cur.f, sizes, cur.F, 0, NULL, NULL, NULL};
        r = spia__adjacency_build(&fine, &adj, status);
        if (r == SPIA_OK) {
            r = spia__loop_hoppe_limit_stencils(&fine, &adj, opt, clock, &s, status);
            spia__adjacency_free(&adj);
        }
        if (r == SPIA_OK) spia_stencils_apply(s, cur.P, lim);
        if (r == SPIA_OK && spia__refine_level_done(clock, levels)) r = spia__refine_cancelled(status, clock);
        if (r == SPIA_OK) {
            for (int64_t k = 0; k < 3 * (int64_t)cur.n; ++k) positions[k] = (float)lim[k];
            memcpy(faces, cur.F, sizeof(int32_t) * 3 * (size_t)cur.f);
            spia__ok(status);
        }
    }
    if (r == SPIA_ERROR_OUT_OF_MEMORY) spia__fail(status, r, -1, "out of memory refining the surface");
    spia_stencils_free(s);
    free(sizes);
    free(fpos);
    free(lim);
    free(cur.P);
    free(cur.F);
    return r;
}
