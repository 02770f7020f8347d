# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender's own way of putting a scan's detail on a cage in Multires levels,
and a measurement of a subdivided result against the scan.

Importable inside Blender (bpy, numpy, mathutils):

    multires_levels(obj, levels, quality=3) -> the new Multires modifier
    blender_workflow(cage_obj, scan_obj, levels=3, method='PROJECT') -> new object
    top_level_mesh(obj) -> (positions, face_sizes, face_vertices)
    measure_detail(positions, face_sizes, face_vertices, scan_obj,
                   start_positions=None) -> dict

The workflow is the one Blender's manual describes for transferring detail
from a high-resolution mesh onto a Multires: subdivide a copy of the cage
`levels` times with the Multires modifier (Catmull-Clark), add a Shrinkwrap
modifier after it that targets the scan, and take the evaluated result.
With method 'PROJECT' each vertex of the subdivided mesh is projected along
its normal, forwards and backwards (no axis, no face culling, Above
Surface); with 'NEAREST' it is moved to the nearest point of the scan.  The
evaluated mesh (top level plus shrinkwrap) becomes a new mesh object.

The measurement is independent of the project's C library: distances are
found with mathutils' BVHTree, both ways, and are given relative to the
bounding-box diagonal of the scan's vertices used by faces.  From the
surface to the scan it takes the centre (mean of the vertices) of each
face; from the scan to the surface, each scan vertex.  Given the positions
of the same mesh before the detail was added (e.g. the cage's own Multires
top level), it also counts the faces whose normal turned round.
"""
import os
import sys
import time

import bpy
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fit_cases import _activate, diagonal, scan_geometry, world_positions  # noqa: E402


# --------------------------------------------------------------------------
# Blender's workflow

def multires_levels(obj, levels, quality=3):
    """Add a Multires modifier to obj (a mesh object without other
    modifiers) and subdivide it `levels` times, Catmull-Clark.  Quality (the
    accuracy of the limit surface evaluation, where the modifier has it) is
    set before subdividing; levels, sculpt and render levels end at
    `levels`.  Returns the modifier."""
    _activate(obj)
    mod = obj.modifiers.new("Multires", 'MULTIRES')
    if hasattr(mod, "quality"):
        mod.quality = quality
    # Same operator and options in Blender 3.4 to 5.3.
    for _ in range(levels):
        result = bpy.ops.object.multires_subdivide(modifier=mod.name, mode='CATMULL_CLARK')
        if result != {'FINISHED'}:
            raise RuntimeError("multires_subdivide on %s returned %s" % (obj.name, result))
    mod.levels = mod.sculpt_levels = mod.render_levels = levels
    return mod


def blender_workflow(cage_obj, scan_obj, levels=3, method='PROJECT', name=None, report=None):
    """Subdivide a copy of cage_obj `levels` times in a Multires modifier,
    shrinkwrap it onto scan_obj, and return a new mesh object made from the
    evaluated result (same matrix as the cage, linked to the scene).  The
    copy is removed afterwards; cage_obj is not changed.

    method 'PROJECT': Shrinkwrap Project along the vertex normals in both
    directions, Above Surface, no face culling, no limit.  'NEAREST':
    Nearest Surface Point.  If `report` is a dict it gets the times in
    seconds: subdivide_s (the Multires operator, `levels` times),
    evaluate_s (evaluating the modifiers and copying the result), and
    multires_s and shrinkwrap_s, the modifiers' own execution times in that
    evaluation (None before Blender 4.0, which does not record them)."""
    if method not in ('PROJECT', 'NEAREST'):
        raise ValueError("method must be 'PROJECT' or 'NEAREST'")
    work = cage_obj.copy()
    work.data = cage_obj.data.copy()
    work.modifiers.clear()
    work.name = work.data.name = "%s_workflow_tmp" % cage_obj.name
    bpy.context.scene.collection.objects.link(work)
    work.matrix_world = cage_obj.matrix_world.copy()
    try:
        t0 = time.perf_counter()
        multires_levels(work, levels)
        subdivide_s = time.perf_counter() - t0

        sw = work.modifiers.new("Shrinkwrap", 'SHRINKWRAP')
        sw.target = scan_obj
        if method == 'PROJECT':
            sw.wrap_method = 'PROJECT'
            sw.use_project_x = sw.use_project_y = sw.use_project_z = False  # along normals
            sw.use_negative_direction = True
            sw.use_positive_direction = True
            sw.cull_face = 'OFF'
            sw.wrap_mode = 'ABOVE_SURFACE'
        else:
            sw.wrap_method = 'NEAREST_SURFACEPOINT'

        t0 = time.perf_counter()
        dg = bpy.context.evaluated_depsgraph_get()
        dg.update()
        evaluated = work.evaluated_get(dg)
        mesh = bpy.data.meshes.new_from_object(evaluated)
        evaluate_s = time.perf_counter() - t0
        # Blender 4.0+ times each modifier on the evaluated copy.
        multires_s, shrinkwrap_s = (getattr(evaluated.modifiers[m], "execution_time", None)
                                    for m in ("Multires", sw.name))
    finally:
        work_mesh = work.data
        bpy.data.objects.remove(work)
        bpy.data.meshes.remove(work_mesh)

    mesh.name = name or "%s_%s%d" % (cage_obj.name, method.lower(), levels)
    obj = bpy.data.objects.new(mesh.name, mesh)
    obj.matrix_world = cage_obj.matrix_world.copy()
    bpy.context.scene.collection.objects.link(obj)
    if report is not None:
        report.update(subdivide_s=subdivide_s, evaluate_s=evaluate_s,
                      multires_s=multires_s, shrinkwrap_s=shrinkwrap_s,
                      vertices=len(mesh.vertices), faces=len(mesh.polygons))
    return obj


# --------------------------------------------------------------------------
# Meshes as arrays

def face_offsets(face_sizes):
    """Index of each face's first entry in the flattened face_vertices."""
    offsets = np.zeros(len(face_sizes), np.int64)
    np.cumsum(face_sizes[:-1], out=offsets[1:])
    return offsets


