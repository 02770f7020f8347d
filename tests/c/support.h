// SPDX-License-Identifier: GPL-3.0-or-later
/* Test support: a growable mesh, generated shapes, an OBJ reader, checks. */
#ifndef SPIA_TEST_SUPPORT_H
#define SPIA_TEST_SUPPORT_H

#include "subdiv_pia.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

static int test_failures = 0;
#define CHECK(cond, ...)                                                         \
    do {                                                                         \
        if (!(cond)) {                                                           \
            ++test_failures;                                                     \
            fprintf(stderr, "%s:%d: check failed: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                        \
            fputc('\n', stderr);                                                 \
        }                                                                        \
    } while (0)
#define TEST_MAIN_END()                                                          \
    do {                                                                         \
        if (test_failures) fprintf(stderr, "%d checks failed\n", test_failures); \
        else printf("all checks passed\n");                                      \
        return test_failures ? 1 : 0;                                            \
    } while (0)

typedef struct tmesh {
    int32_t nv, nf, ne;
    float *pos;
    int32_t *sizes;
    int32_t *fv;
    int64_t nfv;
    int32_t *edges;
    float *edge_creases;
    float *vertex_creases;
    /* What tmesh_grow allocated last, for each array (in the order of
     * TMESH_POS ...): the block and its room, so that building a mesh a
     * vertex at a time reallocates log n times, not n times (a sanitizer's
     * realloc copies every time). */
    struct {
        void *block;
        size_t room;
    } grown[6];
} tmesh;

enum { TMESH_POS, TMESH_VERTEX_CREASES, TMESH_SIZES, TMESH_FV, TMESH_EDGES, TMESH_EDGE_CREASES };

static void *tgrow(void *p, size_t n, size_t size) {
    void *q = realloc(p, (n ? n : 1) * size);
    if (!q) abort();
    return q;
}

/* Array `which` of m, p, with room for at least n items of `size` bytes;
 * an array not grown here (set by a test itself) is reallocated the first
 * time. */
static void *tmesh_grow(tmesh *m, int which, void *p, size_t n, size_t size) {
    if (p && p == m->grown[which].block && n <= m->grown[which].room) return p;
    size_t room = p && p == m->grown[which].block ? 2 * m->grown[which].room : 16;
    while (room < n) room *= 2;
    void *q = tgrow(p, room, size);
    m->grown[which].block = q;
    m->grown[which].room = room;
    return q;
}

static int32_t tmesh_vertex(tmesh *m, double x, double y, double z) {
    m->pos = (float *)tmesh_grow(m, TMESH_POS, m->pos, 3 * (size_t)(m->nv + 1), sizeof(float));
    m->pos[3 * m->nv] = (float)x;
    m->pos[3 * m->nv + 1] = (float)y;
    m->pos[3 * m->nv + 2] = (float)z;
    if (m->vertex_creases) {
        m->vertex_creases =
            (float *)tmesh_grow(m, TMESH_VERTEX_CREASES, m->vertex_creases, (size_t)m->nv + 1, sizeof(float));
        m->vertex_creases[m->nv] = 0.0f;
    }
    return m->nv++;
}

static void tmesh_face(tmesh *m, int n, const int32_t *v) {
    m->sizes = (int32_t *)tmesh_grow(m, TMESH_SIZES, m->sizes, (size_t)m->nf + 1, sizeof(int32_t));
    m->fv = (int32_t *)tmesh_grow(m, TMESH_FV, m->fv, (size_t)(m->nfv + n), sizeof(int32_t));
    m->sizes[m->nf++] = n;
    for (int i = 0; i < n; ++i) m->fv[m->nfv++] = v[i];
}

static void tmesh_quad(tmesh *m, int32_t a, int32_t b, int32_t c, int32_t d) {
    int32_t v[4] = {a, b, c, d};
    tmesh_face(m, 4, v);
}

static void tmesh_tri(tmesh *m, int32_t a, int32_t b, int32_t c) {
    int32_t v[3] = {a, b, c};
    tmesh_face(m, 3, v);
}

/* An edge with a crease (the edge may or may not be a face edge). */
static void tmesh_edge(tmesh *m, int32_t a, int32_t b, float crease) {
    m->edges = (int32_t *)tmesh_grow(m, TMESH_EDGES, m->edges, 2 * (size_t)(m->ne + 1), sizeof(int32_t));
    m->edge_creases = (float *)tmesh_grow(m, TMESH_EDGE_CREASES, m->edge_creases, (size_t)m->ne + 1, sizeof(float));
    m->edges[2 * m->ne] = a;
    m->edges[2 * m->ne + 1] = b;
    m->edge_creases[m->ne++] = crease;
}

static void tmesh_vertex_crease(tmesh *m, int32_t v, float crease) {
    if (!m->vertex_creases) m->vertex_creases = (float *)calloc((size_t)m->nv, sizeof(float));
    m->vertex_creases[v] = crease;
}

static spia_mesh tmesh_view(const tmesh *m) {
    spia_mesh s;
    s.vertex_count = m->nv;
    s.positions = m->pos;
    s.face_count = m->nf;
    s.face_sizes = m->sizes;
    s.face_vertices = m->fv;
    s.edge_count = m->ne;
    s.edges = m->edges;
    s.edge_creases = m->edge_creases;
    s.vertex_creases = m->vertex_creases;
    return s;
}

static void tmesh_free(tmesh *m) {
    free(m->pos);
    free(m->sizes);
    free(m->fv);
    free(m->edges);
    free(m->edge_creases);
    free(m->vertex_creases);
    memset(m, 0, sizeof *m);
}

/* Open (nx x ny)-quad grid in the z = 0 plane, slightly bumped. */
static tmesh make_grid(int nx, int ny) {
    tmesh m;
    memset(&m, 0, sizeof m);
    for (int j = 0; j <= ny; ++j)
        for (int i = 0; i <= nx; ++i) tmesh_vertex(&m, i, j, 0.1 * sin(1.3 * i + 0.7 * j));
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            int32_t a = j * (nx + 1) + i;
            tmesh_quad(&m, a, a + 1, a + nx + 2, a + nx + 1);
        }
    return m;
}

/* Closed quad torus, every vertex of valence 4; triangulated if asked. */
static tmesh make_torus(int nu, int nv, int triangles) {
    tmesh m;
    memset(&m, 0, sizeof m);
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv;
            tmesh_vertex(&m, (2 + 0.7 * cos(v)) * cos(u), (2 + 0.7 * cos(v)) * sin(u), 0.7 * sin(v));
        }
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            int32_t a = j * nu + i, b = j * nu + (i + 1) % nu, c = ((j + 1) % nv) * nu + (i + 1) % nu,
                    d = ((j + 1) % nv) * nu + i;
            if (triangles) {
                tmesh_tri(&m, a, b, c);
                tmesh_tri(&m, a, c, d);
            } else {
                tmesh_quad(&m, a, b, c, d);
            }
        }
    return m;
}

