# SPDX-License-Identifier: GPL-3.0-or-later
"""Surface samples, closest points and fitting a cage to a scan, checked
against independent computations: the bicubic B-spline on regular faces,
numpy geometry on spheres, and the library's own limit stencils."""

import numpy as np
import pytest

import spheres


def quad_sphere(n, radius=1.0):
    """A cube with every face cut into n x n quads, projected to a sphere."""
    p, faces = spheres.cube_sphere(n, radius)
    return p.astype(np.float32), faces.astype(np.int32)


def uv_sphere(nu, nv, cap_angle=0.0):
    """A triangulated unit sphere; with cap_angle > 0 the triangles within
    that angle of +z are left out (a hole)."""
    theta = np.linspace(0.0, np.pi, nv + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, nu, endpoint=False)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], axis=-1).reshape(-1, 3)
    pos = np.vstack([[0, 0, 1], ring, [0, 0, -1]]).astype(np.float32)
    tris = []
    for j in range(nu):
        tris.append([0, 1 + j, 1 + (j + 1) % nu])
    for i in range(nv - 2):
        for j in range(nu):
            a, b = 1 + i * nu + j, 1 + i * nu + (j + 1) % nu
            tris += [[a, a + nu, b + nu], [a, b + nu, b]]
    last, base = len(pos) - 1, 1 + (nv - 2) * nu
    for j in range(nu):
        tris.append([base + j, last, base + (j + 1) % nu])
    tris = np.asarray(tris, np.int32)
    if cap_angle > 0:
        z = pos[tris][:, :, 2].max(axis=1)
        tris = tris[z < np.cos(cap_angle)]
    return pos, tris


@pytest.fixture(scope="module")
def sphere_scan(native):
    pos, tris = uv_sphere(400, 200)
    return native.Scan(native.Mesh.from_faces(pos, tris))


def bspline(s):
    return np.array([(1 - s) ** 3, 3 * s ** 3 - 6 * s ** 2 + 4, -3 * s ** 3 + 3 * s ** 2 + 3 * s + 1, s ** 3]) / 6


def test_regular_samples_are_the_bicubic_bspline(native):
    """On faces whose 16 neighbours are all regular, the samples are the
    uniform bicubic B-spline at the grid centres (Catmull-Clark's regular
    case), at the documented (s, t) and in the documented order."""
    n, k = 7, 3
    rng = np.random.default_rng(3)
    grid = np.array([[i, j, 0.0] for j in range(n + 1) for i in range(n + 1)])
    grid[:, 2] = rng.normal(scale=0.3, size=len(grid))
    faces = [[j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
             for j in range(n) for i in range(n)]
    mesh = native.Mesh.from_faces(grid.astype(np.float32), faces)
    M = native.surface_stencils(mesh, samples_per_edge=k)
    assert M.row_count == n * n * k * k
    samples = M.apply(mesh.positions)
    P = mesh.positions.astype(np.float64).reshape(n + 1, n + 1, 3)
    checked = 0
    for fj in range(2, n - 2):
        for fi in range(2, n - 2):
            f = fj * n + fi
            for j in range(k):
                for i in range(k):
                    s, t = (i + 0.5) / k, (j + 0.5) / k
                    patch = P[fj - 1:fj + 3, fi - 1:fi + 3]
                    expect = np.einsum("a,b,abx->x", bspline(t), bspline(s), patch)
                    got = samples[(f * k + j) * k + i]
                    assert np.abs(got - expect).max() < 1e-6, (f, i, j)
                    checked += 1
    assert checked == 9 * k * k


def test_sample_count_matches_ptex_layout(native):
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0], [0.5, -1, 0]], np.float32)
    mesh = native.Mesh.from_faces(pos, [[0, 1, 2, 3], [1, 4, 2], [0, 5, 1]])
    # one quad (1 ptex face) and two triangles (3 each)
    assert native.surface_stencils(mesh, samples_per_edge=2).row_count == (1 + 3 + 3) * 4


