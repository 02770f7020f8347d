# SPDX-License-Identifier: GPL-3.0-or-later
"""The ctypes mirror of the library's header (csrc/include/subdiv_pia.h):
its structures and the argument and result types of every function the
binding calls (:func:`_declare`).  A structure lists the header's fields in
the header's order: a field added there is added here in the same place."""

import ctypes

_i32p = ctypes.POINTER(ctypes.c_int32)
_i64p = ctypes.POINTER(ctypes.c_int64)
_f32p = ctypes.POINTER(ctypes.c_float)
_f64p = ctypes.POINTER(ctypes.c_double)

_PROGRESS = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int32, ctypes.c_double)


class _Status(ctypes.Structure):
    _fields_ = [("code", ctypes.c_int), ("index", ctypes.c_int64), ("message", ctypes.c_char * 256)]


class _Mesh(ctypes.Structure):
    _fields_ = [
        ("vertex_count", ctypes.c_int32), ("positions", _f32p),
        ("face_count", ctypes.c_int32), ("face_sizes", _i32p), ("face_vertices", _i32p),
        ("edge_count", ctypes.c_int32), ("edges", _i32p), ("edge_creases", _f32p),
        ("vertex_creases", _f32p),
    ]


class _Options(ctypes.Structure):
    _fields_ = [
        ("scheme", ctypes.c_int), ("boundary_smooth", ctypes.c_int), ("ignore_creases", ctypes.c_int32),
        ("quality", ctypes.c_int32), ("method", ctypes.c_int), ("tolerance", ctypes.c_double),
        ("max_iterations", ctypes.c_int32), ("progress", _PROGRESS), ("progress_user_data", ctypes.c_void_p),
        ("boundary_rule", ctypes.c_int), ("weight", ctypes.c_double), ("staged", ctypes.c_int32),
        ("shape_parameter", ctypes.c_double), ("face_shape_parameters", _f32p), ("threads", ctypes.c_int32),
        ("opensubdiv_version", ctypes.c_int32), ("initial_cage", _f32p), ("solve_flags", ctypes.c_int32),
        ("memory_budget", ctypes.c_int64),
    ]


class _Report(ctypes.Structure):
    _fields_ = [
        ("result", ctypes.c_int), ("method", ctypes.c_int), ("iterations", ctypes.c_int32),
        ("diagonal", ctypes.c_double), ("max_error", ctypes.c_double), ("mean_error", ctypes.c_double),
        ("max_error_relative", ctypes.c_double), ("mean_error_relative", ctypes.c_double),
        ("initial_max_error_relative", ctypes.c_double),
        ("unreachable_count", ctypes.c_int32), ("reachable_max_error_relative", ctypes.c_double),
        ("weight", ctypes.c_double), ("stage_iterations", ctypes.c_int32 * 2),
        ("stencil_seconds", ctypes.c_double), ("solve_seconds", ctypes.c_double),
        ("history", _f64p), ("history_capacity", ctypes.c_int32), ("history_count", ctypes.c_int32),
        ("unreachable", ctypes.POINTER(ctypes.c_uint8)),
    ]


class _FitOptions(ctypes.Structure):
    _fields_ = [
        ("mode", ctypes.c_int), ("samples_per_edge", ctypes.c_int32), ("cutoff", ctypes.c_double),
        ("smoothing", ctypes.c_double), ("point_weight", ctypes.c_double), ("max_rounds", ctypes.c_int32),
        ("round_tolerance", ctypes.c_double), ("solver_iterations", ctypes.c_int32),
        ("robust_scale", ctypes.c_double), ("slide_weight", ctypes.c_double), ("flags", ctypes.c_uint32),
    ]


class _FitDistances(ctypes.Structure):
    _fields_ = [("mean", ctypes.c_double), ("p95", ctypes.c_double), ("max", ctypes.c_double),
                ("ignored", ctypes.c_int64)]


class _FitReport(ctypes.Structure):
    _fields_ = [
        ("result", ctypes.c_int), ("mode", ctypes.c_int), ("rounds", ctypes.c_int32),
        ("sample_count", ctypes.c_int64), ("diagonal", ctypes.c_double),
        ("before", _FitDistances), ("after", _FitDistances),
        ("iterations", ctypes.c_int32), ("max_error_relative", ctypes.c_double),
        ("stencil_seconds", ctypes.c_double), ("query_seconds", ctypes.c_double),
        ("solve_seconds", ctypes.c_double),
        ("vertex_distances", _f32p), ("history", _f64p), ("history_capacity", ctypes.c_int32),
        ("history_count", ctypes.c_int32),
        ("folded_before", ctypes.c_int64), ("folded_after", ctypes.c_int64),
        ("scan_point_count", ctypes.c_int64), ("scan_before", _FitDistances), ("scan_after", _FitDistances),
        ("scan_distances", _f32p), ("flat_positions", _f32p), ("flat_positions_written", ctypes.c_int32),
    ]


