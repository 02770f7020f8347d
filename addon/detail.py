# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels: a fitted cage's Multires modifier whose levels are fitted
to the scan (settings fit_detail_levels).

The library fits the levels (native.fit_detail) and gives the finest
level's vertices in its own order; Blender numbers the vertices of a
Multires level its own way, which multires_order computes from the
library's levels.  Then a Multires modifier is subdivided to the same
level and reshaped (Blender's Reshape, from a mesh of the finest level's
fitted positions in Blender's order).  Where the levels do not fit the
computed numbering (a cage with loose edges, say), the order is read from
Blender instead: a Subdivision Surface modifier with Use Limit Surface
off, on a copy of the cage, gives the finest level in Blender's order
with each vertex at its control position, which is the library's
subdivided cage (native.subdivide) in another order; each of Blender's
vertices is matched to the library's vertex at the same place.

Reads and writes Blender's data; the library's share (fit_detail_work) is
a function that touches nothing of Blender's.
"""

import numpy as np
import bpy

from . import multires_order, native
from .mesh_io import mesh_arrays, native_mesh, read_positions, write_positions

MODIFIER_NAME = "Multires"
# A vertex of Blender's finest level matches the library's vertex at the
# same place to within this share of the cage's bounding-box diagonal.
MATCH_TOLERANCE = 1e-5
# Vertices apart by more (Blender's and the library's rules differing near
# a non-manifold vertex) are paired only up to this share of the diagonal.
APART_TOLERANCE = 1e-2
# At most this many vertices are looked for among all (each a pass over them).
MAX_SEARCHED = 1000
# How the Multires levels are made before Reshape sets them (see
# _new_multires): the modifier's quality meanwhile (None: the settings'
# quality throughout), Subdivide's mode for the first level and for the
# later ones, and whether the modifier is hidden from the viewport until
# Reshape is done.
SUBDIVIDE_QUALITY = 1
SUBDIVIDE_MODES = ('CATMULL_CLARK', 'LINEAR')
HIDE_WHILE_SUBDIVIDING = True


def surface_options(settings):
    from .settings import opensubdiv_version_of
    return dict(boundary_smooth=settings["boundary_smooth"], use_creases=bool(settings["use_creases"]),
                quality=int(settings["quality"]), opensubdiv_version=opensubdiv_version_of(settings))


def fit_detail_work(cage_mesh, cage_positions, scan, settings, progress=None, begin=None):
    """The library's share, as a function that touches nothing of
    Blender's: it fits the levels on the fitted cage and returns the
    native.DetailResult.  progress(round, mean) as the fit's; True
    cancels.  begin(text, rounds=True), if given, names each level's
    stage as it starts (on the library's thread)."""
    levels = int(settings["fit_detail_levels"])
    base = native.Mesh(cage_positions, cage_mesh.face_sizes, cage_mesh.face_vertices, edges=cage_mesh.edges,
                       edge_creases=cage_mesh.edge_creases, vertex_creases=cage_mesh.vertex_creases)
    options = surface_options(settings)
    follow = None
    if progress is not None:
        started = [0]

        def follow(level, iteration, value):
            if begin is not None and level != started[0]:
                started[0] = level
                begin("detail level %d of %d" % (level, levels), rounds=True)
            return progress(iteration, value)

    def run():
        return native.fit_detail(base, scan, levels, samples_per_edge=settings["fit_samples"],
                                 cutoff=settings["fit_cutoff"], progress=follow, **options)
    return run


def order_work(obj, detail):
    """Blender's numbering of obj's Multires finest level, as the library's
    finest level's vertex numbers (multires_order), as a function that
    touches nothing of Blender's: obj's mesh is read here, the numbering
    computed when the function is called.  It gives None where the
    library's levels do not fit the numbering (match_order then pairs the
    vertices, through Blender's own subdivision)."""
    if len(detail.level_topology) != int(detail.levels) + 1:
        return _nothing
    arrays = mesh_arrays(obj.data)
    count, face_sizes, face_vertices = detail.level_topology[0]
    if (count != len(arrays["positions"]) or not np.array_equal(face_sizes, arrays["face_sizes"]) or
            not np.array_equal(face_vertices, arrays["face_vertices"])):
        return _nothing

    def work():
        try:
            return multires_order.blender_order(face_sizes, face_vertices, arrays["edges"], count,
                                                [(n, faces) for n, _sizes, faces in detail.level_topology[1:]])
        except multires_order.OrderMismatch:
            return None
    return work


def _nothing():
    """Work that does nothing (and finds no order): yielded between
    Blender's stages, where a job's caller (the operator's modal run)
    redraws the window and hears Esc."""
    return None


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


def _cell_pairs(ours, theirs, cell, offset):
    """Pairs (i, j) of the library's point ours[i] and Blender's theirs[j]
    alone together in a cube of side `cell` (the cubes shifted by
    offset * cell): one sort of both sets' cubes."""
    lo = np.minimum(ours.min(axis=0), theirs.min(axis=0)) - cell
    q = np.floor((np.concatenate((ours, theirs)) - lo) / cell + offset).astype(np.int64)
    keys = (q[:, 0] << 42) | (q[:, 1] << 21) | q[:, 2]
    by_key = np.argsort(keys)
    keys = keys[by_key]
    # A pair: two neighbours in the sort with one cube, unlike the ones
    # either side, one of each set.
    same = keys[1:] == keys[:-1]
    lone = np.ones(len(same), bool)
    lone[1:] &= ~same[:-1]
    lone[:-1] &= ~same[1:]
    first = np.flatnonzero(same & lone)
    a, b = by_key[first], by_key[first + 1]
    n = len(ours)
    a, b = np.minimum(a, b), np.maximum(a, b)
    mixed = (a < n) & (b >= n)
    return a[mixed], b[mixed] - n


def match_order(blender_points, faces_mesh, diagonal):
    """For each of Blender's vertices, the library's vertex at the same
    place.  The two agree to within rounding: a point and its match are
    alone together in a cube of a grid 4 MATCH_TOLERANCE wide, or else of a
    second grid shifted by half a cube (a pair the first grid splits lies
    near one of its faces, so far from the second's); what is left goes as
    _settle says, or, more than MAX_SEARCHED left, to match_order_searched.
    Raises RuntimeError where a vertex has no match within MATCH_TOLERANCE
    or two share one."""
    ours = np.asarray(faces_mesh.positions, np.float64)
    theirs = np.asarray(blender_points, np.float64)
    scale = max(diagonal, 1e-30)
    cell = 4.0 * MATCH_TOLERANCE * scale
    # The cube's coordinates take 21 bits each.
    if (len(ours) != len(theirs) or not len(ours) or
            np.ptp(np.concatenate((ours, theirs)), axis=0).max() > cell * ((1 << 21) - 4)):
        return match_order_searched(blender_points, faces_mesh, diagonal)
    order = np.full(len(theirs), -1, np.int64)
    i, j = _cell_pairs(ours, theirs, cell, 0.0)
    order[j] = i
    free = np.ones(len(ours), bool)
    free[i] = False
    ours_left, theirs_left = np.flatnonzero(free), np.flatnonzero(order < 0)
    if len(theirs_left):
        i, j = _cell_pairs(ours[ours_left], theirs[theirs_left], cell, 0.5)
        order[theirs_left[j]] = ours_left[i]
    gap = np.full(len(theirs), np.inf)
    found = np.flatnonzero(order >= 0)
    gap[found] = np.linalg.norm(ours[order[found]] - theirs[found], axis=1) / scale
    if _settle(order, gap, ours, theirs, scale):
        return order
    return match_order_searched(blender_points, faces_mesh, diagonal)


def match_order_searched(blender_points, faces_mesh, diagonal):
    """match_order by search: for each of Blender's vertices, the closest
    face of the library's mesh (a native.Mesh of its subdivided cage, by
    the library's closest-point search) and its closest corner; where that
    corner is not at the same place (a face of a folded cage passing
    nearer), a search over every vertex."""
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
    if not _settle(order, gap, faces_mesh.positions, blender_points, scale):
        raise RuntimeError("Blender's Multires levels do not match the library's subdivision (more than %d of "
                           "%d vertices apart); the detail levels were not made" % (MAX_SEARCHED, len(order)))
    return order


def _settle(order, gap, ours, theirs, scale):
    """Makes order (each of Blender's vertices' candidate among the
    library's, -1 for none; gap: how far apart, a share of the diagonal)
    one to one, in place.  Where Blender's rules for a non-manifold vertex
    differ from the library's, a few vertices near it sit apart: each
    library vertex keeps the Blender vertex nearest it, and those left over
    are paired among themselves, nearest first.  False where more than
    MAX_SEARCHED are left over; raises RuntimeError where a pair ends
    further apart than APART_TOLERANCE or more than MAX_SEARCHED are apart."""
    first = order >= 0
    if np.bincount(order[first], minlength=len(ours)).max(initial=0) > 1:
        by_gap = np.argsort(gap, kind="stable")
        by_gap = by_gap[order[by_gap] >= 0]
        values = order[by_gap]
        by_value = np.argsort(values, kind="stable")
        runs = np.ones(len(by_value), bool)
        runs[1:] = values[by_value[1:]] != values[by_value[:-1]]
        first[:] = False
        first[by_gap[by_value[runs]]] = True
    left = np.flatnonzero(~first)
    if len(left) > MAX_SEARCHED:
        return False
    if len(left):
        free = np.ones(len(ours), bool)
        free[order[first]] = False
        free = np.flatnonzero(free)
        for j in left:
            distances = np.linalg.norm(ours[free] - theirs[j], axis=1)
            k = int(np.argmin(distances))
            order[j], gap[j] = free[k], distances[k] / scale
            free = np.delete(free, k)
    worst = float(gap.max()) if len(gap) else 0.0
    apart = int(np.count_nonzero(gap > MATCH_TOLERANCE))
    if worst > APART_TOLERANCE or apart > MAX_SEARCHED:
        raise RuntimeError("Blender's Multires levels do not match the library's subdivision (a vertex "
                           "%.3g of the diagonal away, %d apart); the detail levels were not made"
                           % (worst, apart))
    return True


def _new_multires(obj, settings):
    modifier = obj.modifiers.new(MODIFIER_NAME, 'MULTIRES')
    modifier.use_creases = bool(settings["use_creases"])
    modifier.boundary_smooth = settings["boundary_smooth"]
    modifier.uv_smooth = 'NONE'
    # Reshape sets every level from the finest, so how the levels are made
    # first does not show (test_levels_do_not_depend_on_how_they_are_made):
    # Linear gave the same levels to the bit as Catmull-Clark (the bunny, 2
    # levels) in half the time (the 50k cage to 3 levels: 33 s against 66 s
    # in Blender 5.3), and so did the lowest quality, which Reshape does not
    # use (it runs at the modifier's own): each Subdivide builds Blender's
    # evaluator of the cage again, at the modifier's quality (the 50k cage:
    # 14 s at quality 1, 30 s at 3).  The first level's Catmull-Clark only
    # allocates the displacement (0.08 s against Linear's 1.4 to 2.0).
    # Hidden, the modifier is not evaluated at each new level: bpy.ops
    # updates the view layer after every operator.  On the 50k cage at 3
    # levels (Blender 5.3) the Subdivides took 7.4 s hidden against 10.5 to
    # 14.7 shown, and Reshape 5.4 s against 12.2 to 13.4, then the one
    # evaluation once shown 5.7 to 6.1 s (1.3 after a shown Reshape).
    if hasattr(modifier, "quality") and SUBDIVIDE_QUALITY is not None:
        modifier.quality = SUBDIVIDE_QUALITY
    if HIDE_WHILE_SUBDIVIDING:
        modifier.show_viewport = False
    return modifier


def _subdivide_multires(obj, modifier, context):
    """One more level on obj's Multires modifier (Blender's Subdivide)."""
    mode = SUBDIVIDE_MODES[0 if modifier.total_levels == 0 else 1]
    with context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.multires_subdivide(modifier=modifier.name, mode=mode)


def _show_multires(modifier, levels, settings):
    if hasattr(modifier, "quality"):
        modifier.quality = int(settings["quality"])
    modifier.levels = modifier.sculpt_levels = modifier.render_levels = levels


def _matched_order(base, blender_points, levels, settings):
    """match_order of Blender's finest level's points against the library's
    subdivision of base (a native.Mesh of the cage) `levels` deep."""
    subdivided = base
    for _ in range(levels):
        subdivided = native.subdivide(subdivided, 1, **surface_options(settings))
    if len(blender_points) != len(subdivided.positions):
        raise RuntimeError("Blender's level %d has %d vertices, the library's %d: the detail levels were "
                           "not made" % (levels, len(blender_points), len(subdivided.positions)))
    diagonal = float(np.linalg.norm(np.ptp(subdivided.positions, axis=0)))
    return match_order(blender_points, subdivided, diagonal)


def apply_detail_steps(obj, detail, settings, context=None, stage=None):
    """obj (the new fitted cage, its mesh the fitted positions) gets a
    Multires modifier with the detail's levels, its finest level at the
    detail's points, in Blender's order (order_work, or where that cannot
    say, match_order against Blender's own subdivision).  The Subdivision
    Surface modifier build_object put on it goes: Multires shows the
    levels.  Returns the modifier.  As interpolate_steps' steps (run_steps
    drives them at once): what touches nothing of
    Blender's (the order computed or matched) is yielded as work, and so,
    between Blender's own stages (each level's Subdivide, Reshape), is
    work that does nothing, at which a job's caller redraws and hears Esc.
    stage(text), if given, names each stage as it begins.  Each stage reads
    bpy.context as it runs where context is None (a job's steps outlive
    the operator call's context)."""
    def begin(text):
        if stage is not None:
            stage(text)
    levels = int(detail.levels)
    begin("computing Blender's numbering of the finest level")
    order = yield order_work(obj, detail)
    if order is not None:
        # Reshape reads the other object's vertices only.
        top = bpy.data.meshes.new(obj.name + "_pia_detail")
        top.vertices.add(len(order))
        write_positions(top, detail.points[order])
    else:
        begin("Blender: a Subdivision Surface to read its numbering from")
        yield _nothing
        top = _subsurf_topology(obj, levels, settings, context or bpy.context)
    try:
        if order is None:
            begin("matching Blender's numbering by position")
            base, blender_points = native_mesh(obj.data), read_positions(top)
            order = yield lambda: _matched_order(base, blender_points, levels, settings)
            write_positions(top, detail.points[order])
        for modifier in [m for m in obj.modifiers if m.type == 'SUBSURF']:
            obj.modifiers.remove(modifier)
        modifier = _new_multires(obj, settings)
        for level in range(1, levels + 1):
            begin("Blender: Multires, subdividing level %d of %d" % (level, levels))
            yield _nothing
            _subdivide_multires(obj, modifier, context or bpy.context)
        _show_multires(modifier, levels, settings)
        begin("Blender: Multires Reshape to the fitted positions")
        yield _nothing
        _reshape(obj, modifier, top, context or bpy.context)
        modifier.show_viewport = True
    finally:
        bpy.data.meshes.remove(top)
    return modifier


def _reshape(obj, modifier, top, context):
    """Blender's Reshape of obj's Multires from an object of mesh top."""
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
