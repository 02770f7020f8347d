# SPDX-License-Identifier: GPL-3.0-or-later
"""A cage exported with native.write_usd and read back by Blender's own USD
import (import_subdiv, from 5.0 import_subdivision): the imported points
are the cage's (a point between two loose edges where the cage's modifier
shows it, USD having no loose edges), and its Subdivision Surface modifier
puts the first N evaluated vertices on the original vertices, as the
cage's own modifier does.

What the import does (measured in Blender 4.2 to 5.3): it adds a
Subdivision Surface modifier for subdivisionScheme "catmullClark" only
(levels 1, render levels 2, quality 3, use_limit_surface on: the defaults;
no USD attribute holds the quality, so the tests set it); from 4.4 on it
reads interpolateBoundary as boundary_smooth, faceVaryingLinearInterpolation
as uv_smooth, and creaseSharpnesses / cornerSharpnesses as crease_edge /
crease_vert with c = sqrt(s / 10); Blender's modifier then applies its
two-edge rule once more to those creases (see test_two_edge_rule_applied_again).
Blender 4.2 and 4.3 read neither the creases nor interpolateBoundary: there
the tests complete the import from the file the way 4.4 does
(complete_import), and test_import_mapping pins what each version reads.

Only Blenders built with USD (bpy.app.build_options.usd) can import it;
Debian's blender (3.4.1 on Debian 12, 4.3.2 on 13) is built without. There
the export alone is checked inside that Blender's Python
(test_export_where_blender_has_no_usd, the only test defined there), rather
than the others skipped.
"""

import math
import os
import re

import bpy
import numpy as np
import pytest

import shapes
import subdiv_pia
from subdiv_pia import api, native
from conftest import DATA, MATCH, diagonal, evaluated_control_points, import_obj, positions

READS_CREASES = bpy.app.version >= (4, 4, 0)
BOUNDARY_OF_TOKEN = {"edgeOnly": 'ALL', "edgeAndCorner": 'PRESERVE_CORNERS'}


# --- the file --------------------------------------------------------------------

def usd_array(text, name):
    """The numbers of the array attribute `name`, or [] when it is not written."""
    match = re.search(r"\b%s = \[([^\]]*)\]" % name, text)
    return re.findall(r"[-+]?[\d.]+(?:e[-+]?\d+)?", match.group(1)) if match else []


def usd_token(text, name):
    return re.search(r'\b%s = "(\w+)"' % name, text).group(1)


def file_sharpness(text):
    """({(a, b) a < b: edge sharpness}, {vertex: sharpness}) as written."""
    indices = [int(i) for i in usd_array(text, "creaseIndices")]
    lengths = [int(n) for n in usd_array(text, "creaseLengths")]
    values = [float(s) for s in usd_array(text, "creaseSharpnesses")]
    assert set(lengths) <= {2} and len(indices) == 2 * len(lengths) == 2 * len(values)
    edges = {(min(a, b), max(a, b)): s for a, b, s in zip(indices[::2], indices[1::2], values)}
    corners = dict(zip((int(i) for i in usd_array(text, "cornerIndices")),
                       (float(s) for s in usd_array(text, "cornerSharpnesses"))))
    return edges, corners


def sharpness_to_crease(s):
    return min(1.0, math.sqrt(s / 10.0))


# --- Blender's side ----------------------------------------------------------------

def edge_keys(mesh):
    ev = np.empty(len(mesh.edges) * 2, np.int32)
    mesh.edges.foreach_get("vertices", ev)
    return [(min(a, b), max(a, b)) for a, b in ev.reshape(-1, 2).tolist()]


def faces_of(mesh):
    return [tuple(p.vertices) for p in mesh.polygons]


def float_attribute(mesh, name):
    attr = mesh.attributes.get(name)
    if attr is None:
        return None
    values = np.empty(len(attr.data), np.float32)
    attr.data.foreach_get("value", values)
    return values


