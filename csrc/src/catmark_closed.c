// SPDX-License-Identifier: GPL-3.0-or-later
/* Catmull-Clark limit points that have a closed form, from a vertex's own
 * faces, without OpenSubdiv.
 *
 * Blender's modifier evaluates a control vertex on adaptive patches, which at
 * most vertices reproduce the exact limit point.  Where that point has a
 * closed form, the row is written here; OpenSubdiv (osd_*.cpp) is
 * built only around the other vertices.  The closed forms, with sharpness as
 * OpenSubdiv takes it (boundary edges and sharpness >= 10 infinitely sharp):
 *
 *  - a smooth interior vertex V with n >= 3 faces f_1..f_n (any sizes) and
 *    neighbours w_1..w_n along its edges.  One Catmull-Clark step gives
 *    the vertex point V1 = ((n - 2) V + (sum w + sum F) / n) / n (F the
 *    face centroids), the edge points (V + w + F_a + F_b) / 4 and the face
 *    points F; after it every face is a quad, where the limit mask is
 *    (n^2 V1 + 4 sum E1 + sum F) / (n (n + 5)).  Expanded (each face lies
 *    on two of V's edges):
 *        limit = ((n^2 - n) V + 2 sum w + 4 sum F) / (n (n + 5));
 *  - two infinitely sharp edges (a crease, or a boundary with >= 2 faces
 *    and no sharp interior edge) to neighbours a and b: (a + 4 V + b) / 6;
 *  - three or more, or an infinitely sharp vertex (a boundary vertex with
 *    one face when corners are preserved): V itself.
 *
 * Everything else goes to OpenSubdiv: vertices that are not one consistently
 * oriented fan of faces (non-manifold), semi-sharp vertices and edges and
 * darts (Blender's surface there depends on the isolation level), interior
 * vertices with two faces, and boundary vertices with one face when
 * boundaries are smooth (Blender is not at the limit there). */

#include "internal.h"

#include <stdlib.h>
#include <string.h>

enum { SHARP_EDGE_LIMIT = 8 };

float spia__catmark_edge_sharpness(const spia_catmark_sharpness *sh, int32_t v, int32_t w) {
    if (!sh->crease_first) return 0.0f;
    for (int64_t i = sh->crease_first[v]; i < sh->crease_first[v + 1]; ++i)
        if (sh->crease_other[i] == w) return sh->crease_sharpness[i];
    return 0.0f;
}

static int grow(spia_row_scratch *s, int64_t need) {
    if (need <= s->capacity) return 1;
    int64_t cap = s->capacity > 0 ? s->capacity : 64;
    while (cap < need) cap *= 2;
    spia_row_entry *e = (spia_row_entry *)realloc(s->entries, sizeof(spia_row_entry) * (size_t)cap);
    if (e) s->entries = e;
    spia_fan_corner *fan = (spia_fan_corner *)realloc(s->fan, sizeof(spia_fan_corner) * (size_t)cap);
    if (fan) s->fan = fan;
    if (!e || !fan) return 0;
    s->capacity = cap;
    return 1;
}

static int by_column(const void *a, const void *b) {
    const int32_t x = ((const spia_row_entry *)a)->column, y = ((const spia_row_entry *)b)->column;
    return (x > y) - (x < y);
}

/* Sorts the entries by column (stable for short rows), adds repeats up and
 * drops zeros; returns the length. */
static int32_t finish_row(spia_row_entry *e, int32_t count) {
    if (count <= 48) {
        for (int32_t i = 1; i < count; ++i) {
            spia_row_entry x = e[i];
            int32_t j = i;
            while (j > 0 && e[j - 1].column > x.column) {
                e[j] = e[j - 1];
                --j;
            }
            e[j] = x;
        }
    } else {
        qsort(e, (size_t)count, sizeof *e, by_column);
    }
    int32_t out = 0;
    for (int32_t i = 0; i < count;) {
        const int32_t c = e[i].column;
        double w = 0.0;
        while (i < count && e[i].column == c) w += e[i++].weight;
        if (w != 0.0) {
            e[out].column = c;
            e[out].weight = w;
            ++out;
        }
    }
    return out;
}

