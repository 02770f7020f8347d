# SPDX-License-Identifier: GPL-3.0-or-later
"""The scan's boundary marking and its build on large or awkward meshes,
against plain numpy."""
import numpy as np
import pytest


def grid(n, holes=0, seed=0):
    """An n x n grid of quads cut into triangles in a wavy sheet, with
    `holes` random triangles left out."""
    x, y = np.meshgrid(np.arange(n + 1, dtype=np.float64), np.arange(n + 1, dtype=np.float64))
    pos = np.stack([x.ravel(), y.ravel(), 0.3 * np.sin(x.ravel()) * np.cos(0.7 * y.ravel())], 1)
    v = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    a, b, c, d = v[:-1, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, 1:].ravel(), v[1:, :-1].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    if holes:
        rng = np.random.default_rng(seed)
        tris = np.delete(tris, rng.choice(len(tris), holes, replace=False), axis=0)
    return pos, tris


def boundary_vertices(tris, vertex_count):
    """Vertices on an edge that one triangle only uses (numpy)."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e.sort(axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    out = np.zeros(vertex_count, bool)
    out[edges[counts == 1].ravel()] = True
    return out


def flagged_vertices(native, pos, tris):
    """The library's boundary flag at each vertex a triangle uses (the query
    point on the vertex: its closest point is that corner exactly)."""
    scan = native.Scan(native.Mesh(np.asarray(pos, np.float32), np.full(len(tris), 3, np.int32),
                                   np.ascontiguousarray(tris, np.int32).ravel()))
    used = np.unique(tris)
    _, _, d, _, rim = scan.closest_points(np.asarray(pos, np.float32)[used], with_boundary=True)
    assert np.all(d == 0)
    return used, rim


@pytest.mark.parametrize("holes", [0, 1, 37, 400])
def test_boundary_marking_matches_numpy(native, holes):
    pos, tris = grid(40, holes, seed=holes)
    used, rim = flagged_vertices(native, pos, tris)
    assert rim.tolist() == boundary_vertices(tris, len(pos))[used].tolist()


def test_boundary_marking_with_hubs_duplicates_and_non_manifold_edges(native):
    """A fan of 300 triangles round vertex 0 (its bucket is sorted, not
    searched pairwise), an open fan round the last vertex, a triangle given
    twice (its edges are used twice: not boundary) and three triangles on
    one edge."""
    rng = np.random.default_rng(3)
    k = 300
    angle = np.linspace(0, 2 * np.pi, k, endpoint=False)
    ring = np.stack([np.cos(angle), np.sin(angle), 0.1 * rng.standard_normal(k)], 1)
    pos = [np.zeros((1, 3)), ring]
    tris = [np.stack([np.zeros(k, int), 1 + np.arange(k), 1 + (np.arange(k) + 1) % k], 1)]
    base = 1 + k
    extra = np.array([[3.0, 0, 0], [4, 0, 0], [3.5, 1, 0], [3.5, -1, 0], [3.5, 0, 1], [3.2, 0.4, 0.5]])
    pos.append(extra)
    tris.append(np.array([[0, 1, 2], [0, 1, 2], [0, 1, 3], [0, 1, 4], [0, 4, 5]]) + base)
    hub = base + len(extra)
    fan_k = 120
    fan_angle = np.linspace(0, 1.5 * np.pi, fan_k + 1)
    pos.append(np.array([[0.0, 5, 0]]))
    pos.append(np.stack([np.cos(fan_angle), 5 + np.sin(fan_angle), np.zeros(fan_k + 1)], 1))
    tris.append(np.stack([np.full(fan_k, hub), hub + 1 + np.arange(fan_k), hub + 2 + np.arange(fan_k)], 1))
    pos = np.concatenate(pos)
    tris = np.concatenate(tris)
    # the triangles shuffled: buckets fill in another order
    order = rng.permutation(len(tris))
    used, rim = flagged_vertices(native, pos, tris[order])
    want = boundary_vertices(tris, len(pos))[used]
    assert want[hub] and not want[0]
    assert rim.tolist() == want.tolist()


def test_boundary_marking_is_independent_of_face_order(native):
    pos, tris = grid(30, 200, seed=5)
    used, rim = flagged_vertices(native, pos, tris)
    rng = np.random.default_rng(1)
    shuffled = tris[rng.permutation(len(tris))][:, [1, 2, 0]]
    used2, rim2 = flagged_vertices(native, pos, shuffled)
    assert used.tolist() == used2.tolist() and rim.tolist() == rim2.tolist()


def test_renumbered_vertices_give_the_same_closest_points(native):
    """The scan renumbers its vertices internally: the closest points,
    normals and faces are those of a brute-force search over the triangles
    (distances in double), vertices no face uses included."""
    pos, tris = grid(20, 50, seed=2)
    pos = np.concatenate([pos, [[100.0, 100, 100]]])  # used by no face
    scan = native.Scan(native.Mesh(pos.astype(np.float32), np.full(len(tris), 3, np.int32),
                                   tris.astype(np.int32).ravel()))
    rng = np.random.default_rng(4)
    q = np.concatenate([rng.uniform(-2, 22, (300, 2)), rng.uniform(-1, 1, (300, 1))], 1).astype(np.float32)
    closest, normals, d, faces = scan.closest_points(q)
    p32 = pos.astype(np.float32).astype(np.float64)
    a, b, c = p32[tris[:, 0]], p32[tris[:, 1]], p32[tris[:, 2]]
    for i in range(0, len(q), 7):
        best = brute_force_distance(q[i].astype(np.float64), a, b, c)
        assert abs(d[i] - best.min()) <= 1e-5 * (1 + best.min())
        assert abs(best[faces[i]] - best.min()) <= 1e-6 * (1 + best.min())
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)


def test_closest_points_do_not_depend_on_the_order_of_the_points(native):
    """Each search starts from the triangle nearest the point before it: the
    same points in order (each seeded by its neighbour) and shuffled (seeded
    by points anywhere) give the same closest points, normals, distances
    and faces to the bit, and the faces are a brute-force search's."""
    pos, tris = grid(60, 40, seed=5)
    scan = native.Scan(native.Mesh(pos.astype(np.float32), np.full(len(tris), 3, np.int32),
                                   tris.astype(np.int32).ravel()))
    rng = np.random.default_rng(6)
    t = np.linspace(0.0, 1.0, 20000)
    q = np.c_[2 + 55 * t, 30 + 8 * np.sin(40 * t), 0.5 * np.cos(25 * t)].astype(np.float32)
    shuffle = rng.permutation(len(q))
    ordered = scan.closest_points(q)
    shuffled = scan.closest_points(q[shuffle])
    for mine, theirs in zip(ordered, shuffled):
        assert np.array_equal(np.asarray(mine)[shuffle].view(np.uint32), np.asarray(theirs).view(np.uint32))
    p32 = pos.astype(np.float32).astype(np.float64)
    a, b, c = p32[tris[:, 0]], p32[tris[:, 1]], p32[tris[:, 2]]
    for i in range(0, len(q), 997):
        best = brute_force_distance(q[i].astype(np.float64), a, b, c)
        assert abs(ordered[2][i] - best.min()) <= 1e-5 * (1 + best.min())


