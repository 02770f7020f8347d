// SPDX-License-Identifier: GPL-3.0-or-later
/* spia_flat_positions: a quad mesh's vertices placed so that its flat
 * quads follow its limit surface: each quad's 3 x 3 grid of limit points
 * from stencils of its own, then spia__flat_solve (flat_solve.c). */
#include "fit.h"

#include <stdlib.h>

static spia_result flat_oom(spia_status *status) {
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the flat positions");
}

spia_result spia_flat_positions(const spia_mesh *mesh, const spia_options *options, float *out, spia_status *status) {
    if (!out) return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "out must not be NULL");
    spia_options opt;
    spia_result r = spia__resolve_options(options, &opt, status);
    if (r != SPIA_OK) return r;
    if (opt.scheme != SPIA_SCHEME_CATMULL_CLARK)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "flat positions are for Catmull-Clark cages");
    if ((r = spia_mesh_validate(mesh, status)) != SPIA_OK) return r;
    for (int32_t f = 0; f < mesh->face_count; ++f)
        if (mesh->face_sizes[f] != 4)
            return spia__fail(status, SPIA_ERROR_FACE_SIZE, f,
                              "face %d has %d corners: flat positions are for quad meshes (a subdivided cage)",
                              (int)f, (int)mesh->face_sizes[f]);
    if ((r = spia__fit_samples_memory(mesh, &opt, 3, 1, "the flat positions", status)) != SPIA_OK) return r;
    spia_adjacency adj;
    if ((r = spia__adjacency_build(mesh, &adj, status)) != SPIA_OK) return r;
    fit_clock clock = {opt.progress, opt.progress_user_data, spia__now(), 0.0, 0, 0};
    sample_blocks B;
    r = spia__fit_blocks_build(mesh, &adj, &opt, 3, 1, &B, &clock, status);
    spia__adjacency_free(&adj);
    if (r != SPIA_OK) return r;
    const int64_t points = 9 * (int64_t)mesh->face_count, N3 = 3 * (int64_t)mesh->vertex_count;
    float *X = malloc(sizeof(float) * 3 * (size_t)(points > 0 ? points : 1));
    double *V = malloc(sizeof(double) * (size_t)(N3 > 0 ? N3 : 1));
    if (!X || !V) {
        free(X), free(V), spia__fit_blocks_free(&B);
        return flat_oom(status);
    }
    for (int64_t i = 0; i < N3; ++i) V[i] = mesh->positions[i];
    spia__fit_blocks_apply_float(&B, V, X);
    free(V);
    spia__fit_blocks_free(&B);
    r = clock.cancelled ? spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the flat positions")
                        : spia__flat_solve(mesh, X, 3, out, &clock, status);
    free(X);
    if (r == SPIA_OK) spia__ok(status);
    return r;
}