/* A cube with every face cut into k x k quads, pushed toward a sphere:
 * valence-3 vertices at the 8 corners, valence 4 elsewhere. */
static tmesh make_cut_cube(int k) {
    tmesh m;
    memset(&m, 0, sizeof m);
    /* Vertices on the cube surface, deduplicated through a (k+1)^3 lattice. */
    int n = k + 1;
    int32_t *id = (int32_t *)malloc(sizeof(int32_t) * (size_t)(n * n * n));
    for (int i = 0; i < n * n * n; ++i) id[i] = -1;
#define LAT(x, y, z) id[((x) * n + (y)) * n + (z)]
    for (int x = 0; x < n; ++x)
        for (int y = 0; y < n; ++y)
            for (int z = 0; z < n; ++z) {
                if (x && y && z && x < k && y < k && z < k) continue;
                double p[3] = {2.0 * x / k - 1, 2.0 * y / k - 1, 2.0 * z / k - 1};
                double r = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
                double s = 0.5 + 0.5 / r;
                LAT(x, y, z) = tmesh_vertex(&m, p[0] * s, p[1] * s * 0.8, p[2] * s * 1.1);
            }
    for (int a = 0; a < k; ++a)
        for (int b = 0; b < k; ++b) {
            /* Faces at x = 0 / k, y = 0 / k, z = 0 / k, wound outward. */
            tmesh_quad(&m, LAT(0, a, b), LAT(0, a, b + 1), LAT(0, a + 1, b + 1), LAT(0, a + 1, b));
            tmesh_quad(&m, LAT(k, a, b), LAT(k, a + 1, b), LAT(k, a + 1, b + 1), LAT(k, a, b + 1));
            tmesh_quad(&m, LAT(a, 0, b), LAT(a + 1, 0, b), LAT(a + 1, 0, b + 1), LAT(a, 0, b + 1));
            tmesh_quad(&m, LAT(a, k, b), LAT(a, k, b + 1), LAT(a + 1, k, b + 1), LAT(a + 1, k, b));
            tmesh_quad(&m, LAT(a, b, 0), LAT(a, b + 1, 0), LAT(a + 1, b + 1, 0), LAT(a + 1, b, 0));
            tmesh_quad(&m, LAT(a, b, k), LAT(a + 1, b, k), LAT(a + 1, b + 1, k), LAT(a, b + 1, k));
        }
#undef LAT
    free(id);
    return m;
}

