# SPDX-License-Identifier: GPL-3.0-or-later
"""Fitting a cage to a scan (the operator's `target`): surface samples
against Blender's evaluated modifier, closest points against mathutils'
BVH tree, the Stanford bunny with a QuadriFlow cage, bad input, the
attributes and properties on the result, transforms, progress and the
command line."""

import os
import re
import subprocess

import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Vector
from mathutils.bvhtree import BVHTree
from mathutils.kdtree import KDTree

import shapes
import subdiv_pia
from shapes import fine_sphere, quad_sphere
from subdiv_pia import api, native, objects
from conftest import (DATA, assert_unchanged, evaluated_control_points, evaluated_points, expect_error, import_obj,
                      link_and_activate, link_and_activate_existing, object_from_pydata, positions,
                      run_operator, snapshot)


# --- helpers ---------------------------------------------------------------------

def activate(obj):
    return link_and_activate_existing(obj)


def scan_in_cage_space(scan, cage):
    """(vertices (N, 3) float64, polygons) of scan's evaluated mesh, in cage's object space."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = scan.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        co = positions(mesh).astype(np.float64)
        polygons = [tuple(p.vertices) for p in mesh.polygons]
    finally:
        evaluated.to_mesh_clear()
    m = np.array(cage.matrix_world.inverted() @ scan.matrix_world)
    return co @ m[:3, :3].T + m[:3, 3], polygons


def bvh_of(vertices, polygons):
    return BVHTree.FromPolygons([Vector(v) for v in vertices], polygons, all_triangles=False, epsilon=0.0)


def bvh_distances(bvh, points):
    out = np.empty(len(points))
    for i, p in enumerate(points):
        out[i] = bvh.find_nearest(Vector(p))[3]
    return out


def used_diagonal(vertices, polygons):
    used = np.unique(np.fromiter((v for p in polygons for v in p), np.int64))
    pts = vertices[used]
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def native_scan(vertices, polygons):
    return native.Scan(native.Mesh.from_faces(vertices, polygons))


def surface_samples(obj, samples_per_edge=4, **options):
    mesh = api.native_mesh(obj.data)
    stencils = native.surface_stencils(mesh, samples_per_edge=samples_per_edge, **options)
    return stencils.apply(mesh.positions)


def fit(cage, scan, **settings):
    """Run the operator on cage with scan as target; the new object."""
    activate(cage)
    before = snapshot(cage)
    assert run_operator(target=scan.name, **settings) == {'FINISHED'}
    new_obj = bpy.context.active_object
    assert new_obj is not cage and new_obj.name.startswith(cage.name + "_pia")
    assert_unchanged(cage, before)
    return new_obj


# --- the samples are points of Blender's surface ----------------------------------------

def _mixed_with_crease():
    obj = shapes.mixed()  # triangles, quads, a pentagon, an open boundary, a valence-6 vertex
    values = np.zeros(len(obj.data.edges), np.float32)
    for edge in obj.data.edges:
        if set(edge.vertices) in ({1, 4}, {4, 7}):
            values[edge.index] = 0.5  # semi-sharp: Blender's adaptive patches there
    assert np.count_nonzero(values) == 2
    shapes.set_edge_creases(obj.data, values)
    return obj


@pytest.mark.parametrize("make", (_mixed_with_crease, shapes.edge_creases, shapes.ngon_cylinder),
                         ids=("mixed-crease", "cube-creases", "ngon-cylinder"))
def test_surface_samples_are_blender_surface_points(make):
    obj = make()
    points = surface_samples(obj, samples_per_edge=4, quality=3)
    sizes = np.array([len(p.vertices) for p in obj.data.polygons])
    assert len(points) == 16 * int(np.where(sizes == 4, 1, sizes).sum())
    # (2i+1)/8 is a grid point of a quad at level 3; Blender samples the
    # corner sub-quads of other polygons with half as many segments, so
    # level 4 holds every sample of every face.
    mod = obj.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels, mod.quality, mod.use_limit_surface = 4, 3, True
    grid = evaluated_points(obj)
    tree = KDTree(len(grid))
    for i, p in enumerate(grid):
        tree.insert(p, i)
    tree.balance()
    diag = float(np.linalg.norm(grid.max(axis=0) - grid.min(axis=0)))
    found = [tree.find(p) for p in points]
    miss = max(d for _, _, d in found) / diag
    assert miss <= 1e-6, miss
    assert len({i for _, i, _ in found}) == len(points), "two samples at one surface point"


# --- synthetic: a quad sphere on a finely tessellated sphere ------------------------

def test_surface_fit_puts_every_sample_on_the_sphere():
    scan = fine_sphere()
    cage = quad_sphere(cuts=3)
    new_obj = fit(cage, scan, fit='SURFACE')
    vertices, polygons = scan_in_cage_space(scan, new_obj)
    diag = used_diagonal(vertices, polygons)
    points = surface_samples(new_obj)
    _, _, dist, _ = native_scan(vertices, polygons).closest_points(points)
    rel = dist.astype(np.float64) / diag
    assert rel.max() <= 1e-4, rel.max()
    assert new_obj["pia_fit_mean_before"] > 100 * rel.mean()  # the plain cage was far off
    # An independent closest-point oracle on a subset.
    rng = np.random.default_rng(0)
    subset = rng.choice(len(points), 400, replace=False)
    oracle = bvh_distances(bvh_of(vertices, polygons), points[subset]) / diag
    np.testing.assert_allclose(rel[subset], oracle, rtol=0, atol=2e-7)
    # The report is the same measurement.
    assert new_obj["pia_fit_max_after"] == pytest.approx(rel.max(), rel=1e-3, abs=1e-7)
    assert new_obj["pia_fit_mean_after"] == pytest.approx(rel.mean(), rel=1e-3, abs=1e-7)


def test_vertices_fit_puts_every_limit_point_on_the_sphere():
    scan = fine_sphere()
    cage = quad_sphere(cuts=3)
    new_obj = fit(cage, scan, fit='VERTICES', quality=3)
    n = len(cage.data.vertices)
    limit_points = evaluated_control_points(new_obj, n)  # Blender's modifier, identity transforms
    vertices, polygons = scan_in_cage_space(scan, new_obj)
    diag = used_diagonal(vertices, polygons)
    rel = bvh_distances(bvh_of(vertices, polygons), limit_points) / diag
    assert rel.max() <= 1e-5, rel.max()
    assert new_obj["pia_fit"] == 'VERTICES' and new_obj["pia_status"] == 'CONVERGED'


def test_fit_attributes_and_properties():
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    new_obj = fit(cage, scan, fit='SURFACE', fit_cutoff=0.05)
    mesh = new_obj.data
    n = len(mesh.vertices)
    attr = mesh.attributes[api.DISTANCE_ATTRIBUTE]
    assert (attr.domain, attr.data_type, len(attr.data)) == ('POINT', 'FLOAT', n)
    distances = np.empty(n, np.float32)
    attr.data.foreach_get("value", distances)
    # Each vertex: the largest distance of the samples on its faces (all quads: 16 per face).
    vertices, polygons = scan_in_cage_space(scan, new_obj)
    diag = used_diagonal(vertices, polygons)
    _, _, dist, _ = native_scan(vertices, polygons).closest_points(surface_samples(new_obj))
    per_face = (dist.astype(np.float64) / diag).reshape(len(mesh.polygons), 16).max(axis=1)
    expected = np.zeros(n)
    for face in mesh.polygons:
        for v in face.vertices:
            expected[v] = max(expected[v], per_face[face.index])
    np.testing.assert_allclose(distances, expected, rtol=1e-3, atol=1e-8)
    assert distances.max() == pytest.approx(new_obj["pia_fit_max_after"], rel=1e-5)

    colors = mesh.color_attributes.get(api.COLOR_ATTRIBUTE)
    assert colors is not None and colors.domain == 'POINT' and len(colors.data) == n
    assert mesh.color_attributes.active_color.name == api.COLOR_ATTRIBUTE
    rgba = np.empty(4 * n, np.float32)
    colors.data.foreach_get("color", rgba)
    np.testing.assert_allclose(rgba.reshape(n, 4), api.heat_colors(distances), atol=1e-6)
    np.testing.assert_allclose(api.heat_colors([0.0, api.HEAT_SCALE, 10 * api.HEAT_SCALE]),
                               [(0, 0, 1, 1), (1, 0, 0, 1), (1, 0, 0, 1)])

    for key in ("pia_fit", "pia_fit_target", "pia_fit_rounds", "pia_distance_scale",
                "pia_fit_mean_before", "pia_fit_p95_before", "pia_fit_max_before",
                "pia_fit_mean_after", "pia_fit_p95_after", "pia_fit_max_after"):
        assert key in new_obj, key
    assert (new_obj["pia_fit"], new_obj["pia_fit_target"]) == ('SURFACE', scan.name)
    assert 1 <= new_obj["pia_fit_rounds"] <= 20
    assert new_obj["pia_fit_mean_after"] < new_obj["pia_fit_mean_before"]
    assert new_obj["pia_fit_mean_after"] <= new_obj["pia_fit_p95_after"] <= new_obj["pia_fit_max_after"]
    mod = new_obj.modifiers[0]
    assert mod.type == 'SUBSURF' and mod.use_limit_surface


# --- real: the Stanford bunny scan and a QuadriFlow cage -----------------------------

def _level3_distances(obj, bvh, diag):
    """Distances of Blender's level-3 limit surface vertices to the scan, relative."""
    mod = obj.modifiers[0]
    mod.levels, mod.quality, mod.use_limit_surface = 3, 3, True
    return bvh_distances(bvh, evaluated_points(obj)) / diag