def numpy_vertex_normals(pos, tris):
    """Area-weighted vertex normals in double from the float32 positions
    (NaN where no triangle is)."""
    p = pos.astype(np.float32).astype(np.float64)
    cross = np.cross(p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]])
    acc = np.zeros_like(p)
    for k in range(3):
        np.add.at(acc, tris[:, k], cross)
    with np.errstate(invalid="ignore", divide="ignore"):
        return acc / np.linalg.norm(acc, axis=1, keepdims=True)


def test_vertex_normals_match_numpy(native):
    """At a scan vertex the closest point's normal is the vertex's
    area-weighted normal: the triangles' cross products summed (numpy, in
    double) and made unit; on a scan of quads and triangles large enough
    (about 400k faces) for the fans and normals to be made in pieces on
    several threads."""
    pos, tris = grid(450)
    cells = len(tris) // 2  # triangles (a, b, c) of every cell, then (a, c, d)
    half = cells // 2       # the first half of the cells as quads (a, b, c, d): the same fans
    quads = np.concatenate([tris[:half], tris[cells:cells + half, 2:]], 1)
    rest = np.concatenate([tris[half:cells], tris[cells + half:]])
    sizes = np.r_[np.full(half, 4), np.full(len(rest), 3)].astype(np.int32)
    scan = native.Scan(native.Mesh(pos.astype(np.float32), sizes, np.r_[quads.ravel(), rest.ravel()].astype(np.int32)))
    want = numpy_vertex_normals(pos, tris)
    pick = np.arange(0, len(pos), 37)
    _, normals, d, _ = scan.closest_points(pos[pick].astype(np.float32))
    assert d.max() == 0.0
    assert np.abs(normals - want[pick]).max() < 1e-6


