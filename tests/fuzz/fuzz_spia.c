// SPDX-License-Identifier: GPL-3.0-or-later
/* The fuzz target: every public function on meshes and options decoded from
 * the input bytes.  Built with libFuzzer (tests/fuzz/CMakeLists.txt, `make
 * fuzz`) it is the fuzzer; built without it (tests/c: test_fuzz_replay) a
 * main() runs it on files, so that every input the fuzzer ever crashed on
 * stays a regression test.
 *
 * Beyond "no crash, no leak, no undefined behaviour" it checks what the
 * header promises: a known result code and the same one in the status with
 * a message, *out NULL and output buffers untouched on failure, tables in
 * valid CSR form, finite results.  A broken promise aborts.
 *
 * Input layout (missing bytes read as 0, all little endian):
 *   16 bytes of settings (see decode_settings): operations, scheme, flags,
 *   method, quality, iterations, tolerance and weight, shape parameter and
 *   threads and OpenSubdiv version, levels, samples, cancel, fit settings
 *   (3 bytes), fit flags, subdivision
 *   u16 vertex count, u16 face count, u8 edge count
 *   face sizes (u8 each, taken mod 9: 0 to 8)
 *   corners (u16 each; see index_of)
 *   positions (3 x i16 per vertex; see coordinate_of)
 *   edges (2 x u16), edge creases (u8), vertex creases (u8),
 *   face shape parameters (u8), then query points (3 x i16 each)
 */
#include "subdiv_pia.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FUZZ_MAX_VERTICES 2048
#define FUZZ_MAX_FACES 2048
#define FUZZ_MAX_QUERIES 64
#define FUZZ_SETTINGS 16

typedef struct reader {
    const uint8_t *p;
    size_t n, at;
} reader;

static uint8_t u8(reader *r) { return r->at < r->n ? r->p[r->at++] : 0; }
static uint16_t u16(reader *r) {
    uint16_t a = u8(r);
    return (uint16_t)(a | (uint16_t)(u8(r) << 8));
}

static void fuzz_fail(const char *what, const char *detail) {
    fprintf(stderr, "fuzz check failed: %s (%s)\n", what, detail ? detail : "");
    abort();
}

/* Vertex indices: in range modulo vertex_count + 1 (so vertex_count itself,
 * one past the end, occurs), and four codes for the extremes. */
static int32_t index_of(uint16_t x, int32_t nv) {
    switch (x) {
    case 0xFFFF: return -1;
    case 0xFFFE: return nv;
    case 0xFFFD: return INT32_MAX;
    case 0xFFFC: return INT32_MIN;
    default: return nv > 0 ? (int32_t)(x % (uint32_t)(nv + 1)) : (int32_t)x;
    }
}

static float coordinate_of(int16_t s) {
    if (s == INT16_MAX) return NAN;
    if (s == INT16_MAX - 1) return INFINITY;
    if (s == INT16_MIN) return -INFINITY;
    return (float)s / 1024.0f;
}

static float crease_of(uint8_t b) { return b == 255 ? NAN : b == 254 ? INFINITY : (float)b / 250.0f; }

typedef struct settings {
    uint8_t ops;
    spia_options o;
    int32_t levels, samples, cancel_at;
    spia_fit_options fit;
    uint8_t has_edges, has_edge_creases, has_vertex_creases, has_face_shapes;
    int16_t raw_vertex_count, raw_face_count;
    int subdivide;
} settings;

enum {
    OP_VALIDATE = 1 << 0,
    OP_STENCILS = 1 << 1,
    OP_INTERPOLATE = 1 << 2,
    OP_REFINE = 1 << 3,
    OP_SURFACE = 1 << 4,
    OP_SCAN = 1 << 5,
    OP_FIT = 1 << 6,
    OP_NULLS = 1 << 7
};

