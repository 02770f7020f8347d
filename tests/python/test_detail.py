# SPDX-License-Identifier: GPL-3.0-or-later
"""The cage subdivided (subdivide) and detail levels fitted to a scan
(fit_detail), checked with numpy: limit points from the stencils' CSR
arrays, distances to an analytic sphere and brute-force distances to a
scan's triangles."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ADDON_DIR
from spheres import cube_sphere, icosphere


def _mesh(native, positions, faces, **kwargs):
    return native.Mesh.from_faces(np.asarray(positions, np.float32), [list(f) for f in faces], **kwargs)


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_subdivided_cage_has_the_cages_limit_surface(native, levels):
    positions, quads = cube_sphere(3)
    positions = positions * np.array([1.0, 0.7, 1.3])
    cage = _mesh(native, positions, quads)
    fine = native.subdivide(cage, levels)
    assert (fine.face_sizes == 4).all() and len(fine.face_sizes) == len(quads) * 4 ** levels
    assert len(fine.positions) == 6 * (3 * 2 ** levels) ** 2 + 2  # a closed genus-0 quad mesh: V = F + 2
    # numpy's products over the CSR arrays (Stencils.apply), for both meshes.
    ours = native.limit_stencils(cage).apply(cage.positions)
    theirs = native.limit_stencils(fine).apply(fine.positions)[: len(positions)]
    assert np.abs(theirs - ours).max() < 1e-6
    # Every face is a quad of distinct vertices, and the edges are the faces' edges.
    corners = fine.face_vertices.reshape(-1, 4)
    assert all(len(set(q)) == 4 for q in corners)
    face_edges = {tuple(sorted((q[i], q[(i + 1) % 4]))) for q in corners for i in range(4)}
    assert face_edges == {tuple(sorted(e)) for e in fine.edges}
    assert not fine.edge_creases.any() and not fine.vertex_creases.any()


def test_subdivided_creases_are_one_step_softer(native):
    positions, quads = cube_sphere(2)
    ring = [(quads[0][i], quads[0][(i + 1) % 4]) for i in range(4)]
    cage = _mesh(native, positions, quads, edges=np.array(ring, np.int32),
                 edge_creases=np.array([1.0, 0.5, 0.5, 0.5], np.float32))
    fine = native.subdivide(cage, 1)
    sharpness = 10.0 * fine.edge_creases.astype(np.float64) ** 2
    # Each creased edge's two halves: sharpness 10 stays 10 (infinite); 2.5 becomes 1.5.
    values = np.sort(sharpness[sharpness > 0])
    assert len(values) == 8
    assert np.allclose(values[:6], 1.5, atol=1e-5) and np.allclose(values[6:], 10.0)


def test_subdivide_refuses(native):
    positions, quads = cube_sphere(1)
    cage = _mesh(native, positions, quads)
    for levels in (0, 7):
        with pytest.raises(native.PiaError, match="levels must be 1 to 6"):
            native.subdivide(cage, levels)
    with pytest.raises(native.PiaCancelled):
        native.subdivide(cage, 2, progress=lambda level, share: True)


def test_detail_levels_lie_on_the_sphere(native):
    scan_positions, triangles = icosphere(5)
    scan = native.Scan(_mesh(native, scan_positions, triangles))
    positions, quads = cube_sphere(2, radius=0.85)
    cage = _mesh(native, positions, quads)
    fitted, report = native.fit(cage, scan, cutoff=0.3)
    base = native.Mesh(fitted, cage.face_sizes, cage.face_vertices)
    calls = []
    detail = native.fit_detail(base, scan, 2, cutoff=0.3, progress=lambda *a: calls.append(a) and False)
    assert detail.levels == 2 and len(detail.reports) == 2
    assert len(detail.points) == len(detail.mesh.positions) == 6 * 8 * 8 + 2
    assert {c[0] for c in calls} == {1, 2}
    # The finest level's flat quads straddle the sphere: vertices outside it,
    # face centres inside, within the quads' own sagitta (and the scan's).
    quads = detail.mesh.face_vertices.reshape(-1, 4)
    points = detail.points.astype(np.float64)
    edge = np.linalg.norm(points[quads[:, 0]] - points[quads[:, 1]], axis=1).max()
    sagitta = 1.0 - np.cos(np.arcsin(edge / 2.0))
    scan_edge = np.linalg.norm(scan_positions[triangles[:, 0]] - scan_positions[triangles[:, 1]], axis=1).max()
    slack = 1.0 - np.cos(np.arcsin(scan_edge / 2.0))
    radius = np.linalg.norm(points, axis=1)
    centres = np.linalg.norm(points[quads].mean(axis=1), axis=1)
    assert (radius > 1.0 - slack).all() and (radius < 1.0 + 1.5 * sagitta).all()
    assert (centres < 1.0 + slack).all() and (centres > 1.0 - sagitta).all()
    # Closer than the flat quads through the limit points, at vertices,
    # edge midpoints and centres alike.
    limit = native.limit_stencils(detail.mesh).apply(detail.mesh.positions)

    def flat_error(p):
        mids = 0.5 * (p[quads] + p[np.roll(quads, -1, axis=1)]).reshape(-1, 3)
        samples = np.concatenate([p, mids, p[quads].mean(axis=1)])
        return np.abs(np.linalg.norm(samples, axis=1) - 1.0).mean()
    assert flat_error(points) < 0.6 * flat_error(limit)
    assert detail.report.after.mean < 2.0 * slack
    with pytest.raises(native.PiaCancelled):
        native.fit_detail(base, scan, 2, cutoff=0.3, progress=lambda level, it, value: level == 2)
    with pytest.raises(native.PiaError, match="levels must be 1 to 6"):
        native.fit_detail(base, scan, 0)


def test_detail_stages_go_through_the_package(native, monkeypatch):
    # A script that wraps spia.subdivide, spia.fit and spia.flat_positions
    # (bench/bench_detail_scale.py times each stage so) sees fit_detail's
    # own calls: one subdivision and one fit a level, the finest level's fit
    # giving the flat positions.
    scan_positions, triangles = icosphere(3)
    scan = native.Scan(_mesh(native, scan_positions, triangles))
    positions, quads = cube_sphere(1, radius=0.95)
    cage = _mesh(native, positions, quads)
    calls = []
    for name in ("subdivide", "fit", "flat_positions"):
        def wrapper(mesh, *args, _name=name, _real=getattr(native, name), **kwargs):
            calls.append((_name, mesh.vertex_count))
            return _real(mesh, *args, **kwargs)
        monkeypatch.setattr(native, name, wrapper)
    detail = native.fit_detail(cage, scan, 2, cutoff=0.3)
    assert calls == [("subdivide", 8), ("fit", 26), ("subdivide", 26), ("fit", 98)]
    assert len(detail.points) == 98
    assert np.array_equal(detail.points, detail.report.flat_positions)
    # Without the scan's measure (whose grid of limit points they come
    # from), flat_positions gives them.
    calls.clear()
    detail = native.fit_detail(cage, scan, 1, cutoff=0.3, measure_scan=False)
    assert calls == [("subdivide", 8), ("fit", 26), ("flat_positions", 26)]
    assert detail.report.flat_positions is None


@pytest.mark.parametrize("per_edge", [1, 2, 4])
def test_fit_gives_the_flat_positions_of_the_cage_written(native, per_edge):
    # From the grid that measured the scan: 3, 5 and 9 points along a
    # face's edge, of which the corners, midpoints and centre are taken.
    scan_positions, triangles = icosphere(4)
    scan = native.Scan(_mesh(native, scan_positions, triangles))
    positions, quads = cube_sphere(3, radius=0.9)
    cage = native.subdivide(_mesh(native, positions * np.array([1.0, 0.8, 1.2]), quads), 1)
    fitted, report = native.fit(cage, scan, cutoff=0.3, samples_per_edge=per_edge, flat=True, max_rounds=3)
    assert report.flat_positions is not None
    written = native.Mesh(fitted, cage.face_sizes, cage.face_vertices)
    theirs = native.flat_positions(written)
    assert np.abs(report.flat_positions - theirs).max() < 1e-6
    # Not the limit points, which they are not.
    limit = native.limit_stencils(written).apply(written.positions)
    assert np.abs(report.flat_positions - limit).max() > 1e-4
    # Not for a cage with a face that is not a quad, nor without the measure.
    assert native.fit(cage, scan, cutoff=0.3, samples_per_edge=per_edge, max_rounds=1)[1].flat_positions is None
    assert native.fit(cage, scan, cutoff=0.3, flat=True, measure_scan=False, max_rounds=1)[1].flat_positions is None
    tri_positions, triangles = icosphere(1)
    tri = _mesh(native, tri_positions * 0.95, triangles)
    assert native.fit(tri, scan, cutoff=0.3, flat=True, max_rounds=1)[1].flat_positions is None


def test_detail_samples_halve_down_to_two(native):
    assert [native.detail_samples(8, level) for level in range(1, 5)] == [4, 2, 2, 2]
    assert native.detail_samples(4, 1) == 2


def test_flat_positions_refuse_what_is_not_a_quad_mesh(native):
    positions, triangles = icosphere(1)
    with pytest.raises(native.PiaError, match="quad"):
        native.flat_positions(_mesh(native, positions, triangles))
    positions, quads = cube_sphere(2)
    flat = native.flat_positions(_mesh(native, positions, quads))
    assert flat.shape == positions.shape and np.isfinite(flat).all()


def test_scan_pull_brings_the_scan_closer(native):
    """A rippled sphere whose flat facets are larger than the samples'
    spacing, and a cube cage fitted with and without the scan's pull: the
    scan's vertices (off the facets' planes the samples land on) come closer to the limit surface with it (measured in numpy on a grid of
    the surface's points)."""
    positions, triangles = icosphere(4)
    direction = positions / np.linalg.norm(positions, axis=1)[:, None]
    bumpy = direction * (1.0 + 0.01 * np.sin(9.0 * direction[:, 0]) * np.sin(7.0 * direction[:, 1]))[:, None]
    scan = native.Scan(_mesh(native, bumpy, triangles))
    cage_positions, quads = cube_sphere(12, radius=1.0)
    cage = _mesh(native, cage_positions, quads)
    grid = native.surface_stencils(cage, samples_per_edge=6)
    gaps = []
    for pull in (False, True):
        fitted, report = native.fit(cage, scan, cutoff=0.3, smoothing=1e-6, scan_pull=pull)
        surface = grid.apply(fitted)
        # Both are star-shaped about the centre: each scan point against the
        # surface point in its direction (the nearest direction on a fine
        # grid), radius to radius.
        unit = surface / np.linalg.norm(surface, axis=1)[:, None]
        points = bumpy
        nearest = np.argmax(points @ unit.T, axis=1)
        gaps.append(np.abs(np.linalg.norm(points, axis=1) - np.linalg.norm(surface[nearest], axis=1)).mean())
    assert gaps[1] < 0.8 * gaps[0], gaps  # measured 0.70
    with pytest.raises(native.PiaError, match="samples_per_edge"):
        native.fit(cage, scan, samples_per_edge=1, scan_pull=True)


def test_subdividing_twice_is_subdividing_two_levels(native):
    """An open grid (one-face corners, boundary edges): its boundary edges,
    which OpenSubdiv makes sharp by itself, are not written as creases, so
    that reading the refined mesh again (Blender's two-edge rule included)
    refines it as OpenSubdiv would have gone on: the same positions as two
    levels at once, vertex by vertex where the numbering agrees."""
    n = 4
    positions = np.array([[i, j, 0.3 * np.sin(i + 2.0 * j)] for j in range(n + 1) for i in range(n + 1)], np.float32)
    quads = [[j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
             for j in range(n) for i in range(n)]
    grid = _mesh(native, positions, quads)
    once = native.subdivide(grid, 1)
    assert not once.edge_creases.any() and not once.vertex_creases.any()
    twice = native.subdivide(once, 1)
    both = native.subdivide(grid, 2)
    first = len(once.positions)  # the children of the level-1 vertices come first in both
    assert np.abs(twice.positions[:first] - both.positions[:first]).max() < 1e-6
    assert sorted(map(tuple, np.round(twice.positions, 5))) == sorted(map(tuple, np.round(both.positions, 5)))


def _point_triangle_distances(points, a, b, c):
    """Each point's distance to the nearest of the triangles (a[i], b[i],
    c[i]): the nearest of each triangle's inside, edges and corners."""
    ab, ac, bc = b - a, c - a, c - b
    normal = np.cross(ab, ac)
    area2 = (normal * normal).sum(axis=1)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        # The plane's foot where it falls inside (barycentric weights >= 0).
        ap = p - a
        t = (ap * normal).sum(axis=1) / area2
        foot = p - t[:, None] * normal
        fa = foot - a
        u = (np.cross(fa, ac) * normal).sum(axis=1) / area2
        v = (np.cross(ab, fa) * normal).sum(axis=1) / area2
        inside = (u >= 0) & (v >= 0) & (u + v <= 1)
        best = np.where(inside, np.abs(t) * np.sqrt(area2), np.inf)
        for start, edge in ((a, ab), (a, ac), (b, bc)):
            s = np.clip(((p - start) * edge).sum(axis=1) / (edge * edge).sum(axis=1), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(start + s[:, None] * edge - p, axis=1))
        out[i] = best.min()
    return out


def _bumped_sphere(h, w, axis):
    positions, triangles = icosphere(6)
    direction = positions / np.linalg.norm(positions, axis=1)[:, None]
    angle = np.arccos(np.clip(direction @ axis, -1.0, 1.0))
    return direction * (1.0 + h * np.exp(-(angle / w) ** 2))[:, None], triangles, angle


def test_detail_levels_reach_a_bump_the_cage_cannot_hold(native):
    """A narrow bump on a sphere (a claw on a scan) that a 96-face cage's
    fit rounds off: the detail levels reach up it.  With the base fit's
    robust scale (6 times the median distance, which a detail level starts
    with at a fraction of the base's) the kernel took the bump for an
    outlier and stopped 58% of its height short of its top; the detail
    levels' own (15) come within 11%.  Distances from the bump's scan
    vertices to the finest level's flat triangles, in numpy."""
    h, w, axis = 0.1, 0.1, np.array([0.6, 0.0, 0.8])
    bumped, triangles, angle = _bumped_sphere(h, w, axis)
    scan = native.Scan(_mesh(native, bumped, triangles))
    positions, quads = cube_sphere(4, radius=0.9)
    cage = _mesh(native, positions, quads)
    fitted, _ = native.fit(cage, scan, cutoff=0.3)
    base = native.Mesh(fitted, cage.face_sizes, cage.face_vertices)
    bump = bumped[angle < 2 * w]
    gaps = {}
    for robust_scale in (6.0, native.DETAIL_ROBUST_SCALE):
        detail = native.fit_detail(base, scan, 3, robust_scale=robust_scale)
        p = detail.points.astype(np.float64)
        q = detail.mesh.face_vertices.reshape(-1, 4)
        a, b, c = p[np.concatenate([q[:, 0], q[:, 0]])], p[np.concatenate([q[:, 1], q[:, 2]])], p[np.concatenate([q[:, 2], q[:, 3]])]
        gaps[robust_scale] = _point_triangle_distances(bump, a, b, c).max()
    assert gaps[native.DETAIL_ROBUST_SCALE] < 0.2 * h, gaps  # measured 0.106 h
    assert gaps[native.DETAIL_ROBUST_SCALE] < 0.5 * gaps[6.0], gaps  # measured 0.58 h


def test_detail_levels_leave_a_stray_layer_and_span_a_hole(native):
    """The detail levels' guards: a sphere scan with a hole around +z and a
    stray copy of a patch of it 2% of the radius above +x (a scan's
    double layer).  The finest level stays on the sphere under the patch,
    does not sink into the hole, and spans it as smoothly as the fitted
    base's own surface does there (the largest angle between neighbouring
    faces); checked against the analytic sphere."""
    positions, triangles = icosphere(5)
    positions = np.asarray(positions, np.float64)
    centres = (positions[triangles] / np.linalg.norm(positions[triangles], axis=2)[:, :, None]).mean(axis=1)
    patch = triangles[centres[:, 0] > 0.985]
    lifted = np.unique(patch)
    index = np.full(len(positions), -1)
    index[lifted] = len(positions) + np.arange(len(lifted))
    scan_positions = np.concatenate([positions, 1.02 * positions[lifted]])
    scan_triangles = np.concatenate([triangles[centres[:, 2] < 0.9], index[patch]])
    scan = native.Scan(_mesh(native, scan_positions, scan_triangles))
    cage_positions, quads = cube_sphere(4, radius=0.9)
    cage = _mesh(native, cage_positions, quads)
    fitted, _ = native.fit(cage, scan, cutoff=0.3)
    base = native.Mesh(fitted, cage.face_sizes, cage.face_vertices)
    detail = native.fit_detail(base, scan, 3)
    plain = base
    for _ in range(3):
        plain = native.subdivide(plain, 1)
    base_points = native.flat_positions(plain).astype(np.float64)
    points = detail.points.astype(np.float64)
    quads = detail.mesh.face_vertices.reshape(-1, 4)
    radius = np.linalg.norm(points, axis=1)
    direction = points / radius[:, None]
    assert (radius[direction[:, 0] > 0.99] - 1.0).max() < 0.002  # measured 0.0003 under a layer at 0.02
    over_hole = direction[:, 2] > 0.93
    assert radius[over_hole].min() > 0.995  # measured 1.0008

    def largest_bend(p):
        n = np.cross(p[quads[:, 2]] - p[quads[:, 0]], p[quads[:, 3]] - p[quads[:, 1]])
        n /= np.linalg.norm(n, axis=1)[:, None]
        faces_of = {}
        for f, quad in enumerate(quads):
            if over_hole[quad].all():
                for k in range(4):
                    faces_of.setdefault(tuple(sorted((quad[k], quad[(k + 1) % 4]))), []).append(f)
        pairs = np.array([f for f in faces_of.values() if len(f) == 2])
        return np.degrees(np.arccos(np.clip((n[pairs[:, 0]] * n[pairs[:, 1]]).sum(axis=1), -1.0, 1.0))).max()
    assert largest_bend(points) < 1.1 * largest_bend(base_points)  # measured 6.0 and 6.3 degrees


def test_detail_memory_estimate_counts_the_levels_samples(native):
    """The estimate's samples are those of fit_detail's level with the
    most (its reports' sample counts): with 10 samples per edge the first
    level's 5 x 5 per face outnumber the second's 2 x 2 on four times the
    faces; with the default the finest level has the most."""
    positions, quads = cube_sphere(3)
    scan_positions, triangles = icosphere(4)
    scan = native.Scan(_mesh(native, scan_positions, triangles))
    cage = _mesh(native, positions, quads)
    counts = {}
    for samples_per_edge, levels in ((10, 2), (4, 2)):
        detail = native.fit_detail(cage, scan, levels, samples_per_edge=samples_per_edge, cutoff=0.3)
        counts[samples_per_edge] = [report.sample_count for report in detail.reports]
        need, faces = native.detail_memory_estimate(cage, levels, samples_per_edge)
        # the finest level's measuring grid: 2 samples an edge, so 4 x 4
        # quads (5 x 5 points) a ptex face, two levels finer: far below 2M
        finest = len(detail.mesh.face_sizes)
        grid = native.DETAIL_BYTES_PER_GRID_POINT * 25 * finest + native.DETAIL_BYTES_PER_SEARCHED_QUAD * 16 * finest
        per_level = [native.DETAIL_BYTES_PER_SAMPLE * n for n in counts[samples_per_edge]]
        per_level[-1] += grid
        assert need == native.DETAIL_BYTES_FIXED + max(per_level)
        assert faces == finest
    # Both cases as the docstring has them, so the first is the remainder's.
    assert counts[10][0] > counts[10][1] and counts[4][0] < counts[4][1], counts
    assert native.detail_memory_estimate(int(np.sum(cage.face_sizes)), 2, 10) == native.detail_memory_estimate(cage, 2, 10)


def test_detail_memory_estimate_searches_a_large_grid_through_its_faces(native):
    """Past MEASURE_GRID_QUADS quads the finest level's grid is searched
    through one quad a ptex face: 5 levels on a 3,052-quad cage (3.1M ptex
    faces at the finest, 2 samples an edge) count 9 grid points (the grid
    one level finer, not two, to stay near the cap) and 1 searched quad a
    face; at the cap, 4 a face."""
    d = native.detail_levels
    corners = 4 * 3052
    finest = corners * 4 ** 4
    need, faces = d.detail_memory_estimate(corners, 5)
    assert faces == finest
    assert need == (d.DETAIL_BYTES_FIXED + d.DETAIL_BYTES_PER_SAMPLE * 4 * finest
                    + d.DETAIL_BYTES_PER_GRID_POINT * 9 * finest + d.DETAIL_BYTES_PER_SEARCHED_QUAD * finest)
    small = d.MEASURE_GRID_QUADS // 4  # 4 quads a face: exactly at the cap
    assert d._measure_grid(small, 2) == (9 * small, 4 * small)
    assert d._measure_grid(small + 1, 2) == (9 * (small + 1), small + 1)
    # the measured growth over the whole call on the dragon's 50k-vertex
    # cage at 3 levels (4.7e9 bytes, 12.9M samples at the finest) is within
    # the estimate, by less than a third
    ptex = 3226624
    points, searched = d._measure_grid(ptex, 2)
    estimate = (d.DETAIL_BYTES_FIXED + d.DETAIL_BYTES_PER_SAMPLE * 4 * ptex + d.DETAIL_BYTES_PER_GRID_POINT * points
                + d.DETAIL_BYTES_PER_SEARCHED_QUAD * searched)
    assert 4.7e9 < estimate < 1.33 * 4.7e9


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's peak resident size reset")
def test_detail_memory_estimate_bounds_the_peak(native):
    """detail_memory_estimate against fit_detail's measured peak: the
    bunny's cage to 3 levels in a process of its own on two threads, its
    peak resident size (Linux's VmHWM, reset just before the call) over its
    size before (measured 0.36e9 bytes, the estimate 0.57e9: at 3 levels
    the fixed part weighs)."""
    code = (
        "import sys; sys.path[:0] = %r\n"
        "from conftest import load\n"
        "from subdiv_pia import native\n"
        "def status(key):\n"
        "    return 1024 * next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith(key))\n"
        "scan = native.Scan(native.Mesh.from_faces(*load('bun_zipper')[:2]))\n"
        "cage = native.Mesh.from_faces(*load('bun_zipper_quadriflow_cage')[:2])\n"
        "fitted, _ = native.fit(cage, scan, threads=2)\n"
        "base = native.Mesh(fitted, cage.face_sizes, cage.face_vertices)\n"
        "open('/proc/self/clear_refs', 'w').write('5')  # the peak from here on\n"
        "before = status('VmRSS:')\n"
        "detail = native.fit_detail(base, scan, 3, threads=2)\n"
        "after = status('VmHWM:')\n"
        "need, faces = native.detail_memory_estimate(base, 3)\n"
        "print(after - before, need, faces, len(detail.mesh.face_sizes))\n"
        % ([ADDON_DIR, os.path.dirname(__file__)],))
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    grown, need, faces, made = (int(x) for x in out.split())
    assert faces == made == 2803 * 4 ** 3
    assert grown < need < 2.0 * grown, (grown, need)


def test_flat_positions_are_the_least_squares_of_the_limit_grid(native):
    """The flat positions of a quad mesh are scipy's solve of the same
    least squares (each face's bilinear quad against its 3 x 3 grid of
    limit points, the corners weighted 1/16) over the limit points of the
    mesh subdivided once, which keeps the cage's vertices (its limit
    points are the grid's corners), numbers face f's point n + f and puts
    each face's children at 4f to 4f + 3, each from its corner: corner,
    edge point towards the next corner, face point, edge point from the
    one before.  The same to the bit on 1, 2 and 3 threads."""
    import scipy.sparse
    import scipy.sparse.linalg
    positions, quads = cube_sphere(24)
    mesh = _mesh(native, positions * np.array([1.0, 0.8, 1.3]), quads)
    n, faces = mesh.vertex_count, mesh.face_vertices.reshape(-1, 4)
    sub = native.subdivide(mesh, 1)
    grid = native.limit_stencils(sub).apply(sub.positions).astype(np.float64)
    children = sub.face_vertices.reshape(len(faces), 4, 4)
    # Each child turned to start at its corner, the one vertex of the cage's.
    first = np.argmax(children < n, axis=2)
    children = np.take_along_axis(children, (first[:, :, None] + np.arange(4)) % 4, axis=2)
    order = np.argsort(np.argsort(faces, axis=1), axis=1)  # each child where its corner is in the face
    children = np.take_along_axis(children[np.arange(len(faces))[:, None], np.argsort(children[:, :, 0], axis=1)],
                                  order[:, :, None], axis=1)
    assert (children[:, :, 0] == faces).all() and (children[:, :, 2] == n + np.arange(len(faces))[:, None]).all()
    edge_next = children[:, :, 1]  # the point on the edge from corner c to corner c + 1
    at = {(0, 0): faces[:, 0], (2, 0): faces[:, 1], (2, 2): faces[:, 2], (0, 2): faces[:, 3],
          (1, 1): n + np.arange(len(faces)), (1, 0): edge_next[:, 0], (2, 1): edge_next[:, 1],
          (1, 2): edge_next[:, 2], (0, 1): edge_next[:, 3]}
    rows, cols, values, targets = [], [], [], []
    for r, ((i, j), points) in enumerate(sorted(at.items())):
        s, t = i / 2.0, j / 2.0
        root = 1.0 if i == 1 or j == 1 else 0.25  # the square root of the corners' 1/16
        for c, w in enumerate(((1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t)):
            rows.append(r * len(faces) + np.arange(len(faces)))
            cols.append(faces[:, c])
            values.append(np.full(len(faces), root * w))
        targets.append(root * grid[points])
    A = scipy.sparse.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(9 * len(faces), n))
    theirs = scipy.sparse.linalg.spsolve((A.T @ A).tocsc(), A.T @ np.concatenate(targets))
    ours = [native.flat_positions(mesh, threads=threads) for threads in (1, 2, 3)]
    extent = np.ptp(positions, axis=0).max()
    assert np.abs(ours[0] - theirs).max() < 1e-6 * extent  # measured 2.3e-7
    assert np.abs(ours[0] - grid[:n]).max() > 1e-4 * extent  # not the limit points
    for other in ours[1:]:
        assert np.array_equal(other.view(np.uint32), ours[0].view(np.uint32))
