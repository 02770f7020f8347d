# SPDX-License-Identifier: GPL-3.0-or-later
"""Two-phase Doo-Sabin: Blender has no Doo-Sabin modifier, so the operator
makes the cage (no modifier) and a child `<cage>_limit` holding the cage
refined by the library (native.refine). That is a control mesh: its
vertices are not on the limit surface, but the centroids of its faces are.

After one level the faces of native.refine are the F-faces (one per cage
face), then the E-faces (one per edge), then the V-faces in vertex order;
deeper levels keep each face index on its descendant, so the centroid of
face F + E + v (any level >= 1) is the limit point of cage vertex v. Those
centroids, read back from the `_limit` object Blender holds, must be the
original vertices."""

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

SETTING_KEYS = ("pia_scheme", "pia_levels", "pia_shape_parameter", "pia_shape_attribute",
                "pia_status", "pia_method", "pia_iterations", "pia_max_error", "pia_tolerance")
CLOSED = ("mushroom", "double-torus")


def face_sizes(mesh):
    sizes = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    return sizes


def centroids(mesh):
    """Centroid of every face of a Blender mesh, in the mesh's space."""
    starts = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    sizes = face_sizes(mesh)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    order = np.concatenate([np.arange(s, s + n) for s, n in zip(starts, sizes)])
    points = positions(mesh).astype(np.float64)[corners[order]]
    offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    return np.add.reduceat(points, offsets, axis=0) / sizes[:, None]


def limit_points(cage, limit):
    """World-space limit points of the cage vertices: centroids of the V-faces."""
    f, e, n = len(cage.data.polygons), len(cage.data.edges), len(cage.data.vertices)
    return world(limit, centroids(limit.data)[f + e:f + e + n])


def shape_values(mesh, name="pia_shape"):
    attr = mesh.attributes[name]
    values = np.empty(len(attr.data), np.float32)
    attr.data.foreach_get("value", values)
    return values


def add_shape_attribute(obj, values, name="pia_shape"):
    attr = obj.data.attributes.new(name, 'FLOAT', 'FACE')
    attr.data.foreach_set("value", np.asarray(values, np.float32))
    obj.data.update()
    return attr


def native_cage_mesh(cage):
    a = api.mesh_arrays(cage.data)
    return native.Mesh(a["positions"], a["face_sizes"], a["face_vertices"], edges=a["edges"])


def make_doosabin(source, **settings):
    return make_limit_cage(source, 'DOO_SABIN', SETTING_KEYS, **settings)