def test_bunny_scan_surface_fit():
    scan = import_obj(os.path.join(DATA, "bun_zipper.obj"))
    cage = import_obj(os.path.join(DATA, "bun_zipper_quadriflow_cage.obj"))
    assert np.allclose(np.array(cage.matrix_world), np.array(scan.matrix_world))
    new_obj = fit(cage, scan, fit='SURFACE', levels=3, quality=3)

    baseline = bpy.data.objects.new("Baseline", cage.data.copy())
    bpy.context.scene.collection.objects.link(baseline)
    baseline.matrix_world = cage.matrix_world.copy()
    baseline.modifiers.new("Subdivision", 'SUBSURF')

    vertices, polygons = scan_in_cage_space(scan, cage)
    diag = used_diagonal(vertices, polygons)
    bvh = bvh_of(vertices, polygons)
    stats = {}
    for label, obj in (("fitted", new_obj), ("baseline", baseline)):
        d = _level3_distances(obj, bvh, diag)
        kept = d[d <= 0.02]
        stats[label] = (float(kept.mean()), float(np.percentile(kept, 95)), float(kept.max()),
                        len(d) - len(kept))
    print("\nbunny level-3 distances (mean, p95, max, ignored): fitted %s, baseline %s; reported "
          "mean %.3g p95 %.3g max %.3g, %d rounds"
          % (stats["fitted"], stats["baseline"], new_obj["pia_fit_mean_after"],
             new_obj["pia_fit_p95_after"], new_obj["pia_fit_max_after"], new_obj["pia_fit_rounds"]))
    mean, p95 = stats["fitted"][:2]
    assert mean <= 1.5e-4, stats
    assert p95 <= 8e-4, stats
    assert stats["baseline"][0] >= 5 * mean, stats

    # Folds, judged by Blender's level-3 surface: its vertex normals against
    # the normal of the scan triangle holding each vertex's closest point
    # (the orientation most of them agree on).
    points, normals, _ = _level3_surface(new_obj)
    cosines, d = [], []
    for p, n in zip(points, normals):
        location, normal, _, distance = bvh.find_nearest(Vector(p))
        cosines.append(Vector(n).dot(normal))
        d.append(distance / diag)
    cosines, d = np.array(cosines), np.array(d)
    kept = d <= 0.02
    folded = float((np.sign(cosines[kept].sum()) * cosines[kept] < 0).mean())
    print("bunny level-3 points facing away from the scan: %.3f%% (reported on the samples %.3f%%)"
          % (100 * folded, 100 * new_obj["pia_fit_folded_after"]))
    assert folded < 0.001
    assert abs(new_obj["pia_fit_folded_after"] - folded) < 0.001


