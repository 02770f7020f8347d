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
from conftest import DATA, assert_unchanged, diagonal, import_obj, object_from_pydata, positions, run_operator, snapshot
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


@pytest.mark.parametrize("order", ["computed", "matched"])
def test_finest_level_is_the_librarys_detail(order, monkeypatch):
    """Reshape puts Blender's finest level where the library put it: every
    vertex Blender shows is one of the library's points (computed again
    here, the library being deterministic), within float rounding, and
    each face Blender shows is one of the library's.  Blender's numbering
    computed (multires_order) or, where that cannot say, read from
    Blender's own subdivision and matched."""
    from subdiv_pia import detail as detail_module
    if order == "computed":
        monkeypatch.setattr(detail_module, "_subsurf_topology", lambda *a, **k: pytest.fail("Blender subdivided"))
    else:
        monkeypatch.setattr(detail_module, "order_work", lambda *a, **k: (lambda: None))
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
    # In Blender's order: each face Blender shows is one of the library's.
    library_faces = {frozenset(face) for face in detail.mesh.face_vertices.reshape(-1, 4).tolist()}
    assert all(frozenset(found[list(p)].tolist()) in library_faces for p in polygons)


def _mixed_mesh():
    """Quads around a hole, a triangle, a pentagon and a hexagon, with
    open edges, and a loose vertex."""
    vertices = [(x, y, 0.1 * x * y) for y in range(4) for x in range(4)]
    faces = [(y * 4 + x, y * 4 + x + 1, (y + 1) * 4 + x + 1, (y + 1) * 4 + x) for y in range(3) for x in range(3)
             if (x, y) != (1, 1)]
    vertices += [(1.5, -1.0, 0.2), (4.0, 0.5, 0.1), (4.0, 2.5, 0.3), (-0.5, -0.5, 0.0), (-0.2, -1.5, 0.1),
                 (0.8, -1.6, 0.2), (2.0, 2.0, 1.0)]
    faces += [(2, 1, 16), (3, 17, 18, 11, 7), (0, 19, 20, 21, 16, 1)]
    return vertices, faces


def _untidy_meshes():
    """A cage as scans leave them: a face turned the other way, an edge
    with three faces, two fans meeting at one vertex."""
    grid = [(x, y, 0.2 * np.sin(x + 2 * y)) for y in range(3) for x in range(3)]
    quads = [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8, 7)]
    return [("Turned", grid, [quads[0], quads[1][::-1], quads[2], quads[3]]),
            ("ThreeFaces", grid + [(1.5, 0.5, 1.0), (1.0, 0.5, 1.0)], quads + [(4, 5, 9, 10)]),
            ("Bowtie", grid + [(3.0, 3.0, 0.0), (3.0, 2.0, 0.0), (2.0, 3.0, 1.0)], quads + [(8, 10, 9, 11)])]


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_computed_order_is_blenders(levels):
    """multires_order's numbering of the library's levels against
    Blender's: its Subdivision Surface (control points, one pass at the
    finest level) puts each of its vertices where the library's levels put
    the vertex the order names; on tidy cages and untidy ones."""
    from subdiv_pia import detail, multires_order
    from subdiv_pia.mesh_io import mesh_arrays
    from conftest import object_from_pydata
    bpy.ops.mesh.primitive_cylinder_add(vertices=24, depth=1.0, location=(8.0, 0.0, 0.0))
    cylinder = bpy.context.active_object
    untidy = [object_from_pydata(name, vertices, faces, validate=False) for name, vertices, faces in _untidy_meshes()]
    for obj in [object_from_pydata("Mixed", *_mixed_mesh()), cylinder] + untidy:
        arrays = mesh_arrays(obj.data)
        assert obj.name != "Mixed" or len(arrays["positions"]) == 23  # the loose vertex kept
        mesh = native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"], edges=arrays["edges"])
        settings = {"quality": 3, "use_creases": True, "boundary_smooth": 'ALL'}
        meshes = [mesh]
        for _ in range(levels):
            meshes.append(native.subdivide(meshes[-1], 1, boundary_smooth='ALL'))
        order = multires_order.blender_order(arrays["face_sizes"], arrays["face_vertices"], arrays["edges"],
                                             len(arrays["positions"]),
                                             [(m.vertex_count, m.face_vertices) for m in meshes[1:]])
        top = detail._subsurf_topology(obj, levels, settings, bpy.context)
        try:
            theirs = positions(top).astype(np.float64)
        finally:
            bpy.data.meshes.remove(top)
        ours = meshes[-1].positions.astype(np.float64)[order]
        assert len(theirs) == len(ours)
        np.testing.assert_allclose(ours, theirs, atol=1e-5 * diagonal(theirs))


