# SPDX-License-Identifier: GPL-3.0-or-later
"""Loop scheme: Blender has no Loop modifier, so the operator makes the cage
(no modifier) and a child `<cage>_limit` holding the library's Loop limit
surface (native.refine). Its first N vertices are the limit points of
the N cage vertices: they must be the original vertices, as Blender stores
them (positions read back from the objects, in world space)."""

import os

import bpy
import numpy as np
import pytest

import shapes
import subdiv_pia
from subdiv_pia import api, native
from conftest import (DATA, MATCH, assert_unchanged, diagonal, expect_error, import_obj, make_limit_cage,
                      positions, run_operator, snapshot, world)
from test_api_cli import run_cli
from test_ui import draw_panel

SETTING_KEYS = ("pia_scheme", "pia_boundary_rule", "pia_boundary_smooth", "pia_use_creases",
                "pia_triangulate", "pia_levels", "pia_status", "pia_method", "pia_iterations",
                "pia_max_error", "pia_tolerance")


def make_loop(source, **settings):
    return make_limit_cage(source, 'LOOP', SETTING_KEYS, **settings)


def check_limit(cage, limit, targets, levels):
    bpy.context.view_layer.update()  # matrix_world of a new child
    mesh = limit.data
    n = len(cage.data.vertices)
    assert n == len(targets)
    sizes = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    assert (sizes == 3).all()
    assert len(mesh.polygons) == len(cage.data.polygons) * 4 ** levels
    assert len(mesh.vertices) > n if levels else len(mesh.vertices) == n
    smooth = np.empty(len(mesh.polygons), bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    assert smooth.all()
    miss = float(np.abs(world(limit)[:n] - targets).max()) / diagonal(targets)
    assert miss <= MATCH, "levels=%d: limit misses the original vertices by %.3g of diagonal" % (
        levels, miss)
    return miss


# --- meshes made by others ---------------------------------------------------------

REAL = [(name, rule, levels) for name in ("bunny", "elephant-with-holes", "teapot")
        for rule in ('SMOOTH', 'HOPPE') for levels in (1, 2)]


@pytest.mark.parametrize("name,rule,levels", REAL, ids=["%s-%s-L%d" % c for c in REAL])
def test_real_mesh(name, rule, levels):
    source = import_obj(os.path.join(DATA, name + ".obj"))
    cage, limit, targets = make_loop(source, boundary_rule=rule, levels=levels)
    assert cage["pia_boundary_rule"] == rule and cage["pia_levels"] == levels
    check_limit(cage, limit, targets, levels)
    # The cage differs from the mesh: the plain Loop surface of the mesh misses.
    plain = api.limit_arrays(source.data, api.stored_settings(cage))[0]
    assert np.abs(world(source, plain[:len(targets)]) - targets).max() > 1e-4 * diagonal(targets)


def test_placement_follows_source():
    source = import_obj(os.path.join(DATA, "teapot.obj"))
    source.location = (1.0, -2.0, 0.5)
    source.rotation_euler = (0.3, 0.1, -0.4)
    source.scale = (1.5, 0.5, 2.0)
    material = bpy.data.materials.new("Blue")
    source.data.materials.append(material)
    bpy.context.view_layer.update()
    cage, limit, targets = make_loop(source, levels=1, boundary_smooth='PRESERVE_CORNERS')
    assert np.allclose(np.array(cage.matrix_world), np.array(source.matrix_world), atol=1e-6)
    assert cage.material_slots[0].material == material
    check_limit(cage, limit, targets, 1)


def test_boundary_first_reaches_the_same_cage():
    """The open-mesh paper's staged solve, from the operator: the same cage
    as solving everything at once, and both stages reported."""
    source = import_obj(os.path.join(DATA, "teapot.obj"))
    together, _, targets = make_loop(source, levels=1, boundary_rule='HOPPE', tolerance=1e-7)
    bpy.context.view_layer.objects.active = source
    source.select_set(True)
    staged, limit, _ = make_loop(source, levels=1, boundary_rule='HOPPE', tolerance=1e-7, staged=True)
    assert staged["pia_staged"] and not together["pia_staged"]
    check_limit(staged, limit, targets, 1)
    assert np.abs(positions(staged.data) - positions(together.data)).max() < 1e-5 * diagonal(targets)
    _, report = subdiv_pia.interpolate(source, scheme='LOOP', boundary_rule='HOPPE', staged=True, levels=1)
    assert report.stage_iterations[0] > 0 and report.stage_iterations[1] > 0
    assert "boundary first" in api.format_report(report)


def test_closed_mesh_uses_cg():
    source = shapes.ico_sphere()
    cage, limit, targets = make_loop(source, levels=2, method='CG')
    assert cage["pia_method"] == 'CG'
    check_limit(cage, limit, targets, 2)


# --- bad input and triangulate ----------------------------------------------------

def test_quads_refused_without_triangulate():
    source = shapes.open_grid()  # 5 x 4 quads
    before = snapshot(source)
    message = expect_error(r"20 of 20 faces are not", scheme='LOOP')
    assert "Triangulate" in message
    assert_unchanged(source, before)


def test_mixed_mesh_refused_names_count():
    source = shapes.mixed()  # three quads, two triangles, one pentagon
    expect_error(r"needs triangles: 4 of 6 faces are not", scheme='LOOP')
    assert len(source.data.polygons) == 6


@pytest.mark.parametrize("make", (shapes.open_grid,
                                  lambda: import_obj(os.path.join(DATA, "mushroom.obj"))),
                         ids=("grid", "mushroom"))
def test_triangulate(make):
    source = make()
    faces = len(source.data.polygons)
    cage, limit, targets = make_loop(source, triangulate=True, levels=1)
    sizes = np.empty(len(cage.data.polygons), np.int32)
    cage.data.polygons.foreach_get("loop_total", sizes)
    assert (sizes == 3).all() and len(sizes) > faces
    assert len(source.data.polygons) == faces  # the source keeps its quads
    assert bool(cage["pia_triangulate"])
    check_limit(cage, limit, targets, 1)


def test_triangulate_ignored_for_catmull_clark():
    source = shapes.open_grid()
    assert run_operator(triangulate=True) == {'FINISHED'}
    new_obj = bpy.context.active_object
    assert len(new_obj.data.polygons) == len(source.data.polygons)
    assert new_obj.modifiers[0].type == 'SUBSURF'
    assert api.find_limit_object(new_obj) is None


def test_hoppe_refuses_non_manifold_fin():
    source = shapes.fin()
    before = snapshot(source)
    expect_error(r"Hoppe's boundary rules need a manifold mesh: \d+ vertices are non-manifold",
                 scheme='LOOP', boundary_rule='HOPPE', triangulate=True)
    assert_unchanged(source, before)
    cage, limit, targets = make_loop(source, boundary_rule='SMOOTH', triangulate=True, levels=1)
    assert len(limit.data.polygons) == 4 * len(cage.data.polygons)


def test_fin_smooth_limit_passes_through():
    """Next to a non-manifold edge the stencils and the preview both use
    OpenSubdiv's exact limit masks, so the preview passes through vertex 7
    (in one triangle beside the edge of three faces) too."""
    source = shapes.fin()
    cage, limit, targets = make_loop(source, boundary_rule='SMOOTH', triangulate=True, levels=1)
    check_limit(cage, limit, targets, 1)


def test_cg_refused_for_open_meshes():
    shapes.open_grid()
    expect_error(r"'Grid': CG needs .*use AUTO", method='CG')
    import_obj(os.path.join(DATA, "teapot.obj"))
    expect_error(r"CG needs .*closed meshes", scheme='LOOP', method='CG')


def test_too_many_levels():
    shapes.ico_sphere()
    expect_error(r"levels must be in 0\.\.8", scheme='LOOP', levels=9)


def test_a_preview_beyond_memory_is_refused_before_it_is_made():
    """8 levels of a 20,480-triangle sphere would make 1.3 billion triangles
    (some 380 GB): the library refuses before it allocates, naming the
    levels that fit, and the operator reports it and makes nothing."""
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=6)
    source = bpy.context.active_object
    before = snapshot(source)
    message = expect_error(r"refining 8 levels \(1342177280 faces\) needs about [0-9.]+ GB, more than the [0-9.]+ "
                           r"GB of memory available: at most [1-7] levels? fit", scheme='LOOP', levels=8)
    assert "GB of memory available" in message
    assert_unchanged(source, before)


