# SPDX-License-Identifier: GPL-3.0-or-later
"""The objects made: the cage object with its modifier and placement, the
`_limit` child of a Loop or Doo-Sabin cage, the custom properties that
store a cage's settings and its solve's or fit's figures, the vertex group
of unreachable vertices and the distance heat maps (on the cage and,
when asked, on the scan).
"""

import numpy as np
import bpy

from . import cleanup, native
from .mesh_io import new_mesh, write_positions
from .settings import DEFAULT_SETTINGS, LIMIT_SCHEMES, find_subsurf, opensubdiv_version_of, opensubdiv_version_string

# The heat map is red at this distance (relative to the scan's diagonal) and beyond.
HEAT_SCALE = 1e-3
DISTANCE_ATTRIBUTE = "pia_distance"
COLOR_ATTRIBUTE = "pia_distance_color"
# On the scan (fit_paint_scan): its vertices' distances to the fitted surface.
SCAN_DISTANCE_ATTRIBUTE = "pia_scan_distance"
SCAN_COLOR_ATTRIBUTE = "pia_scan_distance_color"
# The heat map's colour of scan vertices no face uses (not measured).
UNMEASURED_COLOR = (0.5, 0.5, 0.5, 1.0)

# Custom properties of a Loop or Doo-Sabin cage: what refresh_limit needs to remake its
# limit surface, and what a re-run needs to repeat it.
LIMIT_SUFFIX = "_limit"
LIMIT_MARK = "pia_limit_surface"   # on the child that holds the limit surface
STORED_SETTINGS = ("scheme", "boundary_rule", "boundary_smooth", "use_creases", "triangulate", "staged",
                   "levels", "render_levels", "quality", "method", "tolerance", "max_iterations",
                   "shape_parameter", "shape_attribute", "cleanup", "cleanup_distance")
# What the cleanup did, stored on the cage as pia_cleanup_<name> (cleanup.STAT_NAMES).
CLEANUP_PREFIX = "pia_cleanup_"
# The vertex group of a cage's vertices that no cage can put on their targets
# (their limit points are tied to other vertices'), so that they can be
# selected in Edit Mode; the custom property with their count.
UNREACHABLE_GROUP = "pia_unreachable"
UNREACHABLE_COUNT = "pia_unreachable_count"
REACHABLE_MAX_ERROR = "pia_reachable_max_error"  # max error over the other vertices, while there are any


def store_cleanup(obj, stats):
    """What the cleanup did, as custom properties of the cage."""
    for name in cleanup.STAT_NAMES:
        obj[CLEANUP_PREFIX + name] = int(stats.get(name, 0))


def cleanup_stats(obj):
    """What the cleanup did for the cage obj (a dict), or None if it had no cleanup."""
    if obj is None or not obj.get("pia_cleanup"):
        return None
    return {name: int(obj.get(CLEANUP_PREFIX + name, 0)) for name in cleanup.STAT_NAMES}


def _link_like(source, new_obj, context):
    collections = list(source.users_collection) or [context.scene.collection]
    for collection in collections:
        collection.objects.link(new_obj)
    new_obj.parent = source.parent
    new_obj.parent_type = source.parent_type
    if source.parent_type == 'BONE':
        new_obj.parent_bone = source.parent_bone
    new_obj.matrix_parent_inverse = source.matrix_parent_inverse.copy()
    new_obj.rotation_mode = source.rotation_mode
    new_obj.matrix_basis = source.matrix_basis.copy()
    for i, slot in enumerate(source.material_slots):
        if i < len(new_obj.material_slots):
            new_obj.material_slots[i].link = slot.link
            new_obj.material_slots[i].material = slot.material


def limit_mesh(name, points, face_sizes, face_vertices, materials=()):
    """A new smooth-shaded mesh from limit_arrays' output."""
    mesh = new_mesh(name, points, face_sizes, face_vertices)
    if hasattr(mesh, "shade_smooth"):  # Blender 4.1+
        mesh.shade_smooth()
    else:
        mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
    for material in materials:
        mesh.materials.append(material)
    mesh.update()
    return mesh


def find_limit_object(cage):
    """The child of cage that holds its limit surface, or None."""
    if cage is None:
        return None
    for child in cage.children:
        if child.get(LIMIT_MARK):
            return child
    return None


