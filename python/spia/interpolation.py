# SPDX-License-Identifier: GPL-3.0-or-later
"""Interpolation: limit stencil tables (:class:`Stencils`), the solve of
``L V = P`` on them, and :func:`interpolate`, which does both in one call;
:class:`Report` says what a solve did."""

import ctypes
from dataclasses import dataclass, field

import numpy as np

from .errors import _RESULT_NAMES, _STATUS_OF_RESULT, PiaError, _raise
from .header import _Report, _Status
from .library import _library
from .mesh import METHODS, _as, _options, _ptr


@dataclass
class Report:
    """What a solve did.  Errors are distances |P_i - (L V)_i|."""
    status: str                 # 'CONVERGED', 'MAX_ITERATIONS' or 'STAGNATED'
    converged: bool
    message: str
    method: str                 # the method used (AUTO resolved)
    iterations: int
    diagonal: float             # bounding-box diagonal of the targets
    max_error: float
    mean_error: float
    max_error_relative: float
    mean_error_relative: float
    initial_max_error_relative: float
    unreachable_count: int      # vertices no cage can put on their targets (least squares leaves them closest)
    reachable_max_error_relative: float   # max error over the other vertices
    weight: float               # WPIA's weight (0 for the other methods)
    stage_iterations: tuple     # staged solves: (boundary, interior) iterations
    stencil_seconds: float
    solve_seconds: float
    history: np.ndarray = field(repr=False)   # relative max error after each iteration
    unreachable: np.ndarray = field(repr=False)  # bool per vertex

    @property
    def unreachable_indices(self):
        """The unreachable vertices' indices, in order (int32)."""
        return np.flatnonzero(self.unreachable).astype(np.int32)

    def summary(self):
        state = "converged" if self.converged else self.status.lower().replace("_", " ")
        extra = (f"; {self.unreachable_count} vertices cannot be reached (the others: "
                 f"{self.reachable_max_error_relative:.3g})") if self.unreachable_count else ""
        return (f"{state} in {self.iterations} iterations ({self.method}): max error "
                f"{self.max_error_relative:.3g}, mean {self.mean_error_relative:.3g} of the diagonal "
                f"(was {self.initial_max_error_relative:.3g}){extra}")


def _report_buffers(max_iterations, vertex_count):
    history = np.empty(max_iterations, dtype=np.float64)
    unreachable = np.zeros(vertex_count, dtype=np.uint8)
    rep = _Report(history=_ptr(history, ctypes.c_double), history_capacity=len(history),
                  unreachable=_ptr(unreachable, ctypes.c_uint8))
    return rep, history, unreachable


def _report(code, rep, history, unreachable, status):
    return Report(
        status=_STATUS_OF_RESULT[code], converged=code == 0,
        message=status.message.decode("utf-8", "replace"),
        method=METHODS[rep.method] if 0 <= rep.method < len(METHODS) else str(rep.method),
        iterations=rep.iterations, diagonal=rep.diagonal, max_error=rep.max_error, mean_error=rep.mean_error,
        max_error_relative=rep.max_error_relative, mean_error_relative=rep.mean_error_relative,
        initial_max_error_relative=rep.initial_max_error_relative,
        unreachable_count=rep.unreachable_count, reachable_max_error_relative=rep.reachable_max_error_relative,
        unreachable=unreachable.astype(bool), weight=rep.weight, stage_iterations=tuple(rep.stage_iterations),
        stencil_seconds=rep.stencil_seconds, solve_seconds=rep.solve_seconds,
        history=history[: rep.history_count].copy())


