# SPDX-License-Identifier: GPL-3.0-or-later
"""The library's work on Blender's data: the cage (interpolation or fit),
the scan and the Loop and Doo-Sabin limit surfaces, each in two halves:
reading Blender's meshes here, and a function for the library's share that
touches nothing of Blender's (a job runs it on another thread).  The
library's errors are given back in the mesh's and the settings' terms.

Reads objects and meshes; writes nothing.
"""

import numpy as np
import bpy

from . import cleanup, native
from .mesh_io import face_shape_parameters, mesh_arrays, native_mesh, non_triangle_count, scan_arrays
from .settings import check_memory, opensubdiv_version_of


def _shape_error(error, values, settings):
    """The library's refusal of shape parameters, with the attribute named."""
    if (values is not None and error.code == 'INVALID_ARGUMENT'
            and "shape parameter" in error.message):
        return type(error)(error.code, "%s (face attribute '%s')"
                           % (error.message, settings["shape_attribute"]), error.index)
    return None


def check_source(obj):
    """Raise ValueError with a user-facing message if obj cannot be used."""
    if obj is None:
        raise ValueError("No active object: select a mesh object")
    if obj.type != 'MESH':
        raise ValueError("'%s' is not a mesh object (type %s)" % (obj.name, obj.type))
    mesh = obj.data
    if len(mesh.vertices) == 0:
        raise ValueError("Mesh '%s' has no vertices" % mesh.name)
    if len(mesh.polygons) == 0:
        raise ValueError("Mesh '%s' has no faces: subdivision needs faces" % mesh.name)


def require_library():
    if not native.available():
        raise RuntimeError("Subdivision PIA library not loaded: %s" % native.load_error())


def find_target(obj, settings):
    """The target object (the scan) named by settings["target"], or None when
    no target is set. ValueError with a user-facing message if it cannot be
    used: not found, not a mesh object, obj itself, or no faces after its
    modifiers."""
    name = settings.get("target") or ""
    if not name:
        return None
    target = bpy.data.objects.get(name)
    if target is None:
        raise ValueError("Target '%s' not found: give the name of the mesh object to fit to (the scan)"
                         % name)
    if target.type != 'MESH':
        raise ValueError("Target '%s' is not a mesh object (type %s): the scan must be a mesh"
                         % (target.name, target.type))
    if obj is not None and target == obj:
        raise ValueError("Target '%s' is the cage itself: pick the scan to fit '%s' to"
                         % (target.name, obj.name))
    return target


def make_scan(target, cage_obj, context=None, progress=None):
    """native.Scan of target's evaluated mesh in cage_obj's object space.
    progress(iteration, relative_error), as interpolate's, is called with
    (0, 0.0) while the scan is read and through the build (seconds for a
    scan of millions of triangles) and once at its end; True cancels
    (native.PiaCancelled)."""
    return scan_work(target, cage_obj, context, progress)()


def scan_work(target, cage_obj, context=None, progress=None):
    """make_scan in two halves: reads the scan here (Blender's data) and
    returns the library's share, a function that builds the native.Scan and
    touches nothing of Blender's (InterpolateJob runs it on another thread)."""
    require_library()
    tick = None if progress is None else (lambda: progress(0, 0.0))
    positions, face_sizes, face_vertices = scan_arrays(target, cage_obj, context, tick=tick)
    building = None if progress is None else (lambda _phase, _fraction: progress(0, 0.0))
    return lambda: native.Scan(native.Mesh(positions, face_sizes, face_vertices), progress=building)


def compute_cage(obj, settings, progress=None, mesh=None, scan=None, measure_scan=True):
    """Run the solver on obj's mesh data (not its modifiers), or on mesh if given.
    With scan (a native.Scan), fit the cage to it instead (native.fit;
    measure_scan=False leaves out the scan-to-surface distances).

    Returns (cage, report): a native.Report, or a native.FitReport for a fit."""
    run, explain = prepare_cage(obj, settings, progress=progress, mesh=mesh, scan=scan, measure_scan=measure_scan)
    try:
        return run()
    except native.PiaError as error:
        named = explain(error)
        if named is None:
            raise
        raise named from None


