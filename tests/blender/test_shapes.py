# SPDX-License-Identifier: GPL-3.0-or-later
"""OpenSubdiv's Catmull-Clark regression shapes in Blender.

The shapes are read at test time from OpenSubdiv's source package, which
`make build` unpacks at build/src/opensubdiv-3.6.0 (tools/osd_shapes.py; in
the Debian chroot the project root is /src, so they are found there too).
Every shape Blender's modifier can express, with its creases, in both
boundary modes and at qualities 1, 3 and 6, goes through the script API (the
operator's path); Blender's own modifier on the new object is the oracle:
every vertex outside the `pia_unreachable` vertex group must be on its
target, and the group must hold exactly the vertices the report flags.
Some shapes have singular limit matrices (catmark_val2_*): the library gives
a least-squares cage there and flags what it cannot reach.

One test per shape, its six settings in a loop (a factory reset per setting
would cost more than the shapes); a failure lists every setting that missed,
with its figures.  Shapes with a vertex of valence above 100 (the 360-valent
poles) only at quality 1: Blender's own evaluation takes about 50 s there at
higher qualities.
"""

import os
import sys

import bpy
import numpy as np
import pytest

import subdiv_pia
from conftest import (MATCH, ROOT, assert_unchanged, diagonal, evaluated_control_points, object_from_pydata,
                      positions, snapshot)
from subdiv_pia import live
from shapes import set_edge_creases, set_vertex_creases

sys.path.insert(0, os.path.join(ROOT, "tools"))
import osd_shapes  # noqa: E402

SHAPES = ({s.name: s for s in osd_shapes.load_testable(scheme="CATMULL_CLARK")}
          if osd_shapes.available() else {})
QUALITIES = (1, 3, 6)
# Blender's modifier takes about 50 s per evaluation at quality 2 and above
# around a vertex of valence 360 (catmark_pole360, the quad pole: OpenSubdiv
# builds the patches there; 0.7 s at quality 1, 0.4 s at valence 64): such
# shapes are evaluated at quality 1 only.
SLOW_VALENCE = 100
GROUP = "pia_unreachable"
# With SUBDIV_PIA_SHAPES_TABLE naming a file, each setting's figures are
# added to it as a line of tab-separated values (bench/shapes_table.py runs
# the file in a Blender that way and prints the table).
TABLE = os.environ.get("SUBDIV_PIA_SHAPES_TABLE")
# The shapes with vertices no cage reaches (singular limit matrices with
# targets outside their range: tests/python/test_shapes.py finds the same
# ones against numpy's lstsq), and the use_creases settings where they have
# them: there every setting flags vertices, and no other shape does anywhere.
UNREACHABLE = {"catmark_val2_interior": (False,), "catmark_val2_back2back": (True, False),
               "catmark_val2_nonman": (True, False)}


def settings_of(shape):
    """(boundary_smooth, quality, use_creases): with the shape's creases; the
    valence-2 shapes, whose limit matrices lose rank without them, also
    without."""
    qualities = QUALITIES[:1] if shape.max_valence > SLOW_VALENCE else QUALITIES
    creases = (True, False) if shape.name.startswith("catmark_val2") else (True,)
    return [(b, q, c) for c in creases for b in ('ALL', 'PRESERVE_CORNERS') for q in qualities]


def blender_name():
    return "Blender %s (OpenSubdiv %s)" % (bpy.app.version_string,
                                          ".".join(map(str, bpy.app.opensubdiv.version)))


def object_from_shape(shape):
    """A mesh object with the shape's vertices, faces and creases (not
    validated: that would drop the faces of back-to-back pairs)."""
    obj = object_from_pydata(shape.name, shape.positions, shape.faces, validate=False)
    mesh = obj.data
    assert len(mesh.vertices) == shape.vertex_count and len(mesh.polygons) == len(shape.faces)
    creases = shape.creases_by_edge()
    pairs = np.empty(len(mesh.edges) * 2, np.int32)
    mesh.edges.foreach_get("vertices", pairs)
    pairs = pairs.reshape(-1, 2)
    values = np.array([creases.get(frozenset(map(int, e)), 0.0) for e in pairs], np.float32)
    assert np.count_nonzero(values) == len(creases), "an edge of a crease tag is not an edge in Blender"
    if values.any():
        set_edge_creases(mesh, values)
    if shape.vertex_creases.any():
        set_vertex_creases(mesh, shape.vertex_creases)
    return obj


def group_members(obj):
    """Vertices in obj's pia_unreachable group (bool per vertex) and their weights, or None without the group."""
    group = obj.vertex_groups.get(GROUP)
    if group is None:
        return None, []
    members = np.zeros(len(obj.data.vertices), bool)
    weights = []
    for vertex in obj.data.vertices:
        for g in vertex.groups:
            if g.group == group.index:
                members[vertex.index] = True
                weights.append(g.weight)
    return members, weights


def remove(obj):
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)