def _level3_surface(obj):
    """Blender's level-3 limit surface of obj: (vertices, vertex normals, polygons)."""
    mod = obj.modifiers[0]
    mod.levels, mod.quality, mod.use_limit_surface = 3, 3, True
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        pts = positions(mesh).astype(np.float64)
        nrm = np.empty(3 * len(mesh.vertices), np.float32)
        mesh.vertices.foreach_get("normal", nrm)
        return pts, nrm.reshape(-1, 3).astype(np.float64), [tuple(p.vertices) for p in mesh.polygons]
    finally:
        evaluated.to_mesh_clear()


def test_scan_to_surface_distances_are_blenders():
    """The reported distances from the scan's vertices to the fitted
    surface, against mathutils' BVH tree over Blender's own level-3
    surface (the library measures on a grid of the same density)."""
    scan = import_obj(os.path.join(DATA, "bun_zipper.obj"))
    cage = import_obj(os.path.join(DATA, "bun_zipper_quadriflow_cage.obj"))
    new_obj = fit(cage, scan, fit='SURFACE', levels=3, quality=3)
    points, _, faces = _level3_surface(new_obj)
    surface = bvh_of(points, faces)
    vertices, polygons = scan_in_cage_space(scan, cage)
    diag = used_diagonal(vertices, polygons)
    used = np.unique(np.fromiter((v for p in polygons for v in p), np.int64))
    d = bvh_distances(surface, vertices[used]) / diag
    kept = d <= new_obj["pia_fit_cutoff"]
    mean, p95, top = float(d[kept].mean()), float(np.percentile(d[kept], 95)), float(d[kept].max())
    print("scan to surface: Blender mean %.4g p95 %.4g max %.4g unreached %.4g; reported %.4g %.4g %.4g %.4g"
          % (mean, p95, top, 1 - kept.mean(), new_obj["pia_fit_scan_mean_after"], new_obj["pia_fit_scan_p95_after"],
             new_obj["pia_fit_scan_max_after"], new_obj["pia_fit_scan_unreached_after"]))
    assert new_obj["pia_fit_scan_points"] == len(used)
    assert new_obj["pia_fit_scan_mean_after"] == pytest.approx(mean, rel=0.02)
    assert new_obj["pia_fit_scan_p95_after"] == pytest.approx(p95, rel=0.03)
    assert new_obj["pia_fit_scan_max_after"] == pytest.approx(top, rel=0.05, abs=1e-4)
    assert new_obj["pia_fit_scan_unreached_after"] == pytest.approx(1 - kept.mean(), abs=2e-4)
    assert new_obj["pia_fit_scan_mean_before"] > 4 * new_obj["pia_fit_scan_mean_after"]


