# SPDX-License-Identifier: GPL-3.0-or-later
"""Fixtures and helpers for the tests that run inside Blender (see run.py)."""

import os
import sys

import bpy
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DATA = os.path.join(ROOT, "tests", "data")

# Blender's evaluated control points must match the originals to this,
# relative to the bounding-box diagonal.
MATCH = 1e-5


def factory_reset():
    """An empty factory scene, with the add-on still registered.

    The reset also resets the preferences: an add-on or extension enabled
    there (an installed package, SUBDIV_PIA_ADDON_MODULE as run.py sets it)
    is disabled by it, and is enabled again here, as the same module.
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if getattr(bpy.types, "OBJECT_OT_subdiv_pia_interpolate", None) is not None:
        return
    name = os.environ.get("SUBDIV_PIA_ADDON_MODULE")
    if name:
        import addon_utils
        module = addon_utils.enable(name, default_set=True)
        assert module is sys.modules["subdiv_pia"], "enabling %s loaded another copy" % name
    else:
        sys.modules["subdiv_pia"].register()
    assert getattr(bpy.types, "OBJECT_OT_subdiv_pia_interpolate", None) is not None


@pytest.fixture(autouse=True)
def empty_scene():
    """Every test starts from an empty factory scene."""
    factory_reset()
    yield
    factory_reset()


def link_and_activate(obj):
    bpy.context.scene.collection.objects.link(obj)
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    return obj


def object_from_pydata(name, vertices, faces, edges=(), validate=True):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in vertices],
                     [tuple(e) for e in edges], [tuple(f) for f in faces])
    if validate:
        mesh.validate()
    mesh.update()
    return link_and_activate(bpy.data.objects.new(name, mesh))


from subdiv_pia.cli import import_mesh_file, operator_exists  # noqa: E402,F401  (run.py makes the add-on importable)


def import_obj(path):
    """The mesh of an OBJ file as the file has it (the importer's validation,
    on by default since Blender 4.2, would drop the scans' duplicate faces)."""
    before = set(bpy.data.objects)
    obj = import_mesh_file(path)
    new = [o for o in bpy.data.objects if o not in before and o.type == 'MESH']
    assert new == [obj], "expected one mesh object from %s" % path
    return link_and_activate_existing(obj)


def link_and_activate_existing(obj):
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    return obj


def positions(mesh):
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def diagonal(points):
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def evaluated_points(obj):
    """Every vertex of obj as Blender evaluates it (modifiers applied), in object space."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        return positions(mesh).astype(np.float64)
    finally:
        evaluated.to_mesh_clear()


def evaluated_control_points(obj, count):
    """First `count` vertices of obj as Blender evaluates it (modifiers applied)."""
    points = evaluated_points(obj)
    assert len(points) >= count
    return points[:count]


def relative_miss(obj, targets):
    """max |evaluated control point - target| / bbox diagonal of targets."""
    points = evaluated_control_points(obj, len(targets))
    return float(np.abs(points - targets).max()) / diagonal(targets)


def snapshot(obj):
    """What must not change on the source object."""
    return {
        "positions": positions(obj.data).copy(),
        "mesh": obj.data.name,
        "modifiers": [(m.name, m.type) + tuple(
            getattr(m, a) for a in ("levels", "render_levels", "quality", "boundary_smooth",
                                    "use_creases", "use_limit_surface"))
                      if m.type == 'SUBSURF' else (m.name, m.type) for m in obj.modifiers],
        "matrix": [list(row) for row in obj.matrix_world],
    }


def assert_unchanged(obj, before):
    after = snapshot(obj)
    np.testing.assert_array_equal(after["positions"], before["positions"])
    assert after["mesh"] == before["mesh"]
    assert after["modifiers"] == before["modifiers"]
    assert after["matrix"] == before["matrix"]


def run_operator(**settings):
    return bpy.ops.object.subdiv_pia_interpolate(**settings)


def object_counts():
    return len(bpy.data.objects), len(bpy.data.meshes)


def world(obj, points=None):
    """Positions of obj's vertices (or points in obj's space) in world space."""
    points = positions(obj.data) if points is None else points
    m = np.array(obj.matrix_world, dtype=np.float64)
    return points.astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def expect_error(pattern, **settings):
    """The operator refuses with a message matching pattern and makes nothing."""
    before = object_counts()
    with pytest.raises(RuntimeError, match=pattern) as info:
        run_operator(**settings)
    assert object_counts() == before, "nothing may be created on error"
    return str(info.value)


def make_limit_cage(source, scheme, setting_keys, **settings):
    """Run the operator with a scheme Blender cannot show (LOOP, DOO_SABIN);
    check the cage (no modifier, settings stored, converged) and its
    `_limit` child (parented, same collections, sitting on the cage); return
    (cage, limit, world-space targets)."""
    from subdiv_pia import api
    before = snapshot(source)
    targets = world(source)
    assert run_operator(scheme=scheme, **settings) == {'FINISHED'}
    cage = bpy.context.active_object
    assert cage is not source and cage.name.startswith(source.name + "_pia")
    assert cage.select_get() and not source.select_get()
    assert not [m for m in cage.modifiers if m.type == 'SUBSURF']
    for key in setting_keys:
        assert key in cage, key
    assert cage["pia_scheme"] == scheme
    assert cage["pia_status"] == 'CONVERGED', cage["pia_status"]
    limit = api.find_limit_object(cage)
    assert limit is not None and limit.name == cage.name + "_limit"
    assert limit.parent is cage
    assert set(limit.users_collection) == set(cage.users_collection)
    bpy.context.view_layer.update()
    assert np.array_equal(np.array(limit.matrix_basis), np.eye(4))
    assert np.array_equal(np.array(limit.matrix_parent_inverse), np.eye(4))
    assert np.allclose(np.array(limit.matrix_world), np.array(cage.matrix_world), atol=1e-6)
    assert_unchanged(source, before)
    return cage, limit, targets