static void decode_settings(reader *r, settings *s) {
    static const double tolerances[8] = {1e-6, 1e-3, 1e-9, 0.0, -1.0, NAN, INFINITY, 1e-14};
    static const double weights[8] = {0.0, 0.5, 1.0, 1.9, -1.0, NAN, 2.5, 1e-30};
    static const double shapes[8] = {0.0, 0.5, 0.25, 0.9, 1.0, -0.1, NAN, 1e-6};
    static const int32_t osd_versions[4] = {0, 30600, 30700, -5};
    static const double cutoffs[8] = {0.0, 0.02, 1.0, -1.0, NAN, 1e-9, INFINITY, 0.5};
    static const double terms[8] = {0.0, 1e-5, -1.0, NAN, 1.0, 1e3, INFINITY, 1e-3};
    memset(s, 0, sizeof *s);
    s->ops = u8(r);
    uint8_t b = u8(r);
    s->o.scheme = (spia_scheme)(b % 4); /* 3: unknown */
    uint8_t flags = u8(r);
    s->o.boundary_smooth = (spia_boundary_smooth)(flags & 1);
    s->o.ignore_creases = (flags >> 1) & 1;
    s->o.boundary_rule = (spia_boundary_rule)((flags >> 2) & 1);
    s->o.staged = (flags >> 3) & 1;
    s->has_edges = (flags >> 4) & 1;
    s->has_edge_creases = (flags >> 5) & 1;
    s->has_vertex_creases = (flags >> 6) & 1;
    s->has_face_shapes = (flags >> 7) & 1;
    b = u8(r);
    /* 7: least squares, or with bit 6 set the unknown method after it
     * (0 to 6 read as before it came) */
    s->o.method = (spia_method)(b % 8 == 7 ? SPIA_METHOD_LEAST_SQUARES + ((b >> 6) & 1) : b % 8);
    s->o.solve_flags = (int32_t)(b >> 3) & 7; /* the three SPIA_SOLVE_* */
    s->o.quality = u8(r) % 12;              /* 0: default, 11: out of range */
    b = u8(r);
    s->o.max_iterations = b == 255 ? -1 : 1 + b % 48;
    b = u8(r);
    s->o.tolerance = tolerances[b % 8];
    s->o.weight = weights[(b >> 3) % 8];
    b = u8(r);
    s->o.shape_parameter = shapes[b % 8];
    s->o.threads = (b >> 3) % 4 == 3 ? -1 : (b >> 3) % 4;
    s->o.opensubdiv_version = osd_versions[(b >> 5) % 4];
    b = u8(r);
    s->levels = (int32_t)(b % 11) - 1; /* -1 to 9 */
    b = u8(r);
    s->samples = (int32_t)(b % 67) - 1; /* -1 to 65 */
    b = u8(r);
    s->cancel_at = b % 8; /* 0: never */
    {
        /* Every call under a memory budget the fuzzer's own limit (2 GB)
         * holds: the library must refuse what would need more. */
        static const int64_t budgets[4] = {(int64_t)1 << 30, (int64_t)256 << 20, 4096, (int64_t)64 << 20};
        s->o.memory_budget = budgets[(b >> 3) % 4];
    }
    b = u8(r);
    s->fit.mode = (spia_fit_mode)(b % 3); /* 2: unknown */
    s->fit.samples_per_edge = (int32_t)((b >> 2) % 6) - 1;
    s->fit.max_rounds = (int32_t)((b >> 5) % 4);
    b = u8(r);
    s->fit.cutoff = cutoffs[b % 8];
    s->fit.smoothing = terms[(b >> 3) % 8];
    b = u8(r);
    s->fit.point_weight = terms[b % 8];
    s->fit.round_tolerance = terms[(b >> 3) % 8];
    s->fit.solver_iterations = (int32_t)(b >> 6) * 4;
    b = u8(r);
    s->fit.flags = b & 31; /* the five spia_fit_flags */
    b = u8(r);
    s->subdivide = b & 1;  /* spia_subdivide and spia_flat_positions */
}

static int known_code(spia_result r) { return r >= SPIA_ERROR_INTERNAL && r <= SPIA_STAGNATED; }