def limit_cage_of(obj):
    """The Loop or Doo-Sabin cage for obj: obj itself, or the cage whose limit
    surface obj is (None if there is none)."""
    if obj is None:
        return None
    if obj.get("pia_scheme") in LIMIT_SCHEMES:
        return obj
    if (obj.get(LIMIT_MARK) and obj.parent is not None
            and obj.parent.get("pia_scheme") in LIMIT_SCHEMES):
        return obj.parent
    return None


# The name from when Loop was the only scheme with a `_limit` child.
loop_cage_of = limit_cage_of


def stored_settings(cage):
    """The settings stored on a cage by build_object (defaults for missing ones)."""
    s = dict(DEFAULT_SETTINGS)
    for name in STORED_SETTINGS:
        key = "pia_" + name
        if key in cage:
            value = cage[key]
            s[name] = bool(value) if isinstance(DEFAULT_SETTINGS[name], bool) else value
    if "pia_requested_method" in cage:  # pia_method is the method AUTO chose
        s["method"] = cage["pia_requested_method"]
    return s


def set_limit_object(cage, limit, context=None):
    """Put the limit surface (limit_arrays' output) on cage's `_limit` child,
    creating the child if there is none. Returns the child."""
    context = context or bpy.context
    child = find_limit_object(cage)
    name = cage.name + LIMIT_SUFFIX
    mesh = limit_mesh(name, *limit, materials=[m for m in cage.data.materials if m is not None])
    if child is None:
        child = bpy.data.objects.new(name, mesh)
        for collection in list(cage.users_collection) or [context.scene.collection]:
            collection.objects.link(child)
        child.parent = cage
        child[LIMIT_MARK] = True
    else:
        old = child.data
        child.data = mesh
        if old is not None and old.users == 0:
            bpy.data.meshes.remove(old)
        mesh.name = name
    # Sits exactly on the cage: identity local transform, no parent inverse.
    child.matrix_parent_inverse.identity()
    child.matrix_basis.identity()
    return child


def heat_colors(distances, scale=HEAT_SCALE):
    """RGBA (N, 4) float32 for relative distances: blue at 0 through cyan,
    green and yellow to red at `scale` and beyond (hue 240 to 0 degrees)."""
    t = np.clip(np.asarray(distances, np.float64) / scale, 0.0, 1.0)
    hue = (1.0 - t) * 4.0  # 4 = blue, 2 = green, 0 = red, in sixths of the circle
    rgb = np.empty((len(t), 3))
    rgb[:, 0] = np.clip(2.0 - hue, 0.0, 1.0)                     # red: rises from green to red
    rgb[:, 1] = np.clip(np.minimum(hue, 4.0 - hue), 0.0, 1.0)    # green: 0 at blue and red
    rgb[:, 2] = np.clip(hue - 2.0, 0.0, 1.0)                     # blue: falls from blue to green
    rgba = np.ones((len(t), 4), np.float32)
    rgba[:, :3] = rgb
    return rgba


def store_fit(obj, report, settings):
    """Custom properties and distance attributes of a fitted cage."""
    obj["pia_status"] = str(report.status)
    # Surface: the library's least squares; Vertices: the interpolation's method as requested.
    obj["pia_method"] = "LEAST_SQUARES" if report.mode == 'SURFACE' else str(settings["method"])
    obj["pia_iterations"] = int(report.iterations)
    obj["pia_fit"] = str(report.mode)
    obj["pia_fit_target"] = str(settings["target"])
    obj["pia_fit_rounds"] = int(report.rounds)
    obj["pia_fit_sample_count"] = int(report.sample_count)
    for when, d in (("before", report.before), ("after", report.after)):
        obj["pia_fit_mean_%s" % when] = float(d.mean)
        obj["pia_fit_p95_%s" % when] = float(d.p95)
        obj["pia_fit_max_%s" % when] = float(d.max)
        obj["pia_fit_ignored_%s" % when] = int(d.ignored)
    # The other way: the scan's vertices to the limit surface; "unreached"
    # is the share of them farther than the cut-off.
    scan_points = int(report.scan_point_count)
    obj["pia_fit_scan_points"] = scan_points
    if scan_points:
        for when, d in (("before", report.scan_before), ("after", report.scan_after)):
            obj["pia_fit_scan_mean_%s" % when] = float(d.mean)
            obj["pia_fit_scan_p95_%s" % when] = float(d.p95)
            obj["pia_fit_scan_max_%s" % when] = float(d.max)
            obj["pia_fit_scan_unreached_%s" % when] = float(d.ignored) / scan_points
    if report.folded_after >= 0 and report.sample_count:
        obj["pia_fit_folded_before"] = float(report.folded_before) / report.sample_count
        obj["pia_fit_folded_after"] = float(report.folded_after) / report.sample_count
    for key in ("fit_cutoff", "fit_smoothing", "fit_samples"):
        obj["pia_" + key] = settings[key]
    obj["pia_distance_scale"] = HEAT_SCALE
    mesh = obj.data
    distances = np.ascontiguousarray(report.vertex_distances, np.float32)
    write_heat_map(mesh, DISTANCE_ATTRIBUTE, COLOR_ATTRIBUTE, distances, heat_colors(distances))


