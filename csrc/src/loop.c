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

spia_result spia__loop_hoppe_limit_stencils(const spia_mesh *m, const spia_adjacency *a, const spia_options *opt,
                                            spia_stencils **out, spia_status *status) {
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
        const int64_t faces = a->first[v + 1] - a->first[v];
        int32_t k = spia__vertex_neighbours(m, a, v, nb, fe, cap), boundary_edges = 0, bad = 0;
        for (int32_t i = 0; i < k; ++i) {
            if (fe[i] == 1) ++boundary_edges;
            if (fe[i] > 2) bad = 1;
        }
        valence[v] = k;
        boundary[v] = boundary_edges > 0;
        if (faces > 0 && (bad || (boundary_edges != 0 && boundary_edges != 2) || fan_count(m, a, v, parent) != 1)) {
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
                          "Hoppe's boundary rules need a manifold mesh: %lld vertices are non-manifold "
                          "(first: vertex %lld); use the SMOOTH boundary rule or clean the mesh",
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
        s->offsets[v] = pos;
        if (a->first[v + 1] == a->first[v]) { /* used by no face: stays put */
            s->indices[pos] = v;
            s->weights[pos++] = 1.0;
            continue;
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
            continue;
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