/* What every call promises about its result and status. */
static void check_status(const char *call, spia_result r, const spia_status *st) {
    if (!known_code(r)) fuzz_fail("unknown result code", call);
    if (st->code != r) fuzz_fail("status code differs from the result", call);
    if (!memchr(st->message, 0, sizeof st->message)) fuzz_fail("message not terminated", call);
    if (r < 0 && st->message[0] == 0) fuzz_fail("failure without a message", call);
    const char *name = spia_result_name(r);
    if (!name || strncmp(name, "SPIA_", 5) != 0) fuzz_fail("result name", call);
}

static void fill(void *p, size_t n) { memset(p, 0xA5, n); }
static void check_untouched(const char *call, const void *p, size_t n) {
    const uint8_t *q = (const uint8_t *)p;
    for (size_t i = 0; i < n; ++i)
        if (q[i] != 0xA5) fuzz_fail("output written by a failed call", call);
}
static void check_finite(const char *call, const float *p, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(p[i])) fuzz_fail("non-finite output", call);
}

typedef struct cancel_state {
    int32_t calls, cancel_at;
} cancel_state;

static int progress(void *user, int32_t iteration, double relative_error) {
    (void)iteration;
    (void)relative_error;
    cancel_state *c = (cancel_state *)user;
    return c->cancel_at && ++c->calls >= c->cancel_at;
}

static void check_table(const char *call, const spia_stencils *s, int32_t rows, int32_t columns) {
    if (spia_stencils_row_count(s) != rows) fuzz_fail("row count", call);
    const int64_t nnz = spia_stencils_weight_count(s);
    if (nnz < 0) fuzz_fail("weight count", call);
    int64_t *off = (int64_t *)malloc(sizeof(int64_t) * ((size_t)rows + 1));
    int32_t *idx = (int32_t *)malloc(sizeof(int32_t) * ((size_t)nnz + 1));
    double *w = (double *)malloc(sizeof(double) * ((size_t)nnz + 1));
    if (!off || !idx || !w) abort();
    spia_status st;
    spia_result r = spia_stencils_copy_csr(s, off, idx, w);
    if (r != SPIA_OK) fuzz_fail("copy_csr failed", call);
    if (off[0] != 0 || off[rows] != nnz) fuzz_fail("offsets do not span the weights", call);
    for (int32_t i = 0; i < rows; ++i) {
        if (off[i + 1] < off[i]) fuzz_fail("offsets decrease", call);
        for (int64_t k = off[i]; k < off[i + 1]; ++k) {
            if (idx[k] < 0 || idx[k] >= columns) fuzz_fail("column out of range", call);
            if (k > off[i] && idx[k] <= idx[k - 1]) fuzz_fail("columns not increasing", call);
            if (!isfinite(w[k])) fuzz_fail("non-finite weight", call);
        }
    }
    /* Applying it to the unit cage (1, 1, 1) gives the row sums. */
    double *cage = (double *)malloc(sizeof(double) * 3 * ((size_t)columns + 1));
    double *out = (double *)malloc(sizeof(double) * 3 * ((size_t)rows + 1));
    if (!cage || !out) abort();
    for (int64_t i = 0; i < 3 * (int64_t)columns; ++i) cage[i] = 1.0;
    r = spia_stencils_apply(s, cage, out);
    if (r != SPIA_OK) fuzz_fail("apply failed", call);
    for (int32_t i = 0; i < rows; ++i) {
        double sum = 0.0;
        for (int64_t k = off[i]; k < off[i + 1]; ++k) sum += w[k];
        if (!(fabs(out[3 * (int64_t)i] - sum) <= 1e-9 * (1.0 + fabs(sum)))) fuzz_fail("apply differs from the rows", call);
    }
    (void)st;
    free(cage);
    free(out);
    free(off);
    free(idx);
    free(w);
}