def _attribute(mesh, name, width=1):
    values = np.empty(len(mesh.vertices) * width, np.float32)
    mesh.attributes[name].data.foreach_get("color" if width == 4 else "value", values)
    return values.reshape(-1, width) if width > 1 else values


def test_paint_scan_writes_blenders_distances():
    """fit_paint_scan writes onto the scan each vertex's distance to the
    fitted surface, as mathutils' BVH tree over Blender's own level-3
    surface measures it, and its heat map (the active colour attribute);
    the scan changes in nothing else."""
    scan = import_obj(os.path.join(DATA, "bun_zipper.obj"))
    cage = import_obj(os.path.join(DATA, "bun_zipper_quadriflow_cage.obj"))
    before = snapshot(scan)
    names = set(scan.data.attributes.keys())
    new_obj = fit(cage, scan, fit='SURFACE', levels=3, quality=3, fit_paint_scan=True)
    assert new_obj["pia_fit_scan_painted"] and "pia_fit_scan_not_painted" not in new_obj
    assert set(scan.data.attributes.keys()) - names == {api.SCAN_DISTANCE_ATTRIBUTE, api.SCAN_COLOR_ATTRIBUTE}
    assert scan.data.color_attributes.active_color.name == api.SCAN_COLOR_ATTRIBUTE
    assert_unchanged(scan, before)
    painted = _attribute(scan.data, api.SCAN_DISTANCE_ATTRIBUTE)
    colors = _attribute(scan.data, api.SCAN_COLOR_ATTRIBUTE, 4)

    points, _, faces = _level3_surface(new_obj)
    vertices, polygons = scan_in_cage_space(scan, cage)
    diag = used_diagonal(vertices, polygons)
    used = np.unique(np.fromiter((v for p in polygons for v in p), np.int64))
    bvh = bvh_of(points, faces)
    nearest = [bvh.find_nearest(Vector(p)) for p in vertices[used]]
    d = np.array([hit[3] for hit in nearest]) / diag
    gap = np.abs(painted[used] - d)
    # The library's grid and Blender's level 3 are the same points of the
    # limit surface, their quads split into triangles their own ways.  Over
    # a quad (a, b, c, d) the two splits lie within |a - b + c - d| / 2 (its
    # twist) of each other, so a vertex whose closest point on Blender's
    # surface is on quad Q is no farther than Q's twist from the library's
    # surface; and no nearer to it than to both splits of every quad at
    # once.  Most vertices agree to a few percent of a typical distance
    # (distances written to the wrong vertices would not).
    quad = np.array([faces[hit[2]] for hit in nearest])
    twist = np.linalg.norm(points[quad[:, 0]] - points[quad[:, 1]] + points[quad[:, 2]] - points[quad[:, 3]],
                           axis=1) / (2 * diag)
    both = [t for f in faces for t in ((f[0], f[1], f[2]), (f[0], f[2], f[3]), (f[0], f[1], f[3]), (f[1], f[2], f[3]))]
    d_both = bvh_distances(bvh_of(points, both), vertices[used]) / diag
    print("painted against Blender's level-3 surface: median %.3g, 99th percentile %.3g, max %.3g of the "
          "diagonal (distances: median %.3g); beyond the twist %.3g, below both splits %.3g"
          % (np.median(gap), np.percentile(gap, 99), gap.max(), np.median(d), (painted[used] - d - twist).max(),
             (d_both - painted[used]).max()))
    assert np.median(gap) < 0.1 * np.median(d)
    assert np.percentile(gap, 99) < 0.5 * np.median(d)
    assert np.all(painted[used] - d <= twist + 1e-6)
    assert np.all(painted[used] >= d_both - 1e-6)
    np.testing.assert_allclose(colors[used], api.heat_colors(painted[used]), atol=1e-6)
    unused = np.setdiff1d(np.arange(len(painted)), used)
    assert (painted[unused] == -1.0).all()


