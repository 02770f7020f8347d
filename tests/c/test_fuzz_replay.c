// SPDX-License-Identifier: GPL-3.0-or-later
/* The fuzz target (tests/fuzz/fuzz_spia.c) without libFuzzer:
 *
 *   test_fuzz_replay FILE_OR_DIR...   runs the target on every file (every
 *                                     file in a directory): the inputs the
 *                                     fuzzer once crashed on stay fixed;
 *   test_fuzz_replay --seeds DIR      writes the seed corpus: meshes of
 *                                     tests/data (their first faces) and
 *                                     generated shapes, in the target's
 *                                     input format, under several settings.
 *
 * With no argument it replays tests/fuzz/regressions and the seeds it
 * generates in memory.  The target aborts on any broken promise; a replay
 * that returns has passed. */
#include "../fuzz/fuzz_spia.c"
#include "support.h"

#include <dirent.h>
#include <sys/stat.h>

#ifndef SPIA_FUZZ_REGRESSIONS_DIR
#define SPIA_FUZZ_REGRESSIONS_DIR "tests/fuzz/regressions"
#endif

typedef struct bytes {
    uint8_t *p;
    size_t n, cap;
} bytes;

static void put8(bytes *b, uint8_t x) {
    if (b->n == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 4096;
        b->p = (uint8_t *)tgrow(b->p, b->cap, 1);
    }
    b->p[b->n++] = x;
}
static void put16(bytes *b, uint16_t x) {
    put8(b, (uint8_t)(x & 0xFF));
    put8(b, (uint8_t)(x >> 8));
}

/* A mesh's first `max_faces` faces (those of 3 to 8 corners), renumbered,
 * scaled into the target's coordinate range; `settings` are the 16 leading
 * bytes. */
static void encode(bytes *b, const tmesh *m, int max_faces, const uint8_t settings[FUZZ_SETTINGS]) {
    b->n = 0;
    for (int i = 0; i < FUZZ_SETTINGS; ++i) put8(b, settings[i]);
    int32_t *map = (int32_t *)tgrow(NULL, (size_t)m->nv, sizeof(int32_t));
    for (int32_t v = 0; v < m->nv; ++v) map[v] = -1;
    int32_t nv = 0, nf = 0;
    int64_t c = 0;
    for (int32_t f = 0; f < m->nf && nf < max_faces; c += m->sizes[f], ++f) {
        if (m->sizes[f] < 3 || m->sizes[f] > 8) continue;
        int fits = 1;
        for (int32_t k = 0; k < m->sizes[f]; ++k)
            if (map[m->fv[c + k]] < 0 && nv + k >= FUZZ_MAX_VERTICES - 8) fits = 0;
        if (!fits) break;
        for (int32_t k = 0; k < m->sizes[f]; ++k)
            if (map[m->fv[c + k]] < 0) map[m->fv[c + k]] = nv++;
        ++nf;
    }
    int32_t *order = (int32_t *)tgrow(NULL, (size_t)nv + 1, sizeof(int32_t));
    for (int32_t v = 0; v < m->nv; ++v)
        if (map[v] >= 0) order[map[v]] = v;
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    for (int32_t i = 0; i < nv; ++i)
        for (int a = 0; a < 3; ++a) {
            double x = m->pos[3 * order[i] + a];
            if (x < lo[a]) lo[a] = x;
            if (x > hi[a]) hi[a] = x;
        }
    double extent = 1e-30;
    for (int a = 0; a < 3; ++a)
        if (hi[a] - lo[a] > extent) extent = hi[a] - lo[a];
    put16(b, (uint16_t)nv);
    put16(b, (uint16_t)nf);
    const int edges = (settings[2] >> 4) & 1;
    if (edges) put8(b, 0);
    int32_t written = 0;
    c = 0;
    for (int32_t f = 0; f < m->nf && written < nf; c += m->sizes[f], ++f)
        if (m->sizes[f] >= 3 && m->sizes[f] <= 8) {
            put8(b, (uint8_t)m->sizes[f]);
            ++written;
        }
    written = 0;
    c = 0;
    for (int32_t f = 0; f < m->nf && written < nf; c += m->sizes[f], ++f)
        if (m->sizes[f] >= 3 && m->sizes[f] <= 8) {
            for (int32_t k = 0; k < m->sizes[f]; ++k) put16(b, (uint16_t)map[m->fv[c + k]]);
            ++written;
        }
    for (int32_t i = 0; i < nv; ++i)
        for (int a = 0; a < 3; ++a) {
            double x = (m->pos[3 * order[i] + a] - 0.5 * (lo[a] + hi[a])) / extent * 2.0 * 16.0 * 1024.0;
            put16(b, (uint16_t)(int16_t)lrint(x));
        }
    if ((settings[2] >> 6) & 1)
        for (int32_t i = 0; i < nv; ++i) put8(b, (uint8_t)(i % 7 == 0 ? 125 : 0));
    if ((settings[2] >> 7) & 1)
        for (int32_t f = 0; f < nf; ++f) put8(b, (uint8_t)(64 + f % 128));
    free(map);
    free(order);
}

