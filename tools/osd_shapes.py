# SPDX-License-Identifier: GPL-3.0-or-later
"""OpenSubdiv's regression shapes, read from its source package.

`make build` unpacks Debian's source package of OpenSubdiv 3.6.0 at
build/src/opensubdiv-3.6.0 (tools/package.py); its regression/shapes/*.h are
C++ headers, each holding one shape as OBJ text in a string constant:

    static const std::string catmark_cube = "v ...\\n" "f 1/1 2/2 ...\\n" "t crease 2/1/0 0 1 2.0\\n" ;

Nothing of them is copied into this project: the tests read them from there.
Tags are applied as OpenSubdiv's regression code does
(regression/common/shape_utils.cpp parses them, far_utils.h applies them):

- ``t crease nints/nfloats/0 i0 i1 i2 i3 ... s...``: the edges (i0, i1),
  (i2, i3), ... (pairs, OpenSubdiv steps through the integers two at a
  time) get sharpness ``floats[j]`` for the pair starting at integer j when
  there is more than one float, else ``floats[0]``; negative sharpness is 0;
  a pair that is not an edge makes OpenSubdiv refuse the shape (ValueError
  here); a later tag on the same edge replaces an earlier one.
- ``t corner n/m/0 v... s...``: vertex sharpness, likewise per vertex.
- ``t interpolateboundary 1/0/0 k``: 0 none, 1 edge and corner, 2 edge only
  (the default when there is no tag).
- ``t hole``, ``t creasemethod ... chaikin``, ``t smoothtriangles ... smooth``,
  ``t vertexedit`` / ``edgeedit`` / ``faceedit``, the bilinear scheme and
  faces that use a vertex twice (degenerate polygons to OpenSubdiv; a
  Blender mesh cannot hold them) are what Blender's Subdivision Surface
  modifier cannot express: they are named in ``Shape.inexpressible``.
  ``Shape.dissolved()`` gives such a shape with those faces as the add-on's
  cleanup leaves them; ``load_testable()`` the shapes Blender can express
  and those variants.

Blender's crease c in [0, 1] is sharpness 10 c^2 to OpenSubdiv (10: infinitely
sharp), so a sharpness s becomes c = sqrt(min(s, 10) / 10).

Standard library and numpy only:

    import osd_shapes                      # tools/ on sys.path
    for shape in osd_shapes.load_testable():   # or load_all(), load("catmark_val2_interior")
        shape.positions, shape.faces, shape.edges, shape.edge_creases, shape.vertex_creases
"""
import os
import re
from dataclasses import dataclass, field

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OPENSUBDIV_VERSION = "3.6.0"
# The environment variable SUBDIV_PIA_OSD_SHAPES may name another shapes folder.
SHAPES_DIR = os.path.join(ROOT, "build", "src", "opensubdiv-" + OPENSUBDIV_VERSION, "regression", "shapes")

# The scheme of each shape, by the prefix of its name (as the regression
# programs' init_shapes.h pair them).
SCHEMES = {"catmark": "CATMULL_CLARK", "loop": "LOOP", "bilinear": "BILINEAR"}
# Shapes the regression programs read with isLeftHanded (far_regression/init_shapes.h):
# the corners of their faces after the first are taken in reverse order.
LEFT_HANDED = frozenset(["catmark_lefthanded"])
# OpenSubdiv's infinitely sharp crease.
SHARPNESS_INFINITE = 10.0

_DECLARATION = re.compile(r"static\s+const\s+std::string\s+(\w+)\s*=(.*?);", re.S)
_LITERAL = re.compile(r'"((?:[^"\\]|\\.)*)"')
_ESCAPES = {"n": "\n", "t": "\t", "r": "\r", '"': '"', "\\": "\\", "'": "'", "0": "\0"}


def shapes_dir():
    """The folder of the shape headers (SUBDIV_PIA_OSD_SHAPES, else build/src/...)."""
    return os.environ.get("SUBDIV_PIA_OSD_SHAPES") or SHAPES_DIR


def available():
    return os.path.isdir(shapes_dir())


def missing_message():
    return ("OpenSubdiv's regression shapes are not at %s: run `make build` (it unpacks OpenSubdiv %s's "
            "source package there)" % (shapes_dir(), OPENSUBDIV_VERSION))


