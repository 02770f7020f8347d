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

The package's modules, each by what it does (everything is used from
``spia`` itself, as above): ``library`` finds and loads the library and
says why it could not; ``header`` is the ctypes mirror of its C header;
``errors`` holds :class:`PiaError`; ``mesh`` holds :class:`Mesh` and the
settings every call takes; ``interpolation`` the stencil tables, their
solve and :func:`interpolate`; ``refinement`` :func:`refine`,
:func:`subdivide` and :func:`flat_positions`; ``usd`` the USD writer;
``fitting`` :class:`Scan` and :func:`fit`; ``detail_levels``
:func:`fit_detail`.
"""

# The standard modules the loader uses stay reachable through the package
# (the load-error tests fake the platform through spia.sys, spia.platform,
# spia.os and spia.ctypes).
import ctypes  # noqa: F401
import os  # noqa: F401
import platform  # noqa: F401
import re  # noqa: F401
import sys  # noqa: F401
from dataclasses import dataclass, field  # noqa: F401

import numpy as np  # noqa: F401

# The names below are the package's, private ones too: scripts and tests
# reach some of them through it (spia._options, spia._Status, ...).
from . import library  # the loader's state: see __getattr__ below
from .errors import _RESULT_NAMES, _STATUS_OF_RESULT, PiaCancelled, PiaError, _raise
from .header import (_PROGRESS, FIT_ALLOW_FOLDS, FIT_FREE_RIMS, FIT_HARD_CUTOFF, FIT_NO_SCAN_BEFORE,
                     FIT_NO_SCAN_DISTANCES, FIT_SCAN_PULL, _declare, _f32p, _f64p, _FitDistances, _FitOptions, _FitReport, _i32p,
                     _i64p, _Mesh, _Options, _Report, _Status)
from .library import (_MACHINES, _SYSTEM_NAMES, _SYSTEM_OF_PLATFORM, LIBRARY_NAMES, _library,
                      _library_candidates, _manifest, _package_dir, _platform_name, _system, available,
                      available_memory, explain_load_failure, glibc_version, library_name, library_path,
                      load_error, package_info, platform_tag, version)
from .mesh import (BOUNDARY_RULES, BOUNDARY_SMOOTH, METHODS, SCHEMES, SOLVE_FLAGS, Mesh, _as, _enum, _options,
                   _ptr, _solve_flags, opensubdiv_version_number)
from .interpolation import (Report, Stencils, _report, _report_buffers, interpolate, limit_stencils, solve,
                            validate)
from .refinement import flat_positions, refine, subdivide
from .usd import (_USD_BOUNDARY, _USD_NAME, _USD_PER_LINE, _USD_SCHEMES, _USD_SHARPNESS_INFINITE, _usd_array,
                  _usd_cage, _usd_floats, _usd_loose_points, _usd_sharpness, _usd_tuples, sharpness, usd_text,
                  write_usd)
from .fitting import FIT_MODES, FitDistances, FitReport, Scan, _phase_callback, fit, surface_stencils
from .detail_levels import (DETAIL_BYTES_FIXED, DETAIL_BYTES_PER_GRID_POINT, DETAIL_BYTES_PER_SAMPLE,
                            DETAIL_BYTES_PER_SEARCHED_QUAD, DETAIL_FINEST_FROM_LEVEL, DETAIL_FINEST_ROUNDS,
                            DETAIL_ROBUST_SCALE, DETAIL_ROUNDS, MEASURE_GRID_QUADS,
                            DETAIL_SLIDE_WEIGHT, DETAIL_SMOOTHING, DETAIL_SOLVER_ITERATIONS, DetailResult,
                            check_detail_memory, detail_memory_estimate, detail_samples, fit_detail)

__all__ = [
    "Mesh", "Report", "Stencils", "PiaError", "PiaCancelled",
    "available", "load_error", "library_path", "platform_tag", "version", "available_memory", "opensubdiv_version_number", "validate", "limit_stencils", "solve", "interpolate", "refine",
    "subdivide", "flat_positions", "fit", "fit_detail", "detail_samples", "detail_memory_estimate", "check_detail_memory", "DetailResult", "Scan",
    "usd_text", "write_usd", "sharpness",
    "SCHEMES", "BOUNDARY_SMOOTH", "BOUNDARY_RULES", "METHODS", "SOLVE_FLAGS",
]


def __getattr__(name):
    # The loader's state (the library once loaded, its path, why it could
    # not be loaded), read where it is kept; it is set there too
    # (spia.library._lib).
    if name in ("_lib", "_lib_path", "_load_error"):
        return getattr(library, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