def write_heat_map(mesh, distance_name, color_name, distances, colors):
    """The point attribute distance_name (float) and the colour attribute
    color_name (the active one, and the one rendered) on mesh, replacing
    attributes of those names.  Both are written under names of their own
    first and take the old ones' places only once whole: if writing fails,
    mesh's attributes are as they were."""
    written = []  # the names Blender gave the new attributes
    try:
        attr = mesh.attributes.new(distance_name + "_pia_new", 'FLOAT', 'POINT')
        written.append(attr.name)
        attr.data.foreach_set("value", np.ascontiguousarray(distances, np.float32))
        color = mesh.color_attributes.new(color_name + "_pia_new", 'FLOAT_COLOR', 'POINT')
        written.append(color.name)
        color.data.foreach_set("color", np.ascontiguousarray(colors, np.float32).ravel())
    except BaseException:
        for name in written:
            made = mesh.attributes.get(name)
            if made is not None:
                mesh.attributes.remove(made)
        raise
    # Adding or removing an attribute may move the others: each is looked
    # up by name again.
    for name in (distance_name, color_name):
        old = mesh.attributes.get(name)
        if old is not None:
            mesh.attributes.remove(old)
    mesh.attributes[written[0]].name = distance_name
    mesh.attributes[written[1]].name = color_name
    mesh.color_attributes.active_color = mesh.color_attributes[color_name]
    if hasattr(mesh.color_attributes, "render_color_index"):
        mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    mesh.update()


def paint_scan(target, report):
    """Writes report's scan distances onto the target's mesh: the point
    attribute pia_scan_distance (relative to the scan's diagonal; -1 for
    vertices no face uses) and its heat map pia_scan_distance_color (the
    active colour attribute; grey where not measured).  The scan changes in
    nothing else.  Returns None when painted, else why not (the scan is left
    as it was)."""
    distances = getattr(report, "scan_distances", None)
    if distances is None:
        return "no distances from the scan were measured (Catmull-Clark fits measure them)"
    mesh = target.data
    if mesh.library is not None:
        return "the scan's mesh is linked from a library"
    if target.mode == 'EDIT' or mesh.is_editmode:
        return "the scan is in Edit Mode"
    if len(mesh.vertices) != len(distances):
        return ("its modifiers change its vertices (%d measured, the mesh has %d)"
                % (len(distances), len(mesh.vertices)))
    colors = heat_colors(np.maximum(distances, 0.0))
    colors[distances < 0.0] = UNMEASURED_COLOR
    write_heat_map(mesh, SCAN_DISTANCE_ATTRIBUTE, SCAN_COLOR_ATTRIBUTE, distances, colors)
    return None


def write_unreachable_group(obj, report):
    """The vertex group UNREACHABLE_GROUP of obj: exactly the report's
    unreachable vertices, weight 1 (made active, for Select in Edit Mode);
    removed when there are none.  Vertex groups live on the mesh (Blender
    3.0 and later), so a mesh copied from a source brings the source's
    groups along, a `pia_unreachable` of its own among them (a cage made
    from a cage): the group is emptied of every vertex before the flagged
    ones are added.  Returns the group or None."""
    flags = getattr(report, "unreachable", None)
    indices = [] if flags is None else report.unreachable_indices.tolist()
    group = obj.vertex_groups.get(UNREACHABLE_GROUP)
    if not indices:
        if group is not None:
            obj.vertex_groups.remove(group)
        return None
    if group is None:
        group = obj.vertex_groups.new(name=UNREACHABLE_GROUP)
    group.remove(list(range(len(obj.data.vertices))))
    group.add(indices, 1.0, 'REPLACE')
    obj.vertex_groups.active_index = group.index
    return group


