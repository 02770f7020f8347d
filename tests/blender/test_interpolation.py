# SPDX-License-Identifier: GPL-3.0-or-later
"""The oracle is Blender itself: after the operator, the new object's
Subdivision Surface modifier (use_limit_surface) must put its first N
evaluated vertices (the control vertices) on the original vertices."""

import os

import bpy
import numpy as np
import pytest

import shapes
import subdiv_pia
from subdiv_pia import native
from conftest import (DATA, MATCH, assert_unchanged, diagonal, evaluated_control_points,
                      import_obj, positions, relative_miss, run_operator, snapshot)


def make_cage(source, **settings):
    before = snapshot(source)
    targets = positions(source.data).astype("float64")
    assert run_operator(**settings) == {'FINISHED'}
    new_obj = bpy.context.active_object
    assert new_obj is not source and new_obj.name == source.name + "_pia"
    assert_unchanged(source, before)
    assert new_obj["pia_status"] == 'CONVERGED', new_obj["pia_status"]
    return new_obj, targets


def check_modifier(obj, **expected):
    mods = [m for m in obj.modifiers if m.type == 'SUBSURF']
    assert len(mods) == 1
    mod = mods[0]
    assert mod.use_limit_surface
    # 5.0+: Cycles' adaptive dicing would render another surface than the limit one.
    assert not getattr(mod, "use_adaptive_subdivision", False)
    for name, value in expected.items():
        assert getattr(mod, name) == value, name
    return mod


# --- generated shapes -------------------------------------------------------

@pytest.mark.parametrize("levels", (1, 2, 3))
@pytest.mark.parametrize("shape", shapes.ALL, ids=lambda f: f.__name__)
def test_shape_levels(shape, levels):
    new_obj, targets = make_cage(shape(), levels=levels, render_levels=levels)
    check_modifier(new_obj, levels=levels, render_levels=levels, quality=3)
    miss = relative_miss(new_obj, targets)
    assert miss <= MATCH, "levels=%d: miss %.3g of diagonal" % (levels, miss)


@pytest.mark.parametrize("quality", (1, 3, 6))
@pytest.mark.parametrize("boundary_smooth", ('ALL', 'PRESERVE_CORNERS'))
@pytest.mark.parametrize("shape", shapes.ALL, ids=lambda f: f.__name__)
def test_shape_settings(shape, boundary_smooth, quality):
    new_obj, targets = make_cage(shape(), levels=2, quality=quality,
                                 boundary_smooth=boundary_smooth)
    check_modifier(new_obj, quality=quality, boundary_smooth=boundary_smooth)
    miss = relative_miss(new_obj, targets)
    assert miss <= MATCH, "miss %.3g of diagonal" % miss


@pytest.mark.parametrize("shape", (shapes.edge_creases, shapes.vertex_creases),
                         ids=lambda f: f.__name__)
def test_creases_ignored_when_off(shape):
    new_obj, targets = make_cage(shape(), use_creases=False)
    check_modifier(new_obj, use_creases=False)
    assert relative_miss(new_obj, targets) <= MATCH


# --- meshes made by others (tests/data, see README there) -------------------

# name -> levels at which the cage is checked (the control points are limit
# points at every level; big meshes are evaluated at level 1 only to keep the
# suite quick).
REAL = {
    "bunny": (1, 2, 3),
    "elephant-with-holes": (1, 2),
    "bun_zipper": (1,),
    "mushroom": (1, 2, 3),
    "double-torus": (1, 2, 3),
    "catmark_car": (1, 2, 3),
    "catmark_nonman_edges": (1, 2, 3),
    "teapot": (1, 2, 3),
}
REAL_CASES = [(name, levels) for name, all_levels in REAL.items() for levels in all_levels]


@pytest.mark.parametrize("name,levels", REAL_CASES, ids=["%s-L%d" % c for c in REAL_CASES])
def test_real_mesh(name, levels):
    source = import_obj(os.path.join(DATA, name + ".obj"))
    new_obj, targets = make_cage(source, levels=levels, render_levels=levels)
    miss = relative_miss(new_obj, targets)
    assert miss <= MATCH, "%s levels=%d: miss %.3g of diagonal" % (name, levels, miss)


@pytest.mark.parametrize("name", ("catmark_car", "teapot", "elephant-with-holes"))
def test_real_mesh_preserve_corners(name):
    source = import_obj(os.path.join(DATA, name + ".obj"))
    new_obj, targets = make_cage(source, levels=1, boundary_smooth='PRESERVE_CORNERS')
    assert relative_miss(new_obj, targets) <= MATCH


# --- OpenSubdiv versions ------------------------------------------------------

def this_opensubdiv():
    return tuple(bpy.app.opensubdiv.version)