def test_closest_points_on_a_sphere(native, sphere_scan):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = rng.uniform(0.5, 1.5, size=500)
    closest, normals, dist, faces = sphere_scan.closest_points(d * r[:, None])
    # the tessellation is within 1e-4 of the unit sphere at this density
    assert np.abs(dist - np.abs(r - 1)).max() < 1e-4
    assert np.abs(np.linalg.norm(closest, axis=1) - 1).max() < 1e-4
    assert np.degrees(np.arccos(np.clip(np.sum(normals * d, axis=1), -1, 1))).max() < 0.5
    assert faces.min() >= 0


def _fit_sphere(native, scan, mode, **kw):
    cp, cf = quad_sphere(6)
    cage = native.Mesh.from_faces(cp, cf)
    out, rep = native.fit(cage, scan, mode=mode, **kw)
    return cage, out, rep


def test_surface_fit_puts_every_sample_on_the_sphere(native, sphere_scan):
    cage, out, rep = _fit_sphere(native, sphere_scan, "SURFACE")
    assert rep.before.mean > 3e-3          # the plain cage's surface shrinks inside
    M = native.surface_stencils(native.Mesh(out, cage.face_sizes, cage.face_vertices), 4)
    samples = M.apply(out)
    _, _, dist, _ = sphere_scan.closest_points(samples)
    assert dist.max() / sphere_scan.diagonal < 1e-4
    # independent of the scan's tessellation: the unit sphere itself
    assert np.abs(np.linalg.norm(samples, axis=1) - 1).max() / sphere_scan.diagonal < 1e-4
    assert abs(rep.after.max - dist.max() / sphere_scan.diagonal) < 1e-6
    assert rep.history[0] == pytest.approx(rep.before.mean) and len(rep.history) == rep.rounds + 1


@pytest.mark.parametrize("measure_scan", [True, False])
def test_a_fit_stopped_by_max_rounds_says_so(native, sphere_scan, measure_scan):
    # One round cannot settle (settling takes two rounds that gain less
    # than round_tolerance): the result says so whether or not the scan's
    # side is measured after the fit, and the cage is still written.
    cage, out, rep = _fit_sphere(native, sphere_scan, "SURFACE", max_rounds=1, measure_scan=measure_scan)
    assert rep.status == "MAX_ITERATIONS" and "max_rounds" in rep.message
    assert rep.rounds == 1 and rep.after.mean < rep.before.mean
    assert not np.array_equal(out, cage.positions)
    assert (rep.scan_point_count > 0) == measure_scan
    settled_cage, settled_out, settled = _fit_sphere(native, sphere_scan, "SURFACE", measure_scan=measure_scan)
    assert settled.status == "CONVERGED" and settled.message == ""


# Every way a fit can stop short of its tolerance, in each mode and scheme:
# (mode, options, status, words the message has).  The VERTICES solve's
# own result goes through: max_iterations, and least squares stopped by it
# (its vertices beyond the tolerance are reported unreachable).
SHORT_FITS = [
    ("SURFACE", dict(max_rounds=2, round_tolerance=1e-9), "MAX_ITERATIONS", "max_rounds (2)"),
    ("VERTICES", dict(max_iterations=2), "MAX_ITERATIONS", "max_iterations (2)"),
    ("VERTICES", dict(method="LEAST_SQUARES", max_iterations=2), "STAGNATED", "cannot be reached"),
    ("VERTICES", dict(scheme="LOOP", max_iterations=2), "MAX_ITERATIONS", "max_iterations (2)"),
    ("VERTICES", dict(scheme="DOO_SABIN", max_iterations=2), "MAX_ITERATIONS", "max_iterations (2)"),
]


@pytest.mark.parametrize("measure_scan", [True, False], ids=["measure_scan", "no_scan_side"])
@pytest.mark.parametrize("mode, options, status, words", SHORT_FITS,
                         ids=["surface", "vertices", "vertices-least-squares", "vertices-loop",
                              "vertices-doo-sabin"])
