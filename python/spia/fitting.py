# SPDX-License-Identifier: GPL-3.0-or-later
"""Fitting a cage to a scan: the scan prepared for closest-point queries
(:class:`Scan`), stencils of samples over the limit surface
(:func:`surface_stencils`), and :func:`fit`, with what it reports
(:class:`FitReport`)."""

import ctypes
from dataclasses import dataclass, field

import numpy as np

from .errors import _STATUS_OF_RESULT, PiaError, _raise
from .header import (_PROGRESS, FIT_ALLOW_FOLDS, FIT_FREE_RIMS, FIT_HARD_CUTOFF, FIT_NO_SCAN_BEFORE,
                     FIT_NO_SCAN_DISTANCES, FIT_SCAN_PULL, _FitOptions, _FitReport, _Status)
from .interpolation import Stencils
from .library import _library
from .mesh import _as, _enum, _options, _ptr

FIT_MODES = ["SURFACE", "VERTICES"]


def surface_stencils(mesh, samples_per_edge=4, boundary_smooth="ALL", use_creases=True, quality=3,
                     opensubdiv_version=None, memory_budget=0):
    """Catmull-Clark limit stencils at samples_per_edge**2 points inside each
    ptex face (a quad, or each corner's sub-quad of another polygon), at the
    centres of a regular (s, t) grid: row ``(ptex * k + j) * k + i`` is at
    ``((i + 0.5) / k, (j + 0.5) / k)``.  A :class:`Stencils` with
    ``mesh.vertex_count`` columns.  ``opensubdiv_version``: see
    :func:`limit_stencils`."""
    lib = _library()
    opts, _keep = _options(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                           opensubdiv_version=opensubdiv_version, memory_budget=memory_budget)
    handle = ctypes.c_void_p()
    status = _Status()
    cm = mesh._c()
    code = lib.spia_surface_stencils_create(ctypes.byref(cm), ctypes.byref(opts), int(samples_per_edge),
                                            ctypes.byref(handle), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return Stencils(handle.value, lib, columns=mesh.vertex_count)


def _phase_callback(progress):
    """progress(phase, fraction) -> bool as the C callback (keep it alive for the call)."""
    def callback(_user, phase, fraction):
        try:
            return 1 if progress(int(phase), float(fraction)) else 0
        except Exception:  # an exception cannot cross C: treat it as a cancel
            return 1
    return _PROGRESS(callback)


class Scan:
    """A mesh prepared for closest-point queries (the library's own bounding volume hierarchy)."""

    def __init__(self, mesh, progress=None):
        """progress(phase, fraction) -> bool, called about every 0.1 s of the
        build (phase 1 to 4, fraction of the whole done) and once at its end:
        True cancels (PiaError 'CANCELLED', raised within a fraction of a
        second)."""
        lib = _library()
        self._lib = lib
        self._handle = None
        handle = ctypes.c_void_p()
        status = _Status()
        cm = mesh._c()
        if progress is None:
            code = lib.spia_scan_create(ctypes.byref(cm), ctypes.byref(handle), ctypes.byref(status))
        else:
            c_callback = _phase_callback(progress)
            code = lib.spia_scan_create_progress(ctypes.byref(cm), c_callback, None, ctypes.byref(handle),
                                                 ctypes.byref(status))
        if code != 0:
            _raise(code, status)
        self._handle = handle
        self.vertex_count = mesh.vertex_count

    def __del__(self):
        handle, self._handle = getattr(self, "_handle", None), None
        if handle:
            self._lib.spia_scan_free(handle)

    @property
    def diagonal(self):
        """Bounding-box diagonal of the scan's faces."""
        return self._lib.spia_scan_diagonal(self._handle)

    def closest_points(self, points, with_boundary=False, progress=None):
        """For points (N, 3): (closest (N, 3), normals (N, 3), distances (N,), faces (N,)), and with
        with_boundary=True also on_boundary (N,) bool: the closest point is on the scan's boundary
        (the point is beyond the scan's edge, over a hole).  progress(1, fraction) -> bool is called
        about every 0.1 s and at the end; True cancels (PiaError 'CANCELLED')."""
        points = _as(points, np.float32, (3,))
        n = len(points)
        closest = np.empty((n, 3), np.float32)
        normals = np.empty((n, 3), np.float32)
        distances = np.empty(n, np.float32)
        faces = np.empty(n, np.int32)
        boundary = np.empty(n, np.uint8)
        status = _Status()
        outputs = (_ptr(points, ctypes.c_float), _ptr(closest, ctypes.c_float),
                   _ptr(normals, ctypes.c_float), _ptr(distances, ctypes.c_float), _ptr(faces, ctypes.c_int32),
                   _ptr(boundary, ctypes.c_uint8))
        if progress is None:
            code = self._lib.spia_scan_closest_points(self._handle, n, *outputs, ctypes.byref(status))
        else:
            c_callback = _phase_callback(progress)
            code = self._lib.spia_scan_closest_points_progress(self._handle, n, *outputs, c_callback, None,
                                                               ctypes.byref(status))
        if code != 0:
            _raise(code, status)
        if with_boundary:
            return closest, normals, distances, faces, boundary.astype(bool)
        return closest, normals, distances, faces


@dataclass
class FitDistances:
    """Distances relative to the scan's diagonal, over the points within the cut-off: of the
    limit surface's samples to the scan, or (scan_before, scan_after) of the scan's vertices
    to the limit surface."""
    mean: float
    p95: float
    max: float
    ignored: int                # points beyond the cut-off (over holes; scan parts not reached)


@dataclass
class FitReport:
    status: str                 # 'CONVERGED', 'MAX_ITERATIONS' or 'STAGNATED' (from the VERTICES solve)
    message: str
    mode: str
    rounds: int
    sample_count: int
    diagonal: float
    before: FitDistances
    after: FitDistances
    iterations: int             # VERTICES: the interpolation's iterations
    max_error_relative: float   # VERTICES: the interpolation's error
    stencil_seconds: float
    query_seconds: float
    solve_seconds: float
    vertex_distances: np.ndarray = field(repr=False)   # per cage vertex, relative
    history: np.ndarray = field(repr=False)            # mean relative distance per round
    folded_before: int = -1     # samples facing away from the scan (-1: not measured)
    folded_after: int = -1
    scan_point_count: int = 0   # scan vertices measured the other way (0: not measured)
    scan_before: FitDistances = None   # None with measure_scan="after"
    scan_after: FitDistances = None
    scan_distances: np.ndarray = field(default=None, repr=False)  # per scan vertex, relative, -1 unused
    # flat_positions() of the cage written, where fit(flat=True) could give them
    flat_positions: np.ndarray = field(default=None, repr=False)

    def summary(self):
        b, a = self.before, self.after
        return (f"{self.mode.lower()} fit, {self.rounds} rounds: mean distance {a.mean:.3g} (was {b.mean:.3g}), "
                f"95th percentile {a.p95:.3g} (was {b.p95:.3g}), max {a.max:.3g} of the scan's diagonal")


def fit(cage, scan, mode="SURFACE", samples_per_edge=4, cutoff=0.02, smoothing=1e-5, point_weight=1e-3,
        max_rounds=16, round_tolerance=0.01, solver_iterations=20, robust_scale=6.0, slide_weight=0.0, allow_folds=False,
        hard_cutoff=False, measure_scan=True, scan_pull=False, free_rims=False, flat=False, **options):
    """Moves the vertices of ``cage`` (a :class:`Mesh`) so that its limit
    surface lies on ``scan`` (a :class:`Scan`).  mode 'SURFACE' fits the
    whole surface (Catmull-Clark); 'VERTICES' interpolates the closest scan
    points of the cage's limit points (any scheme).  ``options`` are those of
    :func:`interpolate` (scheme, quality, creases, solver, progress, ...).
    ``robust_scale``: the robust kernel's scale as a multiple of the median
    distance; ``slide_weight``: how much samples are held back from sliding
    along the scan within a round; ``allow_folds``: no fold guard; ``hard_cutoff``: the cut-off's
    0/1 weights without the kernel; ``measure_scan``: also measure the
    scan's vertices against the surface (``report.scan_before/after``;
    "after": against the cage written only, SPIA_FIT_NO_SCAN_BEFORE);
    ``scan_pull``: the scan's vertices pull the surface too (SPIA_FIT_SCAN_PULL);
    ``free_rims``: the cage's rims (faces with a boundary vertex) are not
    held smoother than the rest (SPIA_FIT_FREE_RIMS); ``flat``: also
    :func:`flat_positions` of the cage written, from the fit's own limit
    points (``report.flat_positions``; None where the library could not:
    a cage with a face that is not a quad, no ``measure_scan``, or too
    little memory left).
    Returns ``(cage positions (N, 3) float32, FitReport)``."""
    lib = _library()
    opts, _keep = _options(**options)
    fo = _FitOptions()
    fo.mode = _enum(mode, FIT_MODES, "fit")
    for name, value in (("cutoff", cutoff), ("round_tolerance", round_tolerance)):
        if not (value > 0 and np.isfinite(value)):
            raise PiaError("INVALID_ARGUMENT", f"{name} must be a positive number, not {value!r}")
    for name, value in (("smoothing", smoothing), ("point_weight", point_weight)):
        if not (value >= 0 and np.isfinite(value)):
            raise PiaError("INVALID_ARGUMENT", f"{name} must be zero or positive, not {value!r}")
    fo.samples_per_edge = int(samples_per_edge)
    fo.cutoff = float(cutoff)
    # 0 means "the default" in C; a weight the caller sets to 0 means none.
    fo.smoothing = float(smoothing) if smoothing > 0 else -1.0
    fo.point_weight = float(point_weight) if point_weight > 0 else -1.0
    fo.max_rounds = int(max_rounds)
    fo.round_tolerance = float(round_tolerance)
    fo.solver_iterations = int(solver_iterations)
    if not (robust_scale > 0 and np.isfinite(robust_scale)):
        raise PiaError("INVALID_ARGUMENT", f"robust_scale must be a positive number, not {robust_scale!r}")
    fo.robust_scale = float(robust_scale)
    if not (0 <= slide_weight < 1):
        raise PiaError("INVALID_ARGUMENT", f"slide_weight must be at least 0 and below 1, not {slide_weight!r}")
    fo.slide_weight = float(slide_weight)
    if measure_scan not in (True, False, "after"):
        raise PiaError("INVALID_ARGUMENT", f"measure_scan must be True, False or 'after', not {measure_scan!r}")
    fo.flags = ((FIT_ALLOW_FOLDS if allow_folds else 0) | (FIT_HARD_CUTOFF if hard_cutoff else 0)
                | (0 if measure_scan else FIT_NO_SCAN_DISTANCES) | (FIT_SCAN_PULL if scan_pull else 0)
                | (FIT_FREE_RIMS if free_rims else 0) | (FIT_NO_SCAN_BEFORE if measure_scan == "after" else 0))
    if fo.max_rounds < 1 or fo.solver_iterations < 1:
        raise PiaError("INVALID_ARGUMENT", "max_rounds and solver_iterations must be at least 1")
    out = np.empty_like(cage.positions)
    vertex_distances = np.zeros(cage.vertex_count, np.float32)
    history = np.zeros(fo.max_rounds + 1, np.float64)
    per_scan = np.full(max(scan.vertex_count, 1), -1.0, np.float32)
    flat_out = np.empty_like(cage.positions) if flat else None
    rep = _FitReport(vertex_distances=_ptr(vertex_distances, ctypes.c_float),
                     history=_ptr(history, ctypes.c_double), history_capacity=len(history),
                     scan_distances=_ptr(per_scan, ctypes.c_float),
                     flat_positions=_ptr(flat_out, ctypes.c_float) if flat else None)
    status = _Status()
    cm = cage._c()
    code = lib.spia_fit(ctypes.byref(cm), scan._handle, ctypes.byref(opts), ctypes.byref(fo),
                        _ptr(out, ctypes.c_float), ctypes.byref(rep), ctypes.byref(status))
    if code < 0:
        _raise(code, status)

    def dist(d):
        return FitDistances(mean=d.mean, p95=d.p95, max=d.max, ignored=d.ignored)
    return out, FitReport(
        status=_STATUS_OF_RESULT[code], message=status.message.decode("utf-8", "replace"),
        mode=FIT_MODES[rep.mode], rounds=rep.rounds, sample_count=rep.sample_count, diagonal=rep.diagonal,
        before=dist(rep.before), after=dist(rep.after), iterations=rep.iterations,
        max_error_relative=rep.max_error_relative, stencil_seconds=rep.stencil_seconds,
        query_seconds=rep.query_seconds, solve_seconds=rep.solve_seconds,
        vertex_distances=vertex_distances, history=history[: rep.history_count].copy(),
        folded_before=rep.folded_before, folded_after=rep.folded_after, scan_point_count=rep.scan_point_count,
        scan_before=None if measure_scan == "after" else dist(rep.scan_before),
        scan_after=dist(rep.scan_after),
        scan_distances=per_scan[: scan.vertex_count] if rep.scan_point_count else None,
        flat_positions=flat_out if rep.flat_positions_written else None)
