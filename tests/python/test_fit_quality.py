# SPDX-License-Identifier: GPL-3.0-or-later
"""What a fit is worth to an artist: no folds, distances both ways, no pull
from stray scan parts.  Checked against numpy geometry: the unit sphere,
normals from differences on a grid of surface samples and the scan's own
triangle normals, and distances to a clean copy of a scan."""
import os

import numpy as np
import pytest

from meshio import read_obj
from test_fit import quad_sphere, uv_sphere

DATA = os.path.join(os.path.dirname(__file__), "..", "data")


def _obj_mesh(native, name):
    pos, faces, _ = read_obj(os.path.join(DATA, name))
    sizes = np.array([len(f) for f in faces], np.int32)
    return native.Mesh(pos, sizes, np.concatenate(faces).astype(np.int32))


@pytest.fixture(scope="module")
def bunny(native):
    scan = _obj_mesh(native, "bun_zipper.obj")
    cage = _obj_mesh(native, "bun_zipper_quadriflow_cage.obj")
    return scan, cage


def test_scan_distances_on_the_sphere(native):
    """Scan vertices on the unit sphere, a disk 0.25 above it that the
    surface does not reach, and a vertex no face uses: after the fit the
    sphere's vertices are on the surface, the disk's are as far as numpy
    says and counted as not reached, the loose vertex is not measured."""
    pos, tris = uv_sphere(400, 200)
    k = 48
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    disk = np.vstack([[0, 0, 1.25], np.c_[0.3 * np.cos(ang), 0.3 * np.sin(ang), np.full(k, 1.25)]])
    disk_tris = np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)]) + len(pos)
    loose = np.array([[5.0, 5.0, 5.0]])
    allpos = np.vstack([pos, disk, loose]).astype(np.float32)
    scan = native.Scan(native.Mesh.from_faces(allpos, np.vstack([tris, disk_tris])))
    diag = scan.diagonal
    cp, cf = quad_sphere(6)
    cage = native.Mesh.from_faces(cp, cf)
    out, rep = native.fit(cage, scan)
    n_sphere, n_disk = len(pos), len(disk)
    assert rep.scan_point_count == n_sphere + n_disk
    assert rep.scan_after.ignored == n_disk
    d = rep.scan_distances
    assert d.shape == (len(allpos),) and d[-1] == -1.0
    assert d[:n_sphere].max() * diag < 1e-3   # the level-3 grid's flat quads sag ~4e-4 below the sphere
    expected = np.linalg.norm(disk, axis=1) - 1.0          # the surface is the unit sphere
    assert np.abs(d[n_sphere:n_sphere + n_disk] * diag - expected).max() < 1e-3
    assert rep.scan_after.max == pytest.approx(d[:n_sphere].max(), rel=1e-5)

    # the cage given: its surface lies inside the sphere; each scan vertex's
    # distance is 1 minus the surface's radius in its direction, read off
    # dense samples of the surface
    X = native.surface_stencils(cage, 16).apply(cp).astype(np.float64)
    radius, direction = np.linalg.norm(X, axis=1), X / np.linalg.norm(X, axis=1)[:, None]
    u = pos / np.linalg.norm(pos, axis=1)[:, None]
    best = np.concatenate([np.argmax(c @ direction.T, axis=1) for c in np.array_split(u, 100)])
    radial = 1.0 - radius[best]
    assert rep.scan_before.ignored == n_disk
    assert rep.scan_before.mean * diag == pytest.approx(radial.mean(), rel=0.03)
    assert rep.scan_before.max * diag == pytest.approx(radial.max(), rel=0.05)


