# SPDX-License-Identifier: GPL-3.0-or-later
"""spia: numpy interface to the subdiv_pia C library (through ctypes).

It imports no ``bpy``: it runs in any Python 3.9 or newer with numpy, and
inside Blender, where the add-on uses it.  numpy arrays are handed to C as
pointers, without copies when they already have the right dtype and layout.

    import spia
    mesh = spia.Mesh(positions, face_sizes, face_vertices, edges, edge_creases, vertex_creases)
    cage, report = spia.interpolate(mesh, quality=3, boundary_smooth='ALL')
    stencils = spia.limit_stencils(mesh)     # CSR arrays: offsets, indices, weights

It is installed with pip (the ``subdiv_pia`` wheel for the platform), with
the add-on as an extension (Blender 4.2 and newer install the same wheel),
or inside the add-on's folder (the legacy package for Blender 3.4 to 4.1 and
the development build).  The shared library is looked up next to this file
(``libsubdiv_pia.so``, ``subdiv_pia.dll`` or ``libsubdiv_pia.dylib``), or,
instead, at the path in the environment variable ``SUBDIV_PIA_LIBRARY``.
It is loaded on first use; if it cannot be, :func:`available` is False and
:func:`load_error` says why and what is needed (the package for this
platform, a newer glibc, ...).

:func:`write_usd` (or :func:`usd_text`, the same as a string) writes a cage
as a USDA layer with one subdivision ``Mesh`` prim, in text and without any
USD library: the mesh's faces, the cage's points (float32, exactly),
Catmull-Clark or Loop, the boundary mode, and the creases as sharpness with
Blender's own rules made explicit, so that OpenSubdiv-based hosts (usdview,
Houdini, Maya) build the surface Blender's modifier builds (Blender's own
USD import: see :func:`write_usd`).  Hosts evaluate the limit surface at their own refinement level;
where Blender's surface depends on ``quality`` (smooth corners, semi-sharp
creases) the cage interpolates exactly in hosts that evaluate the same way.
"""

import ctypes
import os
import platform
import re
import sys
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Mesh", "Report", "Stencils", "PiaError", "PiaCancelled",
    "available", "load_error", "library_path", "platform_tag", "version", "available_memory", "opensubdiv_version_number", "validate", "limit_stencils", "solve", "interpolate", "refine",
    "subdivide", "flat_positions", "fit", "fit_detail", "detail_samples", "detail_memory_estimate", "check_detail_memory", "DetailResult", "Scan",
    "usd_text", "write_usd", "sharpness",
    "SCHEMES", "BOUNDARY_SMOOTH", "BOUNDARY_RULES", "METHODS", "SOLVE_FLAGS",
]

SCHEMES = ("CATMULL_CLARK", "LOOP", "DOO_SABIN")
BOUNDARY_RULES = ("SMOOTH", "HOPPE")
BOUNDARY_SMOOTH = ("ALL", "PRESERVE_CORNERS")
METHODS = ("AUTO", "PIA", "GS_PIA", "CHEBYSHEV", "WPIA", "CG", "GS_PIA_FAST", "LEAST_SQUARES")
# spia_options.solve_flags, by name (see the header): parts of the
# Gauss-Seidel solvers to switch on.
SOLVE_FLAGS = {"FIRST_STEP": 1, "MULTICOLOUR": 2, "DOUBLE_SWEEPS": 4, "NO_AVX": 8}

_RESULT_NAMES = {
    0: "OK", 1: "MAX_ITERATIONS", 2: "STAGNATED",
    -1: "INVALID_ARGUMENT", -2: "EMPTY_MESH", -3: "FACE_SIZE", -4: "INDEX_RANGE",
    -5: "NONFINITE", -6: "DEGENERATE_FACE", -7: "TOPOLOGY", -8: "OUT_OF_MEMORY",
    -9: "CANCELLED", -10: "DIVERGED", -11: "INTERNAL",
}
_STATUS_OF_RESULT = {0: "CONVERGED", 1: "MAX_ITERATIONS", 2: "STAGNATED"}


class PiaError(Exception):
    """The library refused the input or failed; ``code`` names why."""

    def __init__(self, code, message, index=-1):
        super().__init__(message)
        self.code = code
        self.message = message
        self.index = index


class PiaCancelled(PiaError):
    """The progress callback asked to stop."""


# --------------------------------------------------------------------------
# C declarations
# --------------------------------------------------------------------------

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
        ("scan_distances", _f32p),
    ]


# spia_fit_flags
FIT_ALLOW_FOLDS, FIT_HARD_CUTOFF, FIT_NO_SCAN_DISTANCES, FIT_SCAN_PULL, FIT_FREE_RIMS = 1, 2, 4, 8, 16


_lib = None
_lib_path = None
_load_error = None

# The library's file name on each operating system (sys.platform's start).
LIBRARY_NAMES = {"linux": "libsubdiv_pia.so", "win32": "subdiv_pia.dll", "darwin": "libsubdiv_pia.dylib"}
_SYSTEM_OF_PLATFORM = {"linux": "linux", "win32": "windows", "darwin": "macos"}
_SYSTEM_NAMES = {"linux": "Linux", "windows": "Windows", "macos": "macOS"}
_MACHINES = {"x86_64": "x64", "amd64": "x64", "x64": "x64", "aarch64": "arm64", "arm64": "arm64"}