def subsurf(obj):
    mods = [m for m in obj.modifiers if m.type == 'SUBSURF']
    return mods[0] if mods else None


def shown_points(source, cage):
    """The cage, but a point that no face uses between exactly two loose
    edges where Blender's modifier shows it: (prev + 4 V + next) / 6 (USD
    has no loose edges; write_usd writes it there)."""
    used = {v for f in faces_of(source.data) for v in f}
    around = {}
    for a, b in edge_keys(source.data):
        for v, w in ((a, b), (b, a)):
            if v not in used:
                around.setdefault(v, []).append(w)
    out = cage.astype(np.float64)
    for v, w in around.items():
        if len(w) == 2:
            out[v] = (out[w[0]] + 4 * out[v] + out[w[1]]) / 6
    return out


def import_usd(path):
    # The option's name until Blender 5.0: import_subdiv.
    names = bpy.ops.wm.usd_import.get_rna_type().properties.keys()
    option = "import_subdivision" if "import_subdivision" in names else "import_subdiv"
    before = set(bpy.data.objects)
    assert bpy.ops.wm.usd_import(filepath=str(path), **{option: True}) == {'FINISHED'}
    new = [o for o in bpy.data.objects if o not in before]
    assert len(new) == 1 and new[0].type == 'MESH', new
    return new[0]


def complete_import(obj, text):
    """Blender 4.2 and 4.3: the creases and boundary mode from the file, as 4.4 reads them."""
    mod = subsurf(obj)
    mod.boundary_smooth = BOUNDARY_OF_TOKEN[usd_token(text, "interpolateBoundary")]
    edges, corners = file_sharpness(text)
    mesh = obj.data
    if edges:
        shapes.set_edge_creases(mesh, [sharpness_to_crease(edges.get(k, 0.0)) for k in edge_keys(mesh)])
    if corners:
        values = np.zeros(len(mesh.vertices), np.float32)
        for v, s in corners.items():
            values[v] = sharpness_to_crease(s)
        shapes.set_vertex_creases(mesh, values)


def export_and_import(tmp_path, source, cage_obj, quality=3, **options):
    """(imported object, the file's text): the cage of source, written and read back."""
    mesh = api.native_mesh(source.data)
    cage = positions(cage_obj.data)
    path = tmp_path / "cage.usda"
    assert native.write_usd(path, mesh, cage, **options) == path
    text = path.read_text(encoding="utf-8")
    obj = import_usd(path)
    points = positions(obj.data)
    if options.get("scheme", "CATMULL_CLARK") == "CATMULL_CLARK":
        shown = shown_points(source, cage)
        moved = np.flatnonzero((shown != cage).any(axis=1))
        assert np.abs(points[moved] - shown[moved]).max(initial=0) <= 1e-6 * diagonal(cage)
        points, cage = np.delete(points, moved, axis=0), np.delete(cage, moved, axis=0)
    assert points.tobytes() == cage.tobytes(), "the imported points are not the cage's"
    assert faces_of(obj.data) == faces_of(source.data)
    mod = subsurf(obj)
    if options.get("scheme", "CATMULL_CLARK") == "CATMULL_CLARK":
        assert mod is not None and mod.use_limit_surface
        if not READS_CREASES:
            complete_import(obj, text)
        assert mod.boundary_smooth == options.get("boundary_smooth", 'ALL')
        mod.quality = quality
    return obj, text


def misses(obj, targets):
    """Per original vertex: |evaluated control point - target| / diagonal."""
    points = evaluated_control_points(obj, len(targets))
    return np.abs(points - targets).max(axis=1) / diagonal(targets)


