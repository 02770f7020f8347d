# SPDX-License-Identifier: GPL-3.0-or-later
"""The hard set: messy meshes for bench/bench_hard.py.

Every mesh is a `HardMesh` (points (N, 3) float32, face_sizes and
face_vertices int32, all its edges, and the edge creases its crease variant
carries).  Each generator states what is special about its mesh as
`expect` (a feature and a bound) and `build()` measures the features with
`features()` and refuses to return a mesh that lacks them: a "valence 400"
mesh really has a vertex of valence 400, a "non-manifold edges" mesh really
has edges with three or more faces.

Features (`features()`): valence (edges at a vertex), face sizes, faces per
edge (boundary 1, manifold 2, non-manifold 3 or more), edges that both of
their two faces run the same way (misoriented), fans (the faces at a vertex
split into groups joined across edges with exactly two faces: a vertex with
several fans is non-manifold, as two cones touching at their apex), darts
(a vertex inside a manifold sheet with exactly one incident edge of crease
1.0), and how far apart the two ends of an edge are in the vertex order
(about a third of the vertex count when the order is random).

    /usr/bin/python3 bench/hard_meshes.py [NAME...]   # build and print the features

Debian's STL files come through tools/debian_meshes.py (downloaded with
apt-get at the first use).
"""
import os
import sys
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "tools"))

CREASE_FRACTION = 0.3
CREASE_SEED = 20240601


# --------------------------------------------------------------------------
# Topology
# --------------------------------------------------------------------------

def corner_tables(sizes, fv):
    """For every corner: the next corner of its face, the edge from it to the
    next corner (an index into the sorted unique edges) and that edge's
    direction (True when the corner's vertex is the edge's smaller one)."""
    sizes = np.asarray(sizes, np.int64)
    fv = np.asarray(fv, np.int64)
    start = np.repeat(np.cumsum(sizes) - sizes, sizes)
    nxt = start + (np.arange(len(fv)) - start + 1) % np.repeat(sizes, sizes)
    a, b = fv, fv[nxt]
    pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], 1)
    edges, corner_edge = np.unique(pairs, axis=0, return_inverse=True)
    return nxt, corner_edge.ravel(), a < b, edges


def mesh_edges(sizes, fv):
    """The edges of the faces, (E, 2) int32, each once, smaller vertex first."""
    return corner_tables(sizes, fv)[3].astype(np.int32)


def features(n, sizes, fv, edges=None, creases=None):
    """A dict of what the mesh has (see the module's docstring)."""
    sizes = np.asarray(sizes, np.int64)
    fv = np.asarray(fv, np.int64)
    nxt, ce, forward, face_edges = corner_tables(sizes, fv)
    corners = len(fv)
    faces_per_edge = np.bincount(ce, minlength=len(face_edges))
    valence = np.bincount(face_edges.ravel(), minlength=n)
    # Misoriented: an edge with two faces that both run it the same way.
    runs_forward = np.bincount(ce, weights=forward, minlength=len(face_edges))
    misoriented = int(((faces_per_edge == 2) & (runs_forward != 1)).sum())
    # Fans: join the two corners at v of the faces on each side of a
    # two-face edge at v, then count the groups of v's corners.
    prev = np.empty(corners, np.int64)
    prev[nxt] = np.arange(corners)
    rec_edge = np.concatenate([ce, ce[prev]])
    rec_corner = np.concatenate([np.arange(corners), np.arange(corners)])
    keep = faces_per_edge[rec_edge] == 2
    rec_edge, rec_corner = rec_edge[keep], rec_corner[keep]
    rec_vertex = fv[rec_corner]
    order = np.lexsort((rec_corner, rec_vertex, rec_edge))
    rec_edge, rec_corner, rec_vertex = rec_edge[order], rec_corner[order], rec_vertex[order]
    pair = (rec_edge[:-1] == rec_edge[1:]) & (rec_vertex[:-1] == rec_vertex[1:])
    graph = scipy.sparse.coo_matrix((np.ones(int(pair.sum())), (rec_corner[:-1][pair], rec_corner[1:][pair])),
                                    shape=(corners, corners))
    _, group = scipy.sparse.csgraph.connected_components(graph, directed=False)
    fans = np.bincount(np.unique(np.stack([fv, group], 1), axis=0)[:, 0], minlength=n)
    # Darts: inside a manifold sheet (every edge at the vertex has two faces,
    # one fan) and exactly one incident edge of crease 1.
    darts = 0
    creased_edges = 0
    if edges is not None and creases is not None:
        edges = np.asarray(edges, np.int64)
        creases = np.asarray(creases, np.float64)
        creased_edges = int((creases > 0).sum())
        sharp = edges[creases >= 1.0]
        sharp_count = np.bincount(sharp.ravel(), minlength=n)
        open_edge = face_edges[faces_per_edge != 2]
        touches_open = np.zeros(n, bool)
        touches_open[open_edge.ravel()] = True
        darts = int(((sharp_count == 1) & (fans == 1) & ~touches_open).sum())
    spread = float(np.abs(face_edges[:, 0] - face_edges[:, 1]).mean() / n) if len(face_edges) else 0.0
    return dict(
        vertices=int(n), faces=int(len(sizes)), edges=int(len(face_edges)),
        max_valence=int(valence.max()), high_valence_vertices=int((valence >= 50).sum()),
        min_face_size=int(sizes.min()), max_face_size=int(sizes.max()), ngons_20=int((sizes >= 20).sum()),
        triangles=int((sizes == 3).sum()), quads=int((sizes == 4).sum()),
        boundary_edges=int((faces_per_edge == 1).sum()),
        nonmanifold_edges=int((faces_per_edge > 2).sum()), max_faces_per_edge=int(faces_per_edge.max()),
        misoriented_edges=misoriented,
        multi_fan_vertices=int((fans > 1).sum()), max_fans=int(fans.max()),
        creased_edges=creased_edges, darts=darts, index_spread=round(spread, 3))