def _system():
    for prefix, system in _SYSTEM_OF_PLATFORM.items():
        if sys.platform.startswith(prefix):
            return system
    return sys.platform


def platform_tag():
    """This system as extension platforms are named: 'linux-x64', 'windows-x64',
    'windows-arm64', 'macos-x64', 'macos-arm64' (other systems: their own names)."""
    machine = platform.machine()
    return "%s-%s" % (_system(), _MACHINES.get(machine.lower(), machine.lower() or "unknown"))


def _platform_name(tag):
    system, _, machine = tag.partition("-")
    return "%s %s" % (_SYSTEM_NAMES.get(system, system), machine)


def library_name():
    """The library's file name on this system."""
    for prefix, name in LIBRARY_NAMES.items():
        if sys.platform.startswith(prefix):
            return name
    return LIBRARY_NAMES["linux"]


def glibc_version():
    """(major, minor) of this system's GNU C library, or None (not glibc)."""
    try:
        text = os.confstr("CS_GNU_LIBC_VERSION")  # "glibc 2.36"
    except (AttributeError, ValueError, OSError):
        return None
    match = re.search(r"(\d+)\.(\d+)", text or "")
    return (int(match.group(1)), int(match.group(2))) if match else None


def _package_dir():
    return os.path.dirname(os.path.abspath(__file__))


def _manifest(folder):
    """The Blender add-on's blender_manifest.toml in `folder` or, where this
    package is bundled inside the add-on, its parent; None outside one."""
    for path in (os.path.join(folder, "blender_manifest.toml"),
                 os.path.join(os.path.dirname(folder), "blender_manifest.toml")):
        if os.path.isfile(path):
            return path
    return None


def package_info(folder=None):
    """(version, platforms) of the Blender package this binding is part of,
    from its blender_manifest.toml (None, () outside one: installed with pip,
    or the extension's wheel)."""
    path = _manifest(folder or _package_dir())
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except (OSError, TypeError):
        return None, ()
    version = re.search(r'^version\s*=\s*"([^"]*)"', text, re.M)
    platforms = re.search(r"^platforms\s*=\s*\[([^\]]*)\]", text, re.M)
    return (version.group(1) if version else None,
            tuple(re.findall(r'"([^"]+)"', platforms.group(1))) if platforms else ())


def _library_candidates():
    env = os.environ.get("SUBDIV_PIA_LIBRARY")
    if env:  # named explicitly: that one or none
        yield env
        return
    yield os.path.join(_package_dir(), library_name())


def explain_load_failure(errors, folder=None, tag=None, glibc=None):
    """What the user needs, in a few lines, for a library that did not load.

    errors: [(path, loader's message or None when the file is missing)].
    The first line says what is needed (the package for this platform, a
    newer glibc, a missing library); the lines after it give the details.
    """
    folder = folder or _package_dir()
    tag = tag or platform_tag()
    version, platforms = package_info(folder)
    if _manifest(folder):  # inside the add-on: Blender 4.2 and newer take the extension
        app = getattr(sys.modules.get("bpy"), "app", None)
        extension = app is not None and tuple(app.version) >= (4, 2, 0)
        package = "subdiv_pia-%s-%s%s.zip" % (version or "<version>", "" if extension else "legacy-",
                                              tag.replace("-", "_"))
    else:  # pip's wheel (or the extension's, which Blender installed from it)
        package = "the subdiv_pia wheel for %s" % _platform_name(tag)
    here = _platform_name(tag)
    details = ["%s: %s" % (path, message or "not found") for path, message in errors]
    texts = " ".join(message for _, message in errors if message)
    present = sorted(name for name in LIBRARY_NAMES.values() if os.path.exists(os.path.join(folder, name)))

    needed = re.findall(r"GLIBC_(\d+)\.(\d+)", texts)
    missing = re.findall(r"([\w.+-]+\.so[\w.]*): cannot open shared object file", texts)
    missing = sorted(set(m for m in missing if not m.startswith(("libsubdiv_pia", "subdiv_pia"))))
    if needed:
        need = max((int(a), int(b)) for a, b in needed)
        have = glibc_version() if glibc is None else glibc
        head = "The native library needs glibc %d.%d or newer; this system has %s" % (
            need + ("glibc %d.%d" % have if have else "an older one",))
    elif missing:
        head = "The native library needs %s, which this system lacks" % ", ".join(missing)
    elif os.environ.get("SUBDIV_PIA_LIBRARY"):
        head = ("The library that SUBDIV_PIA_LIBRARY names is %s"
                % ("missing" if not texts else "not a library for this system (%s)" % here))
    elif platforms and tag not in platforms:
        head = ("This package is for %s; this system is %s: install %s"
                % (" and ".join(_platform_name(p) for p in platforms), here, package))
    elif not texts and present:
        head = ("This package has the native library for another system (%s); this system is %s: "
                "install %s" % (", ".join(present), here, package))
    elif not texts:
        head = ("The native library (%s) is missing from the package: install %s again"
                % (library_name(), package))
    elif re.search(r"wrong ELF class|invalid ELF header|not a valid Win32|mach-o|"
                   r"incompatible architecture|file too short", texts, re.I):
        head = "The native library is not built for this system (%s): install %s" % (here, package)
    else:
        head = "The native library could not be loaded"
    return "\n".join([head] + details)


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


