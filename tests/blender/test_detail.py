# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels (fit_detail_levels): the fitted cage's Multires modifier,
its levels fitted to the scan.  Judged by what Blender shows: the
evaluated Multires at its finest level, measured against the scan with
mathutils' BVH tree, against the library's own points, and against the
same cage without detail."""

import bpy
import numpy as np
import pytest
from mathutils import Vector
from mathutils.bvhtree import BVHTree
from mathutils.kdtree import KDTree

from subdiv_pia import api, native
from subdiv_pia.settings import opensubdiv_version_of
from conftest import DATA, assert_unchanged, import_obj, positions, run_operator, snapshot
from test_fit import bvh_distances, bvh_of, fine_sphere, quad_sphere, scan_in_cage_space, used_diagonal


def finest_level(obj):
    """(vertices (N, 3), polygons) of obj as Blender evaluates it (its Multires at the finest level)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        return positions(mesh).astype(np.float64), [tuple(p.vertices) for p in mesh.polygons]
    finally:
        evaluated.to_mesh_clear()


def face_centres(vertices, polygons):
    return np.array([vertices[list(p)].mean(axis=0) for p in polygons])


def without_detail(obj, levels):
    """obj's fitted cage shown by a Subdivision Surface modifier at `levels` (limit surface), evaluated."""
    copy = bpy.data.objects.new(obj.name + "_plain", obj.data.copy())
    bpy.context.scene.collection.objects.link(copy)
    modifier = copy.modifiers.new("Subdivision", 'SUBSURF')
    modifier.levels = levels
    try:
        return finest_level(copy)
    finally:
        bpy.data.objects.remove(copy)


def test_sphere_detail_lies_on_the_sphere():
    scan = fine_sphere("Scan", segments=128, rings=64)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    before = snapshot(cage)
    new_obj, report = api.interpolate(cage, target=scan.name, fit_cutoff=0.3, fit_detail_levels=2)
    assert_unchanged(cage, before)
    assert [m.type for m in new_obj.modifiers] == ['MULTIRES']
    multires = new_obj.modifiers[0]
    assert multires.total_levels == 2 and multires.levels == multires.render_levels == 2
    vertices, polygons = finest_level(new_obj)
    assert len(polygons) == 16 * len(cage.data.polygons)
    # On the scan (a UV sphere of radius 1): the flat quads straddle it,
    # vertices outside and face centres inside, within the quads' sagitta.
    quads = np.array(polygons)
    edge = np.linalg.norm(vertices[quads[:, 0]] - vertices[quads[:, 1]], axis=1).max()
    sagitta = 1.0 - np.cos(np.arcsin(edge / 2.0))
    radius = np.linalg.norm(vertices, axis=1)
    centres = np.linalg.norm(face_centres(vertices, polygons), axis=1)
    assert (radius > 1.0 - 1e-3).all() and (radius < 1.0 + 1.5 * sagitta).all()
    assert (centres < 1.0 + 1e-3).all() and (centres > 1.0 - 1.5 * sagitta).all()
    bvh = bvh_of(*scan_in_cage_space(scan, new_obj))
    assert bvh_distances(bvh, face_centres(vertices, polygons)).max() < 1.5 * sagitta
    assert new_obj["pia_fit_detail_levels"] == 2
    assert 0.0 < new_obj["pia_fit_detail_mean"] < 1e-3
    assert new_obj["pia_fit_detail_folded"] == 0.0


def test_finest_level_is_the_librarys_detail():
    """Reshape puts Blender's finest level where the library put it: every
    vertex Blender shows is one of the library's points (computed again
    here, the library being deterministic), within float rounding."""
    scan = import_obj(DATA + "/bun_zipper.obj")
    cage = import_obj(DATA + "/bun_zipper_quadriflow_cage.obj")
    new_obj, report = api.interpolate(cage, target=scan.name, fit_detail_levels=1)
    vertices, polygons = finest_level(new_obj)
    base = native.Mesh(positions(new_obj.data), *_faces(new_obj.data))
    scan_vertices, scan_polygons = scan_in_cage_space(scan, new_obj)
    native_scan = native.Scan(native.Mesh.from_faces(scan_vertices.astype(np.float32), scan_polygons))
    detail = native.fit_detail(base, native_scan, 1, opensubdiv_version=opensubdiv_version_of({}))
    tree = KDTree(len(detail.points))
    for i, p in enumerate(detail.points):
        tree.insert(Vector(p), i)
    tree.balance()
    found = np.array([tree.find(Vector(v))[1] for v in vertices])
    gaps = np.array([tree.find(Vector(v))[2] for v in vertices])
    diagonal = used_diagonal(scan_vertices, scan_polygons)
    assert gaps.max() < 1e-5 * diagonal
    assert len(np.unique(found)) == len(vertices) == len(detail.points)