def test_a_fit_short_of_its_tolerance_never_says_converged(native, sphere_scan, mode, options, status, words,
                                                          measure_scan):
    """The result of the fit's last step, whatever is measured after it:
    measuring the scan's side (or the limit points, for Loop and Doo-Sabin)
    once the cage is written must not turn it into CONVERGED nor clear the
    message.  The same fits with room to finish do converge."""
    scheme = options.get("scheme", "CATMULL_CLARK")
    cp, cf = quad_sphere(6)
    if scheme == "LOOP":
        cf = np.vstack([cf[:, [0, 1, 2]], cf[:, [0, 2, 3]]])
    cage = native.Mesh.from_faces(cp, cf)
    out, rep = native.fit(cage, sphere_scan, mode=mode, measure_scan=measure_scan, **options)
    assert rep.status == status and words in rep.message, (rep.status, rep.message)
    assert not np.array_equal(out, cage.positions) and rep.after.mean < rep.before.mean
    # the scan's side is measured for Catmull-Clark cages, when asked
    assert (rep.scan_point_count > 0) == (measure_scan and scheme == "CATMULL_CLARK")
    if mode == "SURFACE":
        assert rep.rounds == options["max_rounds"] and len(rep.history) == rep.rounds + 1
    else:
        # the interpolation stopped short: its targets (the given limit
        # points' closest scan points) are not all reached
        assert rep.max_error_relative > 1e-6
    room = {k: v for k, v in options.items() if k not in ("max_rounds", "round_tolerance", "max_iterations")}
    _, done = native.fit(cage, sphere_scan, mode=mode, measure_scan=measure_scan, **room)
    if room.get("method") != "LEAST_SQUARES":   # least squares with room: the targets are reachable
        assert done.status == "CONVERGED" and done.message == "", (done.status, done.message)


@pytest.mark.parametrize("measure_scan", [True, False], ids=["measure_scan", "no_scan_side"])
def test_detail_levels_short_of_their_rounds_say_so(native, measure_scan):
    """fit_detail's levels are fits of their own: each level stopped by
    max_rounds says so, the finest too (the one whose scan side is
    measured), and levels that settle say CONVERGED with no message.  (One
    round never settles: settling takes two rounds that gain less than
    round_tolerance; a level starting on the scan may settle in two.)"""
    p, t = uv_sphere(120, 60)
    scan = native.Scan(native.Mesh.from_faces(p, t))
    cp, cf = quad_sphere(3)
    base, _ = native.fit(native.Mesh.from_faces(cp, cf), scan, cutoff=0.3)
    base = native.Mesh.from_faces(base, cf)
    short = native.fit_detail(base, scan, 2, cutoff=0.3, max_rounds=1, measure_scan=measure_scan)
    for level, rep in enumerate(short.reports, 1):
        assert rep.status == "MAX_ITERATIONS" and "max_rounds (1)" in rep.message, (level, rep.status, rep.message)
        assert rep.rounds == 1
    assert (short.report.scan_point_count > 0) == measure_scan
    assert all(rep.scan_point_count == 0 for rep in short.reports[:-1])
    settled = native.fit_detail(base, scan, 2, cutoff=0.3, max_rounds=50, round_tolerance=0.5,
                                measure_scan=measure_scan)
    for level, rep in enumerate(settled.reports, 1):
        assert rep.status == "CONVERGED" and rep.message == "", (level, rep.status, rep.message)
        assert rep.rounds < 50


