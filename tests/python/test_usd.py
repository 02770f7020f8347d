# SPDX-License-Identifier: GPL-3.0-or-later
"""The USD export (spia.usd_text / write_usd), read back with a small USDA
parser of its own (no USD library needed): points exactly, topology,
scheme and boundary tokens, and crease and corner sharpness against
Blender's rules computed here independently, face by face in plain Python."""
import math
import re

import numpy as np
import pytest

from conftest import load

TEN = np.float32(10.0)


# --- reading the text back ----------------------------------------------------

ATTRIBUTE = re.compile(r'^[ \t]*(uniform[ \t]+)?([A-Za-z0-9]+(?:\[\])?)[ \t]+([A-Za-z_][\w:]*)[ \t]*=[ \t]*'
                       r'(\[[^\]]*\]|"[^"]*")', re.M)
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def parse_usda(text):
    """{'header': {key: text}, 'prims': {name: (type, {attribute: (type, uniform, value)})}}; arrays of
    numbers as lists of their texts, arrays of tuples as lists of lists, tokens as str."""
    assert text.startswith("#usda 1.0\n"), text[:20]
    header = {}
    match = re.match(r"#usda 1\.0\n\(\n(.*?)\n\)\n", text, re.S)
    if match:
        for line in match.group(1).splitlines():
            key, _, value = line.strip().partition(" = ")
            header[key] = value.strip('"')
    prims = {}
    for prim in re.finditer(r'^def (\w+) "(\w+)"\n\{\n(.*?)^\}\n', text, re.S | re.M):
        attributes = {}
        for a in ATTRIBUTE.finditer(prim.group(3)):
            uniform, kind, name, value = bool(a.group(1)), a.group(2), a.group(3), a.group(4)
            assert name not in attributes, "%s written twice" % name
            if value.startswith('"'):
                parsed = value[1:-1]
            elif "(" in value:
                parsed = [NUMBER.findall(t) for t in re.findall(r"\(([^)]*)\)", value)]
            else:
                parsed = NUMBER.findall(value)
            attributes[name] = (kind, uniform, parsed)
        # Nothing in the prim's body but those attributes.
        assert ATTRIBUTE.sub("", prim.group(3)).strip() == "", prim.group(3)
        prims[prim.group(2)] = (prim.group(1), attributes)
    return {"header": header, "prims": prims}


def as_float32(texts):
    """Numbers as USD's text reader takes float values: parsed as double, then rounded to float."""
    return np.array([float(t) for t in texts], np.float64).astype(np.float32)


def as_int(texts):
    return np.array([int(t) for t in texts], np.int64)


def the_mesh(text, name="cage"):
    parsed = parse_usda(text)
    assert list(parsed["prims"]) == [name]
    kind, attributes = parsed["prims"][name]
    assert kind == "Mesh"
    return parsed["header"], attributes


def value(attributes, name, kind, uniform=False):
    assert name in attributes, name
    k, u, v = attributes[name]
    assert (k, u) == (kind, uniform), (name, k, u)
    return v


def points_of(attributes):
    rows = value(attributes, "points", "point3f[]")
    assert all(len(r) == 3 for r in rows)
    return as_float32([x for r in rows for x in r]).reshape(-1, 3)


# --- Blender's rules, independently -------------------------------------------