def store_report(obj, report, settings):
    """A solve's figures on obj (custom properties: pia_iterations,
    pia_max_error, pia_mean_error, pia_status, pia_method,
    pia_unreachable_count and, while there are unreachable vertices,
    pia_reachable_max_error) and its unreachable vertices (the vertex group
    pia_unreachable); a fit's through store_fit.  Used by build_object and
    by each update of a live cage."""
    if isinstance(report, native.FitReport):
        store_fit(obj, report, settings)
        return
    obj["pia_iterations"] = int(report.iterations)
    obj["pia_max_error"] = float(report.max_error_relative)
    obj["pia_mean_error"] = float(report.mean_error_relative)
    obj["pia_status"] = str(report.status)
    obj["pia_method"] = str(report.method)
    obj[UNREACHABLE_COUNT] = int(report.unreachable_count)
    if report.unreachable_count:
        obj[REACHABLE_MAX_ERROR] = float(report.reachable_max_error_relative)
    elif REACHABLE_MAX_ERROR in obj:
        del obj[REACHABLE_MAX_ERROR]
    write_unreachable_group(obj, report)


def build_object(source, cage, report, settings, context=None, name=None, mesh=None, limit=None):
    """New object with the cage positions on a copy of source's mesh (or on mesh).

    Catmull-Clark: with a limit-surface Subdivision Surface modifier.
    Loop, Doo-Sabin: no modifier; limit = limit_arrays' output goes to a
    `_limit` child.  A mesh passed in becomes the new object's.  If anything
    here fails, what it made (and the mesh passed in) is removed again
    before the error is raised.
    """
    context = context or bpy.context
    name = name or source.name + "_pia"
    if mesh is None:
        mesh = source.data.copy()
    new_obj = None
    try:
        mesh.name = name
        write_positions(mesh, cage)
        new_obj = bpy.data.objects.new(name, mesh)
        _dress_object(source, new_obj, report, settings, context, limit)
    except BaseException:
        discard_object(new_obj, mesh)
        raise
    return new_obj


def discard_object(obj, mesh=None):
    """Removes obj (may be None), its `_limit` child and their meshes, and
    mesh, where nothing else uses them: undoes build_object."""
    meshes = {} if mesh is None else {mesh.as_pointer(): mesh}
    if obj is not None:
        child = find_limit_object(obj)
        for o in ((child,) if child is not None else ()) + (obj,):
            if o.data is not None:
                meshes[o.data.as_pointer()] = o.data
            bpy.data.objects.remove(o)
    for m in meshes.values():
        if m.users == 0:
            bpy.data.meshes.remove(m)


def _dress_object(source, new_obj, report, settings, context, limit):
    """build_object's placement, modifier, properties, limit child and selection."""
    _link_like(source, new_obj, context)

    if settings["scheme"] == 'CATMULL_CLARK':
        mod = new_obj.modifiers.new("Subdivision", 'SUBSURF')
        mod.subdivision_type = 'CATMULL_CLARK'
        mod.use_limit_surface = True
        mod.levels = settings["levels"]
        mod.render_levels = settings["render_levels"]
        mod.quality = settings["quality"]
        mod.boundary_smooth = settings["boundary_smooth"]
        mod.use_creases = settings["use_creases"]
        if hasattr(mod, "use_adaptive_subdivision"):  # 5.0+: Cycles' dicing, not the limit surface
            mod.use_adaptive_subdivision = False
        src_mod = find_subsurf(source)
        if src_mod is not None:
            mod.uv_smooth = src_mod.uv_smooth
            mod.show_only_control_edges = src_mod.show_only_control_edges

    store_report(new_obj, report, settings)
    new_obj["pia_tolerance"] = float(settings["tolerance"])
    for key in STORED_SETTINGS:
        if key not in ("method", "tolerance"):  # pia_method is the method used
            value = settings[key]
            new_obj["pia_" + key] = value if isinstance(value, (bool, int, float, str)) else str(value)
    new_obj["pia_requested_method"] = str(settings["method"])
    new_obj["pia_source"] = source.name  # what a Live cage follows (live.py)
    if settings["scheme"] == 'CATMULL_CLARK':
        # Which OpenSubdiv's rules the cage was made for (Blender 5.1 and
        # later differ from earlier ones at some non-manifold vertices).
        new_obj["pia_opensubdiv_version"] = opensubdiv_version_string(opensubdiv_version_of(settings))

    if limit is not None:
        set_limit_object(new_obj, limit, context=context)

    view_layer = context.view_layer
    if view_layer is not None:
        for obj in (source, new_obj):
            try:
                obj.select_set(obj is new_obj, view_layer=view_layer)
            except RuntimeError:  # not in this view layer (excluded collection)
                pass
        if view_layer.objects.get(new_obj.name) is not None:
            view_layer.objects.active = new_obj
    return new_obj