# --- refresh ----------------------------------------------------------------------

def limit_positions(limit):
    return positions(limit.data).astype(np.float64)


def test_refresh_after_editing_cage():
    source = import_obj(os.path.join(DATA, "elephant-with-holes.obj"))
    cage, limit, targets = make_loop(source, levels=1, boundary_rule='HOPPE')
    old = limit_positions(limit)
    old_mesh_name = limit.data.name
    co = positions(cage.data).copy()
    moved = 100
    step = 0.05 * diagonal(targets)
    co[moved, 2] += step
    cage.data.vertices.foreach_set("co", co.ravel())
    cage.data.update()
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    assert api.find_limit_object(cage) is limit
    assert limit.data.name == old_mesh_name  # replaced, old one removed
    new = limit_positions(limit)
    expected = native.refine(native.Mesh(**_arrays(cage)), 1, boundary_rule='HOPPE')[0]
    np.testing.assert_allclose(new, expected, atol=1e-6 * diagonal(targets))
    # the limit point of the moved vertex rose (not by the full step: it is an average)
    rise = new[moved, 2] - old[moved, 2]
    assert 0.2 * step < rise < step
    # unmoved vertices far away did not change; some neighbours did
    changed = np.abs(new[:len(co)] - old[:len(co)]).max(axis=1) > 1e-7 * diagonal(targets)
    assert 2 <= changed.sum() < 30


