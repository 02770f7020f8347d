# SPDX-License-Identifier: GPL-3.0-or-later
"""The cleanup setting: a cleaned copy of the mesh is interpolated, the
source stays as it is, the cage gets the cleaned topology and says what was
cleaned; without it, meshes that cleanup would fix are refused with a hint."""

import os

import bmesh
import bpy
import numpy as np
import pytest

import shapes
from conftest import (MATCH, assert_unchanged, expect_error, make_limit_cage,
                      object_from_pydata, object_counts, positions, relative_miss, run_operator,
                      snapshot)
from subdiv_pia import api, operators
from test_api_cli import run_cli
from test_ui import draw_panel


def bumpy_grid(n=5):
    """An open n x n grid of vertices with a bump; returns (vertices, quads)."""
    vertices = []
    for j in range(n):
        for i in range(n):
            x, y = i / (n - 1.0), j / (n - 1.0)
            vertices.append((x, y, 0.3 * np.sin(np.pi * x) * np.sin(np.pi * y) + 0.05 * x * y))
    faces = [(j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i)
             for j in range(n - 1) for i in range(n - 1)]
    return vertices, faces


def dirty_grid():
    """The bumpy grid with a face repeating a vertex (6), a copy of vertex 12
    used by one face instead of it (25), and a loose vertex (26); the kept
    vertices are 0..24 in order."""
    vertices, faces = bumpy_grid()
    faces[5] = (6, 7, 7, 12, 11)  # repeats 7
    faces[10] = tuple(25 if v == 12 else v for v in faces[10])
    vertices = vertices + [vertices[12], (3.0, 3.0, 3.0)]
    source = object_from_pydata("Dirty", vertices, faces, validate=False)
    assert tuple(source.data.polygons[5].vertices) == (6, 7, 7, 12, 11)
    return source


def test_repeated_vertex_is_refused_with_the_hint():
    source = dirty_grid()
    before = snapshot(source)
    message = expect_error(r"more than once")
    assert "Cleanup setting" in message and "dissolve 1 repeated corner" in message, message
    assert "merge 1 vertex" in message, message
    assert_unchanged(source, before)


def test_cleanup_interpolates_the_cleaned_vertices():
    source = dirty_grid()
    before = snapshot(source)
    loops = [tuple(p.vertices) for p in source.data.polygons]
    targets = positions(source.data)[:25].astype(np.float64)
    assert run_operator(cleanup=True) == {'FINISHED'}
    cage = bpy.context.active_object
    assert cage is not source and cage.name == "Dirty_pia"
    assert len(cage.data.vertices) == 25 and len(cage.data.polygons) == 16
    assert cage["pia_cleanup"] and cage["pia_status"] == 'CONVERGED'
    assert cage["pia_cleanup_merged_vertices"] == 1
    assert cage["pia_cleanup_dissolved_corners"] == 1
    assert cage["pia_cleanup_loose_vertices"] == 1
    assert cage["pia_cleanup_flipped_faces"] == 0
    line = api.format_cleanup(cage)
    for words in ("merged 1 vertex", "dissolved 1 repeated corner", "removed 1 loose vertex"):
        assert words in line, line
    assert relative_miss(cage, targets) <= MATCH
    assert_unchanged(source, before)
    assert [tuple(p.vertices) for p in source.data.polygons] == loops
    assert len(source.data.vertices) == 27


def test_panel_shows_cleanup():
    dirty_grid()
    log = draw_panel()
    assert ("prop", "cleanup") in log and ("prop", "cleanup_distance") in log
    assert run_operator(cleanup=True) == {'FINISHED'}
    labels = [text for kind, text in draw_panel() if kind == "label"]
    assert any("merged 1 vertex" in text for text in labels), labels


def flipped_cube(count=2):
    source = shapes.cube()
    bm = bmesh.new()
    bm.from_mesh(source.data)
    bm.faces.ensure_lookup_table()
    bmesh.ops.reverse_faces(bm, faces=[bm.faces[i] for i in range(0, 4 * count, 4)])
    bm.to_mesh(source.data)
    bm.free()
    source.data.update()
    return source


def outward(mesh):
    """Every face normal points away from the centre (the cube is convex)."""
    centre = positions(mesh).mean(axis=0)
    return all(np.dot(np.array(p.normal), np.array(p.center) - centre) > 0 for p in mesh.polygons)


def test_flipped_faces_are_refused_by_doo_sabin_with_the_hint():
    source = flipped_cube()
    assert not outward(source.data)
    before = snapshot(source)
    message = expect_error(r"oriented", scheme='DOO_SABIN')
    assert "Cleanup setting" in message and "flip 2 faces" in message, message
    assert_unchanged(source, before)