def check_limit(cage, limit, targets, levels, shape=None):
    """The `_limit` child is native.refine of the cage and its V-face
    centroids are the original vertices; so are the library's limit points."""
    bpy.context.view_layer.update()
    mesh = limit.data
    f, e, n = len(cage.data.polygons), len(cage.data.edges), len(cage.data.vertices)
    assert n == len(targets)
    if levels == 1:
        assert len(mesh.polygons) == f + e + n
        # V-face v has one corner per edge at v; E-faces are quads.
        ends = np.empty(2 * e, np.int32)
        cage.data.edges.foreach_get("vertices", ends)
        np.testing.assert_array_equal(face_sizes(mesh)[f + e:], np.bincount(ends, minlength=n))
        assert (face_sizes(mesh)[f:f + e] == 4).all()
        np.testing.assert_array_equal(face_sizes(mesh)[:f], face_sizes(cage.data))
    assert len(mesh.polygons) >= f + e + n
    smooth = np.empty(len(mesh.polygons), bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    assert smooth.all()
    values = (api.face_shape_parameters(cage.data, api.stored_settings(cage))
              if shape is None else None)
    uniform = float(cage["pia_shape_parameter"]) if shape is None else shape
    expected, sizes, _ = native.refine(native_cage_mesh(cage), levels, scheme='DOO_SABIN',
                                       shape_parameter=uniform, face_shape_parameters=values)
    np.testing.assert_array_equal(face_sizes(mesh), sizes)
    np.testing.assert_allclose(positions(mesh), expected, atol=1e-6 * diagonal(targets))
    miss = float(np.abs(limit_points(cage, limit) - targets).max()) / diagonal(targets)
    assert miss <= MATCH, "levels=%d: V-face centroids miss the original vertices by %.3g" % (
        levels, miss)
    stencils = native.limit_stencils(native_cage_mesh(cage), scheme='DOO_SABIN',
                                     shape_parameter=uniform, face_shape_parameters=values)
    points = world(cage, stencils.apply(positions(cage.data)))
    assert float(np.abs(points - targets).max()) / diagonal(targets) < MATCH
    return miss


# --- closed meshes made by others -------------------------------------------------------

REAL = [(name, shape, levels) for name in CLOSED for shape in (0.5, 0.8) for levels in (1, 2)]


@pytest.mark.parametrize("name,shape,levels", REAL, ids=["%s-%g-L%d" % c for c in REAL])
def test_real_mesh(name, shape, levels):
    source = import_obj(os.path.join(DATA, name + ".obj"))
    sizes = face_sizes(source.data)
    assert len(set(sizes.tolist())) > 1  # mixed face sizes
    cage, limit, targets = make_doosabin(source, shape_parameter=shape, levels=levels)
    assert cage["pia_shape_parameter"] == pytest.approx(shape)
    assert cage["pia_levels"] == levels
    np.testing.assert_array_equal(face_sizes(cage.data), sizes)
    check_limit(cage, limit, targets, levels)
    # The cage differs from the mesh: the mesh's own surface misses the vertices.
    stencils = native.limit_stencils(native_cage_mesh(source), scheme='DOO_SABIN',
                                     shape_parameter=shape)
    plain = world(source, stencils.apply(positions(source.data)))
    assert np.abs(plain - targets).max() > 1e-4 * diagonal(targets)


def test_shape_parameter_changes_the_cage():
    source = import_obj(os.path.join(DATA, "double-torus.obj"))
    cage_a, _, targets = make_doosabin(source, shape_parameter=0.5, levels=1)
    bpy.context.view_layer.objects.active = source
    source.select_set(True)
    cage_b, limit_b, _ = make_doosabin(source, shape_parameter=0.8, levels=1)
    gap = np.abs(positions(cage_a.data) - positions(cage_b.data)).max()
    assert gap > 1e-4 * diagonal(targets)
    check_limit(cage_b, limit_b, targets, 1)


# --- per-face shape parameters -----------------------------------------------------------

def test_face_attribute_wins_and_interpolates():
    source = import_obj(os.path.join(DATA, "mushroom.obj"))
    uniform, _, targets = make_doosabin(source, shape_parameter=0.5, levels=1)
    count = len(source.data.polygons)
    values = np.where(np.arange(count) % 3 == 0, 0.8, 0.4).astype(np.float32)
    add_shape_attribute(source, values)
    bpy.context.view_layer.objects.active = source
    source.select_set(True)
    cage, limit, _ = make_doosabin(source, shape_parameter=0.5, levels=1)
    assert cage["pia_shape_attribute"] == "pia_shape"
    np.testing.assert_array_equal(shape_values(cage.data), values)  # the cage keeps it
    gap = np.abs(positions(cage.data) - positions(uniform.data)).max()
    assert gap > 1e-4 * diagonal(targets), "the per-face values were not used"
    check_limit(cage, limit, targets, 1)
    # Where the attribute is there, shape_parameter does not matter.
    other, _ = subdiv_pia.interpolate(source, scheme='DOO_SABIN', levels=1, shape_parameter=0.3)
    np.testing.assert_allclose(positions(other.data), positions(cage.data), atol=1e-6)


def test_other_attribute_name():
    source = import_obj(os.path.join(DATA, "double-torus.obj"))
    count = len(source.data.polygons)
    add_shape_attribute(source, np.linspace(0.2, 0.9, count), name="bulge")
    targets = world(source)
    cage, report = subdiv_pia.interpolate(source, scheme='DOO_SABIN', levels=2,
                                          shape_attribute="bulge")
    assert report.converged and cage["pia_shape_attribute"] == "bulge"
    limit = subdiv_pia.find_limit_object(cage)
    check_limit(cage, limit, targets, 2)
    plain, _ = subdiv_pia.interpolate(source, scheme='DOO_SABIN', levels=1)  # "pia_shape": none
    assert np.abs(positions(plain.data) - positions(cage.data)).max() > 1e-4 * diagonal(targets)


def test_attribute_out_of_range_names_face_count():
    source = import_obj(os.path.join(DATA, "mushroom.obj"))
    values = np.full(len(source.data.polygons), 0.6, np.float32)
    values[[4, 50, 200]] = 1.2
    add_shape_attribute(source, values)
    before = snapshot(source)
    message = expect_error(r"3 faces", scheme='DOO_SABIN')
    assert "pia_shape" in message and "(0, 1)" in message
    assert_unchanged(source, before)
    np.testing.assert_array_equal(shape_values(source.data), values)


def test_shape_parameter_out_of_range():
    source = import_obj(os.path.join(DATA, "mushroom.obj"))
    before = snapshot(source)
    expect_error(r"shape_parameter must be in \(0, 1\).*1\.5", scheme='DOO_SABIN',
                 shape_parameter=1.5)
    expect_error(r"shape_parameter must be in \(0, 1\)", scheme='DOO_SABIN', shape_parameter=0.0)
    with pytest.raises(ValueError, match=r"shape_parameter must be in \(0, 1\)"):
        subdiv_pia.interpolate(source, scheme='DOO_SABIN', shape_parameter=1.5)
    assert_unchanged(source, before)
    # Other schemes ignore it.
    assert run_operator(shape_parameter=1.5) == {'FINISHED'}


@pytest.mark.parametrize("domain,kind", (('POINT', 'FLOAT'), ('FACE', 'INT')))
def test_attribute_of_wrong_domain_or_type(domain, kind):
    source = import_obj(os.path.join(DATA, "mushroom.obj"))
    source.data.attributes.new("pia_shape", kind, domain)
    expect_error(r"Attribute 'pia_shape' of mesh '.*' is a %s attribute on the %s domain: "
                 r"the shape attribute must be a Float attribute on the Face domain"
                 % (kind, domain), scheme='DOO_SABIN')


# --- open meshes ------------------------------------------------------------------------

@pytest.mark.parametrize("make", (shapes.open_grid,
                                  lambda: import_obj(os.path.join(DATA, "teapot.obj"))),
                         ids=("grid", "teapot"))
def test_open_mesh_refused(make):
    source = make()
    before = snapshot(source)
    message = expect_error(r"closed mesh: \d+ vertices lie on a boundary", scheme='DOO_SABIN')
    assert source.name in message
    assert_unchanged(source, before)


# --- refresh ----------------------------------------------------------------------------

def limit_positions(limit):
    return positions(limit.data).astype(np.float64)


def test_refresh_after_repainting_the_cage_attribute():
    source = import_obj(os.path.join(DATA, "mushroom.obj"))
    add_shape_attribute(source, np.full(len(source.data.polygons), 0.5, np.float32))
    cage, limit, targets = make_doosabin(source, levels=1)
    old = limit_positions(limit)
    old_mesh_name = limit.data.name
    values = shape_values(cage.data)
    values[:40] = 0.9
    cage.data.attributes["pia_shape"].data.foreach_set("value", values)
    cage.data.update()
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    assert api.find_limit_object(cage) is limit and limit.data.name == old_mesh_name
    new = limit_positions(limit)
    assert np.abs(new - old).max() > 1e-4 * diagonal(targets)
    expected, _, _ = native.refine(native_cage_mesh(cage), 1, scheme='DOO_SABIN',
                                   face_shape_parameters=values)
    np.testing.assert_allclose(new, expected, atol=1e-6 * diagonal(targets))
    np.testing.assert_array_equal(shape_values(source.data), 0.5)  # the source keeps its own
    # An invalid repaint is refused and leaves the child as it was.
    values[7] = 1.0
    cage.data.attributes["pia_shape"].data.foreach_set("value", values)
    with pytest.raises(RuntimeError, match=r"1 faces? ha"):
        bpy.ops.object.subdiv_pia_refresh_limit()
    np.testing.assert_array_equal(limit_positions(limit), new)


def test_refresh_after_moving_a_cage_vertex_from_child():
    source = import_obj(os.path.join(DATA, "double-torus.obj"))
    cage, limit, targets = make_doosabin(source, levels=2, shape_parameter=0.8)
    old = limit_positions(limit)
    co = positions(cage.data).copy()
    co[10, 2] += 0.05 * diagonal(targets)
    cage.data.vertices.foreach_set("co", co.ravel())
    cage.data.update()
    bpy.context.view_layer.objects.active = limit  # selecting the child works too
    assert bpy.ops.object.subdiv_pia_refresh_limit() == {'FINISHED'}
    new = limit_positions(limit)
    assert np.abs(new - old).max() > 1e-3 * diagonal(targets)
    expected, _, _ = native.refine(native_cage_mesh(cage), 2, scheme='DOO_SABIN',
                                   shape_parameter=0.8)
    np.testing.assert_allclose(new, expected, atol=1e-6 * diagonal(targets))
    # The limit point of the moved vertex rose; far away nothing changed.
    lifted = limit_points(cage, limit)
    assert lifted[10, 2] > targets[10, 2]
    changed = np.abs(lifted - targets).max(axis=1) > 1e-6 * diagonal(targets)
    assert 1 <= changed.sum() < 30


def test_refresh_recreates_deleted_child():
    source = import_obj(os.path.join(DATA, "double-torus.obj"))
    cage, limit, targets = make_doosabin(source, levels=1)
    bpy.data.objects.remove(limit)
    assert api.find_limit_object(cage) is None
    assert subdiv_pia.refresh_limit(cage) is api.find_limit_object(cage)
    check_limit(cage, api.find_limit_object(cage), targets, 1)


# --- command line and panel ------------------------------------------------------------

def test_cli_doosabin(tmp_path):
    output = str(tmp_path / "torus_ds.blend")
    result = run_cli(os.path.join(DATA, "double-torus.obj"), output, "--scheme", "DOO_SABIN",
                     "--shape-parameter", "0.8", "--shape-attribute", "bulge", "--levels", "1")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Converged" in result.stdout and "double-torus_pia_limit" in result.stdout
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = [n for n in data_from.objects if n.startswith("double-torus")]
    objects = {o.name: o for o in data_to.objects}
    cage, limit = objects["double-torus_pia"], objects["double-torus_pia_limit"]
    assert limit.parent is cage and not cage.modifiers
    assert cage["pia_scheme"] == 'DOO_SABIN' and cage["pia_shape_attribute"] == "bulge"
    assert cage["pia_shape_parameter"] == pytest.approx(0.8)
    targets = positions(objects["double-torus"].data).astype(np.float64)
    f, e, n = len(cage.data.polygons), len(cage.data.edges), len(cage.data.vertices)
    miss = np.abs(centroids(limit.data)[f + e:f + e + n] - targets).max() / diagonal(targets)
    assert miss <= MATCH


def test_cli_doosabin_refuses_open_mesh(tmp_path):
    output = str(tmp_path / "never.blend")
    result = run_cli(os.path.join(DATA, "teapot.obj"), output, "--scheme", "DOO_SABIN")
    assert result.returncode == 1
    assert "closed mesh" in result.stderr and "boundary" in result.stderr
    assert not os.path.exists(output)


def drawn_props(scheme):
    from test_ui import draw_panel
    bpy.context.scene.subdiv_pia.scheme = scheme
    return {name for kind, name in draw_panel() if kind == "prop"}


def test_panel_shows_settings_by_scheme():
    source = shapes.cube()
    ds = drawn_props('DOO_SABIN')
    assert {"shape_parameter", "shape_attribute", "levels"} <= ds
    for name in ("boundary_smooth", "quality", "use_creases", "render_levels", "boundary_rule", "triangulate"):
        assert name not in ds, name
    cc = drawn_props('CATMULL_CLARK')
    assert "shape_parameter" not in cc and "shape_attribute" not in cc
    assert {"boundary_smooth", "quality", "use_creases"} <= cc
    loop = drawn_props('LOOP')
    assert "shape_parameter" not in loop and "use_creases" in loop
    # The refresh button shows for a Doo-Sabin cage and its child.
    bpy.context.scene.subdiv_pia.scheme = 'DOO_SABIN'
    source.select_set(True)
    bpy.context.view_layer.objects.active = source
    from test_ui import draw_panel
    assert ("operator", "object.subdiv_pia_refresh_limit") not in draw_panel()
    assert run_operator(scheme='DOO_SABIN', levels=1) == {'FINISHED'}
    assert ("operator", "object.subdiv_pia_refresh_limit") in draw_panel()
    bpy.context.view_layer.objects.active = api.find_limit_object(bpy.context.active_object)
    assert ("operator", "object.subdiv_pia_refresh_limit") in draw_panel()
