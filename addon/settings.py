# SPDX-License-Identifier: GPL-3.0-or-later
"""The settings of a cage: their defaults, names and ranges, what a source's
Subdivision Surface modifier provides, the OpenSubdiv version whose rules
apply, and the memory the library's stencil table would need.

Touches no object: reads only a modifier's settings and bpy.app.
"""

import os
import sys

import numpy as np
import bpy

from . import cleanup, native

# Names follow the Subdivision Surface modifier where one exists.
DEFAULT_SETTINGS = {
    "scheme": 'CATMULL_CLARK',
    "boundary_rule": 'SMOOTH',
    "triangulate": False,
    "staged": False,
    "levels": 1,  # as a new Subdivision Surface modifier: Levels Viewport 1, Render 2
    "render_levels": 2,
    "quality": 3,
    "boundary_smooth": 'ALL',
    "use_creases": True,
    "method": 'AUTO',
    "tolerance": 1e-6,
    "max_iterations": 1000,
    "shape_parameter": 0.5,
    "shape_attribute": "pia_shape",
    # Fitting to a scan (target empty: interpolate the cage's own vertices).
    "target": "",
    "fit": 'SURFACE',
    "fit_cutoff": 0.02,
    "fit_smoothing": 1e-5,
    "fit_samples": 4,
    # Surface fit: that many Multires levels on the new object, fitted to the
    # scan level by level (0: none).
    "fit_detail_levels": 0,
    # Write each scan vertex's distance to the fitted surface onto the scan.
    "fit_paint_scan": False,
    # Catmull-Clark: the OpenSubdiv version whose rules the modifier follows,
    # e.g. "3.7.0" or (3, 7, 0); empty: this Blender's (bpy.app.opensubdiv).
    "opensubdiv_version": "",
    # Interpolate a cleaned copy of the mesh (cleanup.clean); distance relative to the diagonal.
    "cleanup": False,
    "cleanup_distance": cleanup.DEFAULT_DISTANCE,
}

FIT_MODES = tuple(native.FIT_MODES)
SCHEMES = ('CATMULL_CLARK', 'LOOP', 'DOO_SABIN')
# Schemes Blender's modifier cannot show: a `_limit` child shows the surface.
LIMIT_SCHEMES = ('LOOP', 'DOO_SABIN')
BOUNDARY_SMOOTH = ('ALL', 'PRESERVE_CORNERS')
BOUNDARY_RULES = ('SMOOTH', 'HOPPE')
# The library decides where CG (conjugate gradients) applies: it needs a
# symmetrizable limit matrix (closed meshes) and says so otherwise.
METHODS = tuple(native.METHODS)
LOOP_MAX_LEVELS = 8  # native.refine's limit
MAX_DETAIL_LEVELS = 6  # native.fit_detail's limit
SCHEME_NAMES = {'CATMULL_CLARK': "Catmull-Clark", 'LOOP': "Loop", 'DOO_SABIN': "Doo-Sabin"}

# A live cage follows its source's vertices one to one, which a cleaned copy's are not.
LIVE_CLEANUP_MESSAGE = ("A cage made with cleanup cannot be live: its vertices are those of a cleaned copy "
                        "of '%s', not the source's own; clean the source mesh itself, then make a live cage "
                        "without cleanup")

# Settings that a source Subdivision Surface modifier provides.
MODIFIER_SETTINGS = ("levels", "render_levels", "quality", "boundary_smooth", "use_creases")


def blender_opensubdiv_version():
    """The OpenSubdiv version this Blender evaluates the modifier with, as a
    tuple (bpy.app.opensubdiv.version), or None where it does not say."""
    info = getattr(bpy.app, "opensubdiv", None)
    version = tuple(getattr(info, "version", ()) or ())
    if not version or not any(version):
        return None
    return version


def opensubdiv_version_of(settings):
    """The OpenSubdiv version the settings ask for, as the library takes it
    (major * 10000 + minor * 100 + patch): the setting, else this Blender's."""
    version = settings.get("opensubdiv_version") or blender_opensubdiv_version()
    return native.opensubdiv_version_number(version)