def expected_sharpness(positions, faces, edges=(), edge_creases=None, vertex_creases=None, blender=True,
                       use_creases=True, two_edge_rule=True):
    """({(a, b) a < b: edge sharpness}, {vertex: corner sharpness}) as Blender's
    modifier hands them to OpenSubdiv (blender=False: OpenSubdiv's Loop)."""
    face_edges = set()
    neighbours = {}
    used = set()
    for f in faces:
        used.update(f)
        for i, a in enumerate(f):
            b = f[(i + 1) % len(f)]
            face_edges.add((min(a, b), max(a, b)))
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
    crease = {}
    loose_ends = set()
    for i, (a, b) in enumerate(edges):
        key = (min(a, b), max(a, b))
        if key not in face_edges:
            loose_ends.update(v for v in key if v in used)
            continue
        if use_creases and edge_creases is not None:
            c = np.float32(edge_creases[i])
            s = c * c * TEN
            if s >= np.float32(1e-6):
                crease[key] = max(crease.get(key, np.float32(0)), s)
    corner = {}
    for v in sorted(used):
        if blender and v in loose_ends:
            corner[v] = TEN
            continue
        s = np.float32(0)
        if use_creases and vertex_creases is not None:
            c = np.float32(vertex_creases[v])
            s = c * c * TEN
        if blender and two_edge_rule and len(neighbours[v]) == 2:
            two = [crease.get((min(v, w), max(v, w)), np.float32(0)) for w in neighbours[v]]
            s = min(s + min(two), TEN)
        if s > 0:
            corner[v] = np.float32(s)
    return crease, corner


def expected_points(cage, faces, edges, blender=True):
    """The cage, but (Blender's rules) a point that no face uses between
    exactly two loose edges at (prev + 4 V + next) / 6, where Blender's
    modifier shows it."""
    used = {v for f in faces for v in f}
    around = {}
    for a, b in edges:
        for v, w in ((a, b), (b, a)):
            if v not in used:
                around.setdefault(v, []).append(w)
    out = np.array(cage, np.float32)
    if blender:
        for v, (p, q) in ((v, w) for v, w in around.items() if len(w) == 2):
            out[v] = (np.float64(cage[p]) + 4 * np.float64(cage[v]) + np.float64(cage[q])) / 6
    return out


def written_sharpness(attributes):
    """The file's creases and corners as the dictionaries above."""
    crease, corner = {}, {}
    if "creaseIndices" in attributes:
        indices = as_int(value(attributes, "creaseIndices", "int[]"))
        lengths = as_int(value(attributes, "creaseLengths", "int[]"))
        sharpness = as_float32(value(attributes, "creaseSharpnesses", "float[]"))
        assert len(lengths) == len(sharpness) and lengths.sum() == len(indices)
        start = 0
        for length, s in zip(lengths.tolist(), sharpness):
            assert length >= 2
            chain = indices[start:start + length].tolist()
            for a, b in zip(chain, chain[1:]):
                key = (min(a, b), max(a, b))
                assert key not in crease, "edge %s creased twice" % (key,)
                crease[key] = s
            start += length
    else:
        assert "creaseLengths" not in attributes and "creaseSharpnesses" not in attributes
    if "cornerIndices" in attributes:
        indices = as_int(value(attributes, "cornerIndices", "int[]"))
        sharpness = as_float32(value(attributes, "cornerSharpnesses", "float[]"))
        assert len(indices) == len(sharpness) == len(set(indices.tolist()))
        corner = dict(zip(indices.tolist(), sharpness))
    else:
        assert "cornerSharpnesses" not in attributes
    return crease, corner


def assert_same_sharpness(got, expected):
    """Equal keys and bit-identical float32 values."""
    assert sorted(got) == sorted(expected), (sorted(set(got) ^ set(expected)))[:10]
    for key, s in expected.items():
        assert np.float32(got[key]).tobytes() == np.float32(s).tobytes(), (key, got[key], s)


# --- meshes -------------------------------------------------------------------

def face_edge_list(faces):
    seen = {}
    for f in faces:
        for i, a in enumerate(f):
            b = f[(i + 1) % len(f)]
            seen.setdefault((min(a, b), max(a, b)), None)
    return list(seen)