/* The faces around v, read once into fan: for the i-th, the neighbours
 * after and before v in it and where its corners are; total grows by
 * |f| - 2 a face.  0 where v is used twice by a face or a
 * face's next and prev are one vertex. */
static int read_fan(const spia_mesh *m, const spia_adjacency *adj, int32_t v, spia_fan_corner *fan, int64_t *total) {
    const int64_t first = adj->first[v];
    const int32_t k = (int32_t)(adj->first[v + 1] - first);
    for (int32_t i = 0; i < k; ++i) {
        const int64_t c = adj->corner_of[first + i];
        const int32_t f = adj->face_of_corner[c];
        const int64_t c0 = adj->corner_start[f], c1 = adj->corner_start[f + 1];
        const int32_t *fv = m->face_vertices;
        int uses = 0;
        for (int64_t d = c0; d < c1; ++d) uses += fv[d] == v;
        fan[i].corner = c;
        fan[i].start = c0;
        fan[i].size = (int32_t)(c1 - c0);
        fan[i].next = fv[c + 1 == c1 ? c0 : c + 1];
        fan[i].prev = fv[c == c0 ? c1 - 1 : c - 1];
        *total += c1 - c0 - 2;
        if (uses != 1 || fan[i].next == fan[i].prev) return 0;
    }
    return 1;
}

/* One fan, consistently oriented: every neighbour follows v in at most
 * one face and precedes it in at most one; around an interior vertex
 * each face's next is another face's prev, around a boundary vertex all
 * but one (end), and walking from face to face visits every face.
 * succ[i]: the face after face i (its prev is face i's next).
 * start and end: the boundary's first and last faces, -1 inside.  0 where
 * the faces are not one such fan. */
static int one_fan(spia_fan_corner *fan, int32_t k, int32_t *start, int32_t *end) {
    for (int32_t i = 0; i < k; ++i) {
        int32_t succ = -1, pred = -1;
        for (int32_t j = 0; j < k; ++j) {
            if (j != i && (fan[j].next == fan[i].next || fan[j].prev == fan[i].prev)) return 0;
            if (fan[j].prev == fan[i].next) succ = j;
            if (fan[j].next == fan[i].prev) pred = j;
        }
        fan[i].succ = succ;
        if (succ < 0) {
            if (*end >= 0) return 0;
            *end = i;
        }
        if (pred < 0) {
            if (*start >= 0) return 0;
            *start = i;
        }
    }
    const int boundary = *start >= 0;
    if ((*start >= 0) != (*end >= 0)) return 0;
    {
        int32_t i = boundary ? *start : 0, steps = 1;
        while (fan[i].succ >= 0 && fan[i].succ != (boundary ? -1 : 0)) {
            i = fan[i].succ;
            if (++steps > k) return 0;
        }
        if (steps != k) return 0;
    }
    return 1;
}

