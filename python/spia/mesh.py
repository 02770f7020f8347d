# SPDX-License-Identifier: GPL-3.0-or-later
"""Meshes in the library's layout (:class:`Mesh`), the settings every call
takes (:func:`_options`, checked and turned into the header's
``spia_options``), and the helpers that hand numpy arrays to C."""

import ctypes

import numpy as np

from .errors import PiaError
from .header import _PROGRESS, _Mesh, _Options

SCHEMES = ("CATMULL_CLARK", "LOOP", "DOO_SABIN")
BOUNDARY_RULES = ("SMOOTH", "HOPPE")
BOUNDARY_SMOOTH = ("ALL", "PRESERVE_CORNERS")
METHODS = ("AUTO", "PIA", "GS_PIA", "CHEBYSHEV", "WPIA", "CG", "GS_PIA_FAST", "LEAST_SQUARES")
# spia_options.solve_flags, by name (see the header): parts of the
# Gauss-Seidel solvers to switch on.
SOLVE_FLAGS = {"FIRST_STEP": 1, "MULTICOLOUR": 2, "DOUBLE_SWEEPS": 4, "NO_AVX": 8}


def _as(array, dtype, shape_tail=None):
    a = np.ascontiguousarray(array, dtype=dtype)
    if shape_tail is not None:
        a = a.reshape((-1,) + shape_tail) if a.size else a.reshape((0,) + shape_tail)
    return a


def _ptr(a, ctype):
    return a.ctypes.data_as(ctypes.POINTER(ctype)) if a is not None else None


class Mesh:
    """A polygon mesh in the library's layout (Blender's, flattened).

    positions       (N, 3) float32
    face_sizes      (F,)   int32, corners per face
    face_vertices   (sum(face_sizes),) int32, faces one after another
    edges           (E, 2) int32, all edges incl. loose ones, or None
    edge_creases    (E,)   float32 in [0, 1], or None
    vertex_creases  (N,)   float32 in [0, 1], or None

    Arrays that already have these dtypes and are C-contiguous are used in
    place; the Mesh keeps references to them while it lives.
    """

    def __init__(self, positions, face_sizes, face_vertices, edges=None, edge_creases=None, vertex_creases=None):
        self.positions = _as(positions, np.float32, (3,))
        self.face_sizes = _as(face_sizes, np.int32).ravel()
        self.face_vertices = _as(face_vertices, np.int32).ravel()
        self.edges = None if edges is None else _as(edges, np.int32, (2,))
        self.edge_creases = None if edge_creases is None else _as(edge_creases, np.float32).ravel()
        self.vertex_creases = None if vertex_creases is None else _as(vertex_creases, np.float32).ravel()
        corners = int(self.face_sizes.sum(dtype=np.int64))
        if self.face_vertices.size != corners:
            raise PiaError("INVALID_ARGUMENT",
                           f"face_vertices has {self.face_vertices.size} entries but face_sizes add up to {corners}")
        if self.edge_creases is not None and (self.edges is None or len(self.edge_creases) != len(self.edges)):
            raise PiaError("INVALID_ARGUMENT", "edge_creases needs one value per edge")
        if self.vertex_creases is not None and len(self.vertex_creases) != len(self.positions):
            raise PiaError("INVALID_ARGUMENT", "vertex_creases needs one value per vertex")

    @classmethod
    def from_faces(cls, positions, faces, **kwargs):
        """Builds a Mesh from a list of faces (lists of vertex indices)."""
        sizes = np.fromiter((len(f) for f in faces), dtype=np.int32, count=len(faces))
        verts = np.fromiter((v for f in faces for v in f), dtype=np.int32, count=int(sizes.sum()))
        return cls(positions, sizes, verts, **kwargs)

    @property
    def vertex_count(self):
        return len(self.positions)

    def _c(self):
        return _Mesh(
            len(self.positions), _ptr(self.positions, ctypes.c_float),
            len(self.face_sizes), _ptr(self.face_sizes, ctypes.c_int32), _ptr(self.face_vertices, ctypes.c_int32),
            0 if self.edges is None else len(self.edges), _ptr(self.edges, ctypes.c_int32),
            _ptr(self.edge_creases, ctypes.c_float), _ptr(self.vertex_creases, ctypes.c_float))


def _enum(value, names, what):
    try:
        return names.index(value)
    except ValueError:
        raise PiaError("INVALID_ARGUMENT", f"{what} must be one of {', '.join(names)}, not {value!r}") from None