def test_computed_order_holds_where_positions_are_too_close_to_tell():
    """The elephant's cage has faces so small that, 3 levels down, vertices
    lie within 1e-5 of the diagonal of others: pairing by position mixes
    some of them up; the computed order puts every one of Blender's
    vertices within float rounding of its own."""
    from subdiv_pia import detail, multires_order
    from subdiv_pia.mesh_io import mesh_arrays
    obj = import_obj(DATA + "/elephant-with-holes_quadriflow_cage.obj")
    arrays = mesh_arrays(obj.data)
    meshes = [native.Mesh(arrays["positions"], arrays["face_sizes"], arrays["face_vertices"], edges=arrays["edges"])]
    for _ in range(3):
        meshes.append(native.subdivide(meshes[-1], 1))
    order = multires_order.blender_order(arrays["face_sizes"], arrays["face_vertices"], arrays["edges"],
                                         len(arrays["positions"]),
                                         [(m.vertex_count, m.face_vertices) for m in meshes[1:]])
    top = detail._subsurf_topology(obj, 3, {"quality": 3, "use_creases": True, "boundary_smooth": 'ALL'},
                                   bpy.context)
    try:
        theirs = positions(top).astype(np.float64)
    finally:
        bpy.data.meshes.remove(top)
    ours = meshes[-1].positions.astype(np.float64)
    unit = diagonal(theirs)
    assert np.linalg.norm(ours[order] - theirs, axis=1).max() < 1e-6 * unit
    # The premise: two of the library's vertices closer than the match's tolerance.
    tree = KDTree(len(ours))
    for i, p in enumerate(ours):
        tree.insert(Vector(p), i)
    tree.balance()
    nearest = min(tree.find_n(Vector(p), 2)[1][2] for p in ours)
    assert nearest < detail.MATCH_TOLERANCE * unit


def test_computed_order_refuses_what_it_cannot_number():
    """A loose edge (Blender puts points on it, the library does not), a
    level whose faces turn the other way and one missing a face are
    refused, for the match to take over."""
    from subdiv_pia import multires_order
    vertices = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 2, 0)], np.float32)
    quad = native.Mesh(vertices, np.array([4], np.int32), np.array([0, 1, 2, 3], np.int32))
    fine = native.subdivide(quad, 1)
    edges = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (2, 4)], np.int32)
    with pytest.raises(multires_order.OrderMismatch):
        multires_order.blender_order(quad.face_sizes, quad.face_vertices, edges, 5,
                                     [(fine.vertex_count, fine.face_vertices)])
    turned = np.ascontiguousarray(fine.face_vertices.reshape(-1, 4)[:, ::-1]).reshape(-1)
    with pytest.raises(multires_order.OrderMismatch, match="different vertices"):
        multires_order.blender_order(quad.face_sizes, quad.face_vertices, edges[:4], 5,
                                     [(fine.vertex_count, turned)])
    with pytest.raises(multires_order.OrderMismatch, match="a quad for each corner"):
        multires_order.blender_order(quad.face_sizes, quad.face_vertices, edges[:4], 5,
                                     [(fine.vertex_count, fine.face_vertices[:-4])])
    order = multires_order.blender_order(quad.face_sizes, quad.face_vertices, edges[:4], 5,
                                         [(fine.vertex_count, fine.face_vertices)])
    assert sorted(order.tolist()) == list(range(fine.vertex_count))


def test_levels_do_not_depend_on_how_they_are_made(monkeypatch):
    """The Multires levels are subdivided at quality 1, the first by
    Catmull-Clark and the next by Linear, the modifier hidden, and then
    reshaped at the settings' quality: every level Blender shows is the one
    an artist's Catmull-Clark Subdivides at the settings' quality, the
    modifier shown throughout, give."""
    from subdiv_pia import detail as detail_module
    scan = import_obj(DATA + "/bun_zipper.obj")
    cage = import_obj(DATA + "/bun_zipper_quadriflow_cage.obj")
    shown = []
    for quick in (True, False):
        if not quick:
            monkeypatch.setattr(detail_module, "SUBDIVIDE_QUALITY", None)
            monkeypatch.setattr(detail_module, "SUBDIVIDE_MODES", ('CATMULL_CLARK', 'CATMULL_CLARK'))
            monkeypatch.setattr(detail_module, "HIDE_WHILE_SUBDIVIDING", False)
        new_obj, _report = api.interpolate(cage, target=scan.name, fit_detail_levels=2)
        multires = new_obj.modifiers[0]
        assert multires.quality == 3 and multires.show_viewport
        levels = []
        for level in range(3):
            multires.levels = level
            levels.append(finest_level(new_obj)[0])
        shown.append(levels)
    assert len(shown[0][0]) < len(shown[0][1]) < len(shown[0][2])
    for fast, plain in zip(*shown):
        np.testing.assert_allclose(fast, plain, rtol=0, atol=1e-6 * diagonal(plain))


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