def test_the_shapes_are_there():
    assert osd_shapes.available(), osd_shapes.missing_message()
    for name in ("catmark_val2_interior", "catmark_val2_foldover", "catmark_val2_back2back",
                 "catmark_val2_nonman", "catmark_nonman_edges_dissolved", "catmark_car"):
        assert name in SHAPES, name


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_regression_shape(name):
    shape = SHAPES[name]
    source = object_from_shape(shape)
    before = snapshot(source)
    targets = positions(source.data).astype(np.float64)
    d = diagonal(targets)
    problems, flagged_somewhere = [], []
    for boundary_smooth, quality, use_creases in settings_of(shape):
        setting = "boundary_smooth=%s quality=%d use_creases=%s" % (boundary_smooth, quality, use_creases)
        new_obj, report = subdiv_pia.interpolate(source, levels=1, render_levels=1, quality=quality,
                                                 boundary_smooth=boundary_smooth, use_creases=use_creases)
        try:
            assert new_obj is not source
            assert_unchanged(source, before)
            flags = np.asarray(report.unreachable, bool)
            members, weights = group_members(new_obj)
            miss = np.linalg.norm(evaluated_control_points(new_obj, len(targets)) - targets, axis=1) / d
            outside = miss.copy()
            outside[flags] = 0.0
            worst = int(np.argmax(outside))
            figures = "%s %s in %s: %s" % (name, setting, blender_name(), report.summary())
            if TABLE:
                with open(TABLE, "a") as f:
                    f.write("\t".join(map(str, (blender_name(), name, boundary_smooth, quality,
                                                "creases" if use_creases else "no creases", report.status,
                                                report.method, int(flags.sum()), "%.3g" % outside[worst]))) + "\n")
            if outside[worst] > MATCH:
                problems.append("%s: worst miss outside the group %.3g of the diagonal at vertex %d "
                                "(%d vertices beyond %g)" % (figures, outside[worst], worst,
                                                             int((outside > MATCH).sum()), MATCH))
            if flags.any():
                flagged_somewhere.append(setting)
                if members is None or not np.array_equal(members, flags) or not all(w == 1.0 for w in weights):
                    problems.append("%s: group %s, flags %s" % (
                        figures, None if members is None else np.flatnonzero(members).tolist(),
                        np.flatnonzero(flags).tolist()))
                if report.unreachable_count != int(flags.sum()) or new_obj.get("pia_unreachable_count") != int(
                        flags.sum()):
                    problems.append("%s: %d flagged, count %d, pia_unreachable_count %s" % (
                        figures, int(flags.sum()), report.unreachable_count, new_obj.get("pia_unreachable_count")))
                if ("%d vert" % int(flags.sum())) not in subdiv_pia.api.format_report(report) or (
                        GROUP not in subdiv_pia.api.format_report(report)):
                    problems.append("%s: the report line does not name them: %s" % (
                        figures, subdiv_pia.api.format_report(report)))
            elif members is not None:
                problems.append("%s: a %s group without flagged vertices" % (figures, GROUP))
        finally:
            remove(new_obj)
    expected = ["boundary_smooth=%s quality=%d use_creases=%s" % setting for setting in settings_of(shape)
                if setting[2] in UNREACHABLE.get(name, ())]
    if flagged_somewhere != expected:
        problems.append("%s in %s: vertices flagged in %s, expected in %s" % (
            name, blender_name(), flagged_somewhere or "no setting", expected or "none"))
    assert_unchanged(source, before)
    assert not problems, "\n".join(problems)


def test_a_live_cage_keeps_its_group_in_line():
    """catmark_val2_interior without creases has vertices no cage reaches:
    the pia_unreachable group follows every solve of a live cage, in place
    and after a rebuild (a new mesh copied from the source, which brings
    the source's own vertex groups along, as the first cage has them)."""
    shape = SHAPES["catmark_val2_interior"]
    source = object_from_shape(shape)
    other = source.vertex_groups.new(name="Other")  # its weights travel with copies of the mesh
    other.add(list(range(0, shape.vertex_count, 3)), 0.5, 'REPLACE')
    cage, report = subdiv_pia.interpolate(source, levels=1, use_creases=False, live=True)
    try:
        flags = np.asarray(report.unreachable, bool)
        assert flags.any(), report.summary()
        members, weights = group_members(cage)
        assert np.array_equal(members, flags) and set(weights) == {1.0}
        assert cage["pia_unreachable_count"] == int(flags.sum())
        assert cage.vertex_groups.active.name == GROUP
        if report.unreachable_count:
            assert cage["pia_reachable_max_error"] == pytest.approx(report.reachable_max_error_relative)

        # An edit of the positions: solved again, in place.
        co = positions(source.data).copy()
        co[0] += (0.01, 0.02, 0.0)
        source.data.vertices.foreach_set("co", co.ravel())
        source.data.update()
        assert live.sync(cage, force=True)
        members, _ = group_members(cage)
        count = int(cage["pia_unreachable_count"])
        assert count > 0 and members is not None and int(members.sum()) == count
        message = cage.get(live.MESSAGE, "")
        assert GROUP in message and ("%d vert" % count) in message, message

        # A crease changed: the mesh is rebuilt from the source's.
        set_vertex_creases(source.data, np.where(np.arange(shape.vertex_count) == 1, 0.5, 0.0))
        assert live.sync(cage, force=True)
        members, weights = group_members(cage)
        count = int(cage["pia_unreachable_count"])
        assert count > 0 and int(members.sum()) == count and set(weights) == {1.0}
        # The source's own group came along with the mesh (the names live on
        # the mesh since Blender 3.0), untouched.
        assert [g.name for g in cage.vertex_groups] == ["Other", GROUP]
        other_members = np.zeros(shape.vertex_count, bool)
        for vertex in cage.data.vertices:
            for g in vertex.groups:
                if g.group == cage.vertex_groups["Other"].index:
                    other_members[vertex.index] = g.weight == 0.5
        assert np.array_equal(np.flatnonzero(other_members), np.arange(0, shape.vertex_count, 3))
    finally:
        live.set_live(cage, False)
