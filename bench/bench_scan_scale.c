// SPDX-License-Identifier: GPL-3.0-or-later
/* spia_scan_create and the fit's closest-point queries on large scans, on
 * their own (the library's scan.c and bvh.c compiled in: the queries with a
 * radius hint are private).
 *
 *   spia_bench_scan SCAN.bin QUERIES.bin [--reps R] [--threads T]
 *
 * SCAN.bin: int64 vertex count, face count, corner count; float32
 * positions; int32 face sizes; int32 corner vertices.  QUERIES.bin: int64
 * count; float32 points (bench/bench_fit_scale.py --export writes both: a
 * scan and the level-2 subdivision of a cage on it, about the fit's
 * samples).  Prints, per repetition, the seconds of spia_scan_create, of
 * the queries without a hint (the fit's first round), and of the queries
 * with the hints a later round passes (the distance found plus how far
 * each point moved, here by a jitter of 1e-5 of the diagonal), and a
 * checksum of the results (the same whatever the thread count).  Built
 * twice by `make bench-scan`, against this tree and a git revision, to
 * compare them side by side. */
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* scan.c's phase timer (not exported by the library). */
void spia__scan_timings(const spia_scan *scan, double seconds[4]);

/* The peak resident size so far, in MB (Linux; -1 elsewhere). */
static double peak_mb(void) {
    FILE *f = fopen("/proc/self/status", "r");
    if (!f) return -1.0;
    char line[256];
    double kb = -1.0;
    while (fgets(line, sizeof line, f))
        if (!strncmp(line, "VmHWM:", 6)) kb = atof(line + 6);
    fclose(f);
    return kb / 1024.0;
}

static void *read_all(const char *path, size_t *size) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    const long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    void *p = malloc((size_t)n);
    if (!p || fread(p, 1, (size_t)n, f) != (size_t)n) {
        fclose(f);
        free(p);
        return NULL;
    }
    fclose(f);
    *size = (size_t)n;
    return p;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s SCAN.bin QUERIES.bin [--reps R] [--threads T]\n", argv[0]);
        return 2;
    }
    int reps = 3, threads = spia__processor_count();
    for (int i = 3; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--reps")) reps = atoi(argv[i + 1]);
        if (!strcmp(argv[i], "--threads")) threads = atoi(argv[i + 1]);
    }
    size_t size = 0, qsize = 0;
    char *scan_file = read_all(argv[1], &size), *query_file = read_all(argv[2], &qsize);
    if (!scan_file || !query_file) {
        fprintf(stderr, "cannot read %s or %s\n", argv[1], argv[2]);
        return 2;
    }
    const int64_t *head = (const int64_t *)(void *)scan_file;
    spia_mesh mesh;
    memset(&mesh, 0, sizeof mesh);
    mesh.vertex_count = (int32_t)head[0];
    mesh.face_count = (int32_t)head[1];
    mesh.positions = (const float *)(void *)(scan_file + 24);
    mesh.face_sizes = (const int32_t *)(void *)(scan_file + 24 + 12 * head[0]);
    mesh.face_vertices = (const int32_t *)(void *)(scan_file + 24 + 12 * head[0] + 4 * head[1]);
    const int64_t q = *(const int64_t *)(void *)query_file;
    const float *qf = (const float *)(void *)(query_file + 8);
    double *points = malloc(sizeof(double) * 3 * (size_t)q), *moved = malloc(sizeof(double) * 3 * (size_t)q);
    float *closest = malloc(sizeof(float) * 3 * (size_t)q), *normals = malloc(sizeof(float) * 3 * (size_t)q);
    float *dist = malloc(sizeof(float) * (size_t)q), *radius = malloc(sizeof(float) * (size_t)q);
    uint8_t *edge = malloc((size_t)q);
    for (int64_t i = 0; i < 3 * q; ++i) points[i] = qf[i];
    printf("scan: %d vertices, %d faces; %lld queries; %d threads\n", mesh.vertex_count, mesh.face_count,
           (long long)q, threads);
    const double base_mb = peak_mb();
    for (int rep = 0; rep < reps; ++rep) {
        spia_scan *scan = NULL;
        spia_status st;
        double t0 = spia__now();
        if (spia_scan_create(&mesh, &scan, &st) != SPIA_OK) {
            fprintf(stderr, "spia_scan_create: %s\n", st.message);
            return 1;
        }
        const double create = spia__now() - t0;
        double phase[4];
        spia__scan_timings(scan, phase);
        if (rep == 0)
            printf("peak resident size: %.0f MB before spia_scan_create, %.0f MB after it (the build's peak)\n",
                   base_mb, peak_mb());
        const double diag = spia_scan_diagonal(scan);
        t0 = spia__now();
        spia__scan_closest_points_double(scan, q, points, NULL, closest, normals, dist, NULL, edge, threads);
        const double cold = spia__now() - t0;
        /* A later round: each point moved by a small jitter, the hint its
         * last distance plus the move, as fit.c's evaluate makes it. */
        uint64_t seed = 12345;
        for (int64_t i = 0; i < q; ++i) {
            double m2 = 0.0;
            for (int c = 0; c < 3; ++c) {
                seed = seed * 6364136223846793005ull + 1442695040888963407ull;
                const double u = ((double)(seed >> 11) / 9007199254740992.0 - 0.5) * 2e-5 * diag;
                moved[3 * i + c] = points[3 * i + c] + u;
                m2 += u * u;
            }
            radius[i] = (float)((dist[i] + sqrt(m2)) * (1.0 + 1e-5) + 1e-7 * diag);
        }
        t0 = spia__now();
        spia__scan_closest_points_double(scan, q, moved, radius, closest, normals, dist, NULL, edge, threads);
        const double warm = spia__now() - t0;
        double sum = 0.0;
        long long rim = 0;
        for (int64_t i = 0; i < q; ++i) sum += dist[i] + 1e-3 * normals[3 * i] + closest[3 * i + 1], rim += edge[i];
        t0 = spia__now();
        spia_scan_free(scan);
        const double freed = spia__now() - t0;
        printf("rep %d: create %.3f s (checks %.3f, fans %.3f, hierarchy and normals %.3f, boundary %.3f), cold queries %.3f s, warm queries %.3f s, free %.3f s; checksum %.9g, "
               "%lld on the rim\n",
               rep, create, phase[0], phase[1], phase[2], phase[3], cold, warm, freed, sum, rim);
        fflush(stdout);
    }
    return 0;
}