def test_paint_scan_leaves_the_scan_alone_otherwise():
    """Without fit_paint_scan the scan gets nothing; with it, a vertex no
    face uses gets -1 and grey, and a scan whose modifiers change its
    vertices is left as it was, the new object saying why."""
    scan = fine_sphere(segments=32, rings=16)
    cage = quad_sphere(cuts=1)
    scan.data.vertices.add(1)  # a loose vertex: not measured
    scan.data.vertices[-1].co = (3.0, 0.0, 0.0)
    names = set(scan.data.attributes.keys())
    new_obj = fit(cage, scan, fit_cutoff=0.2)
    assert set(scan.data.attributes.keys()) == names and "pia_fit_scan_painted" not in new_obj

    new_obj = fit(cage, scan, fit_cutoff=0.2, fit_paint_scan=True)
    assert new_obj["pia_fit_scan_painted"]
    painted = _attribute(scan.data, api.SCAN_DISTANCE_ATTRIBUTE)
    colors = _attribute(scan.data, api.SCAN_COLOR_ATTRIBUTE, 4)
    assert painted[-1] == -1.0 and tuple(colors[-1]) == pytest.approx(api.UNMEASURED_COLOR)
    assert (painted[:-1] >= 0.0).all() and (painted[:-1] < 0.2).all()

    other = fine_sphere("Scan2", segments=32, rings=16)
    other.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    names = set(other.data.attributes.keys())
    new_obj = fit(cage, other, fit_cutoff=0.2, fit_paint_scan=True)
    assert not new_obj["pia_fit_scan_painted"]
    assert "modifiers change its vertices" in new_obj["pia_fit_scan_not_painted"]
    assert set(other.data.attributes.keys()) == names


def test_paint_scan_failing_midway_keeps_the_last_painting(monkeypatch):
    """Painting that fails after the distances are written (the colours
    do not convert) leaves the scan's attributes, their values and its active colour
    as the painting before left them, and makes no object."""
    scan = fine_sphere(segments=32, rings=16)
    cage = quad_sphere(cuts=1)
    fit(cage, scan, fit_cutoff=0.2, fit_paint_scan=True)
    mesh = scan.data
    before = {name: _attribute(mesh, name, 4 if name == api.SCAN_COLOR_ATTRIBUTE else 1)
              for name in (api.SCAN_DISTANCE_ATTRIBUTE, api.SCAN_COLOR_ATTRIBUTE)}
    names = set(mesh.attributes.keys())
    counts = (len(bpy.data.objects), len(bpy.data.meshes))
    real = objects.heat_colors
    n = len(mesh.vertices)
    # colours that only fail once converted for Blender: after both new attributes are made
    monkeypatch.setattr(objects, "heat_colors", lambda d: np.full((n, 4), "x", object) if len(d) == n else real(d))
    with pytest.raises(ValueError, match="could not convert"):
        api.interpolate(cage, target=scan.name, fit_cutoff=0.2, fit_smoothing=0.1, fit_paint_scan=True)
    assert set(mesh.attributes.keys()) == names
    assert mesh.color_attributes.active_color.name == api.SCAN_COLOR_ATTRIBUTE
    for name, values in before.items():
        np.testing.assert_array_equal(_attribute(mesh, name, values.shape[1] if values.ndim > 1 else 1), values)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == counts
    assert not [m for m in bpy.data.meshes if m.users == 0]


