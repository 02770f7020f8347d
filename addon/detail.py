# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels: a fitted cage's Multires modifier whose levels are fitted
to the scan (settings fit_detail_levels).

The library fits the levels (native.fit_detail) and gives the finest
level's vertices in its own order; Blender numbers the vertices of a
Multires level its own way.  The order is read from Blender: a
Subdivision Surface modifier with Use Limit Surface off, on a copy of the
cage, gives the finest level's topology in Blender's order with each vertex
at its control position, which is the library's subdivided cage
(native.subdivide) in another order; each of Blender's vertices is matched
to the library's vertex at the same place.  Then a Multires modifier is
subdivided to the same level and reshaped (Blender's Reshape, from a copy
of its finest level with the fitted positions).

Reads and writes Blender's data; the library's share (fit_detail_work) is
a function that touches nothing of Blender's.
"""

import numpy as np
import bpy

from . import native
from .mesh_io import read_positions, write_positions

MODIFIER_NAME = "Multires"
# A vertex of Blender's finest level matches the library's vertex at the
# same place to within this share of the cage's bounding-box diagonal.
MATCH_TOLERANCE = 1e-5
# Vertices apart by more (Blender's and the library's rules differing near
# a non-manifold vertex) are paired only up to this share of the diagonal.
APART_TOLERANCE = 1e-2
# At most this many vertices are looked for among all (each a pass over them).
MAX_SEARCHED = 1000


def surface_options(settings):
    from .settings import opensubdiv_version_of
    return dict(boundary_smooth=settings["boundary_smooth"], use_creases=bool(settings["use_creases"]),
                quality=int(settings["quality"]), opensubdiv_version=opensubdiv_version_of(settings))


def fit_detail_work(cage_mesh, cage_positions, scan, settings, progress=None):
    """The library's share, as a function that touches nothing of
    Blender's: it fits the levels on the fitted cage (native.DetailResult)
    and subdivides the cage as many times (the control positions that tell
    Blender's order), and returns both.  progress(round, mean) as the
    fit's; True cancels."""
    levels = int(settings["fit_detail_levels"])
    base = native.Mesh(cage_positions, cage_mesh.face_sizes, cage_mesh.face_vertices, edges=cage_mesh.edges,
                       edge_creases=cage_mesh.edge_creases, vertex_creases=cage_mesh.vertex_creases)
    options = surface_options(settings)
    follow = None if progress is None else (lambda _level, iteration, value: progress(iteration, value))
    tick = None if progress is None else (lambda _level, _share: progress(0, 0.0))

    def run():
        detail = native.fit_detail(base, scan, levels, samples_per_edge=settings["fit_samples"],
                                   cutoff=settings["fit_cutoff"], progress=follow, **options)
        # One level at a time, as fit_detail subdivides: each level's edge
        # vertices come in the order of that level's own edges, which a
        # subdivision of several levels at once numbers otherwise.
        subdivided = base
        for _ in range(levels):
            subdivided = native.subdivide(subdivided, 1, progress=tick, **options)
        return detail, subdivided.positions
    return run


def _subsurf_topology(obj, levels, settings, context):
    """Blender's finest level of obj's mesh `levels` deep: a new mesh (its
    topology, in Blender's order) with the control positions."""
    copy = bpy.data.objects.new(obj.name + "_pia_order", obj.data)
    try:
        (context or bpy.context).scene.collection.objects.link(copy)
        modifier = copy.modifiers.new("Subdivision", 'SUBSURF')
        modifier.levels = modifier.render_levels = levels
        modifier.use_limit_surface = False
        modifier.quality = int(settings["quality"])
        modifier.use_creases = bool(settings["use_creases"])
        modifier.boundary_smooth = settings["boundary_smooth"]
        modifier.uv_smooth = 'NONE'
        depsgraph = (context or bpy.context).evaluated_depsgraph_get()
        depsgraph.update()
        return bpy.data.meshes.new_from_object(copy.evaluated_get(depsgraph))
    finally:
        bpy.data.objects.remove(copy)


def match_order(blender_points, faces_mesh, diagonal):
    """For each of Blender's vertices, the library's vertex at the same
    place: the closest face of the library's mesh (a native.Mesh of its
    subdivided cage, by the library's closest-point search) and its closest
    corner; where that corner is not at the same place (a face of a folded
    cage passing nearer), a search over every vertex.  Raises RuntimeError
    where a vertex has no match within MATCH_TOLERANCE or two share one."""
    scale = max(diagonal, 1e-30)
    scan = native.Scan(faces_mesh)
    faces = scan.closest_points(blender_points)[3]
    starts = np.concatenate(([0], np.cumsum(faces_mesh.face_sizes)[:-1]))
    corners = faces_mesh.face_vertices[starts[faces][:, None] + np.arange(4)[None, :]]
    gaps = np.linalg.norm(faces_mesh.positions[corners] - blender_points[:, None, :], axis=2)
    pick = np.argmin(gaps, axis=1)
    order = corners[np.arange(len(corners)), pick]
    gap = gaps[np.arange(len(corners)), pick] / scale
    astray = np.flatnonzero(gap > MATCH_TOLERANCE)
    for j in astray[:MAX_SEARCHED]:
        distances = np.linalg.norm(faces_mesh.positions - blender_points[j], axis=1)
        order[j] = int(np.argmin(distances))
        gap[j] = distances[order[j]] / scale
    # Where Blender's rules for a non-manifold vertex differ from the
    # library's, a few vertices near it sit apart: each library vertex keeps
    # the Blender vertex nearest it, and those left over are paired among
    # themselves, nearest first.
    by_gap = np.argsort(gap, kind="stable")
    first = np.zeros(len(order), bool)
    _values, keep = np.unique(order[by_gap], return_index=True)
    first[by_gap[keep]] = True
    left = np.flatnonzero(~first)
    if len(left):
        free = np.setdiff1d(np.arange(len(faces_mesh.positions)), order[first])
        if len(left) > MAX_SEARCHED or len(free) != len(left):
            raise RuntimeError("Blender's Multires levels do not match the library's subdivision (%d of %d "
                               "vertices apart); the detail levels were not made" % (len(left), len(order)))
        for j in left:
            distances = np.linalg.norm(faces_mesh.positions[free] - blender_points[j], axis=1)
            k = int(np.argmin(distances))
            order[j], gap[j] = free[k], distances[k] / scale
            free = np.delete(free, k)
    worst = float(gap.max()) if len(gap) else 0.0
    apart = int(np.count_nonzero(gap > MATCH_TOLERANCE))
    if worst > APART_TOLERANCE or apart > MAX_SEARCHED:
        raise RuntimeError("Blender's Multires levels do not match the library's subdivision (a vertex "
                           "%.3g of the diagonal away, %d apart); the detail levels were not made"
                           % (worst, apart))
    return order


def _add_multires(obj, levels, settings, context):
    modifier = obj.modifiers.new(MODIFIER_NAME, 'MULTIRES')
    if hasattr(modifier, "quality"):
        modifier.quality = int(settings["quality"])
    modifier.use_creases = bool(settings["use_creases"])
    modifier.boundary_smooth = settings["boundary_smooth"]
    modifier.uv_smooth = 'NONE'
    # Reshape sets every level from the finest, so how the levels are made
    # first does not show: Linear gave the same levels to the bit as
    # Catmull-Clark (the bunny, 2 levels) in half the time (the 50k cage to
    # 3 levels: 33 s against 66 s in Blender 5.3).
    with context.temp_override(object=obj, active_object=obj):
        for _ in range(levels):
            bpy.ops.object.multires_subdivide(modifier=modifier.name, mode='LINEAR')
    modifier.levels = modifier.sculpt_levels = modifier.render_levels = levels
    return modifier


def apply_detail(obj, detail, subdivided_positions, settings, context=None):
    """obj (the new fitted cage, its mesh the fitted positions) gets a
    Multires modifier with the detail's levels, its finest level at the
    detail's points.  The Subdivision Surface modifier build_object put on
    it goes: Multires shows the levels.  Returns the modifier."""
    context = context or bpy.context
    levels = int(detail.levels)
    top = _subsurf_topology(obj, levels, settings, context)
    try:
        ours = native.Mesh(subdivided_positions, detail.mesh.face_sizes, detail.mesh.face_vertices)
        blender_points = read_positions(top)
        if len(blender_points) != len(subdivided_positions):
            raise RuntimeError("Blender's level %d has %d vertices, the library's %d: the detail levels were "
                               "not made" % (levels, len(blender_points), len(subdivided_positions)))
        diagonal = float(np.linalg.norm(np.ptp(subdivided_positions, axis=0)))
        order = match_order(blender_points, ours, diagonal)
        write_positions(top, detail.points[order])
        for modifier in [m for m in obj.modifiers if m.type == 'SUBSURF']:
            obj.modifiers.remove(modifier)
        modifier = _add_multires(obj, levels, settings, context)
        shape = bpy.data.objects.new(obj.name + "_pia_detail", top)
        context.scene.collection.objects.link(shape)
        try:
            shape.matrix_world = obj.matrix_world
            with context.temp_override(object=obj, active_object=obj, selected_objects=[obj, shape],
                                       selected_editable_objects=[obj, shape]):
                result = bpy.ops.object.multires_reshape(modifier=modifier.name)
            if 'FINISHED' not in result:
                raise RuntimeError("Blender's Multires Reshape refused the detail levels")
        finally:
            bpy.data.objects.remove(shape)
    finally:
        bpy.data.meshes.remove(top)
    return modifier


def store_detail(obj, detail):
    """The finest level's figures on obj (custom properties pia_fit_detail_*)."""
    report = detail.report
    obj["pia_fit_detail_levels"] = int(detail.levels)
    obj["pia_fit_detail_mean"] = float(report.after.mean)
    obj["pia_fit_detail_p95"] = float(report.after.p95)
    obj["pia_fit_detail_max"] = float(report.after.max)
    if report.scan_point_count:
        obj["pia_fit_detail_scan_mean"] = float(report.scan_after.mean)
        obj["pia_fit_detail_scan_p95"] = float(report.scan_after.p95)
        obj["pia_fit_detail_scan_max"] = float(report.scan_after.max)
    if report.folded_after >= 0 and report.sample_count:
        obj["pia_fit_detail_folded"] = float(report.folded_after) / report.sample_count
