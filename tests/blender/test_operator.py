# SPDX-License-Identifier: GPL-3.0-or-later
"""Operator behaviour: what it makes, and bad input (clear message, nothing
created, source unchanged). bpy.ops raises RuntimeError carrying the message
when the operator reports an error."""

import math

import bmesh
import bpy
import numpy as np
import pytest

import shapes
from conftest import (MATCH, assert_unchanged, link_and_activate, object_from_pydata,
                      positions, relative_miss, run_operator, snapshot)


def counts():
    return len(bpy.data.objects), len(bpy.data.meshes)


def expect_error(pattern, **settings):
    before = counts()
    with pytest.raises(RuntimeError, match=pattern):
        run_operator(**settings)
    assert counts() == before, "nothing may be created on error"


# --- bad input -----------------------------------------------------------------

def test_no_active_object():
    shapes.cube()
    bpy.context.view_layer.objects.active = None
    expect_error(r"No active object")


@pytest.mark.parametrize("kind", ("EMPTY", "CAMERA"))
def test_non_mesh_object(kind):
    data = bpy.data.cameras.new("Cam") if kind == 'CAMERA' else None
    link_and_activate(bpy.data.objects.new("Thing", data))
    expect_error(r"'Thing' is not a mesh object \(type %s\)" % kind)


def test_mesh_without_vertices():
    source = link_and_activate(bpy.data.objects.new("Nothing", bpy.data.meshes.new("Nothing")))
    before = snapshot(source)
    expect_error(r"has no vertices")
    assert_unchanged(source, before)


def test_mesh_without_faces():
    source = object_from_pydata("Wire", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [], [(0, 1), (1, 2)])
    before = snapshot(source)
    expect_error(r"has no faces")
    assert_unchanged(source, before)


def test_nan_coordinates():
    source = shapes.cube()
    co = positions(source.data).copy()
    co[3, 1] = np.nan
    source.data.vertices.foreach_set("co", co.ravel())
    before = snapshot(source)
    expect_error(r"(?i)nan|finite")
    after = positions(source.data)
    assert np.isnan(after[3, 1])
    np.testing.assert_array_equal(np.delete(after, 3, 0), np.delete(before["positions"], 3, 0))
    assert [m.name for m in source.modifiers] == []


def test_stencils_beyond_memory(monkeypatch):
    # The estimate is set against a machine of 1 KB: refused up front, the
    # estimate in the message, nothing created, the source untouched.
    from subdiv_pia import api, settings
    source = shapes.cube()
    before = snapshot(source)
    sizes = [len(p.vertices) for p in source.data.polygons]
    need = api.stencil_memory_estimate(sizes, len(source.data.vertices), {})
    assert need > 1 << 10
    monkeypatch.setattr(settings, "machine_memory", lambda: 1 << 10)
    expect_error(r"OUT_OF_MEMORY|would need about [0-9.]+ GB .*more than this machine's")
    assert_unchanged(source, before)
    # With the machine's own memory the same cube goes through.
    monkeypatch.undo()
    assert api.machine_memory() is None or api.machine_memory() > need
    assert run_operator() == {'FINISHED'}


def test_degenerate_face():
    # from_pydata without validate() keeps a face that uses vertex 1 twice.
    source = object_from_pydata("Degenerate", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)],
                                [(0, 1, 2, 3), (1, 4, 4, 2)], validate=False)
    assert tuple(source.data.polygons[1].vertices) == (1, 4, 4, 2)
    before = snapshot(source)
    expect_error(r"(?i)degenerate|repeat|twice|same vertex|duplicate")
    assert_unchanged(source, before)


def test_max_iterations_reached():
    source = shapes.open_grid()
    before = snapshot(source)
    assert run_operator(max_iterations=1, tolerance=1e-12, method='PIA') == {'FINISHED'}
    new_obj = bpy.context.active_object
    assert new_obj is not source
    assert new_obj["pia_status"] in ('MAX_ITERATIONS', 'STAGNATED')
    assert new_obj["pia_iterations"] == 1
    assert new_obj["pia_max_error"] > 1e-12
    assert_unchanged(source, before)


def test_singular_cube_is_reported_not_converged():
    source = shapes.plain_cube()
    before = snapshot(source)
    assert run_operator(max_iterations=200) == {'FINISHED'}
    new_obj = bpy.context.active_object
    assert new_obj is not source
    assert new_obj["pia_status"] in ('MAX_ITERATIONS', 'STAGNATED')
    assert new_obj["pia_max_error"] > 1e-6
    assert_unchanged(source, before)


# --- what the operator makes -------------------------------------------------------

def test_new_object_copies_placement_and_data():
    parent = link_and_activate(bpy.data.objects.new("Parent", None))
    parent.location = (1.0, 2.0, 3.0)
    other = bpy.data.collections.new("Other")
    bpy.context.scene.collection.children.link(other)
    source = shapes.uv_sphere()
    other.objects.link(source)
    source.parent = parent
    source.matrix_parent_inverse = parent.matrix_world.inverted()
    source.location = (0.5, -1.0, 2.0)
    source.rotation_euler = (0.1, 0.2, 0.3)
    source.scale = (1.0, 2.0, 0.5)
    material = bpy.data.materials.new("Red")
    source.data.materials.append(material)
    source.data.uv_layers.new(name="UVMap")
    bpy.context.view_layer.update()
    bpy.context.view_layer.objects.active = source
    source.select_set(True)

    before = snapshot(source)
    assert run_operator() == {'FINISHED'}
    new_obj = bpy.context.active_object
    bpy.context.view_layer.update()
    assert new_obj.name == "%s_pia" % source.name
    assert new_obj.select_get() and not source.select_get()
    assert set(new_obj.users_collection) == set(source.users_collection)
    assert new_obj.parent == parent
    assert np.allclose(np.array(new_obj.matrix_world), np.array(source.matrix_world), atol=1e-6)
    assert new_obj.data is not source.data
    assert new_obj.material_slots[0].material == material
    assert "UVMap" in new_obj.data.uv_layers
    assert len(new_obj.data.vertices) == len(source.data.vertices)
    for key in ("pia_iterations", "pia_max_error", "pia_mean_error", "pia_status", "pia_method"):
        assert key in new_obj
    assert new_obj["pia_max_error"] <= 1e-6
    assert_unchanged(source, before)