def grid(nx=4, ny=3, seed=0):
    """An open quad grid with jittered points: boundary and four valence-2 corners."""
    rng = np.random.default_rng(seed)
    points = np.array([(x, y, 0.0) for y in range(ny + 1) for x in range(nx + 1)], np.float64)
    points += rng.uniform(-0.2, 0.2, points.shape)
    faces = [(y * (nx + 1) + x, y * (nx + 1) + x + 1, (y + 1) * (nx + 1) + x + 1, (y + 1) * (nx + 1) + x)
             for y in range(ny) for x in range(nx)]
    return points.astype(np.float32), faces


def creased(native, points, faces, seed=1, extra_edges=(), vertex_share=0.2, edge_values=(0.3, 0.5, 0.9, 1.0)):
    """A Mesh with every face edge listed, about half creased (values from
    edge_values and tiny ones), vertex creases on some vertices, and extra
    edges (loose ones, or repeats of face edges) after them."""
    rng = np.random.default_rng(seed)
    edges = face_edge_list(faces) + list(extra_edges)
    values = np.array(list(edge_values) + [1e-4, 3e-4, 4e-4, 0.0], np.float32)
    edge_creases = np.where(rng.random(len(edges)) < 0.5, rng.choice(values, len(edges)), 0).astype(np.float32)
    vertex_creases = np.where(rng.random(len(points)) < vertex_share,
                              rng.choice(np.array([0.2, 0.7, 1.0, 2e-4], np.float32), len(points)), 0)
    mesh = native.Mesh.from_faces(points, faces, edges=edges, edge_creases=edge_creases,
                                  vertex_creases=vertex_creases.astype(np.float32))
    return mesh, edges


def car(native):
    """catmark_car: quads, boundaries, its own crease tags as Blender creases
    (c = sqrt(s / 10)), and some vertex creases."""
    points, faces, tags = load("catmark_car")
    edges = face_edge_list(faces)
    edge_creases = np.array([min(1.0, math.sqrt(tags.get(e, tags.get(e[::-1], 0.0)) / 10)) for e in edges],
                            np.float32)
    vertex_creases = np.zeros(len(points), np.float32)
    vertex_creases[::37] = 0.6
    return native.Mesh.from_faces(points, faces, edges=edges, edge_creases=edge_creases,
                                  vertex_creases=vertex_creases), faces, edges


def check_file(native, mesh, faces, edges, cage=None, **options):
    text = native.usd_text(mesh, cage, **options)
    header, attributes = the_mesh(text)
    cage = mesh.positions if cage is None else np.asarray(cage, np.float32)
    scheme = options.get("scheme", "CATMULL_CLARK")
    # Points exactly, as float32 bits (read as USD reads them).
    got = points_of(attributes)
    assert got.shape == cage.shape
    points = expected_points(cage, faces, edges, blender=scheme == "CATMULL_CLARK")
    assert got.tobytes() == points.tobytes()
    assert as_int(value(attributes, "faceVertexCounts", "int[]")).tolist() == [len(f) for f in faces]
    assert as_int(value(attributes, "faceVertexIndices", "int[]")).tolist() == [v for f in faces for v in f]
    extent = as_float32([x for r in value(attributes, "extent", "float3[]") for x in r]).reshape(2, 3)
    assert extent.tobytes() == np.stack([points.min(axis=0), points.max(axis=0)]).tobytes()
    assert value(attributes, "subdivisionScheme", "token", uniform=True) == {
        "CATMULL_CLARK": "catmullClark", "LOOP": "loop"}[scheme]
    assert value(attributes, "interpolateBoundary", "token") == {
        "ALL": "edgeOnly", "PRESERVE_CORNERS": "edgeAndCorner"}[options.get("boundary_smooth", "ALL")]
    assert value(attributes, "triangleSubdivisionRule", "token") == "catmullClark"
    assert value(attributes, "faceVaryingLinearInterpolation", "token") == "all"
    assert value(attributes, "orientation", "token", uniform=True) == "rightHanded"
    assert header["defaultPrim"] == "cage"
    expected = expected_sharpness(
        cage, faces, edges, mesh.edge_creases, mesh.vertex_creases, blender=scheme == "CATMULL_CLARK",
        use_creases=options.get("use_creases", True), two_edge_rule=options.get("two_edge_rule", True))
    crease, corner = written_sharpness(attributes)
    assert_same_sharpness(crease, expected[0])
    assert_same_sharpness(corner, expected[1])
    return text, attributes, crease, corner