def twice_ruled(text, faces):
    """Vertices where Blender applies its two-edge rule to a corner
    sharpness that already holds it: two face edges, the smaller sharpness
    above 0, and the written sharpness below 10."""
    edges, corners = file_sharpness(text)
    neighbours = {}
    for f in faces:
        for i, a in enumerate(f):
            b = f[(i + 1) % len(f)]
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
    out = []
    for v, around in neighbours.items():
        if len(around) != 2:
            continue
        smaller = min(edges.get((min(v, w), max(v, w)), 0.0) for w in around)
        if smaller > 0 and corners.get(v, 0.0) < 10:
            out.append(v)
    return sorted(out)


def interpolate(source, **settings):
    targets = positions(source.data).astype(np.float64)
    cage_obj, _ = subdiv_pia.interpolate(source, **settings)
    assert cage_obj["pia_status"] == 'CONVERGED', cage_obj["pia_status"]
    return cage_obj, targets


def through_usd(tmp_path, source, boundary_smooth='ALL', quality=3):
    """Interpolate, export (both ways of writing the two-edge rule),
    import, and check: the file written for any OpenSubdiv host puts the
    surface on every target but where Blender applies the rule twice; the
    file written without the rule, on every target."""
    cage_obj, targets = interpolate(source, levels=1, quality=quality, boundary_smooth=boundary_smooth)
    assert misses(cage_obj, targets).max() <= MATCH
    imported, text = export_and_import(tmp_path, source, cage_obj, quality=quality, boundary_smooth=boundary_smooth)
    miss = misses(imported, targets)
    twice = twice_ruled(text, faces_of(source.data))
    others = np.delete(miss, twice)
    assert others.max() <= MATCH, "miss %.3g of the diagonal at vertex %d" % (others.max(), np.argmax(others))
    bpy.data.objects.remove(imported)
    imported, _ = export_and_import(tmp_path, source, cage_obj, quality=quality, boundary_smooth=boundary_smooth,
                                    two_edge_rule=False)
    alone = misses(imported, targets)
    assert alone.max() <= MATCH, "miss %.3g of the diagonal at vertex %d" % (alone.max(), np.argmax(alone))
    print("%s %s: miss %.3g (two-edge rule written: %.3g away from the %d vertices it doubles, %.3g there)" % (
        source.name, boundary_smooth, alone.max(), others.max(), len(twice), miss[twice].max() if twice else 0))
    return miss, twice


# --- sources ---------------------------------------------------------------------------

def crease_tags(path):
    """OpenSubdiv's `t crease` tags of an OBJ file: {(a, b) a < b: sharpness}."""
    tags = {}
    with open(path) as f:
        for line in f:
            p = line.split()
            if p[:2] == ["t", "crease"]:
                ints, floats = (int(x) for x in p[2].split("/")[:2])
                chain = [int(x) for x in p[3:3 + ints]]
                s = float(p[3 + ints]) if floats else 10.0
                for a, b in zip(chain, chain[1:]):
                    tags[(min(a, b), max(a, b))] = s
    return tags


def car():
    """catmark_car: quads, boundaries, its crease tags (sharpness 6) as
    Blender creases, vertex creases on every 37th vertex."""
    path = os.path.join(DATA, "catmark_car.obj")
    source = import_obj(path)
    tags = crease_tags(path)
    keys = edge_keys(source.data)
    assert sum(k in tags for k in keys) == len(tags) == 314
    shapes.set_edge_creases(source.data, [sharpness_to_crease(tags.get(k, 0.0)) for k in keys])
    vertex = np.zeros(len(source.data.vertices), np.float32)
    vertex[::37] = 0.6
    shapes.set_vertex_creases(source.data, vertex)
    return source


def teapot():
    """teapot: triangles, boundaries, 88 vertices with two edges; creases
    0.3 to 1.0 on a fifth of the edges, on boundaries as well."""
    source = import_obj(os.path.join(DATA, "teapot.obj"))
    rng = np.random.default_rng(5)
    n = len(source.data.edges)
    values = np.where(rng.random(n) < 0.2, rng.choice(np.float32(shapes.CREASE_VALUES), n), 0)
    shapes.set_edge_creases(source.data, values.astype(np.float32))
    return source