def test_the_finest_of_three_levels_takes_its_own_rounds(native):
    """The finest level of DETAIL_FINEST_FROM_LEVEL levels or more is
    bounded by finest_rounds (DETAIL_FINEST_ROUNDS), the others by
    max_rounds; finest_rounds=None bounds it by max_rounds too, and with
    fewer levels max_rounds bounds them all."""
    assert native.DETAIL_FINEST_ROUNDS < native.DETAIL_ROUNDS and native.DETAIL_FINEST_FROM_LEVEL == 3
    p, t = uv_sphere(120, 60)
    scan = native.Scan(native.Mesh.from_faces(p, t))
    cp, cf = quad_sphere(2)
    base, _ = native.fit(native.Mesh.from_faces(cp, cf), scan, cutoff=0.3)
    base = native.Mesh.from_faces(base, cf)
    # One round never settles (settling takes two), so a bound of one is met.
    three = native.fit_detail(base, scan, 3, cutoff=0.3, finest_rounds=1)
    assert three.report.rounds == 1 and "max_rounds (1)" in three.report.message
    assert all(2 <= rep.rounds <= native.DETAIL_ROUNDS for rep in three.reports[:-1])
    alike = native.fit_detail(base, scan, 3, cutoff=0.3, max_rounds=1, finest_rounds=None)
    assert [rep.rounds for rep in alike.reports] == [1, 1, 1]
    two = native.fit_detail(base, scan, 2, cutoff=0.3, finest_rounds=1)
    assert all(2 <= rep.rounds <= native.DETAIL_ROUNDS for rep in two.reports)
    assert native.fit_detail(base, scan, 3, cutoff=0.3).report.rounds <= native.DETAIL_FINEST_ROUNDS
    with pytest.raises(native.PiaError, match="max_rounds"):  # 0 is no bound of its own, but a wrong one
        native.fit_detail(base, scan, 3, cutoff=0.3, finest_rounds=0)


def test_scan_measured_after_the_fit_only(native):
    """measure_scan="after" (SPIA_FIT_NO_SCAN_BEFORE) leaves out the scan's
    measure against the cage given: the cage, the scan's distances to the
    cage written and the flat positions are those of a fit that measured
    both, scan_before is None; the finest detail level measures so."""
    p, t = uv_sphere(120, 60)
    scan = native.Scan(native.Mesh.from_faces(p, t))
    cp, cf = quad_sphere(3)
    cage = native.Mesh.from_faces(cp * 0.9, cf)
    both = native.fit(cage, scan, cutoff=0.3, flat=True, max_rounds=3)
    after = native.fit(cage, scan, cutoff=0.3, flat=True, max_rounds=3, measure_scan="after")
    assert both[1].scan_before.mean > both[1].scan_after.mean > 0 and after[1].scan_before is None
    assert after[1].scan_after == both[1].scan_after and after[1].scan_point_count == both[1].scan_point_count
    np.testing.assert_array_equal(after[1].scan_distances, both[1].scan_distances)
    np.testing.assert_array_equal(after[0], both[0])
    np.testing.assert_array_equal(after[1].flat_positions, both[1].flat_positions)
    with pytest.raises(native.PiaError, match="measure_scan"):
        native.fit(cage, scan, measure_scan="before")
    detail = native.fit_detail(native.Mesh.from_faces(both[0], cf), scan, 2, cutoff=0.3)
    assert detail.report.scan_before is None and detail.report.scan_point_count == both[1].scan_point_count
    assert 0 < detail.report.scan_after.mean < both[1].scan_after.mean


@pytest.mark.parametrize("per_edge", [1, 2, 3, 5, 6])
def test_sample_products_for_every_grid_size(native, sphere_scan, per_edge):
    """The sample products take eight, four and single samples at a time:
    grids of 1, 4, 9, 25 and 36 samples per face use each mix.  The fit's
    samples are where the library's sample stencils put them (the report's
    largest distance against the closest points of M.apply(cage)), the
    surface reaches the unit sphere where there are enough samples to fit
    it, and the products give the same bits in SSE2 as in AVX (NO_AVX)."""
    cp, cf = quad_sphere(6)
    # quads, and a band of triangles (a ptex face per corner)
    tris = np.vstack([cf[:36, [0, 1, 2]], cf[:36, [0, 2, 3]]])
    cage = native.Mesh(cp, np.r_[np.full(len(tris), 3), np.full(len(cf) - 36, 4)].astype(np.int32),
                       np.r_[tris.ravel(), cf[36:].ravel()])
    fits = [native.fit(cage, sphere_scan, samples_per_edge=per_edge, max_rounds=4, threads=2, solve_flags=flags)
            for flags in ((), ("NO_AVX",))]
    (out, rep), (out_sse2, rep_sse2) = fits
    assert np.array_equal(out.view(np.uint32), out_sse2.view(np.uint32))
    assert rep.after.mean == rep_sse2.after.mean and rep.rounds == rep_sse2.rounds
    M = native.surface_stencils(native.Mesh(out, cage.face_sizes, cage.face_vertices), per_edge)
    samples = M.apply(out)
    assert len(samples) == rep.sample_count
    _, _, dist, _ = sphere_scan.closest_points(samples)
    # (the fit's blocks hold the weights in float: 6e-8 of the cage's size at most)
    assert rep.after.max == pytest.approx(dist.max() / sphere_scan.diagonal, rel=0, abs=5e-8)
    if per_edge >= 2:
        assert rep.after.mean < rep.before.mean / 10
        assert np.abs(np.linalg.norm(samples, axis=1) - 1).mean() / sphere_scan.diagonal < 2e-4


