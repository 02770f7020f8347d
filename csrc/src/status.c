// SPDX-License-Identifier: GPL-3.0-or-later
/* Result codes, messages and options. */
#define _POSIX_C_SOURCE 200809L
#include "internal.h"
#include "threads.h"

#include <math.h>
#include <string.h>
#include <time.h>

const char *spia_result_name(spia_result code) {
    switch (code) {
    case SPIA_OK: return "SPIA_OK";
    case SPIA_MAX_ITERATIONS: return "SPIA_MAX_ITERATIONS";
    case SPIA_STAGNATED: return "SPIA_STAGNATED";
    case SPIA_ERROR_INVALID_ARGUMENT: return "SPIA_ERROR_INVALID_ARGUMENT";
    case SPIA_ERROR_EMPTY_MESH: return "SPIA_ERROR_EMPTY_MESH";
    case SPIA_ERROR_FACE_SIZE: return "SPIA_ERROR_FACE_SIZE";
    case SPIA_ERROR_INDEX_RANGE: return "SPIA_ERROR_INDEX_RANGE";
    case SPIA_ERROR_NONFINITE: return "SPIA_ERROR_NONFINITE";
    case SPIA_ERROR_DEGENERATE_FACE: return "SPIA_ERROR_DEGENERATE_FACE";
    case SPIA_ERROR_TOPOLOGY: return "SPIA_ERROR_TOPOLOGY";
    case SPIA_ERROR_OUT_OF_MEMORY: return "SPIA_ERROR_OUT_OF_MEMORY";
    case SPIA_ERROR_CANCELLED: return "SPIA_ERROR_CANCELLED";
    case SPIA_ERROR_DIVERGED: return "SPIA_ERROR_DIVERGED";
    case SPIA_ERROR_INTERNAL: return "SPIA_ERROR_INTERNAL";
    }
    return "SPIA_UNKNOWN_RESULT";
}

int spia_version(void) {
    return SPIA_VERSION_MAJOR * 10000 + SPIA_VERSION_MINOR * 100 + SPIA_VERSION_PATCH;
}

spia_options spia_options_default(void) {
    spia_options o;
    memset(&o, 0, sizeof o);
    return o;
}

spia_result spia__resolve_options(const spia_options *in, spia_options *out, spia_status *status) {
    spia_options o = in ? *in : spia_options_default();
    if ((int)o.scheme < SPIA_SCHEME_CATMULL_CLARK || (int)o.scheme > SPIA_SCHEME_DOO_SABIN)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown subdivision scheme %d", (int)o.scheme);
    if ((int)o.boundary_smooth != SPIA_BOUNDARY_SMOOTH_ALL &&
        (int)o.boundary_smooth != SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown boundary_smooth value %d",
                          (int)o.boundary_smooth);
    if ((int)o.method < SPIA_METHOD_AUTO || (int)o.method > SPIA_METHOD_LEAST_SQUARES)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown solver method %d", (int)o.method);
    if ((int)o.boundary_rule != SPIA_BOUNDARY_RULE_SMOOTH && (int)o.boundary_rule != SPIA_BOUNDARY_RULE_HOPPE)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown boundary_rule value %d", (int)o.boundary_rule);
    if (o.solve_flags & ~(SPIA_SOLVE_FIRST_STEP | SPIA_SOLVE_MULTICOLOUR | SPIA_SOLVE_DOUBLE_SWEEPS | SPIA_SOLVE_NO_AVX))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "unknown solve_flags 0x%x", (unsigned)o.solve_flags);
    if (o.shape_parameter == 0.0) o.shape_parameter = 0.5;
    if (o.quality == 0) o.quality = 3;
    if (o.quality < 1 || o.quality > 10)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "quality must be 1 to 10, got %d", o.quality);
    if (o.tolerance == 0.0) o.tolerance = 1e-6;
    if (!(o.tolerance > 0.0) || !isfinite(o.tolerance))
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "tolerance must be a positive number");
    if (o.max_iterations == 0) o.max_iterations = 1000;
    if (o.max_iterations < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "max_iterations must be positive, got %d",
                          o.max_iterations);
    if (o.threads < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "threads must be 0 (all) or positive, got %d",
                          (int)o.threads);
    if (o.threads == 0) o.threads = spia__processor_count();
    if (o.opensubdiv_version < 0)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "opensubdiv_version must be 0 or major * 10000 + minor * 100 + patch, got %d",
                          (int)o.opensubdiv_version);
    *out = o;
    spia__ok(status);
    return SPIA_OK;
}