def _arrays(cage):
    a = api.mesh_arrays(cage.data)
    return {k: a[k] for k in ("positions", "face_sizes", "face_vertices", "edges")}


def test_refresh_from_child_and_recreates_deleted_child():
    source = shapes.ico_sphere()
    cage, limit, targets = make_loop(source, levels=1)
    before = limit_positions(limit)
    # selecting the child works too
    bpy.context.view_layer.objects.active = limit
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    np.testing.assert_allclose(limit_positions(limit), before, atol=1e-7)
    bpy.data.objects.remove(limit)
    assert api.find_limit_object(cage) is None
    bpy.context.view_layer.objects.active = cage
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    limit = api.find_limit_object(cage)
    assert limit is not None and limit.parent is cage and limit.name == cage.name + "_limit"
    check_limit(cage, limit, targets, 1)


def test_refresh_refuses_non_loop_objects():
    source = shapes.cube()
    with pytest.raises(RuntimeError, match=r"'Cube' is not a Loop cage"):
        bpy.ops.object.subdiv_pia_refresh_limit()
    run_operator()  # a Catmull-Clark cage is not a Loop cage either
    with pytest.raises(RuntimeError, match=r"is not a Loop cage"):
        bpy.ops.object.subdiv_pia_refresh_limit()
    bpy.context.view_layer.objects.active = None
    with pytest.raises(RuntimeError, match=r"No active object"):
        bpy.ops.object.subdiv_pia_refresh_limit()
    assert source.name in bpy.data.objects


def test_refresh_refuses_cage_edited_into_quads():
    source = shapes.ico_sphere()
    cage, limit, targets = make_loop(source, levels=1)
    before = limit_positions(limit)
    bpy.ops.object.mode_set(mode='EDIT')
    bpy.ops.mesh.select_all(action='SELECT')
    bpy.ops.mesh.tris_convert_to_quads()
    bpy.ops.object.mode_set(mode='OBJECT')
    with pytest.raises(RuntimeError, match=r"needs triangles"):
        bpy.ops.object.subdiv_pia_refresh_limit()
    np.testing.assert_array_equal(limit_positions(limit), before)