def test_vertex_fit_puts_every_limit_point_on_the_sphere(native, sphere_scan):
    cage, out, rep = _fit_sphere(native, sphere_scan, "VERTICES")
    fitted = native.Mesh(out, cage.face_sizes, cage.face_vertices)
    limit = native.limit_stencils(fitted).apply(out)
    _, _, dist, _ = sphere_scan.closest_points(limit)
    assert dist.max() / sphere_scan.diagonal < 1e-5
    assert rep.rounds == 1 and rep.after.mean < rep.before.mean / 10


def test_samples_over_a_hole_do_not_pull(native):
    """A sphere scan with a 35-degree cap cut away and, 0.25 above the hole,
    a loose disk the cage does not cover (a scanning table, say).  With the
    cut-off, the surface over the hole stays near the cage's own surface and
    continues the sphere; with the cut-off at the whole diagonal the disk
    drags it up.  Samples whose closest point is on the hole's rim never
    pull, at any cut-off."""
    pos, tris = uv_sphere(200, 100, cap_angle=np.radians(35))
    k = 48
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    disk = np.vstack([[0, 0, 1.25], np.c_[0.3 * np.cos(ang), 0.3 * np.sin(ang), np.full(k, 1.25)]])
    disk_tris = np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)]) + len(pos)
    scan = native.Scan(native.Mesh.from_faces(np.vstack([pos, disk]).astype(np.float32),
                                              np.vstack([tris, disk_tris])))
    cp, cf = quad_sphere(6)
    cage = native.Mesh.from_faces(cp, cf)
    M = native.surface_stencils(cage, 4)
    baseline = M.apply(cage.positions)
    shrink = np.abs(np.linalg.norm(baseline, axis=1) - 1)
    over_hole = baseline[:, 2] / np.linalg.norm(baseline, axis=1) > np.cos(np.radians(20))
    assert over_hole.sum() > 50

    def fitted(cutoff):
        out, rep = native.fit(cage, scan, cutoff=cutoff)
        return M.apply(out), rep
    kept, rep = fitted(0.02)
    dragged, _ = fitted(1.0)
    assert rep.after.ignored > 0
    moved = np.linalg.norm(kept - baseline, axis=1)
    print("over the hole: moved %.4f, off the sphere %.4f; the baseline's shrinkage %.4f .. %.4f" % (
        moved[over_hole].max(), np.abs(np.linalg.norm(kept[over_hole], axis=1) - 1).max(), shrink.min(),
        shrink.max()))
    # over the hole the surface moves about as far as the baseline is from
    # the sphere (it follows the fitted surroundings) ...
    assert moved[over_hole].max() < 1.5 * shrink.max()
    # ... and continues the sphere more closely than the baseline does
    assert np.abs(np.linalg.norm(kept[over_hole], axis=1) - 1).max() < 0.7 * shrink[over_hole].min()
    assert np.linalg.norm(dragged - baseline, axis=1)[over_hole].max() > 0.15


def test_scan_boundary_flag(native):
    pos, tris = uv_sphere(60, 30, cap_angle=np.radians(35))
    scan = native.Scan(native.Mesh.from_faces(pos, tris))
    points = np.array([[0, 0, 1.0], [0, 0, -1.2], [1.1, 0, 0]], np.float32)
    boundary = scan.closest_points(points, with_boundary=True)[4]
    assert boundary.tolist() == [True, False, False]