# spia_fit_flags
FIT_ALLOW_FOLDS, FIT_HARD_CUTOFF, FIT_NO_SCAN_DISTANCES, FIT_SCAN_PULL, FIT_FREE_RIMS = 1, 2, 4, 8, 16
FIT_NO_SCAN_BEFORE = 32


def _declare(lib):
    def fn(name, restype, *argtypes):
        f = getattr(lib, name)
        f.restype = restype
        f.argtypes = list(argtypes)

    P = ctypes.c_void_p
    fn("spia_version", ctypes.c_int)
    fn("spia_available_memory", ctypes.c_int64)
    fn("spia_result_name", ctypes.c_char_p, ctypes.c_int)
    fn("spia_mesh_validate", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Status))
    fn("spia_limit_stencils_create", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options),
       ctypes.POINTER(P), ctypes.POINTER(_Status))
    fn("spia_stencils_free", None, P)
    fn("spia_stencils_row_count", ctypes.c_int32, P)
    fn("spia_stencils_weight_count", ctypes.c_int64, P)
    fn("spia_stencils_copy_csr", ctypes.c_int, P, _i64p, _i32p, _f64p)
    fn("spia_solve", ctypes.c_int, P, _f32p, ctypes.POINTER(_Options), _f32p, ctypes.POINTER(_Report),
       ctypes.POINTER(_Status))
    fn("spia_refine_size", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), ctypes.c_int32,
       _i32p, _i32p, _i64p, ctypes.POINTER(_Status))
    fn("spia_refine", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), ctypes.c_int32,
       _f32p, _i32p, _i32p, ctypes.POINTER(_Status))
    fn("spia_stencils_apply", ctypes.c_int, P, _f64p, _f64p)
    fn("spia_subdivide_size", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), ctypes.c_int32,
       _i32p, _i32p, _i32p, ctypes.POINTER(_Status))
    fn("spia_subdivide", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), ctypes.c_int32,
       _f32p, _i32p, _i32p, _f32p, _f32p, ctypes.POINTER(_Status))
    fn("spia_flat_positions", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), _f32p,
       ctypes.POINTER(_Status))
    fn("spia_sharpness", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), ctypes.c_int32, _i32p,
       _i32p, _f32p, _f32p, ctypes.POINTER(_Status))
    fn("spia_interpolate", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options), _f32p,
       ctypes.POINTER(_Report), ctypes.POINTER(_Status))
    fn("spia_surface_stencils_create", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(_Options),
       ctypes.c_int32, ctypes.POINTER(P), ctypes.POINTER(_Status))
    fn("spia_surface_sample_count", ctypes.c_int64, ctypes.POINTER(_Mesh), ctypes.c_int32)
    fn("spia_scan_create", ctypes.c_int, ctypes.POINTER(_Mesh), ctypes.POINTER(P), ctypes.POINTER(_Status))
    fn("spia_scan_create_progress", ctypes.c_int, ctypes.POINTER(_Mesh), _PROGRESS, ctypes.c_void_p,
       ctypes.POINTER(P), ctypes.POINTER(_Status))
    fn("spia_scan_free", None, P)
    fn("spia_scan_diagonal", ctypes.c_double, P)
    fn("spia_scan_closest_points", ctypes.c_int, P, ctypes.c_int64, _f32p, _f32p, _f32p, _f32p, _i32p,
       ctypes.POINTER(ctypes.c_uint8), ctypes.POINTER(_Status))
    fn("spia_scan_closest_points_progress", ctypes.c_int, P, ctypes.c_int64, _f32p, _f32p, _f32p, _f32p, _i32p,
       ctypes.POINTER(ctypes.c_uint8), _PROGRESS, ctypes.c_void_p, ctypes.POINTER(_Status))
    fn("spia_fit", ctypes.c_int, ctypes.POINTER(_Mesh), P, ctypes.POINTER(_Options), ctypes.POINTER(_FitOptions),
       _f32p, ctypes.POINTER(_FitReport), ctypes.POINTER(_Status))