# --- bad input ------------------------------------------------------------------------

def _missing(cage):
    return dict(target="NoSuchScan"), r"Target 'NoSuchScan' not found"


def _not_mesh(cage):
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT')))
    return dict(target="Lamp"), r"Target 'Lamp' is not a mesh object \(type LIGHT\)"


def _no_faces(cage):
    wire = bpy.data.meshes.new("Wire")
    wire.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1), (1, 2)], [])
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Wire", wire))
    return dict(target="Wire"), r"Target 'Wire' has no faces"


def _empty_mesh(cage):
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Nothing", bpy.data.meshes.new("Nothing")))
    return dict(target="Nothing"), r"Target 'Nothing' has no faces"


def _itself(cage):
    return dict(target=cage.name), r"Target 'Cage' is the cage itself"


def _loop_surface(cage):
    return dict(target="Scan", scheme='LOOP', triangulate=True), r"Surface fit works on the Catmull-Clark .* only.*'Vertices'"


def _doo_sabin_surface(cage):
    return dict(target="Scan", scheme='DOO_SABIN'), r"Surface fit works on the Catmull-Clark .* only.*'Vertices'"


@pytest.mark.parametrize("case", (_missing, _not_mesh, _no_faces, _empty_mesh, _itself, _loop_surface,
                                  _doo_sabin_surface), ids=lambda f: f.__name__.strip("_"))
def test_bad_target_is_refused(case):
    fine_sphere(segments=16, rings=8)
    cage = quad_sphere(cuts=1)
    settings, pattern = case(cage)
    activate(cage)
    before = snapshot(cage)
    expect_error(pattern, fit='SURFACE', **settings)
    assert_unchanged(cage, before)
    assert not [o for o in bpy.data.objects if o.name.endswith("_pia")]


# --- transforms, modifiers on the scan --------------------------------------------------

@pytest.mark.parametrize("mode", ('SURFACE', 'VERTICES'))
def test_transforms_fit_in_the_cage_space(mode):
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    # Turned off the sphere's symmetry planes: a limit point on one of them
    # is equally close to two faces of the scan, and rounding picks either.
    cage.data.transform(Euler((0.3, 0.5, 0.7)).to_matrix().to_4x4())
    # A cut-off well above every distance: samples near the cut-off could
    # fall on either side of it with rounding and change the result.
    first = fit(cage, scan, fit=mode, fit_cutoff=0.1)
    plain = positions(first.data).astype(np.float64)

    # The same scan, relative to the cage, with other transforms on both.
    cage.matrix_world = Matrix.LocRotScale(Vector((1.0, -2.0, 0.5)), None, Vector((2.0, 2.0, 2.0)))
    scan_matrix = Matrix.LocRotScale(Vector((-3.0, 1.0, 4.0)), Matrix.Rotation(0.7, 3, 'X').to_quaternion(),
                                     Vector((0.5, 0.5, 0.5)))
    moved = scan.data.copy()
    co = positions(moved).astype(np.float64)
    m = np.array(scan_matrix.inverted() @ cage.matrix_world)
    moved.vertices.foreach_set("co", (co @ m[:3, :3].T + m[:3, 3]).astype(np.float32).ravel())
    moved.update()
    scan2 = bpy.data.objects.new("Scan2", moved)
    bpy.context.scene.collection.objects.link(scan2)
    scan2.matrix_world = scan_matrix
    bpy.context.view_layer.update()
    new_obj = fit(cage, scan2, fit=mode, fit_cutoff=0.1)
    assert np.allclose(np.array(new_obj.matrix_world), np.array(cage.matrix_world), atol=1e-6)
    transformed = positions(new_obj.data).astype(np.float64)
    diag = float(np.linalg.norm(plain.max(axis=0) - plain.min(axis=0)))
    print("\n%s: rounds %d / %d, means %.4g / %.4g, position difference %.3g of the diagonal"
          % (mode, first["pia_fit_rounds"], new_obj["pia_fit_rounds"], first["pia_fit_mean_after"],
             new_obj["pia_fit_mean_after"], np.abs(transformed - plain).max() / diag))
    assert np.abs(transformed - plain).max() / diag <= 1e-5
    assert new_obj["pia_fit_mean_after"] == pytest.approx(first["pia_fit_mean_after"], rel=0.02)