def test_fit_is_independent_of_the_thread_count(native):
    """The library's own threads (the options' `threads`; nothing reads
    OMP_NUM_THREADS): 1, 2 and 3 threads give the same cage and report to
    the bit, in both modes, with the scan's side measured."""
    p, t = uv_sphere(120, 60)
    scan = native.Scan(native.Mesh.from_faces(p, t))
    cp, cf = quad_sphere(4)
    cage = native.Mesh.from_faces(cp, cf)
    for mode in ("SURFACE", "VERTICES"):
        fits = [native.fit(cage, scan, mode=mode, threads=threads) for threads in (1, 2, 3)]
        out, rep = fits[0]
        assert not np.array_equal(out, cage.positions) and rep.rounds > 0
        for other, other_rep in fits[1:]:
            assert np.array_equal(out.view(np.uint32), other.view(np.uint32)), mode
            assert (other_rep.rounds, other_rep.iterations, other_rep.status) == (rep.rounds, rep.iterations, rep.status)
            assert np.array_equal(other_rep.history, rep.history)
            assert np.array_equal(other_rep.vertex_distances.view(np.uint32), rep.vertex_distances.view(np.uint32))
            assert (other_rep.after, other_rep.scan_after) == (rep.after, rep.scan_after)
            assert np.array_equal(other_rep.scan_distances.view(np.uint32), rep.scan_distances.view(np.uint32))


def test_a_large_fit_is_independent_of_the_thread_count(native):
    """A cage of more vertices than one chunk of the solver's passes over
    the vertices (their sums are added chunk by chunk), with the scan's
    pull: 1, 2 and 3 threads give the same cage to the bit."""
    p, t = uv_sphere(240, 120)
    scan = native.Scan(native.Mesh.from_faces(p, t))
    cp, cf = quad_sphere(64)
    bumps = 1.0 + 0.02 * np.random.default_rng(1).standard_normal((len(cp), 1))
    cage = native.Mesh.from_faces((cp * bumps).astype(np.float32), cf)
    assert cage.vertex_count > 16384  # fit_system.c's VERTEX_CHUNK
    fits = [native.fit(cage, scan, threads=threads, samples_per_edge=2, max_rounds=2, solver_iterations=4,
                       scan_pull=True) for threads in (1, 2, 3)]
    out, rep = fits[0]
    assert rep.rounds == 2 and np.abs(out - cage.positions).max() > 1e-3
    for other, other_rep in fits[1:]:
        assert np.array_equal(out.view(np.uint32), other.view(np.uint32))
        assert np.array_equal(other_rep.history, rep.history) and other_rep.after == rep.after