static void run_stencils(const spia_mesh *m, const spia_options *o, const float *targets) {
    spia_status st;
    spia_stencils *s = (spia_stencils *)&st; /* must become NULL on failure */
    spia_result r = spia_limit_stencils_create(m, o, &s, &st);
    check_status("spia_limit_stencils_create", r, &st);
    if (r != SPIA_OK) {
        if (s) fuzz_fail("table returned by a failed call", "spia_limit_stencils_create");
        return;
    }
    if (!s) fuzz_fail("no table", "spia_limit_stencils_create");
    check_table("spia_limit_stencils_create", s, m->vertex_count, m->vertex_count);
    const size_t size = sizeof(float) * 3 * (size_t)m->vertex_count;
    float *cage = (float *)malloc(size);
    if (!cage) abort();
    fill(cage, size);
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    double history[8];
    rep.history = history;
    rep.history_capacity = 8;
    r = spia_solve(s, targets, o, cage, &rep, &st);
    check_status("spia_solve", r, &st);
    if (rep.result != r) fuzz_fail("report result differs", "spia_solve");
    if (rep.history_count < 0 || rep.history_count > 8) fuzz_fail("history count", "spia_solve");
    if (r < 0) check_untouched("spia_solve", cage, size);
    else check_finite("spia_solve", cage, 3 * (size_t)m->vertex_count);
    /* From a first iterate: the cage just solved (the output buffer as its
     * own start) or, after a failure, the targets themselves. */
    spia_options warm = *o;
    warm.initial_cage = r >= 0 ? cage : targets;
    if (r < 0) fill(cage, size);
    memset(&rep, 0, sizeof rep);
    r = spia_solve(s, targets, &warm, cage, &rep, &st);
    check_status("spia_solve (initial cage)", r, &st);
    if (rep.result != r) fuzz_fail("report result differs", "spia_solve (initial cage)");
    if (r >= 0) check_finite("spia_solve (initial cage)", cage, 3 * (size_t)m->vertex_count);
    else if (warm.initial_cage == targets) check_untouched("spia_solve (initial cage)", cage, size);
    free(cage);
    spia_stencils_free(s);
}

static void run_interpolate(const spia_mesh *m, const spia_options *o, spia_result validated) {
    const size_t size = sizeof(float) * 3 * ((size_t)(m->vertex_count > 0 ? m->vertex_count : 0) + 1);
    float *cage = (float *)malloc(size);
    if (!cage) abort();
    fill(cage, size);
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    uint8_t *unreachable = NULL;
    if (m->vertex_count > 0) {
        unreachable = (uint8_t *)malloc((size_t)m->vertex_count);
        if (!unreachable) abort();
        rep.unreachable = unreachable;
    }
    spia_status st;
    spia_result r = spia_interpolate(m, o, cage, &rep, &st);
    check_status("spia_interpolate", r, &st);
    /* A mesh that fails validation fails here too (options are checked
     * first, so only when they are valid does the code have to match). */
    if (validated != SPIA_OK && r >= 0) fuzz_fail("interpolated an invalid mesh", "spia_interpolate");
    if (r < 0) check_untouched("spia_interpolate", cage, size);
    else {
        check_finite("spia_interpolate", cage, 3 * (size_t)m->vertex_count);
        if (rep.unreachable_count < 0 || rep.unreachable_count > m->vertex_count)
            fuzz_fail("unreachable count", "spia_interpolate");
    }
    free(unreachable);
    free(cage);
}

static void run_refine(const spia_mesh *m, const spia_options *o, int32_t levels) {
    spia_status st;
    int32_t nv = -7, nf = -7;
    int64_t nc = -7;
    /* At most a few hundred thousand faces: lower the level until it fits. */
    if (levels > 0 && m->face_count > 0)
        while (levels > 0 && (double)m->face_count * pow(4.0, levels) > 6e4) --levels;
    spia_result r = spia_refine_size(m, o, levels, &nv, &nf, &nc, &st);
    check_status("spia_refine_size", r, &st);
    if (r != SPIA_OK) return;
    if (nv < 0 || nf < 0 || nc < 0) fuzz_fail("negative counts", "spia_refine_size");
    /* Exactly the counts (at least one element, for malloc): AddressSanitizer
     * catches a write past them. */
    float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)(nv > 0 ? nv : 1));
    int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nf > 0 ? nf : 1));
    int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nc > 0 ? nc : 1));
    if (!pos || !sizes || !fv) abort();
    r = spia_refine(m, o, levels, pos, sizes, fv, &st);
    check_status("spia_refine", r, &st);
    /* The counts are in closed form: what they accept, the refinement makes,
     * unless it runs out of memory or the progress callback cancels it. */
    if (r != SPIA_OK && r != SPIA_ERROR_OUT_OF_MEMORY && r != SPIA_ERROR_CANCELLED)
        fuzz_fail("refused after its counts were given", "spia_refine");
    if (r == SPIA_OK) {
        int64_t c = 0;
        for (int32_t f = 0; f < nf; ++f) {
            if (sizes[f] < 3) fuzz_fail("refined face size", "spia_refine");
            c += sizes[f];
        }
        if (c != nc) fuzz_fail("refined corner count", "spia_refine");
        for (int64_t k = 0; k < nc; ++k)
            if (fv[k] < 0 || fv[k] >= nv) fuzz_fail("refined index out of range", "spia_refine");
        check_finite("spia_refine", pos, 3 * (size_t)nv);
    }
    free(pos);
    free(sizes);
    free(fv);
}