def describe(f):
    """The features in a few words, for the tables."""
    parts = [f"valence <= {f['max_valence']}"]
    if f["high_valence_vertices"]:
        parts[-1] += f" ({f['high_valence_vertices']} vertices >= 50)"
    sides = (f"{f['min_face_size']}" if f["min_face_size"] == f["max_face_size"]
             else f"{f['min_face_size']}-{f['max_face_size']}")
    parts.append(f"faces of {sides} sides" + (f" ({f['ngons_20']} of 20+)" if f["ngons_20"] else ""))
    if f["nonmanifold_edges"]:
        parts.append(f"{f['nonmanifold_edges']} non-manifold edges (up to {f['max_faces_per_edge']} faces)")
    if f["multi_fan_vertices"]:
        parts.append(f"{f['multi_fan_vertices']} vertices with several fans (up to {f['max_fans']})")
    if f["boundary_edges"]:
        parts.append(f"{f['boundary_edges']} boundary edges")
    if f["misoriented_edges"]:
        parts.append(f"{f['misoriented_edges']} misoriented edges")
    if f["darts"]:
        parts.append(f"{f['darts']} darts")
    if f["index_spread"] > 0.25:
        parts.append("vertex order random")
    return "; ".join(parts)


# --------------------------------------------------------------------------
# The meshes
# --------------------------------------------------------------------------

@dataclass
class HardMesh:
    name: str
    category: str
    what: str                     # what the mesh is, in words
    points: np.ndarray
    face_sizes: np.ndarray
    face_vertices: np.ndarray
    expect: dict = field(default_factory=dict)   # feature -> (">=" | "==" | "<=", value)
    own_creases: np.ndarray = None               # creases per edge the mesh carries itself (darts)
    provenance: str = ""
    edges: np.ndarray = None
    creases: np.ndarray = None                   # what the crease variant uses
    crease_note: str = ""
    features: dict = None

    def finish(self):
        self.points = np.ascontiguousarray(self.points, np.float32)
        self.face_sizes = np.ascontiguousarray(self.face_sizes, np.int32)
        self.face_vertices = np.ascontiguousarray(self.face_vertices, np.int32)
        if self.edges is None:
            self.edges = mesh_edges(self.face_sizes, self.face_vertices)
        if self.own_creases is not None:
            self.creases = np.asarray(self.own_creases, np.float32)
            self.crease_note = "its own creases"
        else:
            self.creases = random_creases(len(self.edges), seed=CREASE_SEED)
            self.crease_note = f"random creases on {CREASE_FRACTION:.0%} of the edges"
        self.features = features(len(self.points), self.face_sizes, self.face_vertices, self.edges,
                                 self.own_creases)
        verify(self.name, self.features, self.expect)
        return self


def verify(name, measured, expect):
    for key, (op, value) in expect.items():
        got = measured[key]
        ok = {">=": got >= value, "==": got == value, "<=": got <= value}[op]
        assert ok, f"{name}: {key} is {got}, expected {op} {value}"