# --- tests --------------------------------------------------------------------

@pytest.mark.parametrize("boundary_smooth", ("ALL", "PRESERVE_CORNERS"))
def test_real_mesh_with_crease_tags(native, boundary_smooth):
    mesh, faces, edges = car(native)
    cage = mesh.positions * np.float32(1.5) + np.float32(0.25)
    _, _, crease, corner = check_file(native, mesh, faces, edges, cage, boundary_smooth=boundary_smooth)
    assert len(crease) == 314
    # sqrt(0.6) squared and times ten in float32: within a float's rounding of 6.
    assert all(abs(float(s) - 6.0) < 4e-6 for s in crease.values())
    assert corner


@pytest.mark.parametrize("seed", range(6))
def test_creased_grid_blender_rules(native, seed):
    """Semi-sharp creases on the boundary and at the corners (the two-edge
    rule), tiny creases (left out), a loose edge off a face vertex, a chain
    of two loose edges between unused vertices, a face edge listed twice."""
    points, faces = grid(seed=seed)
    points = np.concatenate([points, np.float32([[9, 9, 9], [9, 8, 9], [9, 9, 8], [8, 8, 7]])])
    n = len(points)
    extra = [(n - 4, n - 3), (n - 3, n - 2), (6, n - 1), faces[0][1::-1]]
    mesh, edges = creased(native, points, faces, seed=seed, extra_edges=extra)
    for options in ({}, {"boundary_smooth": "PRESERVE_CORNERS"}, {"use_creases": False},
                    {"two_edge_rule": False}):
        text, attributes, crease, corner = check_file(native, mesh, faces, edges, **options)
        assert corner[6] == TEN  # the loose edge's end on the surface
        assert not {n - 1, n - 2, n - 3, n - 4} & set(corner)
        if options.get("use_creases", True) is False:
            assert crease == {} and corner == {6: TEN}
        # The chain's middle point where Blender shows it, the others as they are.
        written = points_of(attributes)
        assert (written[n - 3] != points[n - 3]).any()
        assert written[np.arange(n) != n - 3].tobytes() == points[np.arange(n) != n - 3].tobytes()


def test_two_edge_rule_values(native):
    """The rule itself on a 2 x 2 grid: the corner between creases 0.5
    (2.5) and 0.3 (0.9) gets 0.9 added to its own 0.1 (crease 0.1), the
    opposite corner between 1.0 and 1.0 is capped at 10, the edge midpoints
    (three edges) get nothing."""
    spia = native
    points = np.array([(x, y, 0) for y in range(3) for x in range(3)], np.float32)
    faces = [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8, 7)]
    edges = [(0, 1), (0, 3), (5, 8), (7, 8), (1, 2)]
    vertex_creases = np.zeros(9, np.float32)
    vertex_creases[0] = 0.1
    vertex_creases[8] = 0.5
    mesh = spia.Mesh.from_faces(points, faces, edges=edges, edge_creases=[0.5, 0.3, 1.0, 1.0, 0.0],
                                vertex_creases=vertex_creases)
    _, attributes = the_mesh(spia.usd_text(mesh))
    _, corner = written_sharpness(attributes)
    s01 = np.float32(0.1) * np.float32(0.1) * TEN
    assert corner == {0: s01 + np.float32(0.3) * np.float32(0.3) * TEN, 8: TEN}
    _, attributes = the_mesh(spia.usd_text(mesh, two_edge_rule=False))
    assert written_sharpness(attributes)[1] == {0: s01, 8: np.float32(2.5)}