/* spia_subdivide (counts first, then exactly those), and spia_flat_positions
 * on the mesh and on what spia_subdivide made. */
static void run_subdivide(const spia_mesh *m, const spia_options *o, int32_t levels) {
    spia_status st;
    const size_t flat_size = sizeof(float) * 3 * ((size_t)m->vertex_count + 1);
    float *flat = (float *)malloc(flat_size);
    if (!flat) abort();
    fill(flat, flat_size);
    spia_result r = spia_flat_positions(m, o, flat, &st);
    check_status("spia_flat_positions", r, &st);
    if (r < 0) check_untouched("spia_flat_positions", flat, flat_size);
    else check_finite("spia_flat_positions", flat, 3 * (size_t)m->vertex_count);
    free(flat);
    if (levels > 0 && m->face_count > 0)
        while (levels > 1 && (double)m->face_count * pow(4.0, levels) > 6e4) --levels;
    int32_t nv = -7, nf = -7, ne = -7;
    r = spia_subdivide_size(m, o, levels, &nv, &nf, &ne, &st);
    check_status("spia_subdivide_size", r, &st);
    if (r != SPIA_OK) return;
    if (nv < 0 || nf < 0 || ne < 0) fuzz_fail("negative counts", "spia_subdivide_size");
    float *pos = (float *)malloc(sizeof(float) * 3 * (size_t)(nv > 0 ? nv : 1));
    int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * 4 * (size_t)(nf > 0 ? nf : 1));
    int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (size_t)(nf > 0 ? nf : 1));
    int32_t *edges = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)(ne > 0 ? ne : 1));
    float *ec = (float *)malloc(sizeof(float) * (size_t)(ne > 0 ? ne : 1));
    float *vc = (float *)malloc(sizeof(float) * (size_t)(nv > 0 ? nv : 1));
    float *out = (float *)malloc(sizeof(float) * 3 * (size_t)(nv > 0 ? nv : 1));
    if (!pos || !fv || !sizes || !edges || !ec || !vc || !out) abort();
    r = spia_subdivide(m, o, levels, pos, fv, edges, ec, vc, &st);
    check_status("spia_subdivide", r, &st);
    if (r != SPIA_OK && r != SPIA_ERROR_OUT_OF_MEMORY && r != SPIA_ERROR_CANCELLED)
        fuzz_fail("refused after its counts were given", "spia_subdivide");
    if (r == SPIA_OK) {
        for (int64_t k = 0; k < 4 * (int64_t)nf; ++k)
            if (fv[k] < 0 || fv[k] >= nv) fuzz_fail("subdivided index out of range", "spia_subdivide");
        for (int64_t k = 0; k < 2 * (int64_t)ne; ++k)
            if (edges[k] < 0 || edges[k] >= nv) fuzz_fail("subdivided edge out of range", "spia_subdivide");
        for (int32_t e = 0; e < ne; ++e)
            if (!(ec[e] >= 0.0f && ec[e] <= 1.0f)) fuzz_fail("subdivided crease out of [0, 1]", "spia_subdivide");
        for (int32_t v = 0; v < nv; ++v)
            if (!(vc[v] >= 0.0f && vc[v] <= 1.0f)) fuzz_fail("subdivided crease out of [0, 1]", "spia_subdivide");
        check_finite("spia_subdivide", pos, 3 * (size_t)nv);
        for (int32_t f = 0; f < nf; ++f) sizes[f] = 4;
        spia_mesh fine = {nv, pos, nf, sizes, fv, ne, edges, ec, vc};
        r = spia_flat_positions(&fine, o, out, &st);
        check_status("spia_flat_positions", r, &st);
        if (r == SPIA_OK) check_finite("spia_flat_positions", out, 3 * (size_t)nv);
    }
    free(pos), free(fv), free(sizes), free(edges), free(ec), free(vc), free(out);
}