def random_creases(edge_count, fraction=CREASE_FRACTION, seed=CREASE_SEED):
    """Creases in (0, 1) on `fraction` of the edges (chosen at random), 0 elsewhere."""
    rng = np.random.default_rng(seed)
    creases = np.zeros(edge_count, np.float32)
    chosen = rng.choice(edge_count, int(round(fraction * edge_count)), replace=False)
    creases[chosen] = rng.uniform(0.02, 0.98, len(chosen))
    return creases


class Parts:
    """Collects faces of several parts; `mesh()` merges vertices that are at
    the same place (after rounding to 1e-9) into one."""

    def __init__(self):
        self.points, self.faces = [], []
        self.count = 0

    def add(self, points, faces):
        """faces: a list of index sequences, or an (F, k) array, into `points`."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        self.faces += [np.asarray(f, np.int64) + self.count for f in faces]
        self.points.append(points)
        self.count += len(points)
        return self

    def mesh(self):
        """(points, face_sizes, face_vertices); vertices numbered in the order
        the faces first use them (generated meshes keep their locality)."""
        P = np.concatenate(self.points)
        keys = np.round(P * 1e9).astype(np.int64)
        _, first, welded = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        fv = welded.ravel()[np.concatenate(self.faces)]
        used, first_use = np.unique(fv, return_index=True)
        used = used[np.argsort(first_use)]
        number = np.full(len(first), -1, np.int64)
        number[used] = np.arange(len(used))
        sizes = np.fromiter((len(f) for f in self.faces), np.int32, len(self.faces))
        return P[first[used]], sizes, number[fv].astype(np.int32)


def grid_faces(nu, nv):
    """Quads of an nu x nv grid of cells over (nu + 1) x (nv + 1) points,
    point (i, j) at index i * (nv + 1) + j, turned counter-clockwise in (u, v)."""
    cols = nv + 1
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * cols + j
    b = a + cols
    return np.stack([a, b, b + 1, a + 1], -1).reshape(-1, 4)


def grid_points(nu, nv, f):
    u, v = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    return np.stack(f(u, v), -1).reshape(-1, 3)


# 1. High-valence fans -----------------------------------------------------

def cone_in_grid(valence, n=120):
    """A square n x n quad grid with a square window of valence / 4 cells a
    side cut out and closed by a cone: a triangle fan from the raised apex
    to the window's rim, the apex's valence `valence`."""
    k = valence // 4
    assert 4 * k == valence and k + 4 <= n
    lo = (n - k) // 2
    hi = lo + k
    parts = Parts()
    P = np.stack(np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij"), -1).reshape(-1, 2)
    P = np.column_stack([P, 0.05 * np.sin(P[:, 0] * 0.3) * np.cos(P[:, 1] * 0.2)])
    quads = grid_faces(n, n)
    i, j = quads[:, 0] // (n + 1), quads[:, 0] % (n + 1)
    outside = ~((i >= lo) & (i < hi) & (j >= lo) & (j < hi))
    rim = ([(lo + t, lo) for t in range(k)] + [(hi, lo + t) for t in range(k)]
           + [(hi - t, hi) for t in range(k)] + [(lo, hi - t) for t in range(k)])  # counter-clockwise
    rim = [a * (n + 1) + b for a, b in rim]
    apex = len(P)
    P = np.vstack([P, [(lo + hi) / 2.0, (lo + hi) / 2.0, k * 0.6]])
    fan = [(rim[t], rim[(t + 1) % len(rim)], apex) for t in range(len(rim))]
    parts.add(P, list(quads[outside]) + fan)
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"cone-in-grid-{valence}", "high-valence fan",
                    f"{n}x{n} quad grid, a {k}x{k} window closed by a cone: triangle fan of valence {valence}",
                    pts, sizes, fv, expect=dict(max_valence=("==", valence), nonmanifold_edges=("==", 0),
                                                multi_fan_vertices=("==", 0), misoriented_edges=("==", 0)))


def uv_sphere(segments=400, rings=16):
    """A UV sphere: quads, and a triangle fan of valence `segments` at each pole."""
    parts = Parts()
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2 * np.pi * np.arange(segments) / segments
    T, F = np.meshgrid(theta, phi, indexing="ij")
    P = np.stack([np.sin(T) * np.cos(F), np.sin(T) * np.sin(F), np.cos(T)], -1).reshape(-1, 3)
    P = np.vstack([P, [0, 0, 1], [0, 0, -1]])
    north, south = len(P) - 2, len(P) - 1
    faces = []
    for r in range(rings - 2):
        a = r * segments + np.arange(segments)
        b = r * segments + (np.arange(segments) + 1) % segments
        faces += list(np.stack([a, a + segments, b + segments, b], 1))
    s = np.arange(segments)
    faces += [(north, s[t], s[(t + 1) % segments]) for t in range(segments)]
    last = (rings - 2) * segments
    faces += [(south, last + (t + 1) % segments, last + t) for t in range(segments)]
    parts.add(P, faces)
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"uv-sphere-{segments}", "high-valence fan",
                    f"closed UV sphere, {segments} segments: a triangle fan of valence {segments} at each pole",
                    pts, sizes, fv, expect=dict(max_valence=("==", segments), boundary_edges=("==", 0),
                                                nonmanifold_edges=("==", 0), misoriented_edges=("==", 0)))


def quad_fan_disk(valence=200, rings=15):
    """A disk whose centre has `valence` quads around it (quad fan), polar
    quad rings of 2 x valence segments outside, a gentle dome."""
    parts = Parts()
    m = 2 * valence
    ang = 2 * np.pi * np.arange(m) / m
    P = [np.zeros((1, 3))]
    inner = np.stack([np.cos(ang), np.sin(ang), np.zeros(m)], 1)
    inner[1::2, :2] *= 1.4  # the fan's outer corners stand out
    P.append(inner)
    for r in range(1, rings + 1):
        rad = 1.4 + r
        P.append(np.stack([rad * np.cos(ang), rad * np.sin(ang), np.zeros(m)], 1))
    P = np.vstack(P)
    P[:, 2] = 3.0 * np.exp(-(P[:, 0] ** 2 + P[:, 1] ** 2) / 200)
    ring = lambda r: 1 + r * m + np.arange(m)  # noqa: E731  ring 0 = the fan's rim
    faces = [(0, ring(0)[2 * t], ring(0)[2 * t + 1], ring(0)[(2 * t + 2) % m]) for t in range(valence)]
    for r in range(rings):
        a, b = ring(r), ring(r + 1)
        faces += list(np.stack([a, b, np.roll(b, -1), np.roll(a, -1)], 1))
    parts.add(P, faces)
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"quad-fan-disk-{valence}", "high-valence fan",
                    f"disk, a quad fan of valence {valence} at the centre, polar quad rings outside",
                    pts, sizes, fv, expect=dict(max_valence=("==", valence), quads=("==", len(sizes)),
                                                nonmanifold_edges=("==", 0), misoriented_edges=("==", 0)))


# 2. Vertices with several fans ---------------------------------------------

def bowtie_sheets(sheets=4, cells=20):
    """`sheets` quad sheets, each a square with one corner at the origin in
    its own tilted plane, sharing nothing else: one vertex with `sheets`
    fans (two sheets would be a bow-tie)."""
    parts = Parts()
    half = np.pi / sheets * 0.6
    for s in range(sheets):
        phi = 2 * np.pi * s / sheets
        lift = 0.2 * (s + 1)
        e1 = np.array([np.cos(phi - half), np.sin(phi - half), lift])
        e2 = np.array([np.cos(phi + half), np.sin(phi + half), lift])
        parts.add(grid_points(cells, cells, lambda u, v, e1=e1, e2=e2: tuple(
            u * e1[i] + v * e2[i] + (0.05 * np.sin(6 * u) * np.sin(6 * v) if i == 2 else 0) for i in range(3))),
            list(grid_faces(cells, cells)))
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"bowtie-sheets-{sheets}", "several fans",
                    f"{sheets} quad sheets ({cells}x{cells}) touching at one corner vertex",
                    pts, sizes, fv, expect=dict(multi_fan_vertices=("==", 1), max_fans=("==", sheets),
                                                nonmanifold_edges=("==", 0), misoriented_edges=("==", 0)))


def cones_star(cones=6, segments=24, rings=12):
    """Closed cones (quad rings, a triangle fan at the apex, a 24-gon base)
    along the six axis directions, all apexes at the origin: one vertex with
    six fans."""
    parts = Parts()
    axes = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)], float)[:cones]
    for axis in axes:
        helper = np.array([0, 0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0, 0])
        u = np.cross(axis, helper)
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        ang = 2 * np.pi * np.arange(segments) / segments
        P = [np.zeros((1, 3))]
        for r in range(1, rings + 1):
            t = r / rings
            P.append(t * axis + 0.35 * t * (np.outer(np.cos(ang), u) + np.outer(np.sin(ang), v)))
        P = np.vstack(P)
        ring = lambda r: 1 + (r - 1) * segments + np.arange(segments)  # noqa: E731
        faces = [(0, ring(1)[(t + 1) % segments], ring(1)[t]) for t in range(segments)]
        for r in range(1, rings):
            a, b = ring(r), ring(r + 1)
            faces += list(np.stack([a, np.roll(a, -1), np.roll(b, -1), b], 1))
        faces.append(ring(rings))
        parts.add(P, faces)
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"cones-star-{cones}", "several fans",
                    f"{cones} closed cones ({segments}-gon bases) touching at their apexes",
                    pts, sizes, fv, expect=dict(multi_fan_vertices=("==", 1), max_fans=("==", cones),
                                                boundary_edges=("==", 0), nonmanifold_edges=("==", 0),
                                                misoriented_edges=("==", 0)))


def checkerboard(cells=16, sub=5):
    """The black squares of a cells x cells checkerboard, each a sub x sub
    quad patch on a wavy surface: every inner corner of the board is a
    bow-tie vertex (two fans)."""
    parts = Parts()
    for ci in range(cells):
        for cj in range(cells):
            if (ci + cj) % 2:
                continue
            parts.add(grid_points(sub, sub, lambda u, v: (ci + u, cj + v,
                                                          0.3 * np.sin((ci + u) * 0.7) * np.cos((cj + v) * 0.5))),
                      list(grid_faces(sub, sub)))
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"checkerboard-{cells}", "several fans",
                    f"black squares of a {cells}x{cells} checkerboard ({sub}x{sub} quads each): "
                    "bow-ties at every inner corner",
                    pts, sizes, fv, expect=dict(multi_fan_vertices=("==", (cells - 1) ** 2), max_fans=("==", 2),
                                                nonmanifold_edges=("==", 0)))


# 3. Non-manifold edges -----------------------------------------------------

def box_grid(k, size=(1.0, 1.0, 1.0)):
    """(points, quads) of a box with k x k quads per side, outward: the cube
    lattice of bench/meshes.py's quad sphere, before it is pushed out."""
    from meshes import quad_sphere
    p, quads = quad_sphere(k)
    lattice = np.rint((p / np.abs(p).max(1)[:, None] + 1) * k / 2).astype(np.float64)
    return (lattice * 2.0 / k - 1) * np.asarray(size) / 2, quads