def creased_grid():
    """Open grid, its boundary creased 0.5 (sharpness 2.5): the corners
    have two edges, which Blender's rule makes semi-sharp corners."""
    source = shapes.open_grid()
    keys = edge_keys(source.data)
    faces_per_edge = {}
    for f in faces_of(source.data):
        for i, a in enumerate(f):
            b = f[(i + 1) % len(f)]
            k = (min(a, b), max(a, b))
            faces_per_edge[k] = faces_per_edge.get(k, 0) + 1
    shapes.set_edge_creases(source.data, [0.5 if faces_per_edge[k] == 1 else 0.0 for k in keys])
    return source


# --- tests -------------------------------------------------------------------------------

@pytest.mark.parametrize("boundary_smooth", ('ALL', 'PRESERVE_CORNERS'))
@pytest.mark.parametrize("make", (car, teapot), ids=("car", "teapot"))
def test_real_mesh(tmp_path, make, boundary_smooth):
    through_usd(tmp_path, make(), boundary_smooth)


@pytest.mark.parametrize("shape", (shapes.edge_creases, shapes.vertex_creases, shapes.loose_parts,
                                   shapes.ngon_cylinder, shapes.mixed, shapes.creased_pages),
                         ids=lambda f: f.__name__)
def test_shape(tmp_path, shape):
    source = shape()
    miss, twice = through_usd(tmp_path, source)
    if shape is shapes.loose_parts:
        # The loose chain's middle vertex (11) is moved to where the cage's modifier shows it.
        assert twice == []
        cage = np.zeros((len(source.data.vertices), 3))
        cage[10:13] = np.eye(3)
        assert np.flatnonzero((shown_points(source, cage) != cage).any(axis=1)).tolist() == [11]


def test_two_edge_rule_applied_again(tmp_path):
    """The grid's four corners: written with the rule (2.5) Blender reads
    crease 0.5 and adds the boundary's 2.5 once more (5.0): its surface
    leaves the corner targets, and only them."""
    source = creased_grid()
    miss, twice = through_usd(tmp_path, source)
    corners = [v for v, n in enumerate(np.bincount(np.concatenate(
        [[a, b] for a, b in edge_keys(source.data)]))) if n == 2]
    assert twice == corners and len(corners) == 4
    assert miss[twice].min() > 1e-3, miss[twice]


def test_quality_is_the_modifiers(tmp_path):
    """Smooth corners at quality 5: the imported modifier's default quality
    (3) misses them, the cage's quality hits them."""
    source = shapes.open_grid()
    cage_obj, targets = interpolate(source, levels=1, quality=5)
    imported, _ = export_and_import(tmp_path, source, cage_obj, quality=3)
    assert misses(imported, targets).max() > 1e-3
    subsurf(imported).quality = 5
    assert misses(imported, targets).max() <= MATCH


def test_import_mapping(tmp_path):
    """What the import makes of each attribute, in this Blender."""
    source = creased_grid()
    vertex = np.zeros(len(source.data.vertices), np.float32)
    vertex[7] = 0.3
    shapes.set_vertex_creases(source.data, vertex)
    mesh = api.native_mesh(source.data)
    for boundary_smooth, token in (('ALL', "edgeOnly"), ('PRESERVE_CORNERS', "edgeAndCorner")):
        path = tmp_path / ("%s.usda" % boundary_smooth)
        native.write_usd(path, mesh, boundary_smooth=boundary_smooth, name="imported_" + boundary_smooth.lower())
        text = path.read_text(encoding="utf-8")
        assert usd_token(text, "interpolateBoundary") == token
        obj = import_usd(path)
        assert obj.name == "imported_" + boundary_smooth.lower()
        mod = subsurf(obj)
        assert (mod.levels, mod.render_levels, mod.quality, mod.use_limit_surface, mod.use_creases) == (
            1, 2, 3, True, True)
        edges, corners = file_sharpness(text)
        edge_creases = float_attribute(obj.data, "crease_edge")
        vertex_creases = float_attribute(obj.data, "crease_vert")
        if READS_CREASES:
            assert mod.boundary_smooth == boundary_smooth
            assert mod.uv_smooth == 'NONE'  # faceVaryingLinearInterpolation "all"
            expected = [sharpness_to_crease(edges.get(k, 0.0)) for k in edge_keys(obj.data)]
            assert np.abs(edge_creases - expected).max() < 1e-6
            expected = [sharpness_to_crease(corners.get(v, 0.0)) for v in range(len(obj.data.vertices))]
            assert np.abs(vertex_creases - expected).max() < 1e-6
            # The written corner sharpness holds the two-edge rule: 0.5 read back where 0 was set.
            assert abs(vertex_creases[0] - 0.5) < 1e-6 and abs(vertex_creases[7] - 0.3) < 1e-6
        else:
            assert mod.boundary_smooth == 'ALL'
            assert edge_creases is None and vertex_creases is None


