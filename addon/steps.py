# SPDX-License-Identifier: GPL-3.0-or-later
"""interpolate and refresh_limit, each as a generator of steps: Blender's
data is read and written in the generator, the library's work is yielded
as functions that touch nothing of Blender's.  run_steps drives them on
this thread (interpolate, refresh_limit); jobs.py on another.
"""

import bpy

from . import live as live_module
from . import native
from .detail import apply_detail_steps, fit_detail_work, store_detail
from .compute import (check_source, cleanup_hint, find_target, limit_work, prepare_cage, require_library,
                      scan_work)
from .mesh_io import cleaned_copy, native_mesh, non_triangle_count, triangulated_copy
from .objects import (DISTANCE_ATTRIBUTE, COLOR_ATTRIBUTE, build_object, discard_object, heat_colors,
                      limit_cage_of, paint_scan, set_limit_object, store_cleanup, stored_settings,
                      write_heat_map)
from .settings import LIMIT_SCHEMES, LIVE_CLEANUP_MESSAGE, check_detail_memory, check_settings, settings_from_modifier


def interpolate(obj, *, context=None, name=None, progress=None, live=False, **settings):
    """Make an interpolating cage object for the mesh object obj.

    Settings (keywords, defaults in DEFAULT_SETTINGS; names as the modifier's):
    scheme ('CATMULL_CLARK', 'LOOP' or 'DOO_SABIN'), levels, render_levels, quality,
    boundary_smooth, use_creases, method, tolerance (relative to the
    bounding-box diagonal), max_iterations; for Loop also boundary_rule
    ('SMOOTH' or 'HOPPE') and triangulate (use a triangulated copy of a mesh
    that has quads or n-gons); for Doo-Sabin (closed meshes) shape_parameter
    in (0, 1) and shape_attribute (a float FACE attribute whose per-face
    values replace shape_parameter where the mesh has it); for Catmull-Clark
    opensubdiv_version (e.g. '3.7.0'; empty: this Blender's), the OpenSubdiv
    whose rules the modifier that shows the cage follows: Blender 5.1 and
    later (3.7.0) evaluate some non-manifold vertices differently from
    earlier Blenders, so a cage is exact in the Blenders of its version.
    Settings not given are taken from obj's
    Subdivision Surface modifier if it has one, else the defaults.

    cleanup=True interpolates a cleaned copy of obj's mesh (cleaned_copy,
    cleanup.clean): vertices closer than cleanup_distance x bounding-box
    diagonal merged, repeated corners dissolved, degenerate, zero-area and
    loose geometry removed, faces turned to one orientation per part. The
    new object has the cleaned topology; what was cleaned is in its custom
    properties pia_cleanup_<count> (format_cleanup says it in words).

    Loop: the cage has no modifier; its child ``<cage>_limit`` (find it
    with find_limit_object) holds the Loop limit surface refined `levels`
    times, whose first vertices are the limit points of the cage vertices.
    Doo-Sabin: likewise, the child holds the cage refined `levels` times (a
    control mesh whose face centroids lie on the limit surface).

    Fitting to a scan: target (a mesh object or its name; its evaluated
    mesh, read in obj's object space) fits the cage to that surface instead
    of interpolating obj's vertices: fit 'SURFACE' (Catmull-Clark: the whole
    limit surface, least squares over fit_samples**2 samples per face) or
    'VERTICES' (each control vertex's limit point moves to its closest point
    on the target; any scheme). fit_cutoff (relative to the target's
    bounding-box diagonal): samples farther away do not pull (holes);
    fit_smoothing: fairness weight. fit_detail_levels (Surface fit, 0 to 6)
    gives the new object a Multires modifier with that many levels, fitted
    to the target level by level (native.fit_detail), in place of its
    Subdivision Surface modifier; its finest level lies on the target, the
    heat maps (pia_distance, and the scan's with fit_paint_scan) are that
    level's, and pia_fit_detail_* hold its figures. The report is then a native.FitReport
    (before/after distances relative to the target's diagonal), and the new
    object has the point attributes pia_distance (per vertex, relative) and
    pia_distance_color (heat map, the active colour attribute).
    fit_paint_scan=True also writes each scan vertex's distance to the
    fitted surface onto the target's mesh (paint_scan: pia_scan_distance and
    its heat map pia_scan_distance_color), which changes the target in
    nothing else; pia_fit_scan_painted on the new object says whether it
    could (not through modifiers that change the scan's vertices, nor in
    Edit Mode), pia_fit_scan_not_painted why not.

    progress(iteration, relative_error) -> bool: return True to cancel
    (for a Surface fit: progress(round, mean relative distance)); while a
    Loop or Doo-Sabin preview is refined, it is called again with the
    solve's last figures about every 0.1 s.

    live=True turns the new cage's Live switch on (live.set_live): every
    later change of obj's vertex positions solves the cage again, in place.

    Returns (new_object, report); report.converged is False when the tolerance
    was not reached (the object is made anyway). Raises ValueError or
    native.PiaError on bad input, RuntimeError if the library is missing;
    nothing is created then and obj is never changed.
    """
    return run_steps(interpolate_steps(obj, context=context, name=name, progress=progress, live=live, **settings))