def test_settings_from_source_modifier_without_limit_surface():
    source = shapes.cube()
    mod = source.modifiers.new("Subsurf", 'SUBSURF')
    mod.levels, mod.render_levels, mod.quality = 3, 4, 5
    mod.boundary_smooth = 'PRESERVE_CORNERS'
    mod.use_creases = False
    mod.use_limit_surface = False
    before = snapshot(source)
    targets = positions(source.data).astype(np.float64)
    assert bpy.ops.object.subdiv_pia_interpolate('INVOKE_DEFAULT') == {'FINISHED'}
    new_obj = bpy.context.active_object
    new_mod = new_obj.modifiers[0]
    assert len(new_obj.modifiers) == 1 and new_mod.type == 'SUBSURF'
    assert (new_mod.levels, new_mod.render_levels, new_mod.quality) == (3, 4, 5)
    assert new_mod.boundary_smooth == 'PRESERVE_CORNERS' and not new_mod.use_creases
    assert new_mod.use_limit_surface
    assert relative_miss(new_obj, targets) <= MATCH
    assert_unchanged(source, before)


def test_explicit_settings_override_source_modifier():
    source = shapes.cube()
    source.modifiers.new("Subsurf", 'SUBSURF').levels = 3
    assert run_operator(levels=1, quality=2) == {'FINISHED'}
    mod = bpy.context.active_object.modifiers[0]
    assert (mod.levels, mod.quality) == (1, 2)


def test_undo_restores_scene():
    # Background mode starts without an undo stack; ed.undo_push creates it,
    # and undo needs a step before the operator's own step.
    source = shapes.cube()
    source_name, mesh_name = source.name, source.data.name
    before = snapshot(source)
    bpy.ops.ed.undo_push(message="initial")
    bpy.ops.ed.undo_push(message="before interpolation")
    assert run_operator() == {'FINISHED'}
    assert "%s_pia" % source_name in bpy.data.objects
    bpy.ops.ed.undo()
    assert [o.name for o in bpy.data.objects] == [source_name]
    assert "%s_pia" % source_name not in bpy.data.meshes
    source = bpy.data.objects[source_name]
    assert source.data.name == mesh_name
    assert_unchanged(source, before)


def test_menu_and_panel_registered():
    assert hasattr(bpy.types, "DATA_PT_subdiv_pia")
    assert bpy.types.DATA_PT_subdiv_pia.bl_context == "modifier"
    settings = bpy.context.scene.subdiv_pia
    # the defaults of a new Subdivision Surface modifier
    assert settings.levels == 1 and settings.render_levels == 2 and settings.quality == 3
    assert math.isclose(settings.tolerance, 1e-6, rel_tol=1e-6)


def grid_edited_in_edit_mode():
    """An open grid in Edit Mode, its vertex 0 raised by 0.5 there (not yet in its mesh)."""
    source = shapes.open_grid()
    bpy.ops.object.mode_set(mode='EDIT')
    bm = bmesh.from_edit_mesh(source.data)
    bm.verts.ensure_lookup_table()
    bm.verts[0].co.z += 0.5
    bmesh.update_edit_mesh(source.data)
    return source


def test_edit_mode_edits_are_used():
    source = grid_edited_in_edit_mode()
    assert run_operator() == {'FINISHED'}
    assert source.mode == 'OBJECT'
    targets = positions(source.data).astype(np.float64)
    assert abs(targets[0, 2]) > 0.4
    assert relative_miss(bpy.context.active_object, targets) <= MATCH


def test_edit_mode_kept_when_refused():
    """Input refused after the operator left Edit Mode (Doo-Sabin needs a
    closed mesh): the source is back in Edit Mode with its edit, and
    nothing is made."""
    source = grid_edited_in_edit_mode()
    expect_error(r"closed", scheme='DOO_SABIN')
    assert source.mode == 'EDIT'
    assert bpy.context.view_layer.objects.active == source
    bm = bmesh.from_edit_mesh(source.data)
    bm.verts.ensure_lookup_table()
    assert abs(bm.verts[0].co.z) > 0.4


def test_edit_mode_kept_on_an_unforeseen_error(monkeypatch):
    """An error the operator does not name (here a KeyError from inside the
    run) reaches the caller as it is, and the source is back in Edit Mode."""
    from subdiv_pia import api

    def broken(*args, **kwargs):
        raise KeyError("broken on purpose")
    source = grid_edited_in_edit_mode()
    monkeypatch.setattr(api, "interpolate", broken)
    before = counts()
    with pytest.raises(RuntimeError, match="broken on purpose"):
        run_operator()
    assert counts() == before
    assert source.mode == 'EDIT'