def _faces(mesh):
    sizes = np.array([len(p.vertices) for p in mesh.polygons], np.int32)
    return sizes, np.array([v for p in mesh.polygons for v in p.vertices], np.int32)


def test_bunny_detail_is_closer_than_the_cage_alone():
    """On the Stanford bunny's raw scan: the detail at level 2 against the
    fitted cage's own surface at level 2, both ways, with mathutils' BVH."""
    scan = import_obj(DATA + "/bun_zipper.obj")
    cage = import_obj(DATA + "/bun_zipper_quadriflow_cage.obj")
    new_obj, report = api.interpolate(cage, target=scan.name, fit_detail_levels=2)
    scan_vertices, scan_polygons = scan_in_cage_space(scan, new_obj)
    diagonal = used_diagonal(scan_vertices, scan_polygons)
    scan_bvh = bvh_of(scan_vertices, scan_polygons)
    used = np.unique([v for p in scan_polygons for v in p])
    figures = {}
    for name, (vertices, polygons) in (("detail", finest_level(new_obj)), ("plain", without_detail(new_obj, 2))):
        to_scan = bvh_distances(scan_bvh, face_centres(vertices, polygons)) / diagonal
        from_scan = bvh_distances(bvh_of(vertices, polygons), scan_vertices[used]) / diagonal
        figures[name] = (to_scan.mean(), np.quantile(to_scan, 0.95), from_scan.mean(), np.quantile(from_scan, 0.95))
    detail, plain = figures["detail"], figures["plain"]
    assert detail[0] < 0.8 * plain[0] and detail[1] < 0.8 * plain[1], figures
    assert detail[2] < plain[2] and detail[3] < plain[3], figures


@pytest.mark.parametrize("settings, words", [
    (dict(fit_detail_levels=1), "set a target"),
    (dict(fit_detail_levels=1, target="Scan", fit='VERTICES'), "Fit 'Surface'"),
    (dict(fit_detail_levels=7, target="Scan"), "fit_detail_levels must be in 0..6"),
])
def test_bad_detail_settings_are_refused(settings, words):
    fine_sphere("Scan", segments=32, rings=16)
    cage = quad_sphere("Cage", cuts=1)
    before = snapshot(cage)
    count = len(bpy.data.objects)
    with pytest.raises(ValueError, match=words):
        api.interpolate(cage, **settings)
    assert len(bpy.data.objects) == count
    assert_unchanged(cage, before)


def test_live_cage_has_no_detail():
    fine_sphere("Scan", segments=32, rings=16)
    cage = quad_sphere("Cage", cuts=1)
    with pytest.raises(ValueError, match="Live"):
        api.interpolate(cage, target="Scan", fit_detail_levels=1, live=True)


def test_detail_cancel_leaves_nothing():
    fine_sphere("Scan", segments=64, rings=32)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    # The fit alone's progress calls, then a cancel two calls into the levels.
    base_calls = []
    plain, _report = api.interpolate(cage, target="Scan", fit_cutoff=0.3,
                                     progress=lambda it, value: base_calls.append(it) and False)
    bpy.data.objects.remove(plain)
    count, meshes = len(bpy.data.objects), len(bpy.data.meshes)
    calls = []

    def progress(iteration, value):
        calls.append(iteration)
        return len(calls) > len(base_calls) + 2
    with pytest.raises(native.PiaCancelled):
        api.interpolate(cage, target="Scan", fit_cutoff=0.3, fit_detail_levels=2, progress=progress)
    assert len(bpy.data.objects) == count and len(bpy.data.meshes) == meshes
    assert len(calls) == len(base_calls) + 3