def _bumpy_open_cage(native):
    """A 4 x 4 grid of unit quads over a gentle bump, one quad split into
    two triangles and two merged into a hexagon: triangles, a hexagon and
    boundary corners of one face (the faces OpenSubdiv's patch table
    evaluates) besides plain quads."""
    xs = np.arange(5.0)
    P = np.array([[x, y, 0.15 * np.sin(0.7 * x) * np.cos(0.5 * y)] for y in xs for x in xs], np.float32)
    quad = lambda i, j: [5 * j + i, 5 * j + i + 1, 5 * (j + 1) + i + 1, 5 * (j + 1) + i]
    faces = [quad(i, j) for j in range(4) for i in range(4) if (i, j) not in ((1, 1), (2, 2), (3, 2))]
    a, b, c, d = quad(1, 1)
    faces += [[a, b, c], [a, c, d]]
    faces.append([5 * 2 + 2, 5 * 2 + 3, 5 * 2 + 4, 5 * 3 + 4, 5 * 3 + 3, 5 * 3 + 2])
    return native.Mesh.from_faces(P, faces)


def test_scan_distances_over_every_kind_of_face(native):
    """The scan-to-surface measure covers every face of the limit surface
    and measures it where it is: a scan made of the cage's own limit
    points (a 10 x 10 grid in each ptex face, triangulated), every other
    one moved off the surface by delta along the surface's normal (numpy,
    from differences on the grid).  The given cage's measure finds the
    points on the surface and the moved ones delta away, each
    within a tenth of delta, in quads, triangles, the hexagon and the
    corners."""
    cage = _bumpy_open_cage(native)
    k = 10
    X = native.surface_stencils(cage, k).apply(cage.positions).astype(np.float64)
    G = X.reshape(-1, k, k, 3)
    n = np.cross(np.gradient(G, axis=2), np.gradient(G, axis=1)).reshape(-1, 3)
    n /= np.linalg.norm(n, axis=1)[:, None]
    moved = (np.arange(len(X)) % 2).astype(bool)
    diag = np.linalg.norm(X.max(axis=0) - X.min(axis=0))
    delta = 0.005 * diag
    pts = X + delta * moved[:, None] * n
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1))
    v = (j * k + i).ravel()
    local = np.concatenate([np.c_[v, v + 1, v + k + 1], np.c_[v, v + k + 1, v + k]])
    tris = (np.arange(len(G))[:, None, None] * k * k + local[None]).reshape(-1, 3)
    scan = native.Scan(native.Mesh.from_faces(pts.astype(np.float32), tris))
    _, rep = native.fit(cage, scan, max_rounds=1)
    assert rep.scan_point_count == len(X) and rep.scan_before.ignored == 0
    # half the points at 0, half at delta: a face left out of the grid, or
    # misplaced, would put points a face's size away, or off delta
    unit = scan.diagonal
    assert rep.scan_before.max * unit == pytest.approx(delta, rel=0.1)
    assert rep.scan_before.p95 * unit == pytest.approx(delta, rel=0.1)
    assert rep.scan_before.mean * unit == pytest.approx(0.5 * delta, rel=0.1)


def _plane_grid(native, n, height):
    """An n x n quad grid over the unit square, z = height(x, y)."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n + 1), np.linspace(0.0, 1.0, n + 1))
    pos = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], axis=1).astype(np.float32)
    v = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    faces = np.stack([v, v + 1, v + n + 2, v + n + 1], axis=1).astype(np.int32)
    return native.Mesh(pos, np.full(n * n, 4, np.int32), faces.ravel())


def test_scan_distances_of_a_cage_of_half_a_million_faces(native):
    """A cage whose measuring grid has more than 2M quads (533k faces at 1
    sample per edge: a 3 x 3 grid of limit points each) is searched through
    its faces' corners and then within the face found.  Its scan distances
    are those of an exact search over the same grid: the cage subdivided
    once, whose vertices' limit points are that grid, as a scan."""
    cage = _plane_grid(native, 730, lambda x, y: 0.0 * x)
    scan_mesh = _plane_grid(native, 60, lambda x, y: 0.02 * np.sin(7.0 * x) * np.cos(5.0 * y))
    scan = native.Scan(scan_mesh)
    out, rep = native.fit(cage, scan, samples_per_edge=1, max_rounds=1, solver_iterations=2)
    fine = native.subdivide(native.Mesh(out, cage.face_sizes, cage.face_vertices), 1)
    grid = native.limit_stencils(fine).limit_points(fine.positions).astype(np.float32)
    exact = native.Scan(native.Mesh(grid, fine.face_sizes, fine.face_vertices))
    pts = scan_mesh.positions
    d = np.linalg.norm(exact.closest_points(pts)[0] - pts, axis=1) / scan.diagonal
    assert rep.scan_point_count == len(pts)
    # the fits' quads are split along the other diagonal here and there:
    # differences of a few thousandths of the largest distance
    assert np.abs(rep.scan_distances - d).max() < 0.01 * d.max()
    assert rep.scan_after.mean == pytest.approx(d.mean(), rel=1e-3)
    assert rep.scan_after.max == pytest.approx(d.max(), rel=1e-2)