typedef int (*seed_fn)(const char *name, const uint8_t *data, size_t size, void *user);

/* Every seed, to `fn`. */
static int for_each_seed(seed_fn fn, void *user) {
    /* ops, scheme, flags, method, quality, iterations, tolerance|weight,
     * shape|threads|osd, levels, samples, cancel, fit mode|samples|rounds,
     * cutoff|smoothing, point weight|round tolerance|solver, fit flags,
     * subdivision (the Catmull-Clark seed: the scan's pull, subdivide) */
    static const uint8_t catmark[FUZZ_SETTINGS] = {0x7F, 0, 0, 0, 1, 20, 1, 1 << 3, 1, 3, 0, (2 << 2) | (1 << 5), 1 | (1 << 3), 7 | (1 << 3) | (1 << 6), 8, 1};
    static const uint8_t catmark_vertices[FUZZ_SETTINGS] = {0x67, 0, 0x43, 3, 2, 10, 1, 2 << 5, 0, 2, 0, 1 | (1 << 5), 1, 0, 0, 0};
    static const uint8_t loop[FUZZ_SETTINGS] = {0xEF, 1, 0x08, 2, 0, 20, 1, 1 << 3, 3, 0, 0, 1 | (1 << 5), 1, 0, 0, 0};
    static const uint8_t loop_hoppe[FUZZ_SETTINGS] = {0x0F, 1, 0x04, 5, 0, 20, 1, 0, 2, 0, 0, 0, 0, 0, 0, 0};
    static const uint8_t doo_sabin[FUZZ_SETTINGS] = {0x0F, 2, 0x80, 1, 0, 20, 1, 1, 2, 0, 0, 0, 0, 0, 0, 0};
    static const char *files[] = {"mushroom.obj", "catmark_nonman_edges.obj", "double-torus.obj", "teapot.obj",
                                  "catmark_car.obj", "bunny.obj", "elephant-with-holes.obj",
                                  "bun_zipper_quadriflow_cage.obj"};
    bytes b = {NULL, 0, 0};
    char name[256];
    int failures = 0;
    for (size_t i = 0; i < sizeof files / sizeof files[0]; ++i) {
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", SPIA_TEST_DATA_DIR, files[i]);
        tmesh m;
        memset(&m, 0, sizeof m);
        if (!read_obj(path, &m)) {
            fprintf(stderr, "cannot read %s\n", path);
            ++failures;
            continue;
        }
        int triangles = 1;
        for (int32_t f = 0; f < m.nf; ++f) triangles &= m.sizes[f] == 3;
        snprintf(name, sizeof name, "%s-catmark", files[i]);
        encode(&b, &m, 300, catmark);
        failures += fn(name, b.p, b.n, user);
        snprintf(name, sizeof name, "%s-vertices", files[i]);
        encode(&b, &m, 120, catmark_vertices);
        failures += fn(name, b.p, b.n, user);
        if (triangles) {
            snprintf(name, sizeof name, "%s-loop", files[i]);
            encode(&b, &m, 300, loop);
            failures += fn(name, b.p, b.n, user);
            snprintf(name, sizeof name, "%s-hoppe", files[i]);
            encode(&b, &m, 300, loop_hoppe);
            failures += fn(name, b.p, b.n, user);
        }
        tmesh_free(&m);
    }
    tmesh shapes[3] = {make_torus(8, 6, 0), make_torus(8, 6, 1), make_grid(5, 4)};
    const char *shape_names[3] = {"torus", "torus-triangles", "grid"};
    for (int i = 0; i < 3; ++i) {
        snprintf(name, sizeof name, "%s-catmark", shape_names[i]);
        encode(&b, &shapes[i], 1000, catmark);
        failures += fn(name, b.p, b.n, user);
        snprintf(name, sizeof name, "%s-doo-sabin", shape_names[i]);
        encode(&b, &shapes[i], 1000, doo_sabin);
        failures += fn(name, b.p, b.n, user);
        if (i == 1) {
            snprintf(name, sizeof name, "%s-loop", shape_names[i]);
            encode(&b, &shapes[i], 1000, loop);
            failures += fn(name, b.p, b.n, user);
        }
        tmesh_free(&shapes[i]);
    }
    free(b.p);
    return failures;
}