def prepare_cage(obj, settings, progress=None, mesh=None, scan=None, measure_scan=True):
    """compute_cage in two halves: reads the mesh here (Blender's data) and
    returns (run, explain).  run() calls the library and touches nothing of
    Blender's (InterpolateJob runs it on another thread); explain(error), for
    a native.PiaError that run raised, returns the error to raise instead (in
    the mesh's terms), or None for the error itself."""
    scheme = settings["scheme"]
    require_library()
    data = mesh if mesh is not None else obj.data
    shapes = {}
    values = None
    if scheme == 'DOO_SABIN':
        values = face_shape_parameters(data, settings)
        # Creases are not part of the Doo-Sabin scheme: ignored, as the panel shows.
        shapes = {"shape_parameter": settings["shape_parameter"], "face_shape_parameters": values}
    options = dict(scheme=scheme, boundary_rule=settings["boundary_rule"],
                   boundary_smooth=settings["boundary_smooth"],
                   use_creases=settings["use_creases"] and scheme != 'DOO_SABIN',
                   quality=settings["quality"], method=settings["method"],
                   tolerance=settings["tolerance"], max_iterations=settings["max_iterations"],
                   staged=settings["staged"] and scheme == 'LOOP', progress=progress,
                   opensubdiv_version=opensubdiv_version_of(settings), **shapes)
    cage_mesh = native_mesh(data)
    check_memory(cage_mesh, settings, scan)
    non_triangles = non_triangle_count(data) if scheme == 'LOOP' and not settings["triangulate"] else 0

    def run():
        if scan is not None:
            return native.fit(cage_mesh, scan, mode=settings["fit"],
                              samples_per_edge=settings["fit_samples"], cutoff=settings["fit_cutoff"],
                              smoothing=settings["fit_smoothing"], measure_scan=measure_scan, **options)
        return native.interpolate(cage_mesh, **options)

    def explain(error):
        named = _shape_error(error, values, settings)
        if named is not None:
            return named
        if non_triangles and error.code == 'TOPOLOGY':
            return type(error)(error.code, "%s, or turn on Triangulate to use a triangulated copy"
                               % error.message, error.index)
        return None

    return run, explain


def cleanup_hint(error, mesh, settings):
    """The library's refusal of mesh with a hint that the cleanup setting would
    fix it (and what it would do), or None when cleanup is on or would not help."""
    if settings.get("cleanup") or error.code not in ('DEGENERATE_FACE', 'TOPOLOGY'):
        return None
    if error.code == 'TOPOLOGY' and "triangles" in error.message:
        return None
    try:
        arrays = mesh_arrays(mesh)
        result = cleanup.clean(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                               edges=arrays["edges"],
                               distance=settings.get("cleanup_distance", cleanup.DEFAULT_DISTANCE))
    except ValueError:
        return None
    if not cleanup.changed(result["stats"]):
        return None
    would = cleanup.format_stats(result["stats"], future=True)
    return type(error)(error.code, "%s; the Cleanup setting (cleanup=True, --cleanup) would %s on a "
                       "copy of the mesh" % (error.message, would), error.index)


def limit_arrays(mesh, settings, positions=None):
    """(positions (M,3) float32, face_sizes (K,) int32, face_vertices int32):
    the surface the library shows for a Loop or Doo-Sabin cage mesh, refined
    settings["levels"] times. Loop: triangles, every vertex at its limit
    position. Doo-Sabin: the refined mesh, with the per-face shape parameters
    of the cage mesh (face_shape_parameters) in the first step.

    positions replaces the mesh's vertex positions (the solved cage) if given.
    """
    return limit_work(mesh, settings, positions)()


def limit_work(mesh, settings, positions=None, progress=None):
    """limit_arrays in two halves: reads the mesh here and returns the
    library's share, a function that refines and touches nothing of
    Blender's (InterpolateJob runs it on another thread).  progress(level,
    share_done) -> bool, as native.refine's: True cancels."""
    doo_sabin = settings["scheme"] == 'DOO_SABIN'
    require_library()
    arrays = mesh_arrays(mesh)
    if positions is not None:
        arrays["positions"] = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    cage = native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"],
                       edges=arrays["edges"], edge_creases=arrays["edge_creases"],
                       vertex_creases=arrays["vertex_creases"])
    if not doo_sabin:
        return lambda: native.refine(cage, int(settings["levels"]), scheme='LOOP',
                                     boundary_rule=settings["boundary_rule"],
                                     boundary_smooth=settings["boundary_smooth"],
                                     use_creases=bool(settings["use_creases"]), progress=progress)
    values = face_shape_parameters(mesh, settings)

    def run():
        try:
            return native.refine(cage, int(settings["levels"]), scheme='DOO_SABIN', use_creases=False,
                                 shape_parameter=float(settings["shape_parameter"]),
                                 face_shape_parameters=values, progress=progress)
        except native.PiaError as error:
            named = _shape_error(error, values, settings)
            if named is not None:
                raise named from None
            raise
    return run