def test_double_sided_fins_follow_this_blenders_opensubdiv():
    """Fins hanging from two edges of a vertex: OpenSubdiv 3.7 (Blender 5.1
    and later) puts that vertex's limit point on the vertex itself, 3.6.0 and
    older do not. The library's limit points must be this Blender's, and so
    must the cage's; the other version's rule misses the vertex."""
    source = shapes.double_sided_fins()
    centre = 4
    targets = positions(source.data).astype(np.float64)
    mod = source.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = 1
    mod.quality = 3
    mod.use_limit_surface = True
    blender_limit = evaluated_control_points(source, len(targets))
    source.modifiers.remove(mod)
    faces = [tuple(p.vertices) for p in source.data.polygons]
    mesh = native.Mesh.from_faces(targets, faces)
    size = diagonal(targets)
    library = native.limit_stencils(mesh, quality=3, opensubdiv_version=this_opensubdiv()).apply(targets)
    assert np.abs(library - blender_limit).max() / size <= MATCH
    at_itself = np.abs(blender_limit[centre] - targets[centre]).max() / size <= MATCH
    assert at_itself == (this_opensubdiv() > (3, 6, 0)), (this_opensubdiv(), blender_limit[centre], targets[centre])

    new_obj, _ = make_cage(source, levels=1)
    assert new_obj["pia_opensubdiv_version"] == "%d.%d.%d" % this_opensubdiv()
    assert relative_miss(new_obj, targets) <= MATCH

    other = '3.6.0' if this_opensubdiv() > (3, 6, 0) else '3.7.0'
    wrong, _ = subdiv_pia.interpolate(source, levels=1, opensubdiv_version=other)
    assert wrong["pia_opensubdiv_version"] == other
    miss = np.abs(evaluated_control_points(wrong, len(targets)) - targets).max(axis=1) / size
    assert miss[centre] > 1e-3, miss
    assert np.delete(miss, centre).max() <= MATCH, miss


# --- the plain modifier does not interpolate ---------------------------------

@pytest.mark.parametrize("make", (shapes.cube, shapes.edge_creases,
                                  lambda: import_obj(os.path.join(DATA, "bunny.obj")),
                                  lambda: import_obj(os.path.join(DATA, "mushroom.obj"))),
                         ids=("cube", "edge_creases", "bunny", "mushroom"))
def test_plain_modifier_misses_by_far(make):
    source = make()
    new_obj, targets = make_cage(source, levels=2)
    interpolated = relative_miss(new_obj, targets)
    mod = source.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = 2
    mod.use_limit_surface = True
    plain = relative_miss(source, targets)
    assert plain > 1e-3, plain
    assert plain > 100 * max(interpolated, 1e-9), (plain, interpolated)


def test_dragon_unreachable_vertices_are_reported():
    """The 100k-vertex scan has isolated pairs of duplicated triangles: each
    vertex of such a pair has the triangle's centroid as its limit, so no
    cage reaches them all. Everything else must be hit, and the result must
    say it did not converge.

    Quality 1: Blender builds the modifier's stencil table for the whole
    scan, 15 s at quality 1 against 80 s at quality 3 (other tests judge
    quality 3 on smaller meshes)."""
    source = import_obj(os.path.join(DATA, "dragon_res2.obj"))
    before = snapshot(source)
    targets = positions(source.data).astype(np.float64)
    assert run_operator(levels=1, quality=1) == {'FINISHED'}
    new_obj = bpy.context.active_object
    check_modifier(new_obj, levels=1, quality=1)
    assert_unchanged(source, before)
    assert new_obj["pia_status"] in ('STAGNATED', 'MAX_ITERATIONS')
    miss = np.abs(evaluated_control_points(new_obj, len(targets)) - targets).max(axis=1)
    missed = np.flatnonzero(miss > MATCH * diagonal(targets))
    assert len(missed) > 0  # which ones give way (7 to 11) depends on the solver

    mesh = source.data
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    triangles = np.sort(corners.reshape(-1, 3), axis=1)  # all triangles, loops in face order
    unique, inverse, count = np.unique(triangles, axis=0, return_inverse=True, return_counts=True)
    on_duplicate = np.unique(unique[count > 1].ravel())
    faces_per_vertex = np.bincount(corners, minlength=len(targets))
    isolated = on_duplicate[faces_per_vertex[on_duplicate] == 2]  # only the doubled pair
    wrong = missed[~np.isin(missed, isolated)]
    message = "missed beyond the unreachable pairs: %s (miss %s of diagonal)" % (
        wrong[:10].tolist(), np.round(miss[wrong[:10]] / diagonal(targets), 7).tolist())
    # Blender 5.1 and newer (OpenSubdiv 3.7) make 84 vertices with double-sided
    # fins on two of their edges infinitely sharp, which earlier ones do not:
    # the cage follows this Blender's rule.
    assert len(wrong) == 0, message
    # The vertices the cage cannot reach are in its vertex group, for Select
    # in Edit Mode: every vertex that misses, and as many as the count says.
    group = new_obj.vertex_groups.get("pia_unreachable")
    assert group is not None
    in_group = np.zeros(len(targets), bool)
    for vertex in new_obj.data.vertices:
        if any(g.group == group.index for g in vertex.groups):
            in_group[vertex.index] = True
    assert int(in_group.sum()) == new_obj["pia_unreachable_count"] > 0
    assert in_group[missed].all(), missed[~in_group[missed]].tolist()