def test_loop_follows_opensubdiv_alone(native):
    """Loop: triangles, creases c*c*10, neither the two-edge rule nor sharp
    loose-edge ends, points no face uses as they are."""
    points, faces, _ = load("teapot")
    faces = [tuple(f) for f in faces]
    n = len(points)
    points = np.concatenate([points, np.float32([[9, 9, 9], [9, 8, 9], [9, 9, 8]])])
    extra = [(faces[0][0], faces[5][2]), (n, n + 1), (n + 1, n + 2)]
    mesh, edges = creased(native, points, faces, seed=3, extra_edges=extra)
    for boundary_smooth in ("ALL", "PRESERVE_CORNERS"):
        check_file(native, mesh, faces, edges, scheme="LOOP", boundary_smooth=boundary_smooth)
    _, attributes = the_mesh(native.usd_text(mesh, scheme="LOOP"))
    assert points_of(attributes).tobytes() == points.tobytes()
    blender = expected_sharpness(points, faces, edges, mesh.edge_creases, mesh.vertex_creases)[1]
    assert written_sharpness(attributes)[1] != blender  # the rules differ on this mesh


def test_triangles_and_ngons_catmull_clark(native):
    points, faces, _ = load("double-torus")
    mesh, edges = creased(native, points, faces, seed=5)
    check_file(native, mesh, faces, edges)
    points, faces, _ = load("elephant-with-holes")
    mesh, edges = creased(native, points, faces, seed=6, vertex_share=0.05)
    check_file(native, mesh, faces, edges, boundary_smooth="PRESERVE_CORNERS")