def test_refresh_undo():
    source = shapes.ico_sphere()
    bpy.ops.ed.undo_push(message="initial")
    bpy.ops.ed.undo_push(message="before interpolation")
    cage, limit, targets = make_loop(source, levels=1)
    before = limit_positions(limit)
    cage_name = cage.name
    bpy.ops.ed.undo_push(message="interpolated")
    co = positions(cage.data).copy()
    co[0] *= 1.2
    cage.data.vertices.foreach_set("co", co.ravel())
    cage.data.update()
    bpy.ops.ed.undo_push(message="edited")
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    assert np.abs(limit_positions(limit) - before).max() > 1e-4
    bpy.ops.ed.undo()
    limit = api.find_limit_object(bpy.data.objects[cage_name])
    np.testing.assert_allclose(limit_positions(limit), before, atol=1e-7)


# --- script API, command line, panel ------------------------------------------------

def test_api_loop_and_refresh():
    source = import_obj(os.path.join(DATA, "teapot.obj"))
    targets = world(source)
    cage, report = subdiv_pia.interpolate(source, scheme='LOOP', levels=1, boundary_rule='HOPPE')
    assert report.converged and cage["pia_scheme"] == 'LOOP'
    limit = subdiv_pia.find_limit_object(cage)
    check_limit(cage, limit, targets, 1)
    assert subdiv_pia.refresh_limit(limit) is limit
    check_limit(cage, limit, targets, 1)
    with pytest.raises(ValueError, match="boundary_rule"):
        subdiv_pia.interpolate(source, scheme='LOOP', boundary_rule='CATMARK')


def test_cli_loop(tmp_path):
    output = str(tmp_path / "teapot_loop.blend")
    result = run_cli(os.path.join(DATA, "mushroom.obj"), output, "--scheme", "LOOP",
                     "--triangulate", "--boundary-rule", "HOPPE", "--levels", "1")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Converged" in result.stdout and "mushroom_pia_limit" in result.stdout
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = [n for n in data_from.objects if n.startswith("mushroom")]
    objects = {o.name: o for o in data_to.objects}
    cage, limit = objects["mushroom_pia"], objects["mushroom_pia_limit"]
    assert limit.parent is cage and not cage.modifiers
    assert cage["pia_boundary_rule"] == 'HOPPE'
    n = len(cage.data.vertices)
    targets = positions(objects["mushroom"].data).astype(np.float64)
    miss = float(np.abs(positions(limit.data)[:n] - targets).max()) / diagonal(targets)
    assert miss <= MATCH


def test_cli_loop_refuses_quads(tmp_path):
    output = str(tmp_path / "never.blend")
    result = run_cli(os.path.join(DATA, "mushroom.obj"), output, "--scheme", "LOOP")
    assert result.returncode == 1
    assert "208 of 240 faces are not" in result.stderr
    assert not os.path.exists(output)


def test_panel_shows_loop_settings_and_refresh_button():
    source = shapes.ico_sphere()
    log = draw_panel()
    assert ("prop", "boundary_rule") not in log and ("prop", "triangulate") not in log  # Catmull-Clark
    bpy.context.scene.subdiv_pia.scheme = 'LOOP'
    log = draw_panel()
    assert ("prop", "boundary_rule") in log and ("prop", "triangulate") in log
    assert ("operator", "object.subdiv_pia_refresh_limit") not in log
    make_loop(source, levels=1)
    assert ("operator", "object.subdiv_pia_refresh_limit") in draw_panel()
    bpy.context.view_layer.objects.active = api.find_limit_object(bpy.context.active_object)
    assert ("operator", "object.subdiv_pia_refresh_limit") in draw_panel()