class Stencils:
    """A limit stencil table: row i gives the limit point of vertex i as
    ``sum(weights[k] * cage[indices[k]] for k in range(offsets[i], offsets[i+1]))``."""

    def __init__(self, handle, lib, columns=None):
        self._handle = ctypes.c_void_p(handle)
        self._lib = lib
        self._rows = lib.spia_stencils_row_count(self._handle)
        self.column_count = self._rows if columns is None else int(columns)
        self._arrays = None

    def _csr(self):
        """The CSR arrays, made by the library the first time they are
        asked for (it keeps most tables in their sweep layout alone, about
        40 bytes a vertex): a table that is only solved with (an operator, a
        live cage) never has them (12 bytes per weight more)."""
        if self._arrays is None:
            nnz = self._lib.spia_stencils_weight_count(self._handle)
            offsets = np.empty(self._rows + 1, dtype=np.int64)
            indices = np.empty(nnz, dtype=np.int32)
            weights = np.empty(nnz, dtype=np.float64)
            code = self._lib.spia_stencils_copy_csr(self._handle, _ptr(offsets, ctypes.c_int64),
                                                    _ptr(indices, ctypes.c_int32), _ptr(weights, ctypes.c_double))
            if code != 0:
                name = _RESULT_NAMES.get(code, str(code))
                raise PiaError(name, f"copying the stencil table out failed ({name})")
            self._arrays = offsets, indices, weights
        return self._arrays

    @property
    def offsets(self):
        return self._csr()[0]

    @property
    def indices(self):
        return self._csr()[1]

    @property
    def weights(self):
        return self._csr()[2]

    def __del__(self):
        handle, self._handle = getattr(self, "_handle", None), None
        if handle:
            self._lib.spia_stencils_free(handle)

    @property
    def row_count(self):
        return self._rows

    def to_scipy(self):
        """The table as a scipy.sparse.csr_matrix (needs scipy)."""
        import scipy.sparse
        return scipy.sparse.csr_matrix((self.weights, self.indices, self.offsets),
                                       shape=(self.row_count, self.column_count))

    def apply(self, cage):
        """Limit points (N, 3) of a cage (N, 3), computed in numpy."""
        cage = np.asarray(cage, dtype=np.float64).reshape(-1, 3)
        rows = np.repeat(np.arange(self.row_count), np.diff(self.offsets))
        out = np.zeros((self.row_count, 3))
        np.add.at(out, rows, self.weights[:, None] * cage[self.indices])
        return out

    def limit_points(self, cage):
        """Limit points (N, 3) float64 of a cage (N, 3), computed by the library
        (threads, no Python loop; :meth:`apply` is the numpy computation)."""
        cage = np.ascontiguousarray(cage, dtype=np.float64).reshape(-1, 3)
        out = np.empty((self.row_count, 3), np.float64)
        code = self._lib.spia_stencils_apply(self._handle, _ptr(cage, ctypes.c_double), _ptr(out, ctypes.c_double))
        if code != 0:
            raise PiaError(_RESULT_NAMES.get(code, str(code)), "spia_stencils_apply failed")
        return out

    def solve(self, targets, initial=None, **options):
        """Solves L V = targets; returns (cage, Report).  See :func:`interpolate`.

        initial: the first iterate (row_count x 3), for example the cage
        solved before the targets moved a little; None: the targets."""
        lib = self._lib
        targets = _as(targets, np.float32, (3,))
        if len(targets) != self.row_count:
            raise PiaError("INVALID_ARGUMENT", f"{len(targets)} targets for {self.row_count} stencils")
        opts, _keep = _options(**options)
        if initial is not None:
            initial = _as(initial, np.float32, (3,))
            if initial.shape != targets.shape:
                raise PiaError("INVALID_ARGUMENT", f"initial cage of {len(initial)} vertices for {self.row_count} stencils")
            opts.initial_cage = _ptr(initial, ctypes.c_float)
        cage = np.empty_like(targets)
        rep, history, unreachable = _report_buffers(opts.max_iterations, len(targets))
        status = _Status()
        code = lib.spia_solve(self._handle, _ptr(targets, ctypes.c_float), ctypes.byref(opts),
                              _ptr(cage, ctypes.c_float), ctypes.byref(rep), ctypes.byref(status))
        if code < 0:
            _raise(code, status)
        return cage, _report(code, rep, history, unreachable, status)


def validate(mesh):
    """Raises PiaError if the library would refuse the mesh."""
    status = _Status()
    cm = mesh._c()
    code = _library().spia_mesh_validate(ctypes.byref(cm), ctypes.byref(status))
    if code != 0:
        _raise(code, status)