def run_steps(steps):
    """Drives a generator of interpolate_steps' kind on this thread: each
    function it yields is called at once and its result (or exception) sent
    back; returns what the generator returns."""
    try:
        work = next(steps)
        while True:
            try:
                result = work()
            except BaseException as error:  # into the steps, which clean up and re-raise
                work = steps.throw(error)
            else:
                work = steps.send(result)
    except StopIteration as stop:
        return stop.value


def interpolate_steps(obj, *, context=None, name=None, progress=None, live=False, **settings):
    """interpolate as a generator: Blender's data is read and written in the
    generator itself; the library's work (building the scan, solving or
    fitting: all of the time that grows with the mesh) is yielded as
    functions that touch nothing of Blender's, whose results (or exceptions)
    the driver sends back.  run_steps calls them at once (interpolate);
    InterpolateJob calls them on another thread so that Blender's window
    stays live and Esc can cancel.  Returns (new_object, report)."""
    check_source(obj)
    require_library()
    if obj.mode == 'EDIT':  # edits live in the edit-mesh until synced
        obj.update_from_editmode()
        check_source(obj)
    merged = settings_from_modifier(obj)
    merged.update(settings)
    s = check_settings(merged)
    if live and s["cleanup"]:
        raise ValueError(LIVE_CLEANUP_MESSAGE % obj.name)
    if live and s["fit_detail_levels"]:
        raise ValueError("'%s': Live solves the cage again on each edit, which would leave its detail "
                         "levels behind: set the detail levels to 0 for a live cage" % obj.name)
    # A job's progress takes the names of the stages (detail levels).
    begin = getattr(progress, "begin", None)
    loop = s["scheme"] == 'LOOP'
    separate_limit = s["scheme"] in LIMIT_SCHEMES
    target = find_target(obj, s)
    if target is not None:
        check_detail_memory(len(obj.data.loops), s)
    refining = None
    if progress is not None and separate_limit:
        user, last = progress, [0, 0.0]

        def progress(iteration, value):  # the solve's: remembered for the refinement's calls
            last[:] = iteration, value
            return user(iteration, value)

        def refining(_level, _share):  # the solve's last figures again, so that a cancel is heard
            return user(*last)
    scan = (yield scan_work(target, obj, context, progress)) if target is not None else None
    mesh = None
    made = []  # meshes made here: removed again on failure
    stats = None
    try:
        if s["cleanup"]:
            mesh, stats = cleaned_copy(obj.data, s["cleanup_distance"])
            made.append(mesh)
        data = mesh if mesh is not None else obj.data
        if loop and s["triangulate"] and non_triangle_count(data):
            mesh = triangulated_copy(data)
            made.append(mesh)
            data = mesh
        try:
            run, explain = prepare_cage(obj, s, progress=progress, mesh=mesh, scan=scan)
            try:
                cage, report = yield run
            except native.PiaError as error:
                named = explain(error)
                if named is None:
                    raise
                raise named from None
            limit = (yield limit_work(data, s, cage, progress=refining)) if separate_limit else None
            detail = None
            if scan is not None and s["fit_detail_levels"]:
                detail = yield fit_detail_work(native_mesh(data), cage, scan, s, progress=progress, begin=begin)
        except native.PiaError as error:
            hinted = cleanup_hint(error, data, s)
            if hinted is not None:
                raise hinted from None
            raise
    except BaseException:
        for made_mesh in made:
            try:
                bpy.data.meshes.remove(made_mesh)
            except ReferenceError:  # gone already (an undo while a job worked)
                pass
        raise
    for made_mesh in made[:-1]:  # the cleaned copy, once triangulated
        bpy.data.meshes.remove(made_mesh)
    view_layer = (context or bpy.context).view_layer
    selection = (obj.select_get(view_layer=view_layer), view_layer.objects.active) if view_layer else None
    new_obj = build_object(obj, cage, report, s, context=context, name=name, mesh=mesh, limit=limit)
    try:
        if stats is not None:
            store_cleanup(new_obj, stats)
        if detail is not None:
            yield from apply_detail_steps(new_obj, detail, s, context=context, stage=begin)
            store_detail(new_obj, detail)
            # The heat map at the cage's vertices: the finest level's
            # distances there (vertex i of every level is vertex i's child).
            near = detail.report.vertex_distances[:len(new_obj.data.vertices)]
            write_heat_map(new_obj.data, DISTANCE_ATTRIBUTE, COLOR_ATTRIBUTE, near, heat_colors(near))
        if live:
            live_module.set_live(new_obj, True, source=obj)
        if target is not None and s["fit_paint_scan"]:  # last: the one step that writes to another object
            why_not = paint_scan(target, report if detail is None else detail.report)
            new_obj["pia_fit_scan_painted"] = why_not is None
            if why_not is not None:
                new_obj["pia_fit_scan_not_painted"] = "The scan '%s' was not painted: %s" % (target.name, why_not)
    except BaseException:
        if live:
            live_module.set_live(new_obj, False)
        discard_object(new_obj)
        if selection is not None and view_layer.objects.get(obj.name) is not None:  # as before build_object
            obj.select_set(selection[0], view_layer=view_layer)
            view_layer.objects.active = selection[1]
        raise
    return new_obj, report