def opensubdiv_version_string(number):
    return "%d.%d.%d" % (number // 10000, number // 100 % 100, number % 100) if number else ""


def find_subsurf(obj):
    """The last Subdivision Surface modifier of obj, or None."""
    if obj is None:
        return None
    found = None
    for mod in obj.modifiers:
        if mod.type == 'SUBSURF':
            found = mod
    return found


def settings_from_modifier(obj):
    """Settings taken from obj's Subdivision Surface modifier (empty dict if none).

    The modifier's use_limit_surface is deliberately ignored: the result is
    always a cage for the limit surface.
    """
    mod = find_subsurf(obj)
    if mod is None:
        return {}
    settings = {name: getattr(mod, name) for name in MODIFIER_SETTINGS}
    if mod.subdivision_type == 'CATMULL_CLARK':
        settings["scheme"] = 'CATMULL_CLARK'
    return settings


def check_settings(settings):
    """Complete settings with defaults and check names and ranges (ValueError)."""
    unknown = set(settings) - set(DEFAULT_SETTINGS)
    if unknown:
        raise ValueError("Unknown setting(s): %s" % ", ".join(sorted(unknown)))
    s = dict(DEFAULT_SETTINGS)
    s.update(settings)
    if s["scheme"] not in SCHEMES:
        raise ValueError("scheme must be one of %s, not %r" % (SCHEMES, s["scheme"]))
    if s["boundary_smooth"] not in BOUNDARY_SMOOTH:
        raise ValueError("boundary_smooth must be one of %s, not %r"
                         % (BOUNDARY_SMOOTH, s["boundary_smooth"]))
    if s["boundary_rule"] not in BOUNDARY_RULES:
        raise ValueError("boundary_rule must be one of %s, not %r"
                         % (BOUNDARY_RULES, s["boundary_rule"]))
    if s["method"] not in METHODS:
        raise ValueError("method must be one of %s, not %r" % (METHODS, s["method"]))
    s["triangulate"] = bool(s["triangulate"])
    s["staged"] = bool(s["staged"])
    s["levels"] = int(s["levels"])
    s["render_levels"] = int(s["render_levels"])
    s["quality"] = int(s["quality"])
    s["max_iterations"] = int(s["max_iterations"])
    s["tolerance"] = float(s["tolerance"])
    s["use_creases"] = bool(s["use_creases"])
    s["cleanup"] = bool(s["cleanup"])
    s["fit_paint_scan"] = bool(s["fit_paint_scan"])
    try:
        s["cleanup_distance"] = float(s["cleanup_distance"])
    except (TypeError, ValueError):
        s["cleanup_distance"] = float("nan")
    if not (s["cleanup_distance"] >= 0.0 and np.isfinite(s["cleanup_distance"])):
        raise ValueError("cleanup_distance must be zero or a positive number (a fraction of the "
                         "bounding-box diagonal), not %r" % (settings.get("cleanup_distance"),))
    if not 0 <= s["levels"] <= 11 or not 0 <= s["render_levels"] <= 11:
        raise ValueError("levels and render_levels must be in 0..11")
    if s["scheme"] in LIMIT_SCHEMES and s["levels"] > LOOP_MAX_LEVELS:
        raise ValueError("levels must be in 0..%d for the %s limit surface, not %d"
                         % (LOOP_MAX_LEVELS, SCHEME_NAMES[s["scheme"]], s["levels"]))
    try:
        s["shape_parameter"] = float(s["shape_parameter"])
    except (TypeError, ValueError):
        raise ValueError("shape_parameter must be a number in (0, 1), not %r"
                         % (s["shape_parameter"],)) from None
    if s["scheme"] == 'DOO_SABIN' and not 0.0 < s["shape_parameter"] < 1.0:
        raise ValueError("shape_parameter must be in (0, 1) (exclusive), not %g"
                         % s["shape_parameter"])
    if not isinstance(s["shape_attribute"], str):
        raise ValueError("shape_attribute must be an attribute name (a string), not %r"
                         % (s["shape_attribute"],))
    if not 1 <= s["quality"] <= 10:
        raise ValueError("quality must be in 1..10, not %d" % s["quality"])
    if s["max_iterations"] < 1:
        raise ValueError("max_iterations must be at least 1")
    if not (s["tolerance"] > 0.0 and np.isfinite(s["tolerance"])):
        raise ValueError("tolerance must be a positive number")
    target = s["target"]
    if target is None:
        target = ""
    elif isinstance(target, bpy.types.Object):
        target = target.name
    if not isinstance(target, str):
        raise ValueError("target must be the name of a mesh object (or the object), not %r" % (target,))
    s["target"] = target
    if s["fit"] not in FIT_MODES:
        raise ValueError("fit must be one of %s, not %r" % (FIT_MODES, s["fit"]))
    s["fit_cutoff"] = float(s["fit_cutoff"])
    s["fit_smoothing"] = float(s["fit_smoothing"])
    s["fit_samples"] = int(s["fit_samples"])
    if not (s["fit_cutoff"] > 0.0 and np.isfinite(s["fit_cutoff"])):
        raise ValueError("fit_cutoff must be a positive number (a fraction of the scan's diagonal)")
    if not (s["fit_smoothing"] >= 0.0 and np.isfinite(s["fit_smoothing"])):
        raise ValueError("fit_smoothing must be zero or a positive number")
    if not 1 <= s["fit_samples"] <= 64:
        raise ValueError("fit_samples must be in 1..64, not %d" % s["fit_samples"])
    s["fit_detail_levels"] = int(s["fit_detail_levels"])
    if not 0 <= s["fit_detail_levels"] <= MAX_DETAIL_LEVELS:
        raise ValueError("fit_detail_levels must be in 0..%d, not %d" % (MAX_DETAIL_LEVELS, s["fit_detail_levels"]))
    version = s["opensubdiv_version"]
    if version is None:
        version = ""
    if isinstance(version, str):
        version = version.strip()
    try:
        native.opensubdiv_version_number(version)
    except native.PiaError:
        raise ValueError("opensubdiv_version must be a version such as '3.7.0' or (3, 7, 0), or empty "
                         "for this Blender's, not %r" % (version,)) from None
    s["opensubdiv_version"] = version
    if target and s["fit"] == 'SURFACE' and s["scheme"] != 'CATMULL_CLARK':
        raise ValueError("The Surface fit works on the Catmull-Clark limit surface only: use "
                         "Fit 'Vertices' for %s" % SCHEME_NAMES[s["scheme"]])
    if s["fit_detail_levels"] and not (target and s["fit"] == 'SURFACE'):
        raise ValueError("Detail levels (fit_detail_levels %d) come with a Surface fit: set a target "
                         "(the scan) and Fit 'Surface', or set the levels to 0" % s["fit_detail_levels"])
    return s


def machine_memory():
    """The memory in bytes the machine can give a computation now, as the
    library tells it (spia_available_memory: what is available, within a
    container's limit and the process's address-space limit), else the
    machine's physical memory, or None where neither can be told."""
    try:
        available = native.available_memory()
    except (AttributeError, OSError, native.PiaError):
        available = None
    if available:
        return available
    try:
        if sys.platform == "win32":
            import ctypes

            class _Status(ctypes.Structure):
                _fields_ = [("length", ctypes.c_uint32), ("load", ctypes.c_uint32),
                            ("total_phys", ctypes.c_uint64), ("avail_phys", ctypes.c_uint64),
                            ("total_page", ctypes.c_uint64), ("avail_page", ctypes.c_uint64),
                            ("total_virtual", ctypes.c_uint64), ("avail_virtual", ctypes.c_uint64),
                            ("avail_extended", ctypes.c_uint64)]
            status = _Status()
            status.length = ctypes.sizeof(_Status)
            if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(status)):
                return int(status.total_phys)
            return None
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