def _folded_share(native, cage, V, scan_mesh, scan, k=8, cutoff=0.02):
    """Share of the samples within the cut-off (a k x k grid per ptex face)
    whose normal, from differences on the grid, faces away from the normal
    of the scan triangle holding the closest point; the orientation is the
    one most samples agree on."""
    X = native.surface_stencils(native.Mesh(V, cage.face_sizes, cage.face_vertices), k).apply(V)
    G = X.reshape(-1, k, k, 3).astype(np.float64)
    n = np.cross(np.gradient(G, axis=2), np.gradient(G, axis=1)).reshape(-1, 3)
    _, _, dist, faces = scan.closest_points(X)
    # the scan polygon's normal (the scan is triangles)
    fv = scan_mesh.face_vertices.reshape(-1, 3)
    P = scan_mesh.positions.astype(np.float64)
    fn = np.cross(P[fv[:, 1]] - P[fv[:, 0]], P[fv[:, 2]] - P[fv[:, 0]])[faces]
    kept = dist <= cutoff * scan.diagonal
    dots = np.einsum("ij,ij->i", n, fn)[kept]
    return float((np.sign(dots.sum()) * dots < 0).mean())


def _mean_off_rim(native, cage, V, scan, k=8, cutoff=0.02):
    """Mean distance (relative to the diagonal) of the surface's points (a
    k x k grid per ptex face) within the cut-off whose closest scan point is
    not on the scan's rim: the surface where there is scan under it, not
    over the scan's holes."""
    X = native.surface_stencils(native.Mesh(V, cage.face_sizes, cage.face_vertices), k).apply(V)
    _, _, dist, _, rim = scan.closest_points(X, with_boundary=True)
    kept = (dist <= cutoff * scan.diagonal) & ~rim
    return float(dist[kept].mean() / scan.diagonal)


def _guarded_and_free(native, scan_mesh, cage):
    """The fit with the fold guard and without it (nor the robust kernel):
    their reports, folded shares and means off the rims."""
    scan = native.Scan(scan_mesh)
    guarded, rep = native.fit(cage, scan)
    free, rep_free = native.fit(cage, scan, allow_folds=True, hard_cutoff=True)
    share, share_free = (_folded_share(native, cage, V, scan_mesh, scan) for V in (guarded, free))
    mean, mean_free = (_mean_off_rim(native, cage, V, scan) for V in (guarded, free))
    print("folded: guarded %.3f%%, without the guard %.3f%%; mean %.3g against %.3g, off the rims %.3g against %.3g"
          % (100 * share, 100 * share_free, rep.after.mean, rep_free.after.mean, mean, mean_free))
    return rep, rep_free, share, share_free, mean, mean_free