static void run_surface(const spia_mesh *m, const spia_options *o, int32_t k) {
    int64_t count = spia_surface_sample_count(m, k);
    if (k > 1 && count > 20000) {
        k = 1;
        count = spia_surface_sample_count(m, k);
    }
    if (count > 20000) return;
    spia_status st;
    spia_stencils *s = (spia_stencils *)&st;
    spia_result r = spia_surface_stencils_create(m, o, k, &s, &st);
    check_status("spia_surface_stencils_create", r, &st);
    if (r != SPIA_OK) {
        if (s) fuzz_fail("table returned by a failed call", "spia_surface_stencils_create");
        return;
    }
    if (count < 0) fuzz_fail("sample count negative for a valid mesh", "spia_surface_sample_count");
    if (count > INT32_MAX) fuzz_fail("sample count", "spia_surface_sample_count");
    check_table("spia_surface_stencils_create", s, (int32_t)count, m->vertex_count);
    spia_stencils_free(s);
}

static void run_scan(const spia_mesh *m, const spia_options *o, const settings *set, reader *rd) {
    spia_status st;
    spia_scan *scan = (spia_scan *)&st;
    spia_result r = spia_scan_create(m, &scan, &st);
    check_status("spia_scan_create", r, &st);
    if (r != SPIA_OK) {
        if (scan) fuzz_fail("scan returned by a failed call", "spia_scan_create");
        return;
    }
    const double diagonal = spia_scan_diagonal(scan);
    if (!(diagonal >= 0.0) || !isfinite(diagonal)) fuzz_fail("scan diagonal", "spia_scan_diagonal");
    float points[3 * FUZZ_MAX_QUERIES];
    int64_t count = 0;
    while (count < FUZZ_MAX_QUERIES && rd->at + 6 <= rd->n) {
        for (int a = 0; a < 3; ++a) points[3 * count + a] = coordinate_of((int16_t)u16(rd));
        ++count;
    }
    if (count == 0) { /* the mesh's own vertices, a few */
        for (; count < m->vertex_count && count < 8; ++count)
            for (int a = 0; a < 3; ++a) points[3 * count + a] = m->positions[3 * count + a] * 1.5f;
    }
    float closest[3 * FUZZ_MAX_QUERIES], normals[3 * FUZZ_MAX_QUERIES], distances[FUZZ_MAX_QUERIES];
    int32_t faces[FUZZ_MAX_QUERIES];
    uint8_t boundary[FUZZ_MAX_QUERIES];
    r = spia_scan_closest_points(scan, count, points, closest, normals, distances, faces, boundary, &st);
    check_status("spia_scan_closest_points", r, &st);
    if (r == SPIA_OK) {
        for (int64_t i = 0; i < count; ++i) {
            if (!(distances[i] >= 0.0f) || !isfinite(distances[i])) fuzz_fail("distance", "spia_scan_closest_points");
            if (faces[i] < 0 || faces[i] >= m->face_count) fuzz_fail("face out of range", "spia_scan_closest_points");
            if (boundary[i] > 1) fuzz_fail("boundary flag", "spia_scan_closest_points");
        }
        check_finite("spia_scan_closest_points", closest, 3 * (size_t)count);
        check_finite("spia_scan_closest_points", normals, 3 * (size_t)count);
    }
    /* Only some of the outputs. */
    r = spia_scan_closest_points(scan, count, points, NULL, NULL, distances, NULL, NULL, &st);
    check_status("spia_scan_closest_points", r, &st);

    if (set->ops & OP_FIT) {
        const size_t size = sizeof(float) * 3 * ((size_t)m->vertex_count + 1);
        float *cage = (float *)malloc(size);
        float *vd = (float *)malloc(sizeof(float) * ((size_t)m->vertex_count + 1));
        if (!cage || !vd) abort();
        fill(cage, size);
        spia_fit_report rep;
        memset(&rep, 0, sizeof rep);
        double history[4];
        rep.history = history;
        rep.history_capacity = 4;
        rep.vertex_distances = vd;
        r = spia_fit(m, scan, o, &set->fit, cage, &rep, &st);
        check_status("spia_fit", r, &st);
        if (r < 0) check_untouched("spia_fit", cage, size);
        else check_finite("spia_fit", cage, 3 * (size_t)m->vertex_count);
        if (rep.history_count < 0 || rep.history_count > 4) fuzz_fail("history count", "spia_fit");
        free(cage);
        free(vd);
    }
    spia_scan_free(scan);
}