def test_many_loose_vertices(native):
    """A scan with 30 times more vertices than triangles (points no face
    uses, as a point cloud merged into a scan leaves them): the build's
    steps then need more memory than its hierarchy worked in and take
    fresh memory instead.  Boundary, vertex normals and closest points are
    those of numpy all the same."""
    pos, tris = grid(12, 20, seed=7)
    rng = np.random.default_rng(8)
    loose = rng.uniform(-50, 50, (30 * len(tris), 3))
    pos = np.concatenate([loose[: len(loose) // 2], pos, loose[len(loose) // 2:]])
    tris = tris + len(loose) // 2
    used, rim = flagged_vertices(native, pos, tris)
    assert rim.tolist() == boundary_vertices(tris, len(pos))[used].tolist()
    scan = native.Scan(native.Mesh(pos.astype(np.float32), np.full(len(tris), 3, np.int32),
                                   tris.astype(np.int32).ravel()))
    _, normals, d, _ = scan.closest_points(pos[used].astype(np.float32))
    assert d.max() == 0.0
    assert np.abs(normals - numpy_vertex_normals(pos, tris)[used]).max() < 1e-6
    p = pos.astype(np.float32).astype(np.float64)
    q = (pos[used][rng.integers(0, len(used), 200)] + rng.normal(0, 0.5, (200, 3))).astype(np.float32)
    _, _, d, faces = scan.closest_points(q)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    for i in range(len(q)):
        best = brute_force_distance(q[i].astype(np.float64), a, b, c)
        assert abs(d[i] - best.min()) <= 1e-5 * (1 + best.min())
        assert abs(best[faces[i]] - best.min()) <= 1e-6 * (1 + best.min())


def brute_force_distance(p, a, b, c):
    """Distances from p to every triangle (a, b, c: (T, 3)), by dense
    sampling-free projection: the least of the plane distance (inside) and
    the three edge distances."""
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("ij,ij->i", p - a, n)
    proj = p - h[:, None] * n

    def inside(u, v, w):
        return np.einsum("ij,ij->i", np.cross(v - u, proj - u), n) >= -1e-12
    face = inside(a, b, c) & inside(b, c, a) & inside(c, a, b)

    def seg(u, v):
        t = np.clip(np.einsum("ij,ij->i", p - u, v - u) / np.einsum("ij,ij->i", v - u, v - u), 0, 1)
        return np.linalg.norm(u + t[:, None] * (v - u) - p, axis=1)
    edges = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
    return np.where(face, np.minimum(np.abs(h), edges), edges)


def big_scan_mesh(native, n=700):
    """About a million triangles: a build of a fraction of a second to a second."""
    pos, tris = grid(n)
    return native.Mesh(pos.astype(np.float32), np.full(len(tris), 3, np.int32), tris.astype(np.int32).ravel())


def test_scan_progress_reports_every_phase_and_ends_at_one(native):
    mesh = big_scan_mesh(native)
    calls = []
    scan = native.Scan(mesh, progress=lambda phase, fraction: calls.append((phase, fraction)) and False)
    assert calls and calls[-1] == (4, 1.0)
    phases = [c[0] for c in calls]
    fractions = [c[1] for c in calls]
    assert phases == sorted(phases) and fractions == sorted(fractions)
    assert all(0.0 <= f <= 1.0 for f in fractions)
    plain = native.Scan(mesh)
    q = mesh.positions[::997] + np.float32(0.25)
    assert all(np.array_equal(a, b) for a, b in zip(scan.closest_points(q), plain.closest_points(q)))


@pytest.mark.parametrize("when", ["first", "hierarchy", "boundary", "end"])
def test_scan_build_cancels_promptly(native, when):
    import time
    mesh = big_scan_mesh(native, 1000)
    stopped = []

    def progress(phase, fraction):
        if ((when == "first") or (when == "hierarchy" and phase == 3) or (when == "boundary" and phase == 4)
                or (when == "end" and fraction == 1.0)):
            stopped.append(time.perf_counter())
            return True
        return False
    with pytest.raises(native.PiaError) as error:
        native.Scan(mesh, progress=progress)
    assert error.value.code == 'CANCELLED'
    assert stopped, "no call in that phase"
    assert time.perf_counter() - stopped[0] < 0.5


def test_scan_progress_exception_cancels(native):
    def progress(phase, fraction):
        raise RuntimeError("stop")
    with pytest.raises(native.PiaError) as error:
        native.Scan(big_scan_mesh(native, 300), progress=progress)
    assert error.value.code == 'CANCELLED'


def test_closest_points_progress_and_cancel(native):
    import time
    scan = native.Scan(big_scan_mesh(native, 300))
    rng = np.random.default_rng(0)
    q = np.concatenate([rng.uniform(0, 300, (400000, 2)), rng.uniform(-3, 3, (400000, 1))], 1).astype(np.float32)
    calls = []
    got = scan.closest_points(q[:20000], progress=lambda phase, f: calls.append((phase, f)) and False)
    assert calls[-1] == (1, 1.0)
    plain = scan.closest_points(q[:20000])
    assert all(np.array_equal(a, b) for a, b in zip(got, plain))
    stopped = []

    def stop(phase, fraction):
        stopped.append(time.perf_counter())
        return True
    with pytest.raises(native.PiaError) as error:
        scan.closest_points(q, progress=stop)
    assert error.value.code == 'CANCELLED'
    assert time.perf_counter() - stopped[0] < 0.5


# --- the checks and the fans, over many pieces ------------------------------------------
# The build checks and cuts faces in pieces of 65,536 on threads: these
# meshes span several, and put their faults in late pieces.

def flat_quads(n):
    """An n x n grid of unit quads in the plane z = 0: positions, sizes, corners."""
    x, y = np.meshgrid(np.arange(n + 1, dtype=np.float32), np.arange(n + 1, dtype=np.float32))
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(x.size, np.float32)], 1)
    v = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    quads = np.stack([v[:-1, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, 1:].ravel(), v[1:, :-1].ravel()], 1)
    return pos, np.full(len(quads), 4, np.int32), quads.astype(np.int32)


def first_fault(pos, sizes, corners):
    """(code, index) of the first fault a loop over the mesh meets: a
    non-finite coordinate first, then faces in order (too few corners, or a
    corner out of range)."""
    bad = np.flatnonzero(~np.isfinite(pos).all(axis=1))
    if len(bad):
        return "NONFINITE", bad[0]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    for f, size in enumerate(sizes):
        if size < 3:
            return "FACE_SIZE", f
        c = corners[starts[f]:starts[f] + size]
        if ((c < 0) | (c >= len(pos))).any():
            return "INDEX_RANGE", f
    return None


def scan_of(native, pos, sizes, corners):
    return native.Scan(native.Mesh(np.asarray(pos, np.float32), np.asarray(sizes, np.int32),
                                   np.ascontiguousarray(corners, np.int32).ravel()))


@pytest.mark.parametrize("faults", [
    {"nan": [200_000, 70_000], "size": [3]},                 # two non-finite vertices, a bad face before
    {"index": [150_000], "size": [200_000]},                  # a corner out of range first
    {"size": [140_000], "index": [250_000]},                  # too few corners first
    {"index": [131_072]},                                     # the first face of a piece
    {"index": [262_143]},                                     # the last face of a piece
    {"size": [196_608, 196_609]},
])
def test_scan_reports_the_first_fault_in_order(native, faults):
    pos, sizes, quads = flat_quads(520)  # 270,400 faces: five pieces
    quads = quads.copy()
    for v in faults.get("nan", []):
        pos[v, 1] = np.nan
    for f in faults.get("index", []):
        quads[f, 2] = len(pos) + f
    corners = [q[:2] if f in faults.get("size", []) else q for f, q in enumerate(quads)]
    sizes = np.array([len(c) for c in corners], np.int32)
    corners = np.concatenate(corners)
    code, index = first_fault(pos, sizes, corners)
    with pytest.raises(native.PiaError) as error:
        scan_of(native, pos, sizes, corners)
    assert (error.value.code, error.value.index) == (code, index)
    assert str(index) in str(error.value)


def test_scan_fans_and_skipped_faces_over_many_pieces(native):
    """Quads, pentagons and faces repeating a vertex (left out) spread over
    five pieces: a point just above each kept face's first fan triangle is
    closest to that face, and no left-out face is ever returned."""
    pos, sizes, quads = flat_quads(520)
    rng = np.random.default_rng(5)
    skipped = rng.choice(len(quads), 3000, replace=False)
    faces = [list(q) for q in quads]
    for f in skipped:
        faces[f] = [faces[f][0], faces[f][1], faces[f][1], faces[f][2]]
    # pentagons: a quad with its last edge's midpoint added, as a new vertex
    pentagons = rng.choice(np.setdiff1d(np.arange(len(quads)), skipped), 2000, replace=False)
    extra = []
    for f in pentagons:
        extra.append(0.5 * (pos[faces[f][3]] + pos[faces[f][0]]))
        faces[f] = faces[f] + [len(pos) + len(extra) - 1]
    pos = np.concatenate([pos, np.array(extra, np.float32)])
    sizes = np.array([len(f) for f in faces], np.int32)
    scan = scan_of(native, pos, sizes, np.concatenate(faces))
    kept = np.setdiff1d(np.arange(len(faces)), skipped)
    first_triangle = np.array([[pos[faces[f][0]], pos[faces[f][1]], pos[faces[f][2]]] for f in kept])
    query = first_triangle.mean(axis=1) + np.float32([0, 0, 0.25])
    _, _, distances, found = scan.closest_points(query.astype(np.float32))
    np.testing.assert_allclose(distances, 0.25, rtol=1e-5)
    assert np.array_equal(found, kept)
    everywhere = rng.uniform([0, 0, -1], [520, 520, 1], (200_000, 3)).astype(np.float32)
    assert not np.isin(scan.closest_points(everywhere)[3], skipped).any()