def test_points_round_trip_exactly(native):
    """Awkward float32 values: subnormals, extremes, -0, thirds, random bits."""
    rng = np.random.default_rng(7)
    bits = rng.integers(0, 2**32, 3000, dtype=np.uint64).astype(np.uint32).view(np.float32)
    bits = bits[np.isfinite(bits)]
    special = np.array([0.0, -0.0, 1e-45, -1e-45, 1.1754942e-38, 1.1754944e-38, 3.4028235e38, -3.4028235e38,
                        0.1, 1 / 3, 2 / 3, 16777217.0, 1e-7, 123456.789, np.pi], np.float32)
    values = np.concatenate([special, bits])
    values = np.resize(values, ((len(values) + 2) // 3) * 3).reshape(-1, 3)
    n = len(values)
    faces = [(i, (i + 1) % n, (i + 2) % n) for i in range(0, n - 2, 3)]
    mesh = native.Mesh.from_faces(np.zeros((n, 3), np.float32), faces)
    text, attributes, _, _ = check_file(native, mesh, faces, [], values)
    # Short where numpy's shortest form survives the double path: 0.1, not 0.10000000149011612.
    assert "(0.0, -0.0, 1e-45)" in text
    assert "(3.4028235e+38, -3.4028235e+38, 0.1)" in text
    # numpy's 1.13 printing (6 digits): the values are written exactly all the same.
    with np.printoptions(legacy="1.13"):
        check_file(native, mesh, faces, [], values)


def test_write_usd_writes_usd_text(native, tmp_path):
    points, faces = grid()
    mesh, _ = creased(native, points, faces)
    cage = points + np.float32(0.5)
    path = tmp_path / "cage.usda"
    assert native.write_usd(path, mesh, cage, name="pia_cage", up_axis="Y", meters_per_unit=0.01) == path
    text = path.read_bytes().decode("utf-8")
    assert text == native.usd_text(mesh, cage, name="pia_cage", up_axis="Y", meters_per_unit=0.01)
    assert "\r" not in text
    header, attributes = the_mesh(text, "pia_cage")
    assert header == {"defaultPrim": "pia_cage", "metersPerUnit": "0.01", "upAxis": "Y"}
    assert points_of(attributes).tobytes() == cage.tobytes()


def test_cage_from_interpolation_reaches_targets_through_the_file(native):
    """The file, read back into a Mesh (creases c = sqrt(s / 10), as Blender
    4.4 and later import them; written without the two-edge rule, which the
    library applies itself like Blender's modifier), gives limit points on
    the targets."""
    points, faces = grid(6, 5, seed=11)
    mesh, edges = creased(native, points, faces, seed=12, edge_values=(0.3, 0.5, 0.9))
    # Corner 0 between two semi-sharp creases: the rule matters there.
    mesh.edge_creases[[i for i, e in enumerate(edges) if 0 in e]] = 0.5
    cage, report = native.interpolate(mesh, tolerance=1e-7)
    assert report.converged
    _, attributes = the_mesh(native.usd_text(mesh, cage, two_edge_rule=False))
    crease, corner = written_sharpness(attributes)
    counts = as_int(value(attributes, "faceVertexCounts", "int[]"))
    indices = as_int(value(attributes, "faceVertexIndices", "int[]"))
    read = points_of(attributes)
    vertex_creases = np.zeros(len(read), np.float32)
    for v, s in corner.items():
        vertex_creases[v] = np.sqrt(s / TEN)
    back = native.Mesh(read, counts, indices, edges=np.array(list(crease), np.int32).reshape(-1, 2),
                       edge_creases=np.sqrt(np.array(list(crease.values()), np.float32) / TEN),
                       vertex_creases=vertex_creases)
    limit = native.limit_stencils(back).apply(read)
    diagonal = float(np.linalg.norm(points.max(0) - points.min(0)))
    assert np.abs(limit - points).max() / diagonal <= 1e-5
    # With the rule written too, read back the same way, it is applied twice.
    _, attributes = the_mesh(native.usd_text(mesh, cage))
    twice = written_sharpness(attributes)[1]
    for v, s in twice.items():
        vertex_creases[v] = np.sqrt(s / TEN)
    back.vertex_creases = vertex_creases
    limit = native.limit_stencils(back).apply(read)
    assert np.abs(limit - points).max() / diagonal > 1e-4


def test_no_creases_written_without_creases(native):
    points, faces = grid()
    mesh = native.Mesh.from_faces(points, faces)
    text = native.usd_text(mesh)
    for name in ("crease", "corner"):
        assert name not in text
    mesh, _ = creased(native, points, faces)
    assert "crease" not in native.usd_text(mesh, use_creases=False)
    assert "corner" not in native.usd_text(mesh, use_creases=False)


@pytest.mark.parametrize("cage,pattern", [
    (np.zeros((3, 3)), r"shape \(20, 3\)"),
    (np.zeros((20, 2)), r"shape \(20, 3\)"),
    (np.zeros(60), r"shape \(20, 3\)"),
    ([["a", "b", "c"]] * 20, "array of numbers"),
    (np.full((20, 3), np.nan), "NaN, infinite"),
    (np.full((20, 3), 1e39), "beyond float32"),
])
def test_bad_cage(native, cage, pattern):
    points, faces = grid()
    mesh = native.Mesh.from_faces(points, faces)
    with pytest.raises(native.PiaError, match=pattern):
        native.usd_text(mesh, cage)


def test_refused(native, tmp_path):
    points, faces = grid()
    mesh = native.Mesh.from_faces(points, faces)
    triangles = native.Mesh.from_faces(points, [t for f in faces for t in ((f[0], f[1], f[2]), (f[0], f[2], f[3]))])
    path = tmp_path / "x.usda"
    cases = [
        (dict(scheme="DOO_SABIN"), "no Doo-Sabin"),
        (dict(scheme="LOOP", boundary_rule="HOPPE"), "HOPPE"),
        (dict(scheme="LOOP"), "triangles only"),
        (dict(scheme="BILINEAR"), "scheme must be one of"),
        (dict(boundary_smooth="NONE"), "boundary_smooth must be one of"),
        (dict(name="1cage"), "prim name"),
        (dict(name="a/b"), "prim name"),
        (dict(up_axis="X"), "up_axis"),
        (dict(meters_per_unit=0), "meters_per_unit"),
        (dict(meters_per_unit="cm"), "meters_per_unit"),
    ]
    for options, pattern in cases:
        target = triangles if options.get("scheme") == "LOOP" and "boundary_rule" in options else mesh
        with pytest.raises(native.PiaError, match=pattern):
            native.write_usd(path, target, **options)
        assert not path.exists()
    assert "loop" in native.usd_text(triangles, scheme="LOOP")
    with pytest.raises(native.PiaError, match="spia.Mesh"):
        native.usd_text(points)


@pytest.mark.parametrize("make,code", [
    (lambda n, p: n.Mesh.from_faces(p, [(0, 1)]), "FACE_SIZE"),
    (lambda n, p: n.Mesh.from_faces(p, [(0, 1, 99)]), "INDEX_RANGE"),
    (lambda n, p: n.Mesh.from_faces(p, [(0, 1, 6, 1)]), "DEGENERATE_FACE"),
    (lambda n, p: n.Mesh.from_faces(p, [(0, 1, 6)], edges=[(0, 20)]), "INDEX_RANGE"),
    (lambda n, p: n.Mesh.from_faces(p, [(0, 1, 6)], vertex_creases=np.full(20, np.nan)), "NONFINITE"),
    (lambda n, p: n.Mesh.from_faces(p, []), "EMPTY_MESH"),
    (lambda n, p: n.Mesh.from_faces(np.where(np.arange(20)[:, None] == 3, np.nan, p), [(0, 1, 6)]), "NONFINITE"),
])
def test_bad_mesh_as_the_library_says(native, make, code):
    """The export refuses what the library refuses, with its code and message."""
    points, _ = grid()
    mesh = make(native, points)
    with pytest.raises(native.PiaError) as info:
        native.usd_text(mesh)
    with pytest.raises(native.PiaError) as library:
        native.validate(mesh)
    assert info.value.code == library.value.code == code
    assert info.value.message == library.value.message and info.value.message


def test_exported_names(native):
    assert {"usd_text", "write_usd"} <= set(native.__all__)
    assert "write_usd" in native.__doc__


def test_the_library_gives_the_sharpness_the_file_carries(native):
    """spia.sharpness, the one source of the file's sharpness: the same
    values as the independent reading above, pairs sorted, the two-edge
    rule switched by its flag, Loop without Blender's rules."""
    points = np.array([(x, y, 0) for y in range(3) for x in range(3)], np.float32)
    faces = [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8, 7)]
    edges = [(1, 0), (3, 0), (8, 5), (8, 7), (1, 2), (4, 5)]
    vertex_creases = np.zeros(9, np.float32)
    vertex_creases[0] = 0.1
    mesh = native.Mesh.from_faces(points, faces, edges=edges, edge_creases=[0.5, 0.3, 1.0, 1.0, 0.0, 0.4],
                                  vertex_creases=vertex_creases)
    pairs, creases, vertices = native.sharpness(mesh)
    assert pairs.tolist() == [[0, 1], [0, 3], [4, 5], [5, 8], [7, 8]]
    sq = lambda c: np.float32(c) * np.float32(c) * TEN  # noqa: E731
    np.testing.assert_array_equal(creases, [sq(0.5), sq(0.3), sq(0.4), TEN, TEN])
    assert vertices[0] == sq(0.1) + sq(0.3) and vertices[8] == TEN and vertices[4] == 0
    _, _, plain = native.sharpness(mesh, two_edge_rule=False)
    assert plain[0] == sq(0.1) and plain[8] == 0
    _, attributes = the_mesh(native.usd_text(mesh))
    crease, corner = written_sharpness(attributes)
    assert corner == {int(v): vertices[v] for v in np.flatnonzero(vertices)}
    assert native.sharpness(mesh, scheme="LOOP")[2][8] == 0  # no two-edge rule for Loop