def test_scan_modifiers_are_applied():
    coarse = fine_sphere("Coarse", segments=12, rings=6)
    mod = coarse.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = 3
    cage = quad_sphere(cuts=2, radius=1.0)
    new_obj = fit(cage, coarse, fit='VERTICES')
    limit_points = evaluated_control_points(new_obj, len(cage.data.vertices))
    evaluated = scan_in_cage_space(coarse, new_obj)
    diag = used_diagonal(*evaluated)
    on_evaluated = bvh_distances(bvh_of(*evaluated), limit_points) / diag
    base = (positions(coarse.data).astype(np.float64), [tuple(p.vertices) for p in coarse.data.polygons])
    on_base = bvh_distances(bvh_of(*base), limit_points) / diag
    assert on_evaluated.max() <= 1e-5, on_evaluated.max()
    assert on_base.max() > 1e-3  # the base mesh is elsewhere: it was not what was fitted


def _evaluated_arrays(obj):
    """(positions, face sizes, face vertices) of obj as Blender evaluates it,
    by to_mesh() and per-face loops: independent of api.scan_arrays."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = evaluated.to_mesh()
    try:
        return (np.array([v.co[:] for v in me.vertices], np.float32),
                np.array([p.loop_total for p in me.polygons], np.int32),
                np.array([i for p in me.polygons for i in p.vertices], np.int32))
    finally:
        evaluated.to_mesh_clear()


def test_scan_read_as_blender_evaluates_it():
    """A scan without modifiers is read without a copy of its mesh; one with
    shape keys, or a modifier, through its evaluated copy: either way the
    arrays are those of Blender's evaluated mesh."""
    scan = fine_sphere("Plain", segments=24, rings=12)
    cage = quad_sphere(cuts=1)
    keyed = fine_sphere("Keyed", segments=24, rings=12)
    keyed.shape_key_add(name="Basis")
    key = keyed.shape_key_add(name="Squash")
    for point in key.data:
        point.co = point.co * Vector((1.0, 1.0, 0.5))
    key.value = 1.0
    modified = fine_sphere("Modified", segments=24, rings=12)
    modified.modifiers.new("Displace", 'DISPLACE').strength = 0.25
    bpy.context.view_layer.update()
    for obj in (scan, keyed, modified):
        got = api.scan_arrays(obj, cage)
        want = _evaluated_arrays(obj)
        for a, b in zip(got, want):
            assert a.shape == b.shape and np.array_equal(a, b), obj.name
    # The shape key and the modifier did move the vertices.
    base = positions(keyed.data)
    assert np.abs(api.scan_arrays(keyed, cage)[0] - base).max() > 0.1
    assert np.abs(api.scan_arrays(modified, cage)[0] - positions(modified.data)).max() > 0.1


# --- script API, progress, command line -----------------------------------------------