def box_fins(k=24, height=10):
    """A box (k x k quads a side) with fins of k x height quads: one each on
    two lines of the top, three on a third line (upright and leaning both
    ways: five faces on those edges) and one hanging from an edge of the box."""
    parts = Parts()
    P, quads = box_grid(k, (2.0, 2.0, 2.0))
    parts.add(P, list(quads))
    h = height / k

    def fin(y, tilt):
        return grid_points(k, height, lambda u, v: (-1 + 2 * u, y + np.sin(tilt) * h * v, 1 + np.cos(tilt) * h * v))

    for j, tilt in ((k // 4, 0.0), (k // 2, 0.0), (3 * k // 4, 0.0), (3 * k // 4, 0.6), (3 * k // 4, -0.6)):
        parts.add(fin(-1 + 2 * j / k, tilt), list(grid_faces(k, height)))
    # hanging from the box's edge at y = -1, z = 1, out and up
    parts.add(grid_points(k, height, lambda u, v: (-1 + 2 * u, -1 - 0.7 * h * v, 1 + 0.7 * h * v)),
              list(grid_faces(k, height)))
    pts, sizes, fv = parts.mesh()
    return HardMesh("box-fins", "non-manifold edges",
                    f"box of {k}x{k} quads a side with six fins: on lines of the top (one line carrying three) "
                    "and on an edge of the box",
                    pts, sizes, fv, expect=dict(nonmanifold_edges=("==", 4 * k), max_faces_per_edge=("==", 5)))


def book_pages(pages=5, along=30, across=20):
    """`pages` quad sheets sharing one spine (a line of `along` edges), opened
    like the pages of a book: every spine edge has `pages` faces."""
    parts = Parts()
    for p in range(pages):
        a = np.pi * (0.15 + 0.7 * p / (pages - 1))
        parts.add(grid_points(along, across, lambda u, v, a=a: (
            3 * u, 2 * v * np.cos(a), 2 * v * np.sin(a) + 0.2 * np.sin(4 * u) * v)), list(grid_faces(along, across)))
    pts, sizes, fv = parts.mesh()
    return HardMesh(f"book-pages-{pages}", "non-manifold edges",
                    f"{pages} quad sheets ({along}x{across}) sharing a spine of {along} edges",
                    pts, sizes, fv, expect=dict(nonmanifold_edges=("==", along), max_faces_per_edge=("==", pages)))


# 4. Large n-gons ------------------------------------------------------------

def cylinders(segment_counts=(24, 64, 128), rings=20):
    """Closed cylinders side by side, each capped with two n-gons of its
    segment count (24, 64, 128 sides)."""
    parts = Parts()
    for c, m in enumerate(segment_counts):
        ang = 2 * np.pi * np.arange(m) / m
        P = np.vstack([np.stack([3 * c + np.cos(ang), np.sin(ang), np.full(m, 2.0 * r / rings)], 1)
                       for r in range(rings + 1)])
        faces = []
        for r in range(rings):
            a = r * m + np.arange(m)
            faces += list(np.stack([a, np.roll(a, -1), np.roll(a, -1) + m, a + m], 1))
        faces.append(np.arange(m)[::-1])
        faces.append(rings * m + np.arange(m))
        parts.add(P, faces)
    pts, sizes, fv = parts.mesh()
    return HardMesh("cylinders-ngon-caps", "n-gons",
                    f"closed cylinders of {', '.join(map(str, segment_counts))} segments, n-gon caps",
                    pts, sizes, fv, expect=dict(max_face_size=("==", max(segment_counts)),
                                                ngons_20=("==", 2 * len(segment_counts)),
                                                boundary_edges=("==", 0), misoriented_edges=("==", 0)))


def grid_ngon_holes(n=100, windows=(5, 10, 20, 30)):
    """An n x n quad grid with square windows of 5, 10, 20 and 30 cells a side
    cut out and each filled with one n-gon (20, 40, 80 and 120 sides)."""
    P = np.stack(np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij"), -1).reshape(-1, 2)
    P = np.column_stack([P, 2.0 * np.sin(P[:, 0] / 15) * np.sin(P[:, 1] / 20)])
    quads = grid_faces(n, n)
    i, j = quads[:, 0] // (n + 1), quads[:, 0] % (n + 1)
    keep = np.ones(len(quads), bool)
    ngons = []
    corners = [(8, 8), (8, 60), (55, 10), (55, 55)]
    for (lo_i, lo_j), k in zip(corners, windows):
        hi_i, hi_j = lo_i + k, lo_j + k
        keep &= ~((i >= lo_i) & (i < hi_i) & (j >= lo_j) & (j < hi_j))
        rim = ([(lo_i + t, lo_j) for t in range(k)] + [(hi_i, lo_j + t) for t in range(k)]
               + [(hi_i - t, hi_j) for t in range(k)] + [(lo_i, hi_j - t) for t in range(k)])
        ngons.append(np.array([a * (n + 1) + b for a, b in rim]))
    parts = Parts().add(P, list(quads[keep]) + ngons)
    pts, sizes, fv = parts.mesh()
    return HardMesh("grid-ngon-holes", "n-gons",
                    f"{n}x{n} quad grid, square holes filled by n-gons of "
                    f"{', '.join(str(4 * k) for k in windows)} sides",
                    pts, sizes, fv, expect=dict(max_face_size=("==", 4 * max(windows)), ngons_20=("==", len(windows)),
                                                nonmanifold_edges=("==", 0), misoriented_edges=("==", 0)))


# 5. Darts -------------------------------------------------------------------

def dart_sphere(k=40):
    """A quad sphere with three chains of fully sharp edges (crease 1) on
    one side of the cube, each ending inside the surface at both ends: six
    darts."""
    from meshes import quad_sphere
    P, quads = quad_sphere(k)
    sizes = np.full(len(quads), 4, np.int32)
    fv = quads.ravel().astype(np.int32)
    lattice = np.rint((P / np.abs(P).max(1)[:, None] + 1) * k / 2).astype(np.int64)
    index = {tuple(c): v for v, c in enumerate(lattice)}
    chains = []
    # on the side z = k: a straight chain, an L-shaped one and a short one
    chains.append([(x, k // 2, k) for x in range(8, 30)])
    chains.append([(10, y, k) for y in range(26, 36)] + [(x, 35, k) for x in range(11, 20)])
    chains.append([(25, y, k) for y in range(6, 12)])
    edges = mesh_edges(sizes, fv)
    lookup = {(int(a), int(b)): e for e, (a, b) in enumerate(edges)}
    creases = np.zeros(len(edges), np.float32)
    for chain in chains:
        for c0, c1 in zip(chain, chain[1:]):
            a, b = index[c0], index[c1]
            creases[lookup[(min(a, b), max(a, b))]] = 1.0
    return HardMesh(f"dart-sphere-{k}", "darts",
                    f"quad sphere (k={k}) with three crease-1 edge chains ending inside the surface",
                    P, sizes, fv, edges=edges, own_creases=creases,
                    expect=dict(darts=("==", 6), boundary_edges=("==", 0), nonmanifold_edges=("==", 0)))


# 6. Semi-sharp creases on a regular mesh and on a scan -----------------------

def regular_sphere(k=41):
    from meshes import quad_sphere
    P, quads = quad_sphere(k)
    return HardMesh(f"quad-sphere-{k}", "semi-sharp creases",
                    f"quad sphere (k={k}), regular but for eight valence-3 vertices (the baseline); "
                    f"creases: {CREASE_FRACTION:.0%} semi-sharp",
                    P, np.full(len(quads), 4, np.int32), quads.ravel(),
                    expect=dict(max_valence=("==", 4), boundary_edges=("==", 0), nonmanifold_edges=("==", 0)))


def scan_mesh(name, shuffle=False, seed=7):
    """A scan of tests/data (faces repeating a vertex dropped, as bench/meshes.py does)."""
    from meshes import scan
    P, sizes, fv = scan(name)
    what = f"scan tests/data/{name}.obj"
    expect = {}
    if shuffle:
        P, sizes, fv = shuffled(P, sizes, fv, seed)
        what += ", vertices and faces in random order"
        expect["index_spread"] = (">=", 0.25)
        return HardMesh(f"{name}-shuffled", "shuffled", what, P, sizes, fv, expect=expect,
                        provenance=f"tests/data/{name}.obj")
    return HardMesh(name, "semi-sharp creases", what + f"; creases: {CREASE_FRACTION:.0%} semi-sharp", P, sizes, fv,
                    expect=expect, provenance=f"tests/data/{name}.obj")


# 7. Shuffled vertex order -----------------------------------------------------

def shuffled(P, sizes, fv, seed=7):
    """The same mesh with its vertices renumbered at random, its faces in
    random order and each face starting at a random corner (orientation kept)."""
    rng = np.random.default_rng(seed)
    n = len(P)
    perm = rng.permutation(n)          # new index of old vertex i
    P2 = np.empty_like(P)
    P2[perm] = P
    sizes = np.asarray(sizes, np.int64)
    starts = np.cumsum(sizes) - sizes
    order = rng.permutation(len(sizes))
    shift = rng.integers(0, sizes[order])
    new_sizes = sizes[order]
    new_starts = np.cumsum(new_sizes) - new_sizes
    local = np.arange(new_sizes.sum()) - np.repeat(new_starts, new_sizes)
    src = np.repeat(starts[order], new_sizes) + (local + np.repeat(shift, new_sizes)) % np.repeat(new_sizes, new_sizes)
    fv2 = perm[np.asarray(fv, np.int64)[src]]
    return P2, new_sizes.astype(np.int32), fv2.astype(np.int32)


def surface_net_blob(n=64, seed=3):
    """A smooth blob, the zero set of a sum of Gaussian bumps meshed as a
    naive surface net (one vertex per grid cell the surface crosses, a quad
    per crossed grid edge), then shuffled."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-0.45, 0.45, (7, 3))
    radii = rng.uniform(0.18, 0.3, 7)
    t = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(t, t, t, indexing="ij")
    field = -0.5 + sum(np.exp(-((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) / r ** 2)
                       for c, r in zip(centres, radii))
    inside = field > 0
    # crossing points on the grid edges of each axis
    cell_sum = np.zeros((n - 1,) * 3 + (3,))
    cell_count = np.zeros((n - 1,) * 3)
    grid = np.stack([X, Y, Z], -1)
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        f0, f1 = field[tuple(lo)], field[tuple(hi)]
        cross = (f0 > 0) != (f1 > 0)
        w = np.where(cross, f0 / np.where(cross, f0 - f1, 1.0), 0.0)
        point = grid[tuple(lo)] + w[..., None] * (grid[tuple(hi)] - grid[tuple(lo)])
        # every cell containing this edge gets the point
        others = [a for a in range(3) if a != axis]
        for d0 in (0, 1):
            for d1 in (0, 1):
                sl = [slice(None)] * 3
                sl[others[0]] = slice(d0, d0 + n - 1)
                sl[others[1]] = slice(d1, d1 + n - 1)
                sl = tuple(sl)
                cell_sum += np.where(cross[sl][..., None], point[sl], 0.0)
                cell_count += cross[sl]
    active = cell_count > 0
    cell_index = -np.ones(active.shape, np.int64)
    cell_index[active] = np.arange(int(active.sum()))
    P = cell_sum[active] / cell_count[active][:, None]
    quads = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        f0 = inside[tuple(lo)]
        cross = f0 != inside[tuple(hi)]
        idx = np.argwhere(cross)
        idx = idx[np.all(idx[:, others] >= 1, 1) & np.all(idx[:, others] <= n - 2, 1)]
        rings = []
        for d0, d1 in ((0, 0), (1, 0), (1, 1), (0, 1)):
            c = idx.copy()
            c[:, others[0]] -= 1 - d0
            c[:, others[1]] -= 1 - d1
            rings.append(cell_index[c[:, 0], c[:, 1], c[:, 2]])
        q = np.stack(rings, 1)
        # counter-clockwise about the axis for axes 0 and 2, clockwise for 1;
        # turned so that every quad faces out of the blob
        flip = ~f0[tuple(idx.T)]
        if axis == 1:
            flip = ~flip
        q[flip] = q[flip][:, ::-1]
        quads.append(q)
    quads = np.concatenate(quads)
    assert (quads >= 0).all()
    P, sizes, fv = shuffled(P, np.full(len(quads), 4, np.int32), quads.ravel(), seed)
    return HardMesh("blob-shuffled", "shuffled",
                    f"smooth blob: surface net of seven Gaussian bumps on a {n}^3 grid, "
                    "vertices and faces in random order",
                    P, sizes, fv, expect=dict(index_spread=(">=", 0.25), quads=("==", len(sizes)),
                                              boundary_edges=("==", 0), nonmanifold_edges=("==", 0),
                                              multi_fan_vertices=("==", 0), misoriented_edges=("==", 0)))


# 8. STL files from Debian packages --------------------------------------------

# What each of tools/debian_meshes.py's files is chosen for, checked as for
# the generated meshes (a new package version that lost it fails loudly).
DEBIAN_EXPECT = {
    "lulzbot_taz_pro_bed": dict(max_valence=(">=", 300), multi_fan_vertices=(">=", 10), nonmanifold_edges=(">=", 10)),
    "zav_maxpro": dict(max_valence=(">=", 200), multi_fan_vertices=(">=", 1000)),
    "trimaker_nebula_platform": dict(nonmanifold_edges=(">=", 300)),
    "UltimakerRobot_support": dict(vertices=(">=", 90000)),
    "M3x10_screw": dict(boundary_edges=("==", 0), nonmanifold_edges=("==", 0)),
    "TriLAB_dq2_bed": dict(boundary_edges=("==", 0), nonmanifold_edges=("==", 0)),
}


def debian_stl(name):
    import debian_meshes
    P, tris, info = debian_meshes.fetch(name)
    provenance = f"Debian package {info['package']} {info['version']}: {info['path']}"
    if info["dropped"]:
        provenance += f" ({info['dropped']} triangles with a repeated vertex after welding dropped)"
    return HardMesh(name, "Debian STL", debian_meshes.MESHES[name][2], P, np.full(len(tris), 3, np.int32),
                    tris.ravel(), expect=DEBIAN_EXPECT.get(name, {}), provenance=provenance)


# --------------------------------------------------------------------------

def _catalogue():
    import debian_meshes
    cat = {}

    def put(name, make):
        cat[name] = make
    for v in (100, 200, 400):
        put(f"cone-in-grid-{v}", lambda v=v: cone_in_grid(v))
    put("uv-sphere-400", lambda: uv_sphere(400))
    put("quad-fan-disk-200", lambda: quad_fan_disk(200))
    put("bowtie-sheets-4", lambda: bowtie_sheets(4))
    put("cones-star-6", lambda: cones_star(6))
    put("checkerboard-16", lambda: checkerboard(16))
    put("box-fins", box_fins)
    put("book-pages-5", lambda: book_pages(5))
    put("cylinders-ngon-caps", cylinders)
    put("grid-ngon-holes", grid_ngon_holes)
    put("dart-sphere-40", lambda: dart_sphere(40))
    put("quad-sphere-41", lambda: regular_sphere(41))
    put("bun_zipper", lambda: scan_mesh("bun_zipper"))
    put("blob-shuffled", surface_net_blob)
    for s in ("bunny", "dragon_res2", "elephant-with-holes"):
        put(f"{s}-shuffled", lambda s=s: scan_mesh(s, shuffle=True))
    for name in debian_meshes.MESHES:
        put(name, lambda name=name: debian_stl(name))
    return cat


CATALOGUE = _catalogue()


def build(name):
    """The named mesh, its features measured and its claims checked."""
    mesh = CATALOGUE[name]()
    mesh.name = name
    return mesh.finish()


def main(argv):
    for name in argv[1:] or CATALOGUE:
        m = build(name)
        print(f"{name}: {m.what}\n    {describe(m.features)}\n    {m.features}")
        if m.provenance:
            print("    " + m.provenance)


if __name__ == "__main__":
    main(sys.argv)