def test_fold_guard_on_the_bunny(native, bunny):
    rep, rep_free, share, share_free, mean, mean_free = _guarded_and_free(native, *bunny)
    assert share_free > 0.01                      # the plain fit folds ...
    assert share < min(0.001, share_free / 8)     # ... the guarded one on at most 0.1% of its points
    # for at most 10% more distance where the scan is (over its holes the
    # guarded surface reaches farther out, where the distances grow)
    assert mean < 1.1 * mean_free
    assert rep.after.mean < rep.before.mean / 8
    # the report's own count (4 x 4 samples, smooth scan normals) tells the same
    assert rep.folded_after / rep.sample_count < 0.001 < rep_free.folded_after / rep_free.sample_count


@pytest.mark.parametrize("scan_file,cage_file", [
    ("armadillo.obj", "armadillo_quadriflow_cage.obj"),
    ("ChineseDragon-10kv.obj", "ChineseDragon-10kv_quadriflow_cage.obj"),   # low-poly: flat facets
])
def test_fold_guard_on_other_scans(native, scan_file, cage_file):
    """Scans from outside the Stanford set, with QuadriFlow cages of about
    3,000 faces: the plain fit pleats the surface (on the low-poly target
    along its facets' edges, which a smooth surface cannot follow); the
    guard's barrier keeps the grid from turning over, so that at most 0.1%
    of the surface faces away, for at most 10% more distance."""
    rep, _, share, share_free, mean, mean_free = _guarded_and_free(
        native, _obj_mesh(native, scan_file), _obj_mesh(native, cage_file))
    assert share_free > 0.01
    assert share <= 0.001
    assert mean < 1.1 * mean_free
    assert rep.after.mean < rep.before.mean / 5


def test_an_open_cages_rims_do_not_curl(native):
    """The elephant's QuadriFlow cage has 1,218 boundary edges around the
    scan's holes.  Left free (SPIA_FIT_FREE_RIMS), its rims curl over onto
    the scan beyond them; held smoother, the surface faces away from the
    scan's triangles (numpy normals, as above) on a fraction of the points
    and turns over against the cage given (normals from differences on the
    level-3 grid) on fewer of the points where that cage faced the scan,
    for no more distance.  A closed cage has no rims: there the flag
    changes nothing."""
    scan_mesh = _obj_mesh(native, "elephant-with-holes.obj")
    cage = _obj_mesh(native, "elephant-with-holes_quadriflow_cage.obj")
    scan = native.Scan(scan_mesh)
    held, rep = native.fit(cage, scan)
    free, rep_free = native.fit(cage, scan, free_rims=True)
    share, share_free = (_folded_share(native, cage, V, scan_mesh, scan) for V in (held, free))
    k = 8
    stencils = native.surface_stencils(cage, k)

    def normals(V):
        G = stencils.apply(V).reshape(-1, k, k, 3).astype(np.float64)
        return np.cross(np.gradient(G, axis=2), np.gradient(G, axis=1)).reshape(-1, 3)
    X0 = stencils.apply(cage.positions)
    n0 = normals(cage.positions)
    fv = scan_mesh.face_vertices.reshape(-1, 3)
    P = scan_mesh.positions.astype(np.float64)
    tri_normals = np.cross(P[fv[:, 1]] - P[fv[:, 0]], P[fv[:, 2]] - P[fv[:, 0]])
    facing = np.einsum("ij,ij->i", n0, tri_normals[scan.closest_points(X0)[3]])
    facing *= np.sign(facing.sum())
    turned, turned_free = (float(((np.einsum("ij,ij->i", n0, normals(V)) < 0) & (facing > 0)).mean())
                           for V in (held, free))
    print("facing away %.3f%% (free %.3f%%), turned where the cage faced the scan %.3f%% (free %.3f%%), "
          "mean %.4g (free %.4g)" % (100 * share, 100 * share_free, 100 * turned, 100 * turned_free,
                                     rep.after.mean, rep_free.after.mean))
    assert share < share_free / 2
    assert turned < turned_free / 2
    assert rep.after.mean < 1.02 * rep_free.after.mean

    closed = _obj_mesh(native, "ChineseDragon-10kv_quadriflow_cage.obj")
    closed_scan = native.Scan(_obj_mesh(native, "ChineseDragon-10kv.obj"))
    assert np.array_equal(native.fit(closed, closed_scan)[0], native.fit(closed, closed_scan, free_rims=True)[0])