def crease_of_sharpness(sharpness):
    """Blender's crease (0..1) for OpenSubdiv's sharpness: sqrt(min(s, 10) / 10)."""
    s = np.clip(np.asarray(sharpness, dtype=np.float64), 0.0, SHARPNESS_INFINITE)
    return np.sqrt(s / SHARPNESS_INFINITE)


@dataclass
class Tag:
    name: str
    ints: list
    floats: list
    strings: list


@dataclass
class Shape:
    """One regression shape.

    positions        (N, 3) float32 (OpenSubdiv reads them as floats)
    faces            list of lists of vertex indices (0-based), in OpenSubdiv's corner order
    edges            (E, 2) int32: every edge of the faces once, in the order first met
    edge_sharpness   (E,) float64, OpenSubdiv's sharpness (0: smooth)
    edge_creases     (E,) float32, Blender's crease sqrt(min(s, 10) / 10)
    vertex_sharpness (N,) float64, vertex_creases (N,) float32 likewise
    boundary         the interpolateboundary tag: 'EDGE_ONLY' (default; Blender's
                     boundary_smooth 'ALL'), 'EDGE_AND_CORNER' ('PRESERVE_CORNERS') or 'NONE'
    inexpressible    what Blender's modifier cannot show, in words (empty: nothing)
    """
    name: str
    scheme: str
    positions: np.ndarray = field(repr=False)
    faces: list = field(repr=False)
    edges: np.ndarray = field(repr=False)
    edge_sharpness: np.ndarray = field(repr=False)
    vertex_sharpness: np.ndarray = field(repr=False)
    boundary: str = "EDGE_ONLY"
    inexpressible: tuple = ()
    tags: list = field(default_factory=list, repr=False)
    uvs: int = 0

    @property
    def vertex_count(self):
        return len(self.positions)

    @property
    def edge_creases(self):
        return crease_of_sharpness(self.edge_sharpness).astype(np.float32)

    @property
    def vertex_creases(self):
        return crease_of_sharpness(self.vertex_sharpness).astype(np.float32)

    @property
    def expressible(self):
        """Blender's Subdivision Surface modifier can show the shape (any
        boundary setting: the tests choose it)."""
        return not self.inexpressible

    @property
    def has_creases(self):
        return bool(self.edge_sharpness.any() or self.vertex_sharpness.any())

    @property
    def face_sizes(self):
        return np.fromiter((len(f) for f in self.faces), dtype=np.int32, count=len(self.faces))

    @property
    def face_vertices(self):
        return np.fromiter((v for f in self.faces for v in f), dtype=np.int32, count=int(self.face_sizes.sum()))

    @property
    def all_triangles(self):
        return all(len(f) == 3 for f in self.faces)

    def creases_by_edge(self):
        """{frozenset((a, b)): Blender crease} for the creased edges."""
        creases = self.edge_creases
        return {frozenset(map(int, e)): float(c) for e, c in zip(self.edges, creases) if c > 0}

    @property
    def max_valence(self):
        """The most edges at one vertex (0 without edges)."""
        return int(np.bincount(self.edges.ravel(), minlength=1).max()) if len(self.edges) else 0

    @property
    def degenerate_face_count(self):
        return sum(1 for f in self.faces if len(set(f)) != len(f))

    def dissolved(self):
        """The shape with its faces that use a vertex twice as Blender's
        cleanup leaves them (dissolve_repeated_corners), named
        ``<name>_dissolved``; edges keep their sharpness by vertex pair."""
        faces = dissolve_repeated_corners(self.faces)
        edges, _ = _edges_of(faces)
        sharp = {frozenset(map(int, e)): s for e, s in zip(self.edges, self.edge_sharpness)}
        reasons = tuple(r for r in self.inexpressible if not r.endswith("faces that use a vertex twice"))
        return Shape(name=self.name + "_dissolved", scheme=self.scheme, positions=self.positions, faces=faces,
                     edges=np.asarray(edges, dtype=np.int32).reshape(-1, 2),
                     edge_sharpness=np.array([sharp.get(frozenset(e), 0.0) for e in edges]),
                     vertex_sharpness=self.vertex_sharpness.copy(), boundary=self.boundary,
                     inexpressible=reasons, tags=self.tags, uvs=self.uvs)

    def mesh_arrays(self, creases=True):
        """Keyword arguments for the native binding's Mesh (positions,
        face_sizes, face_vertices, edges, edge_creases, vertex_creases)."""
        arrays = dict(positions=self.positions, face_sizes=self.face_sizes, face_vertices=self.face_vertices)
        if creases:
            arrays.update(edges=self.edges, edge_creases=self.edge_creases, vertex_creases=self.vertex_creases)
        return arrays