def opensubdiv_version_number(version):
    """OpenSubdiv's version as the library takes it (major * 10000 + minor *
    100 + patch) from a tuple such as bpy.app.opensubdiv.version, a string
    such as "3.7.0", or that number; None or 0 is 0 (OpenSubdiv 3.6.0's
    rules)."""
    if version is None:
        return 0
    parts = version
    if isinstance(version, str):
        try:
            parts = [int(p) for p in version.strip().split(".")] if version.strip() else [0]
        except ValueError:
            parts = None
    if isinstance(parts, (int, np.integer)) and not isinstance(parts, bool):
        number = int(parts)
    elif (isinstance(parts, (tuple, list)) and 1 <= len(parts) <= 3
          and all(isinstance(p, (int, np.integer)) and not isinstance(p, bool) and 0 <= p <= 99 for p in parts)):
        major, minor, patch = (list(parts) + [0, 0])[:3]
        number = major * 10000 + minor * 100 + patch
    else:
        number = -1
    if not 0 <= number <= 2**31 - 1:
        raise PiaError("INVALID_ARGUMENT", "opensubdiv_version must be a version such as (3, 7, 0) or "
                       f"'3.7.0', or major * 10000 + minor * 100 + patch, not {version!r}")
    return number


def _options(scheme="CATMULL_CLARK", boundary_smooth="ALL", use_creases=True, quality=3, method="AUTO",
             tolerance=1e-6, max_iterations=1000, progress=None, boundary_rule="SMOOTH", weight=0.0, staged=False,
             shape_parameter=0.5, face_shape_parameters=None, threads=0, opensubdiv_version=None, solve_flags=(),
             memory_budget=0):
    if not isinstance(memory_budget, (int, np.integer)):
        raise PiaError("INVALID_ARGUMENT", f"memory_budget must be a whole number of bytes (0: what the machine "
                                           f"has available; negative: no check), not {memory_budget!r}")
    if not (isinstance(threads, (int, np.integer)) and threads >= 0):
        raise PiaError("INVALID_ARGUMENT", f"threads must be 0 (all processors) or a positive integer, not {threads!r}")
    if not (isinstance(quality, (int, np.integer)) and 1 <= quality <= 10):
        raise PiaError("INVALID_ARGUMENT", f"quality must be an integer from 1 to 10, not {quality!r}")
    if not (tolerance > 0 and np.isfinite(tolerance)):
        raise PiaError("INVALID_ARGUMENT", f"tolerance must be a positive number, not {tolerance!r}")
    if not (isinstance(max_iterations, (int, np.integer)) and max_iterations >= 1):
        raise PiaError("INVALID_ARGUMENT", f"max_iterations must be a positive integer, not {max_iterations!r}")
    opts = _Options()
    opts.scheme = _enum(scheme, SCHEMES, "scheme")
    opts.boundary_smooth = _enum(boundary_smooth, BOUNDARY_SMOOTH, "boundary_smooth")
    opts.ignore_creases = 0 if use_creases else 1
    opts.quality = int(quality)
    opts.method = _enum(method, METHODS, "method")
    opts.tolerance = float(tolerance)
    opts.max_iterations = int(max_iterations)
    opts.boundary_rule = _enum(boundary_rule, BOUNDARY_RULES, "boundary_rule")
    if not (0.0 <= weight < 2.0):
        raise PiaError("INVALID_ARGUMENT", f"weight must be in (0, 2), or 0 to estimate it, not {weight!r}")
    opts.weight = float(weight)
    opts.staged = 1 if staged else 0
    opts.shape_parameter = float(shape_parameter)
    opts.threads = int(threads)
    opts.opensubdiv_version = opensubdiv_version_number(opensubdiv_version)
    opts.solve_flags = _solve_flags(solve_flags)
    opts.memory_budget = int(memory_budget)
    keep = None
    if face_shape_parameters is not None:
        keep = np.ascontiguousarray(face_shape_parameters, dtype=np.float32).ravel()
        opts.face_shape_parameters = _ptr(keep, ctypes.c_float)
    callback = None
    if progress is not None:
        def callback(_user, iteration, relative_error):
            try:
                return 1 if progress(int(iteration), float(relative_error)) else 0
            except Exception:  # an exception cannot cross C: treat it as a cancel
                return 1
        callback = _PROGRESS(callback)
        opts.progress = callback
    return opts, (callback, keep)


def _solve_flags(flags):
    """solve_flags as names (an iterable of SOLVE_FLAGS keys) -> the bits."""
    if isinstance(flags, str):
        flags = (flags,)
    bits = 0
    for name in flags:
        if name not in SOLVE_FLAGS:
            raise PiaError("INVALID_ARGUMENT", f"unknown solve flag {name!r}; expected some of {sorted(SOLVE_FLAGS)}")
        bits |= SOLVE_FLAGS[name]
    return bits