def top_level_mesh(obj):
    """obj as evaluated (e.g. its Multires at the level it is set to) as
    numpy arrays: positions (N, 3) float64 in world space, face sizes (F,)
    and the faces' vertex indices, flattened in face order."""
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        positions = world_positions(me, obj.matrix_world)
        nf = len(me.polygons)
        sizes = np.empty(nf, np.int32)
        starts = np.empty(nf, np.int32)
        me.polygons.foreach_get("loop_total", sizes)
        me.polygons.foreach_get("loop_start", starts)
        loop_v = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", loop_v)
    finally:
        ev.to_mesh_clear()
    # Loops in face order, whatever order the faces' loops are stored in.
    offsets = face_offsets(sizes)
    order = np.repeat(starts.astype(np.int64) - offsets, sizes) + np.arange(int(sizes.sum()))
    return positions, sizes.astype(np.int64), loop_v[order].astype(np.int64)


def newell_normals(positions, face_sizes, face_vertices):
    """Area vectors of the faces (Newell's method; length = area for a
    planar face), about each face's centre for accuracy."""
    offsets = face_offsets(face_sizes)
    corners = positions[face_vertices]
    centres = np.add.reduceat(corners, offsets, axis=0) / face_sizes[:, None]
    local = corners - np.repeat(centres, face_sizes, axis=0)
    nxt = np.arange(len(face_vertices)) + 1
    last = offsets + face_sizes - 1
    nxt[last] = offsets                                   # wrap to each face's first corner
    return 0.5 * np.add.reduceat(np.cross(local, local[nxt]), offsets, axis=0), centres


# --------------------------------------------------------------------------
# The measurement

def _nearest(tree, points, normals=None):
    """Distance from each point to the tree's surface (one find_nearest per
    point; inf where the tree finds nothing); with `normals` (an (N, 3)
    array), also the surface's normal there (zero where nothing is found)."""
    out = np.empty(len(points))
    find = tree.find_nearest
    for i, p in enumerate(points.tolist()):
        _location, normal, _index, d = find(p)
        out[i] = np.inf if d is None else d
        if normals is not None:
            normals[i] = (0.0, 0.0, 0.0) if normal is None else tuple(normal)
    return out


# A turned face farther than this share of the diagonal from the scan
# follows nothing of it: it counts as a fold whichever way it faces.
FOLD_FAR = 1e-3


def _stats(d):
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())}