BLENDER_STAGES = ["computing Blender's numbering of the finest level",
                  "Blender: Multires, subdividing level 1 of 2", "Blender: Multires, subdividing level 2 of 2",
                  "Blender: Multires Reshape to the fitted positions"]


def _poll_through(job, stop_at=None):
    """Polls job as the operator's modal run does, a turn at a time; returns
    (result, the stages seen in order).  At stage text stop_at, cancels it
    as Esc does."""
    stages, result = [], None
    while not job.done:
        result = job.poll()
        if job.stage is not None and (not stages or stages[-1] != job.stage):
            stages.append(job.stage)
            if job.stage[0] == stop_at:
                job.cancel()
        if job.working():
            job._thread.join(0.01)
    return result, stages


def test_job_names_each_detail_stage_and_makes_what_interpolate_makes():
    """The operator's job names each level's fit (whose progress counts its
    rounds) and each of Blender's stages after them, each of which it
    begins on a turn of its own, where the window redraws; the object is
    interpolate's."""
    fine_sphere("Scan", segments=64, rings=32)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    plain, _report = api.interpolate(cage, target="Scan", fit_cutoff=0.3, fit_detail_levels=2, name="Plain")
    job = api.InterpolateJob(cage, target="Scan", fit_cutoff=0.3, fit_detail_levels=2, name="Job",
                             progress=lambda iteration, value: False)
    (new_obj, report), stages = _poll_through(job)
    assert [text for text, rounds in stages if not rounds] == BLENDER_STAGES
    levels = [text for text, rounds in stages if rounds]
    assert levels and set(levels) <= {"detail level 1 of 2", "detail level 2 of 2"} and levels[-1].endswith("2 of 2")
    assert stages.index((levels[-1], True)) < stages.index((BLENDER_STAGES[0], False))
    np.testing.assert_array_equal(finest_level(new_obj)[0], finest_level(plain)[0])
    assert new_obj["pia_fit_detail_mean"] == plain["pia_fit_detail_mean"]


@pytest.mark.parametrize("stage", [BLENDER_STAGES[0], BLENDER_STAGES[2], BLENDER_STAGES[3]])
def test_job_cancelled_between_blenders_stages_leaves_nothing(stage):
    fine_sphere("Scan", segments=64, rings=32)
    cage = quad_sphere("Cage", cuts=2, radius=0.8)
    before = snapshot(cage)
    count, meshes = len(bpy.data.objects), len(bpy.data.meshes)
    job = api.InterpolateJob(cage, target="Scan", fit_cutoff=0.3, fit_detail_levels=2,
                             progress=lambda iteration, value: False)
    with pytest.raises(native.PiaCancelled):
        _poll_through(job, stop_at=stage)
    assert job.cancelled and job.stage[0] == stage
    assert len(bpy.data.objects) == count and len(bpy.data.meshes) == meshes
    assert_unchanged(cage, before)


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
    np.testing.assert_array_equal(detail.match_order_searched(theirs.astype(np.float32), fine, diagonal), shuffle)


def test_the_order_match_pairs_what_its_grids_leave_over():
    """Points that no cube of match_order's grids pairs (moved apart, as
    Blender's rules at a non-manifold vertex put them, or two of the
    library's at one place) are paired nearest first; too far apart, the
    match refuses."""
    from subdiv_pia import detail
    rng = np.random.default_rng(7)
    ours = rng.random((4000, 3))
    diagonal = float(np.linalg.norm(np.ptp(ours, axis=0)))
    shuffle = rng.permutation(len(ours))
    theirs = ours[shuffle].copy()
    moved = rng.choice(len(ours), 6, replace=False)
    theirs[moved] += 50 * detail.MATCH_TOLERANCE * diagonal * np.array([1.0, 0.0, 0.0])
    mesh = native.Mesh.from_faces(ours.astype(np.float32), [(0, 1, 2, 3)])
    order = detail.match_order(theirs.astype(np.float32), mesh, diagonal)
    np.testing.assert_array_equal(order, shuffle)
    # Two of the library's at one place: each of Blender's two takes one.
    twins = ours.copy()
    twins[11] = twins[10]
    mesh = native.Mesh.from_faces(twins.astype(np.float32), [(0, 1, 2, 3)])
    order = detail.match_order(twins[shuffle].astype(np.float32), mesh, diagonal)
    assert sorted(order) == list(range(len(ours)))
    np.testing.assert_array_equal(twins[order], twins[shuffle])
    theirs[moved[0]] += 2 * detail.APART_TOLERANCE * diagonal
    with pytest.raises(RuntimeError, match="do not match"):
        detail.match_order(theirs.astype(np.float32), native.Mesh.from_faces(ours.astype(np.float32), [(0, 1, 2, 3)]),
                           diagonal)