def _edges_of(faces):
    """(edges [(a, b)] in the order first met, {frozenset((a, b)): index})."""
    edge_index, edges = {}, []
    for f in faces:
        for k in range(len(f)):
            key = frozenset((f[k], f[(k + 1) % len(f)]))
            if len(key) == 2 and key not in edge_index:
                edge_index[key] = len(edges)
                edges.append((f[k], f[(k + 1) % len(f)]))
    return edges, edge_index


def dissolve_repeated_corners(faces):
    """Each face without the corners that repeat the next one (a quad
    a b c c becomes the triangle a b c); faces left with fewer than three
    corners, or that still use a vertex twice, are dropped.  What the
    add-on's cleanup (addon/cleanup.py, step 2) does to such faces."""
    out = []
    for f in faces:
        kept = [v for k, v in enumerate(f) if v != f[(k + 1) % len(f)]]
        if len(kept) >= 3 and len(set(kept)) == len(kept):
            out.append(kept)
    return out


def _unescape(text):
    return re.sub(r"\\(.)", lambda m: _ESCAPES.get(m.group(1), m.group(1)), text)


def header_strings(text):
    """{name: OBJ text} of the std::string constants in a header."""
    out = {}
    for name, body in _DECLARATION.findall(re.sub(r"^\s*//.*$", "", text, flags=re.M)):
        out[name] = "".join(_unescape(s) for s in _LITERAL.findall(body))
    return out


def _numbers(words, count, kind):
    values = []
    for word in words[:count]:
        values.append(kind(word))
    if len(values) != count:
        raise ValueError("expected %d values" % count)
    return values


def parse_tag(line):
    """A `t` line as shape_utils.cpp's Shape::tag::parseTag reads it, or None
    where it gives up (a malformed tag is dropped there)."""
    words = line.split()[1:]
    if len(words) < 2:
        return None
    name, counts = words[0], words[1].split("/")
    try:
        nints, nfloats, nstrings = (int(c) for c in counts)
    except ValueError:
        return None
    rest = words[2:]
    try:
        ints = _numbers(rest, nints, int)
        floats = _numbers(rest[nints:], nfloats, float)
    except ValueError:
        return None
    strings = rest[nints + nfloats:nints + nfloats + nstrings]
    if len(strings) != nstrings:
        return None
    return Tag(name, ints, floats, strings)