def test_stray_triangles_do_not_pull(native, bunny):
    """1% of the scan's triangles copied 0.1% to 0.4% of the diagonal off
    the scan along their normals (noise blobs, stray points): within the
    cut-off, so only the robust kernel keeps them from pulling.  Measured
    against the clean scan, the fit stays within 10% of the clean fit."""
    scan_mesh, cage = bunny
    clean = native.Scan(scan_mesh)
    P = scan_mesh.positions.astype(np.float64)
    tris = scan_mesh.face_vertices.reshape(-1, 3)
    rng = np.random.default_rng(7)
    pick = rng.choice(len(tris), len(tris) // 100, replace=False)
    t = P[tris[pick]]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    offset = rng.uniform(0.001, 0.004, len(pick)) * clean.diagonal * rng.choice([-1, 1], len(pick))
    stray = (t + (normal * offset[:, None])[:, None, :]).reshape(-1, 3)
    dirty = native.Scan(native.Mesh.from_faces(np.vstack([P, stray]).astype(np.float32),
                                               np.vstack([tris, len(P) + np.arange(len(stray)).reshape(-1, 3)])))
    M = native.surface_stencils(cage, 4)

    def against_clean(V):
        d = clean.closest_points(M.apply(V))[2] / clean.diagonal
        return d[d <= 0.02].mean()
    reference = against_clean(native.fit(cage, clean)[0])
    robust = against_clean(native.fit(cage, dirty)[0])
    print("mean distance to the clean scan: clean fit %.3g, on the dirty scan %.3g" % (reference, robust))
    assert robust < 1.1 * reference


def test_a_base_plate_does_not_pull(native, bunny):
    """The bunny on a turntable: a plate 0.5% of the diagonal below its
    lowest point, under its open bottom.  Samples over the bottom's holes
    find the plate within the cut-off.  A scanned turntable faces the
    scanner (up, away from the bunny's bottom, as a closed slab's top does
    too): those samples' normals disagree with it, so they weigh nothing,
    and the distances stay within 10% of the fit to the scan without the
    plate (measured against that scan, over the samples within the cut-off
    of it).  A plate facing down, as the bunny's bottom does, is the hard
    case: the normals agree, the robust kernel alone holds it to about a
    tenth more, and the hard cut-off lets it drag the bottom down."""
    scan_mesh, cage = bunny
    clean = native.Scan(scan_mesh)
    P = scan_mesh.positions.astype(np.float64)
    lo, hi = P.min(axis=0), P.max(axis=0)
    y = lo[1] - 0.005 * clean.diagonal                    # the bunny stands along +y
    g = np.linspace(0, 1, 41)
    gx, gz = np.meshgrid(lo[0] - 0.2 * (hi[0] - lo[0]) + 1.4 * (hi[0] - lo[0]) * g,
                         lo[2] - 0.2 * (hi[2] - lo[2]) + 1.4 * (hi[2] - lo[2]) * g, indexing="ij")
    plate = np.c_[gx.ravel(), np.full(gx.size, y), gz.ravel()]
    ij = np.arange(41 * 41).reshape(41, 41)
    a, b, c, d = ij[:-1, :-1].ravel(), ij[1:, :-1].ravel(), ij[1:, 1:].ravel(), ij[:-1, 1:].ravel()
    down = np.vstack([np.c_[a, b, c], np.c_[a, c, d]])    # (b - a) x (c - a) points along -y
    assert np.cross(plate[down[0, 1]] - plate[down[0, 0]], plate[down[0, 2]] - plate[down[0, 0]])[1] < 0
    under = plate - [0.0, 0.01 * clean.diagonal, 0.0]

    def with_plate(parts):
        verts, faces = [P], [scan_mesh.face_vertices.reshape(-1, 3)]
        for points, tris in parts:
            faces.append(tris + sum(len(v) for v in verts))
            verts.append(points)
        return native.Scan(native.Mesh.from_faces(np.vstack(verts).astype(np.float32), np.vstack(faces)))
    facing_down = with_plate([(plate, down)])
    facing_up = with_plate([(plate, down[:, ::-1])])
    slab = with_plate([(plate, down[:, ::-1]), (under, down)])  # a closed turntable's top and bottom
    assert facing_down.diagonal == pytest.approx(clean.diagonal, rel=0.3)
    M = native.surface_stencils(cage, 4)

    def lowest_and_mean(V):
        X = M.apply(V)
        d = clean.closest_points(X)[2] / clean.diagonal
        return X[:, 1].min(), d[d <= 0.02].mean()
    low_ref, reference = lowest_and_mean(native.fit(cage, clean)[0])
    low_up, up = lowest_and_mean(native.fit(cage, facing_up)[0])
    low_slab, on_slab = lowest_and_mean(native.fit(cage, slab)[0])
    low_robust, robust = lowest_and_mean(native.fit(cage, facing_down)[0])
    low_hard, hard = lowest_and_mean(native.fit(cage, facing_down, hard_cutoff=True)[0])
    print("lowest sample: %.4f clean, %.4f up, %.4f slab, %.4f down, %.4f hard (plate %.4f); "
          "mean %.3g, %.3g, %.3g, %.3g, %.3g" % (low_ref, low_up, low_slab, low_robust, low_hard, y,
                                               reference, up, on_slab, robust, hard))
    assert up < 1.10 * reference and on_slab < 1.10 * reference
    assert robust < 1.25 * reference
    assert hard > 1.5 * reference and hard > 1.4 * robust


def test_fit_quality_options_are_checked(native, bunny):
    scan_mesh, cage = bunny
    scan = native.Scan(scan_mesh)
    for kw in ({"robust_scale": 0}, {"robust_scale": float("nan")}, {"slide_weight": 1.0}, {"slide_weight": -0.1}):
        with pytest.raises(native.PiaError):
            native.fit(cage, scan, max_rounds=1, **kw)
    _, rep = native.fit(cage, scan, max_rounds=1, measure_scan=False)
    assert rep.scan_point_count == 0 and rep.scan_distances is None


def test_progress_within_rounds_and_cancel(native):
    """The dragon's cage (9.5k vertices, 8 samples per edge: 600k samples,
    a 100k-vertex scan), on one thread: before the first round ends the
    callback has been called already (with round 0: closest points are
    queried in chunks between which it is called every 0.2 s), and a
    cancel there stops the fit.  Without the scan-to-surface measure the
    first call comes within round 1 (or, on a slow machine, while the
    sample stencils are built); with it, it may come while the scan's
    distances are measured first.  With 4 samples per edge on every thread
    a fast machine ended round 1 in under 0.2 s, before any tick was due;
    this size takes about 1 s to end it on the 2-core test machine."""
    scan = native.Scan(_obj_mesh(native, "dragon_res2.obj"))
    cage = _obj_mesh(native, "dragon_res2_quadriflow_cage.obj")
    stencils = "cancelled computing the sample stencils"
    for measure_scan, phases in ((False, ("cancelled during fitting round 1", stencils)),
                                 (True, ("cancelled during fitting round 1", stencils,
                                         "cancelled measuring the scan's distances to the surface"))):
        calls = []

        def progress(round_, mean):
            calls.append(round_)
            return True
        with pytest.raises(native.PiaCancelled) as e:
            native.fit(cage, scan, progress=progress, measure_scan=measure_scan, samples_per_edge=8, threads=1)
        assert calls == [0]
        assert any(p in str(e.value) for p in phases), str(e.value)