def refresh_limit(obj, context=None):
    """Recompute the limit surface of a Loop or Doo-Sabin cage from its current mesh.

    obj is the cage (pia_scheme 'LOOP' or 'DOO_SABIN') or its `_limit` child.
    The child's mesh is replaced (the child is made again if it was deleted);
    the settings are those stored on the cage, and a Doo-Sabin cage's shape
    parameters are read again from its own face attribute. Returns the child.
    Raises ValueError if obj is not such a cage, native.PiaError if the
    library refuses the edited cage (nothing is changed then).
    """
    return run_steps(refresh_limit_steps(obj, context=context))


def refresh_limit_steps(obj, *, context=None, progress=None):
    """refresh_limit as a generator of interpolate_steps' kind: the
    refinement is yielded as a function that touches nothing of Blender's
    (RefreshLimitJob runs it on another thread).  progress(level,
    share_done) -> bool as native.refine's.  Returns the child."""
    if obj is None:
        raise ValueError("No active object: select a Loop or Doo-Sabin cage or its limit surface")
    cage = limit_cage_of(obj)
    if cage is None:
        raise ValueError("'%s' is not a Loop cage or a Doo-Sabin cage: make one with "
                         "Make Interpolating Cage (scheme Loop or Doo-Sabin), or select "
                         "its limit surface" % obj.name)
    if cage.type != 'MESH':
        raise ValueError("'%s' is not a mesh object (type %s)" % (cage.name, cage.type))
    if cage.mode == 'EDIT':
        cage.update_from_editmode()
    check_source(cage)
    limit = yield limit_work(cage.data, stored_settings(cage), progress=progress)
    return set_limit_object(cage, limit, context=context)