static int write_seed(const char *name, const uint8_t *data, size_t size, void *user) {
    char path[2048];
    snprintf(path, sizeof path, "%s/%s", (const char *)user, name);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, size, f) != size) {
        fprintf(stderr, "cannot write %s\n", path);
        if (f) fclose(f);
        return 1;
    }
    fclose(f);
    return 0;
}

static int run_seed(const char *name, const uint8_t *data, size_t size, void *user) {
    (void)name;
    ++*(int *)user;
    LLVMFuzzerTestOneInput(data, size);
    return 0;
}

static int run_file(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    bytes b = {NULL, 0, 0};
    int ch;
    while ((ch = fgetc(f)) != EOF) put8(&b, (uint8_t)ch);
    fclose(f);
    LLVMFuzzerTestOneInput(b.p ? b.p : (const uint8_t *)"", b.n);
    free(b.p);
    return 1;
}

/* Files in a directory, or the file itself; returns how many were run. */
static int run_path(const char *path) {
    struct stat sb;
    if (stat(path, &sb) != 0) return -1;
    if (!S_ISDIR(sb.st_mode)) return run_file(path);
    DIR *d = opendir(path);
    if (!d) return -1;
    int count = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.') continue;
        char full[2048];
        snprintf(full, sizeof full, "%s/%s", path, e->d_name);
        count += run_file(full);
    }
    closedir(d);
    return count;
}

int main(int argc, char **argv) {
    if (argc == 3 && strcmp(argv[1], "--seeds") == 0) return for_each_seed(write_seed, argv[2]) ? 1 : 0;
    if (argc > 1) {
        int count = 0;
        for (int i = 1; i < argc; ++i) {
            int n = run_path(argv[i]);
            CHECK(n >= 0, "cannot read %s", argv[i]);
            if (n > 0) count += n;
        }
        printf("%d inputs replayed\n", count);
        TEST_MAIN_END();
    }
    int regressions = run_path(SPIA_FUZZ_REGRESSIONS_DIR);
    CHECK(regressions > 0, "no regression inputs in %s", SPIA_FUZZ_REGRESSIONS_DIR);
    int seeds = 0;
    CHECK(for_each_seed(run_seed, &seeds) == 0, "seeds could not be made");
    CHECK(seeds >= 20, "only %d seeds", seeds);
    printf("%d regression inputs and %d seeds replayed\n", regressions, seeds);
    TEST_MAIN_END();
}