int32_t spia__catmark_closed_row(const spia_mesh *m, const spia_adjacency *adj, const spia_catmark_sharpness *sh,
                                 int32_t v, spia_row_scratch *scratch) {
    const int64_t first = adj->first[v], k64 = adj->first[v + 1] - first;
    scratch->on_boundary = -1;
    if (k64 <= 0) return SPIA__ROW_NOT_CLOSED;
    const int32_t k = (int32_t)k64;
    const float vs = sh->vertex[v];
    if (!grow(scratch, (int64_t)k + 1)) return SPIA__ROW_OUT_OF_MEMORY;
    spia_fan_corner *fan = scratch->fan;
    int64_t total = 1; /* 1 + sum (|f| - 2): the smooth row's length bound */
    if (!read_fan(m, adj, v, fan, &total)) return SPIA__ROW_NOT_CLOSED;
    int32_t start = -1, end = -1;
    if (!one_fan(fan, k, &start, &end)) return SPIA__ROW_NOT_CLOSED;
    const int boundary = start >= 0;
    /* One fan: v is on the boundary exactly when it has two ends (an edge
     * of one face each), as spia__boundary_vertices would find. */
    scratch->on_boundary = boundary;
    if (vs > 0.0f && vs < SPIA__SHARPNESS_INFINITE) return SPIA__ROW_NOT_CLOSED; /* a semi-sharp vertex */

    /* Infinitely sharp edges, up to SHARP_EDGE_LIMIT of them. */
    int32_t sharp[SHARP_EDGE_LIMIT];
    int n_sharp = 0;
    if (boundary) {
        sharp[n_sharp++] = fan[start].prev;
        sharp[n_sharp++] = fan[end].next;
    }
    if (sh->crease_first && sh->crease_first[v + 1] > sh->crease_first[v]) {
        for (int32_t i = 0; i < k; ++i) {
            if (boundary && i == end) continue; /* a boundary edge */
            const float s = spia__catmark_edge_sharpness(sh, v, fan[i].next);
            if (s <= 0.0f) continue;
            if (s < SPIA__SHARPNESS_INFINITE) return SPIA__ROW_NOT_CLOSED; /* semi-sharp */
            if (n_sharp < SHARP_EDGE_LIMIT) sharp[n_sharp] = fan[i].next;
            ++n_sharp;
        }
    }
    const int corner_vertex = vs >= SPIA__SHARPNESS_INFINITE || (boundary && k == 1 && sh->preserve_corners);
    spia_row_entry *e = scratch->entries;
    if (corner_vertex || n_sharp >= 3) {
        e[0].column = v;
        e[0].weight = 1.0;
        return 1;
    }
    if (n_sharp == 1) return SPIA__ROW_NOT_CLOSED;       /* a dart */
    if (boundary && k == 1) return SPIA__ROW_NOT_CLOSED; /* a smooth corner */
    if (n_sharp == 2) {
        e[0].column = sharp[0];
        e[0].weight = 1.0 / 6.0;
        e[1].column = v;
        e[1].weight = 4.0 / 6.0;
        e[2].column = sharp[1];
        e[2].weight = 1.0 / 6.0;
        return finish_row(e, 3);
    }
    if (k < 3) return SPIA__ROW_NOT_CLOSED; /* two faces */

    /* Smooth interior: ((n^2 - n) V + 2 sum w + 4 sum F) / (n (n + 5)),
     * one entry per vertex of the fan: V, each neighbour w along an edge
     * (2 plus 4 / |f| from each of the edge's two faces) and the faces'
     * other vertices (4 / |f|).  Repeats (a vertex on two faces that share
     * no edge) are added up by finish_row. */
    if (total > INT32_MAX) return SPIA__ROW_OUT_OF_MEMORY;
    if (!scratch->build) return (int32_t)total; /* a bound on the length */
    if (!grow(scratch, total)) return SPIA__ROW_OUT_OF_MEMORY;
    e = scratch->entries;
    fan = scratch->fan;
    const double n = (double)k, scale = 1.0 / (n * (n + 5.0));
    double centre = (n * n - n) * scale;
    int32_t count = 1;
    for (int32_t i = 0; i < k; ++i) fan[i].inverse_size = 1.0 / (double)fan[i].size;
    for (int32_t i = 0; i < k; ++i) {
        const int64_t c = fan[i].corner, c0 = fan[i].start, c1 = c0 + fan[i].size;
        const double wf = 4.0 * scale * fan[i].inverse_size;
        centre += wf;
        /* The edge to next lies on face i and the face after it. */
        e[count].column = fan[i].next;
        e[count++].weight = 2.0 * scale + wf + 4.0 * scale * fan[fan[i].succ].inverse_size;
        /* The face's vertices from the one after next to the one before
         * prev. */
        int64_t d = c + 2 < c1 ? c + 2 : c + 2 - fan[i].size;
        for (int32_t left = fan[i].size - 3; left > 0; --left) {
            e[count].column = m->face_vertices[d];
            e[count++].weight = wf;
            if (++d == c1) d = c0;
        }
    }
    e[0].column = v;
    e[0].weight = centre;
    return finish_row(e, count);
}

void spia__row_scratch_free(spia_row_scratch *s) {
    free(s->entries);
    free(s->fan);
    memset(s, 0, sizeof *s);
}