def test_api_fit_progress_and_cancel():
    scan = fine_sphere(segments=64, rings=32)
    cage = quad_sphere(cuts=2)
    calls = []
    new_obj, report = subdiv_pia.interpolate(cage, target=scan, fit='SURFACE',
                                             progress=lambda r, d: calls.append((r, d)) and False)
    assert isinstance(report, native.FitReport)
    # after every round; on a slow machine also within rounds (the round
    # under way, 0 before the first)
    assert sorted(set(r for r, _ in calls)) in (list(range(1, report.rounds + 1)), list(range(report.rounds + 1)))
    assert [r for r, _ in calls] == sorted(r for r, _ in calls)
    assert calls[-1][1] == pytest.approx(report.history[-1])
    line = api.format_fit_report(report, scan.name)
    assert line.startswith("Surface fit to '%s': mean distance" % scan.name) and "rounds" in line
    count = len(bpy.data.objects), len(bpy.data.meshes)
    # Reading the scan and its build call it too, so a cancel at the first
    # call stops there, and one at a later call within the build.
    with pytest.raises(native.PiaCancelled) as e:
        subdiv_pia.interpolate(cage, target=scan.name, progress=lambda r, d: True)
    assert "cancelled while reading the scan" in str(e.value), str(e.value)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count
    # (reading takes five steps, a call after each, before the build's)
    assert [r for r, _ in calls[:6]] == [0] * 6, calls[:8]
    seen = []
    with pytest.raises(native.PiaCancelled) as e:
        subdiv_pia.interpolate(cage, target=scan.name, progress=lambda r, d: seen.append(r) or len(seen) >= 6)
    assert "cancelled while" in str(e.value) and "scan" in str(e.value), str(e.value)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count

    # A cancel once a round is done stops the fit there, leaving nothing
    # either.
    def after_round_one(round_, mean):
        return round_ >= 1
    with pytest.raises(native.PiaCancelled) as e:
        subdiv_pia.interpolate(cage, target=scan.name, progress=after_round_one)
    assert "round" in str(e.value), str(e.value)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count
    # Every sample beyond the cut-off: refused with the reason, nothing made.
    with pytest.raises(native.PiaError) as e:
        subdiv_pia.interpolate(cage, target=scan, fit_cutoff=1e-6)
    assert "nothing to fit" in str(e.value) and "cut-off" in str(e.value)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count


def test_panel_passes_the_target():
    from test_ui import draw_panel
    scan = fine_sphere(segments=32, rings=16)
    cage = quad_sphere(cuts=1)
    settings = bpy.context.scene.subdiv_pia
    assert ("prop", "target_object") in draw_panel() and ("prop", "fit") not in draw_panel()
    settings.target_object = scan
    log = draw_panel()
    for name in ("target_object", "fit", "fit_cutoff", "fit_smoothing", "fit_samples", "fit_paint_scan"):
        assert ("prop", name) in log, name
    # a one-cut cube around the sphere is farther from it than the default cut-off
    assert bpy.ops.object.subdiv_pia_interpolate(target=settings.target_object.name,
                                                 fit_cutoff=0.2) == {'FINISHED'}
    labels = [text for kind, text in draw_panel() if kind == "label"]
    assert any(text.startswith("Surface fit to '%s'" % scan.name) for text in labels), labels
    assert any(text.startswith("Mean distance:") for text in labels), labels
    assert cage.name + "_pia" in bpy.data.objects


def _scan_and_cage_file(tmp_path):
    fine_sphere("Scan", segments=64, rings=32)
    quad_sphere("Cage", cuts=2)
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    return path, str(tmp_path / "out.blend")


def test_cli_fits_to_a_target(tmp_path):
    from test_api_cli import run_cli
    path, output = _scan_and_cage_file(tmp_path)
    result = run_cli(path, output, "--object", "Cage", "--target", "Scan", "--fit", "SURFACE",
                     "--fit-cutoff", "0.05", "--fit-samples", "3", "--fit-paint-scan")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Surface fit to 'Scan'" in result.stdout
    assert "distances to the surface written onto 'Scan'" in result.stdout
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = ["Cage_pia", "Scan"]
    new_obj, scan = data_to.objects
    assert new_obj["pia_fit_scan_painted"]
    painted = np.empty(len(scan.data.vertices), np.float32)
    scan.data.attributes[api.SCAN_DISTANCE_ATTRIBUTE].data.foreach_get("value", painted)
    assert (painted >= 0.0).all() and painted.max() < 0.05
    assert new_obj["pia_fit_samples"] == 3
    assert new_obj["pia_fit_sample_count"] == 6 * 3 * 3 * 3 * 3  # 54 quads, 9 samples each
    assert new_obj["pia_fit_cutoff"] == pytest.approx(0.05)
    result = run_cli(path, output, "--object", "Cage", "--target", "NoSuchScan")
    assert result.returncode == 1 and "NoSuchScan" in result.stderr


def test_cli_fit_progress_on_a_terminal(tmp_path):
    """On a terminal the fit shows each round and its mean distance."""
    from test_api_cli import run_cli_on_terminal
    path, output = _scan_and_cage_file(tmp_path)
    status, text = run_cli_on_terminal(path, output, "--object", "Cage", "--target", "Scan", "--fit-cutoff", "0.05")
    assert status == 0, text
    rounds = re.findall(r"\rround (\d+): mean distance ([0-9.e+-]+) of the scan's diagonal", text)
    assert rounds and max(int(r) for r, _ in rounds) >= 2, text
    assert "max error" not in text