def test_loop_imports_without_modifier(tmp_path):
    """Blender has no Loop modifier, and its USD import gives a "loop" mesh
    none: only the points and faces come back, and the Loop cage's
    surface is checked in plain Python (tests/python/test_usd.py) and by
    the add-on's own Loop limit object (test_loop.py)."""
    source = import_obj(os.path.join(DATA, "teapot.obj"))
    cage_obj, _ = subdiv_pia.interpolate(source, scheme='LOOP', levels=1)
    assert cage_obj["pia_status"] == 'CONVERGED'
    imported, text = export_and_import(tmp_path, source, cage_obj, scheme="LOOP")
    assert usd_token(text, "subdivisionScheme") == "loop"
    assert subsurf(imported) is None and len(imported.modifiers) == 0


def test_export_where_blender_has_no_usd(tmp_path):
    """Without USD in Blender: a cage the add-on made, written from
    Blender's own Python, holds the cage's points to the bit, its faces,
    and the crease sharpness Blender's modifier gives OpenSubdiv."""
    assert not bpy.app.build_options.usd
    source = car()
    cage_obj, targets = interpolate(source, levels=1)
    assert misses(cage_obj, targets).max() <= MATCH
    cage = positions(cage_obj.data)
    path = tmp_path / "car.usda"
    mesh = api.native_mesh(source.data)  # the edges and creases as this Blender stores them
    native.write_usd(path, mesh, cage)
    text = path.read_text(encoding="utf-8")
    written = np.array(usd_array(text, "points"), np.float64).astype(np.float32).reshape(-1, 3)
    assert written.tobytes() == cage.tobytes()
    counts = [int(n) for n in usd_array(text, "faceVertexCounts")]
    indices = [int(i) for i in usd_array(text, "faceVertexIndices")]
    assert [tuple(indices[sum(counts[:k]):sum(counts[:k + 1])]) for k in range(len(counts))] == \
        [tuple(f) for f in faces_of(source.data)]
    assert usd_token(text, "subdivisionScheme") == "catmullClark"
    assert usd_token(text, "interpolateBoundary") == "edgeOnly"
    edges, corners = file_sharpness(text)
    expected = {(min(a, b), max(a, b)): float(np.float32(c) * np.float32(c) * np.float32(10))
                for (a, b), c in zip(mesh.edges.tolist(), mesh.edge_creases.tolist()) if c * c * 10 >= 1e-6}
    assert edges.keys() == expected.keys() and len(edges) == 314
    assert max(abs(edges[k] - expected[k]) for k in edges) <= 1e-6
    assert len(corners) >= len(range(0, len(cage), 37))


if not bpy.app.build_options.usd:
    # Nothing can import the file here: the import tests are not defined.
    for _name in [n for n in globals() if n.startswith("test_") and n != "test_export_where_blender_has_no_usd"]:
        del globals()[_name]
else:
    del test_export_where_blender_has_no_usd