@pytest.mark.parametrize("scheme", ('DOO_SABIN', 'LOOP'))
def test_cleanup_turns_flipped_faces(scheme):
    source = flipped_cube()
    extra = {"triangulate": True} if scheme == 'LOOP' else {}
    cage, limit, targets = make_limit_cage(source, scheme, ("pia_cleanup_flipped_faces",),
                                           cleanup=True, levels=1, **extra)
    assert cage["pia_cleanup_flipped_faces"] == 2
    assert cage["pia_cleanup_merged_vertices"] == 0
    assert outward(cage.data)
    assert not outward(source.data)
    assert len(cage.data.vertices) == len(source.data.vertices)
    assert cage["pia_cleanup"] and cage["pia_cleanup_distance"] == pytest.approx(1e-6)
    # The cleaned copy became the cage's mesh, or was removed once triangulated.
    assert {m.name for m in bpy.data.meshes} == {source.data.name, cage.data.name, limit.data.name}


def test_creases_are_carried_over():
    source = shapes.edge_creases()
    targets = positions(source.data).astype(np.float64)
    assert run_operator(cleanup=True) == {'FINISHED'}
    cage = bpy.context.active_object
    assert api.format_cleanup(cage) == "cleanup: nothing to clean"

    def by_pair(mesh):
        edges = np.array([tuple(sorted(e.vertices)) for e in mesh.edges])
        creases, _ = api.read_creases(mesh)
        return dict(zip(map(tuple, edges), creases.tolist()))

    assert by_pair(cage.data) == pytest.approx(by_pair(source.data))
    assert relative_miss(cage, targets) <= MATCH


def test_shape_attribute_follows_the_faces():
    source = flipped_cube()
    attr = source.data.attributes.new("pia_shape", 'FLOAT', 'FACE')
    values = np.linspace(0.3, 0.8, len(source.data.polygons)).astype(np.float32)
    attr.data.foreach_set("value", values)
    assert run_operator(scheme='DOO_SABIN', cleanup=True) == {'FINISHED'}
    cage = bpy.context.active_object
    got = np.empty(len(cage.data.polygons), np.float32)
    cage.data.attributes["pia_shape"].data.foreach_get("value", got)
    np.testing.assert_array_equal(got, values)  # nothing removed: same faces, same order


def test_bad_cleanup_distance_creates_nothing():
    source = dirty_grid()
    before = snapshot(source)
    counts = object_counts()
    with pytest.raises(ValueError, match="cleanup_distance"):
        api.interpolate(source, cleanup=True, cleanup_distance=-1.0)
    assert object_counts() == counts
    assert_unchanged(source, before)


def test_nothing_left_after_cleanup_creates_nothing():
    source = object_from_pydata("Sliver", [(0, 0, 0), (1, 0, 0), (2, 0, 0)], [(0, 1, 2)])
    before = snapshot(source)
    expect_error(r"no faces left after cleanup", cleanup=True)
    assert_unchanged(source, before)


def test_script_api_cleanup():
    source = dirty_grid()
    targets = positions(source.data)[:25].astype(np.float64)
    cage, report = api.interpolate(source, cleanup=True, scheme='CATMULL_CLARK')
    assert report.converged
    assert api.cleanup_stats(cage)["merged_vertices"] == 1
    assert relative_miss(cage, targets) <= MATCH
    line = operators.result_line(cage, report, {"target": ""})  # the operator's report
    assert line.startswith("Dirty_pia: Converged") and "; cleanup: merged 1 vertex" in line, line
    plain, _ = api.interpolate(shapes.cube())
    assert api.cleanup_stats(plain) is None and api.format_cleanup(plain) == ""


def test_cli_cleanup(tmp_path):
    dirty_grid()
    blend = str(tmp_path / "dirty.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend, check_existing=False)
    output = str(tmp_path / "dirty_cage.blend")
    refused = run_cli(blend, str(tmp_path / "never.blend"), "--object", "Dirty")
    assert refused.returncode == 1 and "--cleanup" in refused.stderr, refused.stderr
    assert not os.path.exists(str(tmp_path / "never.blend"))
    result = run_cli(blend, output, "--object", "Dirty", "--cleanup", "--cleanup-distance", "1e-5")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Converged" in result.stdout
    assert "cleanup: merged 1 vertex" in result.stdout, result.stdout
    with bpy.data.libraries.load(output) as (data_from, data_to):
        data_to.objects = ["Dirty_pia"]
    cage = data_to.objects[0]
    assert cage["pia_cleanup_distance"] == pytest.approx(1e-5)
    assert len(cage.data.vertices) == 25


def test_no_hint_where_cleanup_would_not_help():
    source = shapes.open_grid()  # an open, clean mesh: Doo-Sabin needs a closed one
    before = snapshot(source)
    message = expect_error(r"closed mesh", scheme='DOO_SABIN')
    assert "Cleanup" not in message, message
    message = expect_error(r"triangulate", scheme='LOOP')
    assert "Cleanup" not in message, message
    assert_unchanged(source, before)