def _library():
    global _lib, _lib_path, _load_error
    if _lib is not None:
        return _lib
    errors = []
    for path in _library_candidates():
        if not os.path.exists(path):
            errors.append((path, None))
            continue
        try:
            lib = ctypes.CDLL(path)
            _declare(lib)
        except (OSError, AttributeError) as exc:
            errors.append((path, str(exc)))
            continue
        _lib, _lib_path, _load_error = lib, os.path.abspath(path), None
        return lib
    _load_error = explain_load_failure(errors)
    raise PiaError("LIBRARY", _load_error)


def available():
    """True when the native library can be loaded."""
    try:
        _library()
        return True
    except PiaError:
        return False


def load_error():
    """Why the native library could not be loaded, or None: a first line that
    says what is needed, then one line per file tried."""
    available()
    return _load_error


def library_path():
    """The file the native library was loaded from, or None."""
    available()
    return _lib_path


def available_memory():
    """Bytes of memory the machine can give the library now (the default
    ``memory_budget`` of every call), or None where it cannot be told."""
    value = int(_library().spia_available_memory())
    return value if value >= 0 else None


def version():
    """The library's version as a string, e.g. '0.1.0'."""
    v = _library().spia_version()
    return f"{v // 10000}.{v // 100 % 100}.{v % 100}"


# --------------------------------------------------------------------------
# Mesh and options
# --------------------------------------------------------------------------

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


def _raise(code, status):
    name = _RESULT_NAMES.get(code, str(code))
    message = status.message.decode("utf-8", "replace") or name
    cls = PiaCancelled if name == "CANCELLED" else PiaError
    raise cls(name, message, status.index)


# --------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------

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


# --------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------

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