def parse_obj(name, text, scheme=None, left_handed=None):
    """A Shape from OpenSubdiv's OBJ text (Shape::parseObj and far_utils.h)."""
    if scheme is None:
        scheme = SCHEMES.get(name.split("_")[0], "CATMULL_CLARK")
    if left_handed is None:
        left_handed = name in LEFT_HANDED
    verts, faces, tags, uvs = [], [], [], 0
    for raw in text.split("\n"):
        line = raw.strip("\r")
        if line.startswith("v "):
            parts = line.split()
            if len(parts) >= 4:
                verts.append([float(x) for x in parts[1:4]])
        elif line.startswith("vt "):
            uvs += 1
        elif line.startswith("f "):
            corners = [int(w.split("/")[0]) - 1 for w in line.split()[1:]]
            if left_handed:
                corners = corners[:1] + corners[1:][::-1]
            faces.append(corners)
        elif line.startswith("t "):
            tag = parse_tag(line)
            if tag is not None:
                tags.append(tag)
    positions = np.asarray(verts, dtype=np.float32).reshape(-1, 3)
    n = len(positions)
    for f in faces:
        if any(v < 0 or v >= n for v in f):
            raise ValueError("%s: a face uses a vertex outside 1..%d" % (name, n))

    edges, edge_index = _edges_of(faces)
    edge_sharpness = np.zeros(len(edges))
    vertex_sharpness = np.zeros(n)
    boundary = "EDGE_ONLY"
    inexpressible = []
    if scheme == "BILINEAR":
        inexpressible.append("the bilinear scheme")
    degenerate = sum(1 for f in faces if len(set(f)) != len(f))
    if degenerate:
        # OpenSubdiv takes them as degenerate polygons; a Blender mesh cannot
        # hold them (Shape.dissolved: the faces as Blender's cleanup leaves them).
        inexpressible.append("%d faces that use a vertex twice" % degenerate)
    for tag in tags:
        nfloat = len(tag.floats)
        if tag.name == "crease":
            for j in range(0, len(tag.ints) - 1, 2):
                key = frozenset(tag.ints[j:j + 2])
                if key not in edge_index:
                    raise ValueError("%s: no edge (%d, %d) for a crease tag" % (name, tag.ints[j], tag.ints[j + 1]))
                edge_sharpness[edge_index[key]] = max(0.0, tag.floats[j] if nfloat > 1 else tag.floats[0])
        elif tag.name == "corner":
            for j, v in enumerate(tag.ints):
                if not 0 <= v < n:
                    raise ValueError("%s: no vertex %d for a corner tag" % (name, v))
                vertex_sharpness[v] = max(0.0, tag.floats[j] if nfloat > 1 else tag.floats[0])
        elif tag.name == "interpolateboundary" and len(tag.ints) == 1:
            boundary = {0: "NONE", 1: "EDGE_AND_CORNER", 2: "EDGE_ONLY"}.get(tag.ints[0], boundary)
        elif tag.name == "hole":
            inexpressible.append("holes")
        elif tag.name == "creasemethod" and tag.strings[:1] == ["chaikin"]:
            inexpressible.append("Chaikin creases")
        elif tag.name == "smoothtriangles" and tag.strings[:1] == ["smooth"]:
            inexpressible.append("smooth triangles")
        elif tag.name in ("vertexedit", "edgeedit", "faceedit"):
            inexpressible.append("hierarchical edits (%s)" % tag.name)
    return Shape(name=name, scheme=scheme, positions=positions, faces=faces,
                 edges=np.asarray(edges, dtype=np.int32).reshape(-1, 2), edge_sharpness=edge_sharpness,
                 vertex_sharpness=vertex_sharpness, boundary=boundary,
                 inexpressible=tuple(dict.fromkeys(inexpressible)), tags=tags, uvs=uvs)


def names(folder=None):
    """The shapes' names (one per header but all.h), sorted."""
    folder = folder or shapes_dir()
    return sorted(f[:-2] for f in os.listdir(folder) if f.endswith(".h") and f != "all.h")


def load(name, folder=None):
    folder = folder or shapes_dir()
    with open(os.path.join(folder, name + ".h"), encoding="utf-8") as f:
        strings = header_strings(f.read())
    if name not in strings:
        raise ValueError("%s.h defines no string %s" % (name, name))
    return parse_obj(name, strings[name])


def load_all(folder=None, scheme=None, expressible=None):
    """Every shape (of `scheme`; only those Blender can or cannot express)."""
    out = []
    for name in names(folder):
        shape = load(name, folder)
        if scheme is not None and shape.scheme != scheme:
            continue
        if expressible is not None and shape.expressible != expressible:
            continue
        out.append(shape)
    return out


def load_testable(folder=None, scheme=None):
    """The shapes Blender's modifier can express (any boundary setting), and
    the dissolved variants (Shape.dissolved) of those whose only obstacle
    was faces that use a vertex twice, sorted by name."""
    out = []
    for shape in load_all(folder, scheme=scheme):
        if shape.expressible:
            out.append(shape)
        elif shape.degenerate_face_count:
            variant = shape.dissolved()
            if variant.expressible and variant.faces:
                out.append(variant)
    return sorted(out, key=lambda s: s.name)


def main():
    if not available():
        print(missing_message())
        return 1
    for shape in load_all():
        creased = int((shape.edge_sharpness > 0).sum())
        corners = int((shape.vertex_sharpness > 0).sum())
        print("%-28s %-13s %5d vertices %5d faces %3d creased edges %3d corners %-15s %s" % (
            shape.name, shape.scheme, shape.vertex_count, len(shape.faces), creased, corners, shape.boundary,
            ", ".join(shape.inexpressible)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