def measure_detail(positions, face_sizes, face_vertices, scan_obj, start_positions=None,
                   degenerate=1e-6, start_facing=None):
    """Distances between a mesh (world-space arrays as top_level_mesh gives)
    and scan_obj's evaluated mesh in world space, relative to the
    bounding-box diagonal of the scan's vertices used by faces.

    surface_to_scan: from each face centre (mean of its vertices) to the
    nearest point on the scan's triangles.  scan_to_surface: from each scan
    vertex used by a face to the nearest point on the mesh's faces
    (BVHTree.FromPolygons, which splits non-triangular faces itself; for
    non-planar quads its choice of diagonal may differ from the viewport's,
    by about the quads' flatness error).  Both give mean, p95 and max.

    With start_positions (the same mesh before, same vertex order), turned
    is the share of faces whose Newell normal points against the same
    face's normal in start_positions (negative dot product).  Faces whose
    area is at most `degenerate` x their squared perimeter in either mesh
    have no usable normal: they are left out of the share and counted in
    degenerate_faces.  A square has 1/16; the default 1e-6 is a sliver
    whose width is 4e-6 of its length, about the rounding of float32
    coordinates across a face of a subdivided cage, so what is left out
    is faces collapsed to a line or a point (as Nearest Surface Point
    makes them in folds), whose normal is rounding noise.

    Also returned: faces, scan_points, diagonal, the per-point relative
    distances (surface_distances, scan_distances) and the times in seconds
    (build_s for both trees, surface_to_scan_s and scan_to_surface_s for
    the queries, total_s)."""
    t_all = time.perf_counter()
    positions = np.asarray(positions, np.float64)
    face_sizes = np.asarray(face_sizes, np.int64)
    face_vertices = np.asarray(face_vertices, np.int64)
    verts, tris = scan_geometry(scan_obj)
    used = np.unique(tris)
    diag = diagonal(verts[used])

    area, centres = newell_normals(positions, face_sizes, face_vertices)

    t0 = time.perf_counter()
    scan_tree = BVHTree.FromPolygons([Vector(v) for v in verts], tris.tolist(), all_triangles=True)
    polys = np.split(face_vertices, face_offsets(face_sizes)[1:])
    surface_tree = BVHTree.FromPolygons([Vector(v) for v in positions], [p.tolist() for p in polys],
                                        all_triangles=bool(np.all(face_sizes == 3)))
    build_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    scan_normals = np.zeros_like(centres)
    to_scan = _nearest(scan_tree, centres, scan_normals) / diag
    to_scan_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    to_surface = _nearest(surface_tree, verts[used]) / diag
    to_surface_s = time.perf_counter() - t0

    out = {
        "surface_to_scan": _stats(to_scan),
        "scan_to_surface": _stats(to_surface),
        "faces": int(len(face_sizes)),
        "scan_points": int(len(used)),
        "diagonal": diag,
        "surface_distances": to_scan,
        "scan_distances": to_surface,
        "build_s": build_s,
        "surface_to_scan_s": to_scan_s,
        "scan_to_surface_s": to_surface_s,
    }
    if start_positions is not None:
        start_positions = np.asarray(start_positions, np.float64)
        if start_positions.shape != positions.shape:
            raise ValueError("start_positions must have the shape of positions")
        start_area, _ = newell_normals(start_positions, face_sizes, face_vertices)

        def usable(p, a):
            corners = p[face_vertices]
            nxt = np.arange(len(face_vertices)) + 1
            offsets = face_offsets(face_sizes)
            nxt[offsets + face_sizes - 1] = offsets
            perimeter = np.add.reduceat(np.linalg.norm(corners[nxt] - corners, axis=1), offsets)
            return np.linalg.norm(a, axis=1) > degenerate * perimeter ** 2

        ok = usable(positions, area) & usable(start_positions, start_area)
        dots = np.einsum("ij,ij->i", area[ok], start_area[ok])
        out["turned"] = float((dots < 0).mean()) if ok.any() else 0.0
        out["turned_faces"] = int((dots < 0).sum())
        if start_facing is not None:  # of those, where the start faced the scan (a bool per face)
            turned = np.zeros(len(ok), bool)
            turned[np.flatnonzero(ok)[dots < 0]] = True
            out["turned_facing"] = float((turned & start_facing)[ok].mean()) if ok.any() else 0.0
            # And of those, the folds: faces that now face away from the
            # scan's normal at their centre's nearest point, or lie beyond
            # FOLD_FAR of the diagonal from it.  The others turned with the
            # scan (a groove or an overhang the start's coarser surface
            # spans: the scan's normal there is turned from the start's).
            facing = np.einsum("ij,ij->i", area, scan_normals)
            facing *= 1.0 if facing.sum() >= 0.0 else -1.0
            folded = turned & start_facing & ((facing <= 0.0) | (to_scan > FOLD_FAR))
            out["turned_folded"] = float(folded[ok].mean()) if ok.any() else 0.0
        out["degenerate_faces"] = int((~ok).sum())
    out["total_s"] = time.perf_counter() - t_all
    return out