def test_cli_detail_levels(tmp_path):
    from test_api_cli import run_cli
    fine_sphere("Scan", segments=64, rings=32)
    quad_sphere("Cage", cuts=2, radius=0.8)
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    output = str(tmp_path / "out.blend")
    result = run_cli(path, output, "--object", "Cage", "--target", "Scan", "--fit-cutoff", "0.3",
                     "--fit-detail-levels", "2")
    assert result.returncode == 0, result.stdout + result.stderr
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = ["Cage_pia"]
    new_obj = data_to.objects[0]
    assert [m.type for m in new_obj.modifiers] == ['MULTIRES'] and new_obj.modifiers[0].total_levels == 2
    assert new_obj["pia_fit_detail_levels"] == 2
    assert "Cage_pia: 2 detail levels in Multires: the finest" in result.stdout, result.stdout


def test_operator_reports_the_detail():
    scan = fine_sphere("Scan", segments=64, rings=32)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    assert run_operator(target=scan.name, fit_cutoff=0.3, fit_detail_levels=1) == {'FINISHED'}
    new_obj = bpy.data.objects["Cage_pia"]
    assert [m.type for m in new_obj.modifiers] == ['MULTIRES'] and new_obj.modifiers[0].total_levels == 1
    line = api.format_detail(new_obj)
    assert line.startswith("1 detail level in Multires: the finest") and "scan to it" in line
    assert api.format_detail(cage) == ""


def test_detail_beyond_memory_is_refused_up_front(monkeypatch):
    # A machine with 1 byte less than 6 detail levels of this cage need (the
    # finest fit's estimate; the cage's own stencils need far less): refused
    # before the scan is read, with the estimate in the message, nothing
    # made, the cage untouched.  One level fits on the same machine.
    from subdiv_pia import settings
    scan = fine_sphere("Scan", segments=64, rings=32)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    before = snapshot(cage)
    mesh = native.Mesh.from_faces(positions(cage.data), [list(p.vertices) for p in cage.data.polygons])
    need, faces = native.detail_memory_estimate(mesh, 6)
    assert faces == 4 ** 6 * len(cage.data.polygons)
    stencils = api.stencil_memory_estimate(mesh.face_sizes, mesh.vertex_count, {"fit": 'SURFACE'}, scan)
    assert stencils < need // 100
    monkeypatch.setattr(settings, "machine_memory", lambda: need - 1)
    count, meshes = len(bpy.data.objects), len(bpy.data.meshes)
    rounds = []
    words = r"6 detail levels would need about %.1f GB \(%.1fM faces" % (need / 2.0 ** 30, faces / 1e6)
    with pytest.raises(native.PiaError, match=words):
        api.interpolate(cage, target=scan.name, fit_cutoff=0.3, fit_detail_levels=6,
                        progress=lambda it, value: rounds.append(it) or False)
    assert rounds == []  # neither the scan's build nor the fit called back
    assert len(bpy.data.objects) == count and len(bpy.data.meshes) == meshes
    assert_unchanged(cage, before)
    new_obj, _report = api.interpolate(cage, target=scan.name, fit_cutoff=0.3, fit_detail_levels=1)
    assert new_obj.modifiers[0].total_levels == 1


def test_the_order_match_pairs_every_vertex_with_its_own():
    """detail.match_order against the permutation it must undo: the
    library's subdivided grid shuffled and every point moved by a tenth of
    the match tolerance."""
    from subdiv_pia import detail
    n = 24
    g = np.linspace(0.0, 1.0, n + 1)
    xs, ys = np.meshgrid(g, g, indexing="ij")
    points = np.stack([xs.ravel(), ys.ravel(), 0.1 * np.sin(5 * xs.ravel()) * ys.ravel()], axis=1)
    quads = [(i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1)
             for i in range(n) for j in range(n)]
    fine = native.subdivide(native.Mesh.from_faces(points.astype(np.float32), quads), 2)
    ours = fine.positions.astype(np.float64)
    diagonal = float(np.linalg.norm(np.ptp(ours, axis=0)))
    rng = np.random.default_rng(5)
    shuffle = rng.permutation(len(ours))
    theirs = ours[shuffle] + rng.normal(scale=0.1 * detail.MATCH_TOLERANCE * diagonal / 3 ** 0.5, size=ours.shape)
    order = detail.match_order(theirs.astype(np.float32), fine, diagonal)
    np.testing.assert_array_equal(order, shuffle)