/* Reads positions, faces and OpenSubdiv "t crease" tags from an OBJ file.
 * Returns 0 on failure. */
static int read_obj(const char *path, tmesh *m) {
    memset(m, 0, sizeof *m);
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    char line[4096];
    while (fgets(line, sizeof line, f)) {
        if (line[0] == 'v' && line[1] == ' ') {
            double x, y, z;
            if (sscanf(line + 2, "%lf %lf %lf", &x, &y, &z) == 3) tmesh_vertex(m, x, y, z);
        } else if (line[0] == 'f' && line[1] == ' ') {
            int32_t v[64];
            int n = 0;
            char *p = line + 2;
            while (*p && n < 64) {
                while (*p == ' ' || *p == '\t') ++p;
                if (*p == '\n' || *p == '\r' || !*p) break;
                v[n++] = (int32_t)strtol(p, &p, 10) - 1;
                while (*p && *p != ' ' && *p != '\t' && *p != '\n') ++p;
            }
            tmesh_face(m, n, v);
        } else if (!strncmp(line, "t crease 2/1/0 ", 15)) {
            int a, b;
            double s;
            if (sscanf(line + 15, "%d %d %lf", &a, &b, &s) == 3) {
                /* OpenSubdiv sharpness s = 10 c^2 in Blender's terms. */
                double c = sqrt(s > 10 ? 1.0 : s / 10.0);
                tmesh_edge(m, a, b, (float)c);
            }
        }
    }
    fclose(f);
    return m->nv > 0;
}

/* Drops faces that use a vertex twice (as Blender's importer does). */
static void drop_degenerate_faces(tmesh *m) {
    int64_t in = 0, out = 0;
    int32_t nf = 0;
    for (int32_t f = 0; f < m->nf; ++f) {
        int n = m->sizes[f], bad = 0;
        for (int i = 0; i < n; ++i)
            for (int j = i + 1; j < n; ++j) bad |= m->fv[in + i] == m->fv[in + j];
        if (!bad) {
            memmove(m->fv + out, m->fv + in, sizeof(int32_t) * (size_t)n);
            out += n;
            m->sizes[nf++] = n;
        }
        in += n;
    }
    m->nf = nf;
    m->nfv = out;
}

/* Dense row i of a stencil table, into w (vertex_count doubles). */
static void stencil_row(const int64_t *off, const int32_t *idx, const double *wt, int32_t i, double *w, int32_t n) {
    for (int32_t j = 0; j < n; ++j) w[j] = 0.0;
    for (int64_t k = off[i]; k < off[i + 1]; ++k) w[idx[k]] += wt[k];
}

/* The least-squares answer for an isolated double-sided triangle (its two
 * faces alone) on vertices a, b, c: each of the three rows of the limit
 * matrix is the same (the triangle's centroid), so the best any cage can do
 * is put that common limit point on the centroid of the three targets.
 * Returns the largest distance, over the three, of the cage's limit point
 * (applied through the table) from that centroid. */
static double double_sided_miss(const spia_stencils *s, const float *targets, const float *cage, const int32_t v[3]) {
    const int32_t n = spia_stencils_row_count(s);
    double *x = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    double *l = (double *)malloc(sizeof(double) * 3 * (size_t)n);
    if (!x || !l) abort();
    for (int64_t k = 0; k < 3 * (int64_t)n; ++k) x[k] = cage[k];
    spia_stencils_apply(s, x, l);
    double centroid[3] = {0.0, 0.0, 0.0}, worst = 0.0;
    for (int i = 0; i < 3; ++i)
        for (int a = 0; a < 3; ++a) centroid[a] += targets[3 * (int64_t)v[i] + a] / 3.0;
    for (int i = 0; i < 3; ++i) {
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) d2 += (l[3 * (int64_t)v[i] + a] - centroid[a]) * (l[3 * (int64_t)v[i] + a] - centroid[a]);
        worst = fmax(worst, sqrt(d2));
    }
    free(x);
    free(l);
    return worst;
}

#ifdef __cplusplus
}
#endif

#endif