# Bytes per stored weight (a 4-byte column and an 8-byte weight), and how
# much more than the finished table building it takes at its peak.
_BYTES_PER_WEIGHT = 12
_BUILD_FACTOR = 4


def stencil_memory_estimate(face_sizes, vertex_count, settings, scan=None):
    """Bytes the library needs, at its peak, for the stencil table of a mesh
    with these face sizes: a vertex's limit stencil spans the faces around
    it (1 + sum of (size - 2) over them: 9 for a regular quad vertex, 7 for
    a regular triangle one); a surface fit's samples span 16 vertices each."""
    sizes = np.asarray(face_sizes)
    weights = int(vertex_count) + int(np.einsum("i,i->", sizes, np.maximum(sizes - 2, 0), dtype=np.int64))
    rows = int(vertex_count)
    if scan is not None and settings.get("fit") == 'SURFACE':
        k = int(settings.get("fit_samples", 4))
        samples = int(np.sum(np.where(sizes == 4, 1, sizes))) * k * k
        weights += 16 * samples
        rows += samples
    return _BUILD_FACTOR * (_BYTES_PER_WEIGHT * weights + 8 * rows)


def check_detail_memory(corners, settings):
    """Refuses up front detail levels (settings' fit_detail_levels) whose
    fit would need more than the machine's memory, for a cage with this
    many face corners (its loops): before the scan is read or anything is
    fitted.  The scan's and Blender's own memory come on top of the
    estimate."""
    levels = int(settings.get("fit_detail_levels", 0) or 0)
    total = machine_memory() if levels else None
    if not total:
        return
    need, faces = native.detail_memory_estimate(int(corners), levels, int(settings.get("fit_samples", 4)))
    if need > total:
        raise native.PiaError(
            'OUT_OF_MEMORY',
            "%d detail levels would need about %.1f GB (%.1fM faces at the finest level), more than this "
            "machine's %.1f GB of memory; try fewer detail levels" % (levels, need / 2.0 ** 30, faces / 1e6,
                                                                   total / 2.0 ** 30))


def check_memory(mesh, settings, scan=None):
    """Refuses up front a mesh (a native.Mesh) whose stencils would not fit in
    the machine's memory."""
    total = machine_memory()
    if not total:
        return
    need = stencil_memory_estimate(mesh.face_sizes, mesh.vertex_count, settings, scan)
    if need > total:
        raise native.PiaError(
            'OUT_OF_MEMORY',
            "its stencil table would need about %.1f GB (%d vertices, %d faces), more than this "
            "machine's %.1f GB of memory; try a lower quality or a smaller mesh"
            % (need / 2.0 ** 30, mesh.vertex_count, len(mesh.face_sizes), total / 2.0 ** 30))