def refine(mesh, levels, scheme="LOOP", boundary_rule="SMOOTH", boundary_smooth="ALL", use_creases=True,
           shape_parameter=0.5, face_shape_parameters=None, progress=None, memory_budget=0):
    """The surface of ``mesh`` (a cage) refined ``levels`` times, for the
    schemes Blender cannot show: ``(positions (M, 3) float32, face_sizes
    (K,) int32, face_vertices int32)``.  LOOP: triangles, every vertex at its
    limit position, rows 0..N-1 the limit points of the N control vertices.
    DOO_SABIN: the refined control mesh (its face centroids lie on the
    limit surface).  ``progress(level, share_done) -> bool`` is called at
    the end of each level and about every 0.1 s in between, but for steps
    that are single calls (spia_refine in subdiv_pia.h lists them); True
    cancels (:class:`PiaCancelled`)."""
    lib = _library()
    opts, _keep = _options(scheme=scheme, boundary_smooth=boundary_smooth, use_creases=use_creases,
                           boundary_rule=boundary_rule, shape_parameter=shape_parameter,
                           face_shape_parameters=face_shape_parameters, progress=progress,
                           memory_budget=memory_budget)
    cm = mesh._c()
    status = _Status()
    nv, nf, nc = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int64()
    code = lib.spia_refine_size(ctypes.byref(cm), ctypes.byref(opts), int(levels), ctypes.byref(nv),
                                ctypes.byref(nf), ctypes.byref(nc), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    positions = np.empty((nv.value, 3), np.float32)
    sizes = np.empty(nf.value, np.int32)
    face_vertices = np.empty(nc.value, np.int32)
    code = lib.spia_refine(ctypes.byref(cm), ctypes.byref(opts), int(levels), _ptr(positions, ctypes.c_float),
                           _ptr(sizes, ctypes.c_int32), _ptr(face_vertices, ctypes.c_int32), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return positions, sizes, face_vertices



def subdivide(mesh, levels=1, boundary_smooth="ALL", use_creases=True, quality=3, opensubdiv_version=None,
              progress=None, memory_budget=0):
    """The cage ``mesh`` subdivided ``levels`` times (1 to 6) by Catmull-Clark,
    as a :class:`Mesh`: the control mesh of the same limit surface, all
    quads, with every edge and its crease and every vertex's crease (the
    cage's sharpness one step softer a level, in Blender's terms).  Vertex i
    is the child of the cage's vertex i.  ``progress(level, share_done) ->
    bool`` is called at the end of each level; True cancels."""
    lib = _library()
    opts, _keep = _options(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                           opensubdiv_version=opensubdiv_version, progress=progress, memory_budget=memory_budget)
    cm = mesh._c()
    status = _Status()
    nv, nf, ne = ctypes.c_int32(), ctypes.c_int32(), ctypes.c_int32()
    code = lib.spia_subdivide_size(ctypes.byref(cm), ctypes.byref(opts), int(levels), ctypes.byref(nv),
                                   ctypes.byref(nf), ctypes.byref(ne), ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    positions = np.empty((nv.value, 3), np.float32)
    face_vertices = np.empty(4 * nf.value, np.int32)
    edges = np.empty((ne.value, 2), np.int32)
    edge_creases = np.empty(ne.value, np.float32)
    vertex_creases = np.empty(nv.value, np.float32)
    code = lib.spia_subdivide(ctypes.byref(cm), ctypes.byref(opts), int(levels), _ptr(positions, ctypes.c_float),
                              _ptr(face_vertices, ctypes.c_int32), _ptr(edges, ctypes.c_int32),
                              _ptr(edge_creases, ctypes.c_float), _ptr(vertex_creases, ctypes.c_float),
                              ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return Mesh(positions, np.full(nf.value, 4, np.int32), face_vertices, edges=edges, edge_creases=edge_creases,
                vertex_creases=vertex_creases)

# --------------------------------------------------------------------------
# USD export
# --------------------------------------------------------------------------

_USD_SCHEMES = {"CATMULL_CLARK": "catmullClark", "LOOP": "loop"}
# OpenSubdiv's VTX_BOUNDARY_EDGE_ONLY / EDGE_AND_CORNER, as Blender's modifier sets them.
_USD_BOUNDARY = {"ALL": "edgeOnly", "PRESERVE_CORNERS": "edgeAndCorner"}
_USD_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_USD_SHARPNESS_INFINITE = np.float32(10.0)  # Sdc::Crease::SHARPNESS_INFINITE, USD's too
_USD_PER_LINE = 8


def _usd_cage(mesh, cage):
    try:
        array = np.asarray(cage)
    except Exception as exc:  # ragged lists and the like
        raise PiaError("INVALID_ARGUMENT", f"cage must be an (N, 3) array of numbers: {exc}") from None
    if array.dtype.kind not in "biuf":
        raise PiaError("INVALID_ARGUMENT", f"cage must be an (N, 3) array of numbers, not of {array.dtype}")
    if array.shape != (mesh.vertex_count, 3):
        raise PiaError("INVALID_ARGUMENT",
                       f"cage must have shape ({mesh.vertex_count}, 3), one point per mesh vertex, not {array.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        points = np.ascontiguousarray(array, dtype=np.float32)
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise PiaError("NONFINITE", f"{len(bad)} cage points are NaN, infinite or beyond float32's range "
                       f"(first: point {bad[0]})", int(bad[0]))
    return points


def sharpness(mesh, scheme="CATMULL_CLARK", use_creases=True, two_edge_rule=True):
    """The sharpness the library hands OpenSubdiv for ``mesh``: ``(pairs (K, 2)
    int32, crease sharpness (K,) float32, vertex sharpness (N,) float32)``.

    Creases c in [0, 1] become c*c*10 (float32); face edges below 1e-6 are
    left out and an edge listed more than once takes its largest; pairs are
    each creased face edge's (smaller, larger) vertex index, sorted.  With
    Catmull-Clark, Blender's rules: the ends of edges in no face are
    infinitely sharp (10) and, with ``two_edge_rule``, a vertex with exactly
    two face edges gets the smaller of their sharpnesses added to its own,
    capped at 10."""
    lib = _library()
    opts, _keep = _options(scheme=scheme, use_creases=use_creases)
    cm = mesh._c()
    status = _Status()
    flags = 0 if two_edge_rule else 1
    count = ctypes.c_int32(0)
    code = lib.spia_sharpness(ctypes.byref(cm), ctypes.byref(opts), flags, ctypes.byref(count), None, None, None,
                              ctypes.byref(status))
    if code < 0:
        _raise(code, status)
    pairs = np.zeros((count.value, 2), np.int32)
    creases = np.zeros(count.value, np.float32)
    vertices = np.zeros(mesh.vertex_count, np.float32)
    code = lib.spia_sharpness(ctypes.byref(cm), ctypes.byref(opts), flags, ctypes.byref(count),
                              _ptr(pairs, ctypes.c_int32), _ptr(creases, ctypes.c_float),
                              _ptr(vertices, ctypes.c_float), ctypes.byref(status))
    if code < 0:
        _raise(code, status)
    return pairs, creases, vertices


def _usd_sharpness(mesh, scheme, use_creases, two_edge_rule=True):
    """(crease pairs (K, 2), their sharpness (K,), corner vertices (C,), their
    sharpness (C,)): the library's own (:func:`sharpness`)."""
    pairs, creases, vertices = sharpness(mesh, scheme=scheme, use_creases=use_creases, two_edge_rule=two_edge_rule)
    corners = np.flatnonzero(vertices > 0)
    return pairs, creases, corners, vertices[corners]


def _usd_loose_points(mesh, points):
    """points with the vertices that no face uses where Blender's modifier
    shows them: one between exactly two loose edges at (prev + 4 V + next)
    / 6 of the cage (as the library's limit stencils have it), any other at
    its own position.  USD meshes have no loose edges to smooth them."""
    if mesh.edges is None or not len(mesh.edges):
        return points
    n = mesh.vertex_count
    used = np.zeros(n, bool)
    used[mesh.face_vertices] = True
    ends, others = mesh.edges.ravel(), mesh.edges[:, ::-1].ravel()
    loose = ~used[ends]
    degree = np.bincount(ends[loose], minlength=n)
    chosen = loose & (degree[ends] == 2)
    if not chosen.any():
        return points
    order = np.argsort(ends[chosen], kind="stable")
    vertices, neighbours = ends[chosen][order][0::2], others[chosen][order].reshape(-1, 2)
    cage = points.astype(np.float64)
    out = points.copy()
    out[vertices] = ((cage[neighbours[:, 0]] + 4.0 * cage[vertices] + cage[neighbours[:, 1]]) / 6.0).astype(np.float32)
    return out


def _usd_floats(values):
    """float32 values as decimals that give the same float32 back, whether a
    reader parses them as float or (as USD's text reader does) as double
    and then rounds to float: numpy's shortest float32 form, checked
    through double, else the double's own shortest form (exact)."""
    x = np.ascontiguousarray(values, np.float32).ravel()
    text = [str(v) for v in x]
    if not text:
        return text
    back = np.array(text).astype(np.float64).astype(np.float32)
    for i in np.flatnonzero(back.view(np.uint32) != x.view(np.uint32)).tolist():
        text[i] = repr(float(x[i]))
    return text


def _usd_array(kind, name, items, indent="    "):
    if not len(items):
        return f"{indent}{kind} {name} = []\n"
    lines = [", ".join(items[i:i + _USD_PER_LINE]) for i in range(0, len(items), _USD_PER_LINE)]
    if len(lines) == 1:
        return f"{indent}{kind} {name} = [{lines[0]}]\n"
    body = (",\n" + indent + "    ").join(lines)
    return f"{indent}{kind} {name} = [\n{indent}    {body}\n{indent}]\n"


def _usd_tuples(points):
    xyz = _usd_floats(points)
    return ["(%s, %s, %s)" % tuple(xyz[i:i + 3]) for i in range(0, len(xyz), 3)]


def usd_text(mesh, cage=None, *, scheme="CATMULL_CLARK", boundary_smooth="ALL", boundary_rule="SMOOTH",
             use_creases=True, name="cage", up_axis="Z", meters_per_unit=1.0, two_edge_rule=True):
    """The USDA text of a layer with one subdivision ``Mesh`` prim: the
    topology and creases of ``mesh`` (a :class:`Mesh`), the points of
    ``cage`` ((N, 3), default: the mesh's own positions), float32 exactly
    (points no face uses: see :func:`write_usd`)."""
    if not isinstance(mesh, Mesh):
        raise PiaError("INVALID_ARGUMENT", f"mesh must be a spia.Mesh, not {type(mesh).__name__}")
    _enum(scheme, SCHEMES, "scheme")
    _enum(boundary_smooth, BOUNDARY_SMOOTH, "boundary_smooth")
    _enum(boundary_rule, BOUNDARY_RULES, "boundary_rule")
    if scheme == "DOO_SABIN":
        raise PiaError("INVALID_ARGUMENT", "USD has no Doo-Sabin subdivision scheme (only catmullClark, loop and "
                       "bilinear): a Doo-Sabin cage cannot be written as a USD subdivision mesh")
    if scheme == "LOOP" and boundary_rule == "HOPPE":
        raise PiaError("INVALID_ARGUMENT", "USD's loop scheme follows OpenSubdiv's boundary rules "
                       "(boundary_rule 'SMOOTH'); a cage made for boundary_rule 'HOPPE' would not interpolate there")
    if not (isinstance(name, str) and _USD_NAME.match(name)):
        raise PiaError("INVALID_ARGUMENT", f"name must be a USD prim name (letters, digits and _, not starting "
                       f"with a digit), not {name!r}")
    if up_axis not in ("Y", "Z"):
        raise PiaError("INVALID_ARGUMENT", f"up_axis must be 'Y' or 'Z', not {up_axis!r}")
    try:
        unit = float(meters_per_unit)
    except (TypeError, ValueError):
        unit = float("nan")
    if not (unit > 0 and np.isfinite(unit)):
        raise PiaError("INVALID_ARGUMENT", f"meters_per_unit must be a positive number, not {meters_per_unit!r}")
    validate(mesh)  # the library refuses what it would refuse to subdivide
    points = _usd_cage(mesh, mesh.positions if cage is None else cage)
    if scheme == "LOOP":
        other = np.flatnonzero(mesh.face_sizes != 3)
        if len(other):
            raise PiaError("FACE_SIZE", f"USD's loop scheme takes triangles only; {len(other)} faces are not "
                           f"(first: face {other[0]})", int(other[0]))
    if scheme == "CATMULL_CLARK":
        points = _usd_loose_points(mesh, points)
    pairs, edge_sharpness, corners, corner_sharpness = _usd_sharpness(
        mesh, scheme="CATMULL_CLARK" if scheme == "CATMULL_CLARK" else "LOOP", use_creases=bool(use_creases),
        two_edge_rule=bool(two_edge_rule))

    out = ["#usda 1.0\n(\n",
           '    defaultPrim = "%s"\n' % name,
           "    metersPerUnit = %s\n" % repr(unit),
           '    upAxis = "%s"\n' % up_axis,
           ")\n\n",
           'def Mesh "%s"\n{\n' % name]
    out.append(_usd_array("float3[]", "extent", _usd_tuples(np.stack([points.min(axis=0), points.max(axis=0)]))))
    out.append(_usd_array("int[]", "faceVertexCounts", [str(v) for v in mesh.face_sizes.tolist()]))
    out.append(_usd_array("int[]", "faceVertexIndices", [str(v) for v in mesh.face_vertices.tolist()]))
    out.append(_usd_array("point3f[]", "points", _usd_tuples(points)))
    out.append('    uniform token subdivisionScheme = "%s"\n' % _USD_SCHEMES[scheme])
    out.append('    token interpolateBoundary = "%s"\n' % _USD_BOUNDARY[boundary_smooth])
    out.append('    token triangleSubdivisionRule = "catmullClark"\n')
    out.append('    token faceVaryingLinearInterpolation = "all"\n')
    out.append('    uniform token orientation = "rightHanded"\n')
    if len(pairs):
        out.append(_usd_array("int[]", "creaseIndices", [str(v) for v in pairs.ravel().tolist()]))
        out.append(_usd_array("int[]", "creaseLengths", ["2"] * len(pairs)))
        out.append(_usd_array("float[]", "creaseSharpnesses", _usd_floats(edge_sharpness)))
    if len(corners):
        out.append(_usd_array("int[]", "cornerIndices", [str(v) for v in corners.tolist()]))
        out.append(_usd_array("float[]", "cornerSharpnesses", _usd_floats(corner_sharpness)))
    out.append("}\n")
    return "".join(out)


def write_usd(path, mesh, cage=None, *, scheme="CATMULL_CLARK", boundary_smooth="ALL", boundary_rule="SMOOTH",
              use_creases=True, name="cage", up_axis="Z", meters_per_unit=1.0, two_edge_rule=True):
    """Writes a cage to ``path`` as a USDA layer (text: .usda, or .usd,
    which USD reads as text too) with one subdivision ``Mesh`` prim,
    ``name``, its default prim.  Returns the path.

    ``mesh`` (a :class:`Mesh`) gives the faces and creases, ``cage`` the
    points (default: the mesh's positions); scheme, boundary_smooth,
    boundary_rule and use_creases as given to :func:`interpolate`.
    Catmull-Clark is written as Blender's modifier builds it for
    OpenSubdiv: boundary_smooth 'ALL' / 'PRESERVE_CORNERS' as
    interpolateBoundary "edgeOnly" / "edgeAndCorner", creases c as
    sharpness c*c*10, and Blender's own rules made explicit as corner
    sharpness: the end points of loose edges (which USD meshes do not have)
    are infinitely sharp (10, with use_creases False too, as in Blender),
    and a vertex with exactly two face edges gets the smaller of their
    sharpnesses added (capped at 10).  A point that no face uses is
    written where Blender's modifier shows it: the cage's point, but for
    one between exactly two loose edges, (prev + 4 V + next) / 6.  Loop
    (triangles only) is USD's "loop", with OpenSubdiv's rules.  Doo-Sabin,
    and Loop with boundary_rule 'HOPPE', have no USD counterpart: PiaError.

    Blender's own USD import (option ``import_subdiv``, from 5.0
    ``import_subdivision``) reads, from 4.4 on, the creases back as
    c = sqrt(sharpness / 10) and then applies the two-edge rule itself, once
    more: where a vertex has two face edges whose smaller sharpness is
    between 0 and 10, its surface differs there.  ``two_edge_rule=False``
    leaves the rule to the reader: a file for Blender alone.  Blender 4.2
    and 4.3 read neither creases nor interpolateBoundary, and no Blender
    gives a "loop" mesh a modifier.  No USD attribute holds the modifier's
    ``quality``: set it on the imported modifier.
    """
    text = usd_text(mesh, cage, scheme=scheme, boundary_smooth=boundary_smooth, boundary_rule=boundary_rule,
                    use_creases=use_creases, name=name, up_axis=up_axis, meters_per_unit=meters_per_unit,
                    two_edge_rule=two_edge_rule)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return path


# --------------------------------------------------------------------------
# Surface samples, scans and fitting
# --------------------------------------------------------------------------

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
    scan_before: FitDistances = None
    scan_after: FitDistances = None
    scan_distances: np.ndarray = field(default=None, repr=False)  # per scan vertex, relative, -1 unused

    def summary(self):
        b, a = self.before, self.after
        return (f"{self.mode.lower()} fit, {self.rounds} rounds: mean distance {a.mean:.3g} (was {b.mean:.3g}), "
                f"95th percentile {a.p95:.3g} (was {b.p95:.3g}), max {a.max:.3g} of the scan's diagonal")


def fit(cage, scan, mode="SURFACE", samples_per_edge=4, cutoff=0.02, smoothing=1e-5, point_weight=1e-3,
        max_rounds=16, round_tolerance=0.01, solver_iterations=20, robust_scale=6.0, slide_weight=0.0, allow_folds=False,
        hard_cutoff=False, measure_scan=True, scan_pull=False, free_rims=False, **options):
    """Moves the vertices of ``cage`` (a :class:`Mesh`) so that its limit
    surface lies on ``scan`` (a :class:`Scan`).  mode 'SURFACE' fits the
    whole surface (Catmull-Clark); 'VERTICES' interpolates the closest scan
    points of the cage's limit points (any scheme).  ``options`` are those of
    :func:`interpolate` (scheme, quality, creases, solver, progress, ...).
    ``robust_scale``: the robust kernel's scale as a multiple of the median
    distance; ``slide_weight``: how much samples are held back from sliding
    along the scan within a round; ``allow_folds``: no fold guard; ``hard_cutoff``: the cut-off's
    0/1 weights without the kernel; ``measure_scan``: also measure the
    scan's vertices against the surface (``report.scan_before/after``);
    ``scan_pull``: the scan's vertices pull the surface too (SPIA_FIT_SCAN_PULL);
    ``free_rims``: the cage's rims (faces with a boundary vertex) are not
    held smoother than the rest (SPIA_FIT_FREE_RIMS).
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
    fo.flags = ((FIT_ALLOW_FOLDS if allow_folds else 0) | (FIT_HARD_CUTOFF if hard_cutoff else 0)
                | (0 if measure_scan else FIT_NO_SCAN_DISTANCES) | (FIT_SCAN_PULL if scan_pull else 0)
                | (FIT_FREE_RIMS if free_rims else 0))
    if fo.max_rounds < 1 or fo.solver_iterations < 1:
        raise PiaError("INVALID_ARGUMENT", "max_rounds and solver_iterations must be at least 1")
    out = np.empty_like(cage.positions)
    vertex_distances = np.zeros(cage.vertex_count, np.float32)
    history = np.zeros(fo.max_rounds + 1, np.float64)
    per_scan = np.full(max(scan.vertex_count, 1), -1.0, np.float32)
    rep = _FitReport(vertex_distances=_ptr(vertex_distances, ctypes.c_float),
                     history=_ptr(history, ctypes.c_double), history_capacity=len(history),
                     scan_distances=_ptr(per_scan, ctypes.c_float))
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
        scan_before=dist(rep.scan_before), scan_after=dist(rep.scan_after),
        scan_distances=per_scan[: scan.vertex_count] if rep.scan_point_count else None)



def flat_positions(mesh, boundary_smooth="ALL", use_creases=True, quality=3, opensubdiv_version=None, threads=0,
                   progress=None, memory_budget=0):
    """Positions (N, 3) float32 for the vertices of a quad mesh whose faces,
    drawn flat (a Multires modifier's finest level), lie closest to its
    Catmull-Clark limit surface (spia_flat_positions)."""
    lib = _library()
    opts, _keep = _options(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                           opensubdiv_version=opensubdiv_version, threads=threads, progress=progress,
                           memory_budget=memory_budget)
    cm = mesh._c()
    out = np.empty_like(mesh.positions)
    status = _Status()
    code = lib.spia_flat_positions(ctypes.byref(cm), ctypes.byref(opts), _ptr(out, ctypes.c_float),
                                   ctypes.byref(status))
    if code != 0:
        _raise(code, status)
    return out

@dataclass
class DetailResult:
    """What :func:`fit_detail` made: the finest level's control mesh, the
    positions of its vertices as a Multires modifier's finest level shows
    them (flat faces straddling its limit surface), and each level's fit."""
    levels: int
    mesh: Mesh                  # the finest level's control mesh, fitted (mesh.positions)
    points: np.ndarray = field(repr=False)   # (N, 3) float32: the finest level's vertices, drawn flat
    reports: list = field(default_factory=list)  # a FitReport per level, coarse to fine

    @property
    def report(self):
        """The finest level's fit."""
        return self.reports[-1]


def detail_samples(samples_per_edge, level):
    """Samples per ptex edge for detail level ``level``: the base's count
    halved a level (each level's faces are a quarter of the last's), down to
    two, the fewest with which the fold guard sees a sample's neighbours."""
    return max(2, int(samples_per_edge) >> int(level))


# The peak of fit_detail is the fit of its level with the most samples
# (the finest, unless halving samples_per_edge drops a remainder): the
# samples' stencils, closest points and normals, the fold guard's and the
# scan's pull's buffers, the level itself, and the scan side's hierarchy.
# Measured on the bunny's cage on two threads, the peak resident size over
# the call: 0.25e9, 0.41e9, 1.61e9 and 6.32e9 bytes at 2 to 5 levels
# (0.18M to 11.5M samples): 547 bytes a sample from 4 to 5 levels, and up
# to 0.15e9 bytes besides.  The estimate keeps a tenth or more over both.
DETAIL_BYTES_PER_SAMPLE = 600
DETAIL_BYTES_FIXED = 256 << 20


def detail_memory_estimate(cage, levels, samples_per_edge=4):
    """Bytes :func:`fit_detail` needs at its peak for ``cage`` at
    ``levels``, and the finest level's face count, as (bytes, faces).
    ``cage``: a :class:`Mesh`, or its number of face corners (the sum of
    its face sizes).  Each level turns an n-sided face into n quads (a quad
    into 4), each level's fit takes DETAIL_BYTES_PER_SAMPLE per sample
    (:func:`detail_samples` squared per face), and the level with the most
    samples sets the peak, with DETAIL_BYTES_FIXED besides: about 2.4 KB
    per finest face at the default samples.  fit_detail itself does not
    refuse: a script checks this against the memory it has."""
    levels = int(levels)
    if levels <= 0:
        return 0, 0
    corners = int(np.sum(np.asarray(cage.face_sizes, np.int64))) if hasattr(cage, "face_sizes") else int(cage)
    samples = max(corners * 4 ** (level - 1) * detail_samples(samples_per_edge, level) ** 2
                  for level in range(1, levels + 1))
    return DETAIL_BYTES_FIXED + DETAIL_BYTES_PER_SAMPLE * samples, corners * 4 ** (levels - 1)


def check_detail_memory(cage, levels, samples_per_edge=4, memory_budget=0):
    """Raises :class:`PiaError` OUT_OF_MEMORY, naming the levels that fit,
    when ``levels`` detail levels on ``cage`` (a :class:`Mesh` or its corner
    count) would need more than ``memory_budget`` bytes (0: what
    :func:`available_memory` reports; negative: no check)."""
    budget = int(memory_budget)
    if budget == 0:
        budget = available_memory() or -1
    if budget < 0:
        return
    need, faces = detail_memory_estimate(cage, levels, samples_per_edge)
    if need <= budget:
        return
    fit = max((k for k in range(levels) if detail_memory_estimate(cage, k, samples_per_edge)[0] <= budget), default=0)
    where = "the memory budget of" if memory_budget else "the"
    raise PiaError("OUT_OF_MEMORY", "%d detail levels (%.1fM faces at the finest) need about %.2f GB, more than "
                   "%s %.2f GB of memory%s: %s" % (
                       levels, faces / 1e6, need / 2.0 ** 30, where, budget / 2.0 ** 30,
                       "" if memory_budget else " available",
                       "at most %d level%s fit" % (fit, "" if fit == 1 else "s") if fit else "not one level fits"))


# Detail levels start on the scan already: they are held firmer than a
# first fit (fairness, and samples held back from sliding past one another),
# which on the bunny's raw scan at 3 levels turns 0.09% of the finest faces
# over against the starting cage instead of 1.1%, as close to the scan.
DETAIL_SMOOTHING = 1e-3
DETAIL_SLIDE_WEIGHT = 0.1
# And they need fewer rounds and steps: 3 rounds of 5 conjugate-gradient
# steps a level left the bunny's, armadillo's and Chinese dragon's finest
# levels within 2% of 16 rounds of 20 steps (closer, for the bunny), in less
# than half the time.
DETAIL_ROUNDS = 3
DETAIL_SOLVER_ITERATIONS = 5
# The robust kernel's scale is a multiple of the median distance, and a
# detail level starts with a median a fraction of the base fit's: at the
# base's multiple (6) the kernel took the armadillo's claws, scan just
# beyond the base surface, for outliers.  At 15 the scan's mean
# distance from the finest level falls 3% (elephant) to 26% (armadillo) on
# bench_detail.py's five cases, and the folds stay at most 0.04% on the covered
# scans; at 30 the armadillo's folds tripled to 0.08%.
DETAIL_ROBUST_SCALE = 15.0


def fit_detail(cage, scan, levels, samples_per_edge=4, progress=None, boundary_smooth="ALL", use_creases=True,
               quality=3, opensubdiv_version=None, threads=0, measure_scan=True, smoothing=DETAIL_SMOOTHING,
               slide_weight=DETAIL_SLIDE_WEIGHT, scan_pull=True, free_rims=True, max_rounds=DETAIL_ROUNDS,
               solver_iterations=DETAIL_SOLVER_ITERATIONS, robust_scale=DETAIL_ROBUST_SCALE, memory_budget=0,
               **fit_options):
    """Detail levels on a cage whose limit surface lies on ``scan`` (usually
    the result of :func:`fit`): the cage subdivided one level at a time
    (:func:`subdivide`), and each level fitted to the scan as a cage of its
    own (:func:`fit`, with its guards: the fairness term holds each level to
    the level above where the scan says nothing, so holes are spanned
    smoothly; folds and outliers do not pull; with ``scan_pull`` the scan's
    vertices pull each level too, so that it meets the scan from both
    sides; with ``free_rims`` the cage's rims are not held smoother, as the
    fit of a cage not yet on the scan holds them).  Coarse levels take the
    broad shape, fine levels the detail.  The finest level's vertices are
    then placed so that its faces, drawn flat as Multires draws them,
    straddle the fitted limit surface (:func:`flat_positions`).
    ``levels``: 1 to 6.  Each level's samples per edge:
    :func:`detail_samples`.  ``progress(level, round, mean) -> bool``
    follows each level's fit; True cancels (:class:`PiaCancelled`).
    ``fit_options``: those of :func:`fit` (cutoff, ...); ``smoothing``,
    ``slide_weight``, ``max_rounds``, ``solver_iterations`` and
    ``robust_scale`` default to DETAIL_SMOOTHING, DETAIL_SLIDE_WEIGHT,
    DETAIL_ROUNDS, DETAIL_SOLVER_ITERATIONS and DETAIL_ROBUST_SCALE.
    The finest level's vertices are numbered as :func:`subdivide` applied
    one level at a time numbers them.  ``memory_budget`` (bytes; 0: what
    the machine has available, negative: no check): the levels are refused
    before the first is made when :func:`detail_memory_estimate` says they
    would need more (:func:`check_detail_memory`).  A level's report has status
    'MAX_ITERATIONS' when its rounds were all used (the defaults' few rounds
    usually are): the level is written all the same.  Returns a
    :class:`DetailResult`."""
    levels = int(levels)
    if not 1 <= levels <= 6:
        raise PiaError("INVALID_ARGUMENT", f"levels must be 1 to 6, not {levels!r}")
    check_detail_memory(cage, levels, samples_per_edge, memory_budget)
    surface = dict(boundary_smooth=boundary_smooth, use_creases=use_creases, quality=quality,
                   opensubdiv_version=opensubdiv_version, memory_budget=memory_budget)
    current = cage
    reports = []
    for level in range(1, levels + 1):
        tick = None if progress is None else (lambda _l, _s, level=level: progress(level, 0, 0.0))
        refined = subdivide(current, 1, progress=tick, **surface)
        follow = None if progress is None else (lambda it, value, level=level: progress(level, it, value))
        positions, report = fit(refined, scan, samples_per_edge=detail_samples(samples_per_edge, level),
                                measure_scan=measure_scan and level == levels, progress=follow, threads=threads,
                                smoothing=smoothing, slide_weight=slide_weight, scan_pull=scan_pull,
                                free_rims=free_rims, max_rounds=max_rounds, solver_iterations=solver_iterations,
                                robust_scale=robust_scale, **surface, **fit_options)
        reports.append(report)
        current = Mesh(positions, refined.face_sizes, refined.face_vertices, edges=refined.edges,
                       edge_creases=refined.edge_creases, vertex_creases=refined.vertex_creases)
    points = flat_positions(current, threads=threads, **surface)
    return DetailResult(levels=levels, mesh=current, points=points, reports=reports)