/* NULL where pointers are expected: refused, never dereferenced. */
static void run_nulls(const spia_mesh *m) {
    spia_status st;
    spia_stencils *s = NULL;
    spia_scan *scan = NULL;
    float cage[3];
    int32_t a, b;
    int64_t c;
    spia_result r;
    if ((r = spia_mesh_validate(NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL mesh", "validate");
    if ((r = spia_limit_stencils_create(m, NULL, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL out", "stencils");
    if ((r = spia_limit_stencils_create(NULL, NULL, &s, NULL)) != SPIA_ERROR_INVALID_ARGUMENT || s)
        fuzz_fail("NULL mesh", "stencils");
    if ((r = spia_interpolate(m, NULL, NULL, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL cage", "interpolate");
    if ((r = spia_solve(NULL, cage, NULL, cage, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL table", "solve");
    if ((r = spia_refine_size(m, NULL, 1, NULL, &b, &c, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL count", "refine_size");
    if ((r = spia_refine(m, NULL, 1, NULL, &a, &b, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL buffer", "refine");
    if ((r = spia_surface_stencils_create(m, NULL, 2, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL out", "surface");
    if ((r = spia_scan_create(m, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL out", "scan_create");
    if ((r = spia_scan_create(NULL, &scan, &st)) != SPIA_ERROR_INVALID_ARGUMENT || scan) fuzz_fail("NULL mesh", "scan_create");
    if ((r = spia_scan_closest_points(NULL, 1, cage, NULL, NULL, NULL, NULL, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT)
        fuzz_fail("NULL scan", "closest_points");
    if ((r = spia_fit(m, NULL, NULL, NULL, cage, NULL, &st)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL scan", "fit");
    if ((r = spia_stencils_copy_csr(NULL, NULL, NULL, NULL)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL table", "copy_csr");
    if ((r = spia_stencils_apply(NULL, NULL, NULL)) != SPIA_ERROR_INVALID_ARGUMENT) fuzz_fail("NULL table", "apply");
    spia_stencils_free(NULL);
    spia_scan_free(NULL);
    (void)spia_stencils_row_count(NULL);
    (void)spia_stencils_weight_count(NULL);
    (void)spia_scan_diagonal(NULL);
    (void)spia_surface_sample_count(NULL, 2);
    (void)spia_result_name((spia_result)12345);
    if (spia_version() != SPIA_VERSION_MAJOR * 10000 + SPIA_VERSION_MINOR * 100 + SPIA_VERSION_PATCH)
        fuzz_fail("version", "spia_version");
    spia_options d = spia_options_default(), z;
    memset(&z, 0, sizeof z);
    if (memcmp(&d, &z, sizeof d) != 0) fuzz_fail("defaults are not zeros", "spia_options_default");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    reader rd = {data, size, 0};
    settings set;
    decode_settings(&rd, &set);
    uint16_t x = u16(&rd);
    const int32_t nv = x == 0xFFFF ? -1 : (int32_t)(x % (FUZZ_MAX_VERTICES + 1));
    x = u16(&rd);
    const int32_t nf = x == 0xFFFF ? -1 : (int32_t)(x % (FUZZ_MAX_FACES + 1));
    const int32_t ne = set.has_edges ? (int32_t)u8(&rd) : 0;
    const size_t av = nv > 0 ? (size_t)nv : 0, af = nf > 0 ? (size_t)nf : 0;

    int32_t *sizes = (int32_t *)malloc(sizeof(int32_t) * (af + 1));
    if (!sizes) abort();
    int64_t corners = 0;
    for (size_t f = 0; f < af; ++f) corners += sizes[f] = u8(&rd) % 9;
    int32_t *fv = (int32_t *)malloc(sizeof(int32_t) * ((size_t)corners + 1));
    float *pos = (float *)malloc(sizeof(float) * 3 * (av + 1));
    int32_t *edges = (int32_t *)malloc(sizeof(int32_t) * 2 * ((size_t)ne + 1));
    float *edge_creases = (float *)malloc(sizeof(float) * ((size_t)ne + 1));
    float *vertex_creases = (float *)malloc(sizeof(float) * (av + 1));
    float *shapes = (float *)malloc(sizeof(float) * (af + 1));
    if (!fv || !pos || !edges || !edge_creases || !vertex_creases || !shapes) abort();
    for (int64_t k = 0; k < corners; ++k) fv[k] = index_of(u16(&rd), nv);
    for (size_t i = 0; i < 3 * av; ++i) pos[i] = coordinate_of((int16_t)u16(&rd));
    for (int32_t e = 0; e < 2 * ne; ++e) edges[e] = index_of(u16(&rd), nv);
    if (set.has_edge_creases)
        for (int32_t e = 0; e < ne; ++e) edge_creases[e] = crease_of(u8(&rd));
    if (set.has_vertex_creases)
        for (size_t v = 0; v < av; ++v) vertex_creases[v] = crease_of(u8(&rd));
    if (set.has_face_shapes)
        for (size_t f = 0; f < af; ++f) {
            uint8_t b = u8(&rd);
            shapes[f] = b == 255 ? NAN : (float)b / 254.0f;
        }

    spia_mesh m;
    m.vertex_count = nv;
    m.positions = pos;
    m.face_count = nf;
    m.face_sizes = sizes;
    m.face_vertices = fv;
    m.edge_count = ne;
    m.edges = set.has_edges ? edges : NULL;
    m.edge_creases = set.has_edge_creases ? edge_creases : NULL;
    m.vertex_creases = set.has_vertex_creases ? vertex_creases : NULL;

    cancel_state cancel = {0, set.cancel_at};
    spia_options o = set.o;
    o.progress = progress;
    o.progress_user_data = &cancel;
    if (set.has_face_shapes) o.face_shape_parameters = shapes;

    spia_status st;
    spia_result validated = spia_mesh_validate(&m, &st);
    check_status("spia_mesh_validate", validated, &st);
    if (validated > 0) fuzz_fail("validation returned a warning", "spia_mesh_validate");
    if (getenv("SPIA_FUZZ_VERBOSE"))
        fprintf(stderr, "%d vertices, %d faces, scheme %d, ops 0x%x: %s\n", (int)nv, (int)nf, (int)o.scheme,
                (unsigned)set.ops, st.message);

    if (set.ops & OP_NULLS) run_nulls(&m);
    if (set.ops & OP_STENCILS) run_stencils(&m, &o, pos);
    cancel.calls = 0;
    if (set.ops & OP_INTERPOLATE) run_interpolate(&m, &o, validated);
    cancel.calls = 0;
    if (set.ops & OP_REFINE) run_refine(&m, &o, set.levels);
    if (set.subdivide) run_subdivide(&m, &o, set.levels);
    if (set.ops & OP_SURFACE) run_surface(&m, &o, set.samples);
    cancel.calls = 0;
    if (set.ops & (OP_SCAN | OP_FIT)) run_scan(&m, &o, &set, &rd);

    free(sizes);
    free(fv);
    free(pos);
    free(edges);
    free(edge_creases);
    free(vertex_creases);
    free(shapes);
    return 0;
}