def test_the_stencils_of_a_large_open_creased_fit_are_independent_of_the_thread_count(native):
    """The samples' and the scan grid's stencils are made face by face on
    the threads, batch by batch, and handed over in face order: on an open
    grid of more faces than two batches, with faces that go through
    OpenSubdiv's patch table instead of Bfr (corners of one face, a
    sharpened vertex) among them, 1, 2 and 3 threads give the same fit and
    the same scan distances to the bit."""
    n = 130
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n + 1), np.linspace(0.0, 1.0, n + 1))
    bump = 0.05 * np.sin(5.0 * x) * np.cos(4.0 * y)
    pos = np.stack([x.ravel(), y.ravel(), bump.ravel()], axis=1).astype(np.float32)
    v = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    quads = np.stack([v, v + 1, v + n + 2, v + n + 1], axis=1).astype(np.int32)
    creases = np.zeros(len(pos), np.float32)
    creases[(n + 1) * (n // 2) + n // 2] = 0.8
    cage = native.Mesh(pos, np.full(n * n, 4, np.int32), quads.ravel(), vertex_creases=creases)
    assert n * n > 2 * 8192  # osd_samples.cpp's kBatchFaces
    sx, sy = np.meshgrid(np.linspace(-0.05, 1.05, 2 * n), np.linspace(-0.05, 1.05, 2 * n))
    sz = 0.05 * np.sin(5.0 * sx) * np.cos(4.0 * sy) + 0.01 * np.sin(40.0 * sx)
    sp = np.stack([sx.ravel(), sy.ravel(), sz.ravel()], axis=1).astype(np.float32)
    w = (np.arange(2 * n - 1)[None, :] + 2 * n * np.arange(2 * n - 1)[:, None]).ravel()
    tris = np.concatenate([np.c_[w, w + 1, w + 2 * n + 1], np.c_[w, w + 2 * n + 1, w + 2 * n]]).astype(np.int32)
    scan = native.Scan(native.Mesh.from_faces(sp, tris))
    fits = [native.fit(cage, scan, threads=threads, samples_per_edge=2, max_rounds=1, solver_iterations=4)
            for threads in (1, 2, 3)]
    out, rep = fits[0]
    assert rep.scan_point_count == len(sp) and np.abs(out - cage.positions).max() > 1e-4
    for other, other_rep in fits[1:]:
        assert np.array_equal(out.view(np.uint32), other.view(np.uint32))
        assert (other_rep.before, other_rep.after) == (rep.before, rep.after)
        assert (other_rep.scan_before, other_rep.scan_after) == (rep.scan_before, rep.scan_after)
        assert np.array_equal(other_rep.scan_distances.view(np.uint32), rep.scan_distances.view(np.uint32))


def test_bad_input(native, sphere_scan):
    cp, cf = quad_sphere(4)
    cage = native.Mesh.from_faces(cp, cf)
    with pytest.raises(native.PiaError) as e:
        native.Scan(native.Mesh(np.zeros((3, 3), np.float32), np.zeros(0, np.int32), np.zeros(0, np.int32)))
    assert e.value.code == "EMPTY_MESH" and "no faces" in str(e.value)
    with pytest.raises(native.PiaError) as e:
        native.fit(cage, sphere_scan, mode="SURFACE", scheme="DOO_SABIN")
    assert "VERTICES" in str(e.value)
    with pytest.raises(native.PiaError):
        native.fit(cage, sphere_scan, mode="NEAREST")
    with pytest.raises(native.PiaError) as e:
        native.fit(cage, sphere_scan, samples_per_edge=65)
    assert "samples_per_edge" in str(e.value)
    with pytest.raises(native.PiaError):
        native.fit(cage, sphere_scan, cutoff=-1)
    with pytest.raises(native.PiaError) as e:
        sphere_scan.closest_points(np.array([[0.0, np.nan, 0.0]]))
    assert e.value.code == "NONFINITE"
    with pytest.raises(native.PiaCancelled):
        native.fit(cage, sphere_scan, progress=lambda rnd, err: True)
    # a cage nowhere near the scan: nothing to fit, said so, in both modes
    far = native.Mesh.from_faces(cp + np.float32(5.0), cf)
    for mode in ("SURFACE", "VERTICES"):
        with pytest.raises(native.PiaError) as e:
            native.fit(far, sphere_scan, mode=mode)
        assert e.value.code == "INVALID_ARGUMENT" and "nothing to fit" in str(e.value)


def test_vertex_fit_for_loop_cages(native, sphere_scan):
    """VERTICES works for every scheme: a Loop cage's limit points land on the scan."""
    cp, cf = quad_sphere(4)
    tris = np.array([[q[0], q[1], q[2]] for q in cf] + [[q[0], q[2], q[3]] for q in cf], np.int32)
    cage = native.Mesh.from_faces(cp, tris)
    out, rep = native.fit(cage, sphere_scan, mode="VERTICES", scheme="LOOP")
    limit = native.limit_stencils(native.Mesh(out, cage.face_sizes, cage.face_vertices), scheme="LOOP").apply(out)
    _, _, dist, _ = sphere_scan.closest_points(limit)
    assert dist.max() / sphere_scan.diagonal < 1e-5
    # without surface samples the limit points are what the report measures
    assert rep.sample_count == cage.vertex_count
    assert rep.before.mean > 1e-3 and rep.after.max == pytest.approx(dist.max() / sphere_scan.diagonal, abs=1e-7)
    assert rep.vertex_distances.max() == pytest.approx(rep.after.max, abs=1e-7)