def limit_stencils(mesh, scheme="CATMULL_CLARK", boundary_smooth="ALL", use_creases=True, quality=3, progress=None,
                   boundary_rule="SMOOTH", shape_parameter=0.5, face_shape_parameters=None, threads=0,
                   opensubdiv_version=None, memory_budget=0):
    """The limit stencils of ``mesh`` (a :class:`Stencils`).  ``threads``: 0 for
    one per processor; the table does not depend on it.  ``opensubdiv_version``
    (Catmull-Clark): that of the Blender to match, e.g.
    ``bpy.app.opensubdiv.version``; None: OpenSubdiv 3.6.0's rules (Blender
    up to 5.0), which differ from later ones at some non-manifold vertices."""
    lib = _library()
    opts, _keep = _options(scheme=scheme, boundary_smooth=boundary_smooth, use_creases=use_creases,
                           quality=quality, progress=progress, boundary_rule=boundary_rule,
                           shape_parameter=shape_parameter, face_shape_parameters=face_shape_parameters,
                           threads=threads, opensubdiv_version=opensubdiv_version, memory_budget=memory_budget)
    handle = ctypes.c_void_p()
    status = _Status()
    cm = mesh._c()
    code = lib.spia_limit_stencils_create(ctypes.byref(cm), ctypes.byref(opts), ctypes.byref(handle),
                                          ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return Stencils(handle.value, lib)


def solve(stencils, targets, **options):
    """Solves ``stencils`` V = targets; the same as ``stencils.solve(targets, **options)``."""
    return stencils.solve(targets, **options)


def interpolate(mesh, scheme="CATMULL_CLARK", boundary_smooth="ALL", use_creases=True, quality=3, method="AUTO",
                tolerance=1e-6, max_iterations=1000, progress=None, boundary_rule="SMOOTH", weight=0.0,
                staged=False, shape_parameter=0.5, face_shape_parameters=None, threads=0, opensubdiv_version=None,
                solve_flags=(), memory_budget=0):
    """A cage whose limit surface passes through the mesh's vertices.

    scheme 'LOOP' (triangles only) takes boundary_rule 'SMOOTH' (OpenSubdiv's)
    or 'HOPPE' (the open-mesh paper's); 'DOO_SABIN' (closed meshes) takes
    shape_parameter in (0, 1) or face_shape_parameters (one per face);
    method 'WPIA' takes weight (0: estimated); staged=True solves the
    boundary first, then the interior.  ``threads``: 0 for one per
    processor, 1 for the calling thread only; results do not depend on it.
    ``opensubdiv_version``: see :func:`limit_stencils`.  ``solve_flags``:
    names from :data:`SOLVE_FLAGS` (the header's SPIA_SOLVE_*), for the
    Gauss-Seidel solvers.  ``memory_budget``: bytes the call may use (0:
    :func:`available_memory`; negative: no check); every function takes it,
    and one whose settings would need more raises :class:`PiaError`
    OUT_OF_MEMORY at once, naming the setting and what would fit.

    Returns ``(cage, report)``: cage is an (N, 3) float32 array of new
    control positions, report a :class:`Report`.  Stopping at
    max_iterations or on stagnation is not an error: ``report.converged`` is
    False then.  Bad input raises :class:`PiaError`; a progress callback
    ``progress(iteration, relative_error)`` that returns True cancels and
    raises :class:`PiaCancelled`.
    """
    lib = _library()
    opts, _keep = _options(scheme, boundary_smooth, use_creases, quality, method, tolerance, max_iterations, progress,
                           boundary_rule, weight, staged, shape_parameter, face_shape_parameters, threads,
                           opensubdiv_version, solve_flags, memory_budget)
    cage = np.empty_like(mesh.positions)
    rep, history, unreachable = _report_buffers(opts.max_iterations, mesh.vertex_count)
    status = _Status()
    cm = mesh._c()
    code = lib.spia_interpolate(ctypes.byref(cm), ctypes.byref(opts), _ptr(cage, ctypes.c_float),
                                ctypes.byref(rep), ctypes.byref(status))
    if code < 0:
        _raise(code, status)
    return cage, _report(code, rep, history, unreachable, status)
