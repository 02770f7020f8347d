# SPDX-License-Identifier: GPL-3.0-or-later
"""The binding on every mesh shipped in tests/data, checked with scipy."""
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse

from conftest import ADDON_DIR, MESHES, load


def diagonal(points):
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def without_degenerate(faces):
    return [f for f in faces if len(set(f)) == len(f)]


def double_sided_vertices(faces):
    """Vertices of faces that appear twice with the same vertex set."""
    seen, tied = {}, set()
    for f in faces:
        key = frozenset(f)
        if key in seen:
            tied.update(f)
        seen[key] = True
    return tied


@pytest.mark.parametrize("name", MESHES)
def test_interpolates_every_shipped_mesh(native, name):
    P, faces, _ = load(name)
    faces = without_degenerate(faces)
    mesh = native.Mesh.from_faces(P, faces)
    stencils = native.limit_stencils(mesh)
    L = stencils.to_scipy()
    # Row sums are 1 (affine invariance) and the table is sorted CSR.
    assert np.allclose(np.asarray(L.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert L.has_sorted_indices
    cage, report = stencils.solve(P)
    d = diagonal(P.astype(np.float64))
    err = np.linalg.norm(L @ cage.astype(np.float64) - P, axis=1) / d
    used = np.zeros(len(P), bool)
    used[np.concatenate([np.asarray(f) for f in faces])] = True
    # The plain modifier misses the points; the cage's limit hits them.
    before = np.linalg.norm(L @ P.astype(np.float64) - P, axis=1) / d
    assert before[used].max() > 1e-3
    tied = double_sided_vertices(faces)
    if report.converged:
        assert not tied
        assert err.max() <= 1e-5, err.max()
        assert err.max() <= report.max_error_relative * (1 + 1e-6) + 1e-12
    else:
        # Vertices whose limit points are tied to others' (double-sided
        # faces) cannot all be reached: the cage is a least-squares one
        # (L^T (P - L V) = 0, its residual the least-squares residual, which
        # is unique even though L is singular), the vertices it leaves
        # beyond the tolerance are flagged, and everything else is reached.
        assert report.status == "STAGNATED" and report.method == "LEAST_SQUARES", report.summary()
        flags = np.asarray(report.unreachable, bool)
        flagged = set(np.nonzero(flags)[0])
        assert flagged and flagged <= tied, (len(flagged), len(tied))
        assert report.unreachable_count == len(flagged)
        assert err[~flags].max() <= 1e-6 * (1 + 1e-6), err[~flags].max()
        assert err[flags].min() > 1e-6 * (1 - 1e-6), err[flags].min()
        residual = P - L @ cage.astype(np.float64)
        gradient = np.linalg.norm(L.T @ residual, axis=1) / d
        assert gradient.max() <= 1e-5, "not a least-squares cage: |L^T (P - L V)| %.3g of the diagonal at %d" % (
            gradient.max(), int(np.argmax(gradient)))
    # Vertices no face uses keep their position, as in Blender.
    assert np.array_equal(cage[~used], P[~used])


def quad_neighbourhoods(faces, nv):
    """For each vertex: incident faces if all are quads, else None."""
    inc = [[] for _ in range(nv)]
    for f in faces:
        for k, v in enumerate(f):
            inc[v].append((f, k))
    return inc


def test_closed_form_masks_on_a_real_quad_mesh(native):
    """Interior vertices of catmark_car whose faces are all quads: Blender's
    limit mask (n^2 V + 4 sum E + sum F) / (n (n + 5)); smooth boundary
    vertices: (E_prev + 4 V + E_next) / 6.  Built here from the formulas."""
    P, faces, _ = load("catmark_car")
    L = native.limit_stencils(native.Mesh.from_faces(P, faces), use_creases=False).to_scipy().tolil()
    nv = len(P)
    inc = quad_neighbourhoods(faces, nv)
    edge_faces = {}
    for f in faces:
        for k in range(len(f)):
            e = frozenset((f[k], f[(k + 1) % len(f)]))
            edge_faces[e] = edge_faces.get(e, 0) + 1
    checked_interior = checked_boundary = 0
    for v in range(nv):
        ring = inc[v]
        if not ring or any(len(f) != 4 for f, _ in ring):
            continue
        nbrs = {f[(k + 1) % 4] for f, k in ring} | {f[(k + 3) % 4] for f, k in ring}
        boundary = [w for w in nbrs if edge_faces[frozenset((v, w))] == 1]
        expect = {}
        if not boundary:
            n = len(ring)
            if len(nbrs) != n:
                continue
            d = n * (n + 5)
            expect[v] = n * n / d
            for f, k in ring:
                expect[f[(k + 2) % 4]] = expect.get(f[(k + 2) % 4], 0) + 1 / d
            for w in nbrs:
                expect[w] = expect.get(w, 0) + 4 / d
            checked_interior += 1
        elif len(boundary) == 2 and len(ring) >= 2:
            expect = {v: 4 / 6, boundary[0]: 1 / 6, boundary[1]: 1 / 6}
            checked_boundary += 1
        else:
            continue
        row = dict(zip(L.rows[v], L.data[v]))
        for j in set(row) | set(expect):
            assert abs(row.get(j, 0) - expect.get(j, 0)) < 1e-12, (v, j)
    assert checked_interior > 500 and checked_boundary > 20


def test_degenerate_faces_are_refused_with_a_count(native):
    P, faces, _ = load("catmark_nonman_edges")
    with pytest.raises(native.PiaError) as info:
        native.interpolate(native.Mesh.from_faces(P, faces))
    assert info.value.code == "DEGENERATE_FACE"
    assert "14 degenerate faces" in str(info.value)


def grid(n=4):
    P = np.array([(i, j, 0.1 * np.sin(i + j)) for j in range(n + 1) for i in range(n + 1)], np.float32)
    faces = [[j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
             for j in range(n) for i in range(n)]
    return P, faces


@pytest.mark.parametrize("case, code", [
    ("nan", "NONFINITE"), ("face_size", "FACE_SIZE"), ("index", "INDEX_RANGE"),
    ("no_faces", "EMPTY_MESH"), ("no_vertices", "EMPTY_MESH"), ("crease", "INVALID_ARGUMENT"),
])
def test_bad_input_raises_with_code(native, case, code):
    P, faces = grid()
    kwargs = {}
    if case == "nan":
        P[3, 1] = np.nan
    elif case == "face_size":
        faces[2] = faces[2][:2]
    elif case == "index":
        faces[1][2] = len(P) + 4
    elif case == "no_faces":
        faces = []
    elif case == "no_vertices":
        P, faces = np.zeros((0, 3), np.float32), []
    elif case == "crease":
        kwargs = dict(edges=np.array([[0, 1]], np.int32), edge_creases=np.array([2.0], np.float32))
    mesh = native.Mesh.from_faces(P, faces, **kwargs)
    with pytest.raises(native.PiaError) as info:
        native.interpolate(mesh)
    assert info.value.code == code
    assert len(str(info.value)) > 15


@pytest.mark.parametrize("option", [dict(quality=0), dict(quality=11), dict(tolerance=-1.0),
                                    dict(method="NEWTON"), dict(boundary_smooth="SOME"), dict(max_iterations=0),
                                    dict(threads=-1), dict(threads=1.5), dict(opensubdiv_version="3.x"),
                                    dict(opensubdiv_version=-1), dict(opensubdiv_version=(3, 7, 0, 1)),
                                    dict(opensubdiv_version=True), dict(solve_flags=("SIDEWAYS",)),
                                    dict(solve_flags="FIRST")])
def test_bad_options(native, option):
    P, faces = grid()
    with pytest.raises(native.PiaError):
        native.interpolate(native.Mesh.from_faces(P, faces), **option)


def test_progress_cancel_and_max_iterations(native):
    P, faces = grid(8)
    mesh = native.Mesh.from_faces(P, faces)
    seen = []
    cage, report = native.interpolate(mesh, progress=lambda it, err: seen.append((it, err)) and False)
    assert report.converged and len(seen) >= report.iterations
    with pytest.raises(native.PiaCancelled):
        native.interpolate(mesh, method="PIA", progress=lambda it, err: it >= 2)
    cage, report = native.interpolate(mesh, method="PIA", max_iterations=3)
    assert report.status == "MAX_ITERATIONS" and not report.converged and report.iterations == 3
    assert report.max_error_relative < report.initial_max_error_relative
    assert len(report.history) == 3 and np.all(np.diff(report.history) < 0)


def test_every_method_reaches_the_tolerance(native):
    P, faces, _ = load("double-torus")
    mesh = native.Mesh.from_faces(P, faces)
    L = native.limit_stencils(mesh).to_scipy()
    d = diagonal(P)
    # CG needs L = D S, S symmetric: closed meshes have that form (double
    # torus: c_i = 1 / (n_i (n_i + 5))), boundary rows break it.
    P_open, faces_open, _ = load("catmark_car")
    with pytest.raises(native.PiaError, match="CG needs"):
        native.interpolate(native.Mesh.from_faces(P_open, faces_open), method="CG")
    for method in native.METHODS:
        cage, report = native.interpolate(mesh, method=method, tolerance=1e-6)
        assert report.converged, (method, report)
        err = np.linalg.norm(L @ cage.astype(np.float64) - P, axis=1).max() / d
        assert err <= 1.5e-6, (method, err)


def test_fast_gauss_seidel_and_the_solve_flags(native):
    """GS_PIA_FAST and the SPIA_SOLVE_* flags by name: every combination
    reaches the tolerance (measured here with the stencils), and on a table
    large enough for the level layout and pipelined sweeps (a rough torus
    of 54,000 vertices) the cage is the same for 1, 2 and 3 threads, and
    the same to the bit with the residual passes kept from AVX (NO_AVX)."""
    assert native.METHODS[6] == "GS_PIA_FAST" and native.SOLVE_FLAGS == dict(FIRST_STEP=1, MULTICOLOUR=2,
                                                                             DOUBLE_SWEEPS=4, NO_AVX=8)
    P, faces, _ = load("double-torus")
    mesh = native.Mesh.from_faces(P, faces)
    L = native.limit_stencils(mesh).to_scipy()
    for method, flags in (("GS_PIA", ("MULTICOLOUR",)), ("GS_PIA", ("FIRST_STEP", "MULTICOLOUR")),
                          ("GS_PIA_FAST", ()), ("GS_PIA_FAST", "FIRST_STEP"), ("GS_PIA_FAST", ("DOUBLE_SWEEPS",))):
        cage, report = native.interpolate(mesh, method=method, solve_flags=flags)
        assert report.converged and report.method == method, (method, flags, report)
        err = np.linalg.norm(L @ cage.astype(np.float64) - P, axis=1).max() / diagonal(P)
        assert err <= 1.5e-6, (method, flags, err)
    nu, nv = 300, 180
    u, v = np.meshgrid(2 * np.pi * np.arange(nu) / nu, 2 * np.pi * np.arange(nv) / nv)
    r = 0.7 * (1 + 0.004 * np.random.default_rng(5).standard_normal(u.shape))
    P = np.stack([(2 + r * np.cos(v)) * np.cos(u), (2 + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1)
    P = P.reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv))
    quads = np.stack([j * nu + i, j * nu + (i + 1) % nu, (j + 1) % nv * nu + (i + 1) % nu, (j + 1) % nv * nu + i], -1)
    stencils = native.limit_stencils(native.Mesh(P, np.full(nu * nv, 4, np.int32), quads.reshape(-1)))
    cages = [stencils.solve(P, method="GS_PIA_FAST", threads=t, solve_flags=("FIRST_STEP",)) for t in (1, 2, 3)]
    assert all(report.converged and report.method == "GS_PIA_FAST" for _cage, report in cages)
    assert all(np.array_equal(cage, cages[0][0]) for cage, _report in cages[1:])
    assert all(np.array_equal(report.history, cages[0][1].history) for _cage, report in cages[1:])
    # The layout is built on the table's threads (the weights coded range by
    # range): built on 1 and on 3, it solves to the same cage.
    mesh = native.Mesh(P, np.full(nu * nv, 4, np.int32), quads.reshape(-1))
    for threads in (1, 3):
        other = native.limit_stencils(mesh, threads=threads).solve(P, method="GS_PIA_FAST", threads=2,
                                                                   solve_flags=("FIRST_STEP",))
        assert np.array_equal(other[0], cages[0][0]) and np.array_equal(other[1].history, cages[0][1].history)
    for flags in (("FIRST_STEP",), ("DOUBLE_SWEEPS",)):
        with_avx, without = (stencils.solve(P, method="GS_PIA_FAST", threads=2, solve_flags=flags + extra)
                             for extra in ((), ("NO_AVX",)))
        assert np.array_equal(with_avx[0], without[0]), flags
        assert np.array_equal(with_avx[1].history, without[1].history), flags
        assert (with_avx[1].max_error, with_avx[1].mean_error) == (without[1].max_error, without[1].mean_error)
    cage, report = stencils.solve(P)
    assert report.method == "GS_PIA_FAST", report.method  # what AUTO takes on a rough target


def test_thread_count_changes_nothing(native):
    """The threads option reaches the library (a negative count is refused
    there too) and neither the stencils nor the cage depend on it."""
    P, faces, _ = load("bunny")
    mesh = native.Mesh.from_faces(P, faces)
    tables = [native.limit_stencils(mesh, threads=t) for t in (1, 2, 0)]
    for t in tables[1:]:
        assert np.array_equal(t.offsets, tables[0].offsets) and np.array_equal(t.indices, tables[0].indices)
        assert np.array_equal(t.weights, tables[0].weights)
    cages = [native.interpolate(mesh, threads=t)[0] for t in (1, 2)]
    assert np.array_equal(cages[0], cages[1])
    opts, _ = native._options(threads=2)
    assert opts.threads == 2


def test_staged_catmull_clark_moves_exactly_the_boundary(native):
    """A staged solve sweeps the boundary vertices first, with the interior
    held: stopped at the end of that stage, the vertices that moved are
    exactly those on an edge of one face (found here from the faces), also
    where vertex creases (0.3) send some of them, and some interior ones,
    to OpenSubdiv before their fan is read, and where semi-sharp edges do so
    after.  Run to the end it reaches the unstaged cage."""
    nu, nv = 14, 11
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1))
    rng = np.random.default_rng(3)
    P = np.stack([i, j, 0.3 * np.sin(i / 3.0) * np.cos(j / 2.0)], -1).reshape(-1, 3)
    P = (P + rng.normal(0, 0.05, P.shape)).astype(np.float32)
    a = (j[:-1, :-1] * (nu + 1) + i[:-1, :-1]).ravel()
    quads = np.stack([a, a + 1, a + nu + 2, a + nu + 1], -1).astype(np.int32)
    sides = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], -1).reshape(-1, 2), axis=1)
    edges, uses = np.unique(sides, axis=0, return_counts=True)
    boundary = np.zeros(len(P), bool)
    boundary[edges[uses == 1].ravel()] = True
    vertex_creases = np.zeros(len(P), np.float32)
    vertex_creases[rng.choice(np.flatnonzero(boundary), 6, replace=False)] = 0.3
    vertex_creases[rng.choice(np.flatnonzero(~boundary), 6, replace=False)] = 0.3
    edge_creases = np.where(rng.random(len(edges)) < 0.1, 0.5, 0.0).astype(np.float32)
    mesh = native.Mesh(P, np.full(len(quads), 4, np.int32), quads.ravel(), edges.astype(np.int32), edge_creases,
                       vertex_creases)
    together, r1 = native.interpolate(mesh, method="GS_PIA", tolerance=1e-8)
    staged, r2 = native.interpolate(mesh, method="GS_PIA", tolerance=1e-8, staged=True)
    assert r2.stage_iterations[0] > 0 and r2.stage_iterations[1] > 0
    assert sum(r2.stage_iterations) == r2.iterations
    assert np.abs(together - staged).max() < 1e-5 * np.abs(P).max()
    part, r3 = native.interpolate(mesh, method="GS_PIA", tolerance=1e-8, staged=True,
                                  max_iterations=r2.stage_iterations[0])
    assert r3.status == "MAX_ITERATIONS" and tuple(r3.stage_iterations) == (r2.stage_iterations[0], 0)
    moved = np.any(part != P, axis=1)
    assert np.array_equal(moved, boundary), (np.flatnonzero(moved != boundary), boundary.sum())


def test_an_edge_listed_twice_takes_its_largest_crease(native):
    """An edge listed more than once, either way round, takes its largest
    crease, wherever the repeats are: an open grid of quads with edges
    creased 1.0 (infinitely sharp: closed-form crease rows) and 0.5
    (semi-sharp: rings read from the mesh, vertices with two creased
    edges), some listed again reversed with a smaller crease before and
    after, some uncreased ones again with 0.7, gives the table of the list
    with each edge once at its largest, weight for weight: Catmull-Clark at
    quality 1 and 3, and Loop on the grid cut into triangles."""
    nu, nv = 12, 9
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1))
    rng = np.random.default_rng(11)
    P = np.stack([i, j, 0.3 * np.sin(i / 3.0) * np.cos(j / 2.0)], -1).reshape(-1, 3).astype(np.float32)
    a = (j[:-1, :-1] * (nu + 1) + i[:-1, :-1]).ravel()
    quads = np.stack([a, a + 1, a + nu + 2, a + nu + 1], -1).astype(np.int32)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]).astype(np.int32)
    for faces in (quads, tris):
        sides = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], -1).reshape(-1, 2), axis=1)
        edges = np.unique(sides, axis=0).astype(np.int32)
        creases = rng.choice(np.array([0.0, 0.5, 1.0], np.float32), len(edges), p=[0.6, 0.25, 0.15])
        creased, plain = np.flatnonzero(creases > 0), np.flatnonzero(creases == 0)
        again = rng.choice(creased, len(creased) // 2, replace=False)
        raised = rng.choice(plain, 5, replace=False)
        largest = creases.copy()
        largest[raised] = 0.7
        listed = np.concatenate([edges[again][:, ::-1], edges, edges[again][:, ::-1], edges[raised]])
        listed_creases = np.concatenate([0.5 * creases[again], creases, 0.3 * creases[again],
                                         np.full(len(raised), 0.7, np.float32)]).astype(np.float32)
        sizes = np.full(len(faces), faces.shape[1], np.int32)
        once = native.Mesh(P, sizes, faces.ravel(), edges, largest)
        repeated = native.Mesh(P, sizes, faces.ravel(), listed.astype(np.int32), listed_creases)
        runs = [("CATMULL_CLARK", 1), ("CATMULL_CLARK", 3)] if faces is quads else [("LOOP", 3)]
        for scheme, quality in runs:
            want = native.limit_stencils(once, scheme=scheme, quality=quality)
            got = native.limit_stencils(repeated, scheme=scheme, quality=quality)
            assert np.array_equal(want.offsets, got.offsets), (scheme, quality)
            assert np.array_equal(want.indices, got.indices), (scheme, quality)
            assert np.array_equal(want.weights, got.weights), (scheme, quality)
        # the creases matter here: without them the table is another
        plain_table = native.limit_stencils(once, scheme=runs[0][0], use_creases=False)
        assert not np.array_equal(plain_table.weights, want.weights)


def test_opensubdiv_version(native):
    """Versions as Blender gives them (a tuple), as strings or as the number;
    after 3.6.0 the centre of two double-sided fins is infinitely sharp (its
    row is the vertex alone), up to 3.6.0 it is not; elsewhere, and for
    meshes without such vertices, the rule changes nothing."""
    number = native.opensubdiv_version_number
    assert number(None) == number(0) == number("") == 0
    assert number((3, 7, 0)) == number([3, 7]) == number("3.7.0") == number("3.7") == number(30700) == 30700
    assert number((3, 6, 0)) == 30600 and number("3") == 30000
    opts, _ = native._options(opensubdiv_version=(3, 7, 0))
    assert opts.opensubdiv_version == 30700
    P = [(x, y, 0.1 * ((3 * x + 5 * y) % 3)) for y in range(3) for x in range(3)]
    P = np.array(P + [(1.5, 1.2, 1.0), (0.8, 1.5, 0.9)], np.float32)
    faces = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7],
             [4, 5, 9], [4, 9, 5], [4, 10, 7], [4, 7, 10]]
    mesh = native.Mesh.from_faces(P, faces)
    rows = {v: native.limit_stencils(mesh, opensubdiv_version=v).to_scipy().toarray()
            for v in (None, "3.5.0", "3.6.0", "3.7.0", (5, 0, 0))}
    for v in ("3.5.0", "3.6.0"):
        assert np.array_equal(rows[v], rows[None])
    for v in ("3.7.0", (5, 0, 0)):
        centre = np.zeros(len(P))
        centre[4] = 1.0
        assert np.array_equal(rows[v][4], centre)
        assert np.array_equal(np.delete(rows[v], 4, axis=0), np.delete(rows[None], 4, axis=0))
    assert not np.array_equal(rows[None][4], rows["3.7.0"][4])
    # Loop ignores it.
    tri = [f for f in faces if len(f) == 3] + [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6],
                                                [4, 5, 8], [4, 8, 7]]
    tri_mesh = native.Mesh.from_faces(P, tri)
    loop = [native.limit_stencils(tri_mesh, scheme="LOOP", opensubdiv_version=v).to_scipy().toarray()
            for v in (None, "3.7.0")]
    assert np.array_equal(loop[0], loop[1])
    # A scan's cage for either version interpolates in that version's terms.
    P2, faces2, _ = load("bunny")
    mesh2 = native.Mesh.from_faces(P2, faces2)
    assert np.array_equal(native.limit_stencils(mesh2, opensubdiv_version="3.7.0").weights,
                          native.limit_stencils(mesh2).weights)


def test_agrees_with_a_sparse_direct_solve(native):
    P, faces, _ = load("mushroom")
    mesh = native.Mesh.from_faces(P, faces)
    L = native.limit_stencils(mesh).to_scipy().tocsc()
    exact = scipy.sparse.linalg.spsolve(L, P.astype(np.float64))
    cage, report = native.interpolate(mesh, tolerance=1e-7)
    assert np.abs(cage - exact).max() / diagonal(P) < 1e-5


def test_solve_from_an_initial_cage(native):
    """A first iterate: the cage of the mushroom with one vertex moved a
    little, started from the cage before the move, lands on scipy's direct
    solution with fewer GS-PIA iterations; from the exact cage it does
    nothing; a wrong shape or a NaN is refused."""
    P, faces, _ = load("mushroom")
    mesh = native.Mesh.from_faces(P, faces)
    stencils = native.limit_stencils(mesh)
    L = stencils.to_scipy().tocsc()
    before, _ = stencils.solve(P, method="GS_PIA", tolerance=1e-7)
    moved = P.astype(np.float32).copy()
    moved[11, 2] += 1e-3 * diagonal(P)
    exact = scipy.sparse.linalg.spsolve(L, moved.astype(np.float64))
    cold_cage, cold = stencils.solve(moved, method="GS_PIA", tolerance=1e-7)
    warm_cage, warm = stencils.solve(moved, initial=before, method="GS_PIA", tolerance=1e-7)
    assert warm.converged and 0 < warm.iterations < cold.iterations, (warm.iterations, cold.iterations)
    assert np.abs(warm_cage - exact).max() / diagonal(P) < 1e-5
    _same, none = stencils.solve(moved, initial=warm_cage, method="GS_PIA", tolerance=1e-6)
    assert none.iterations == 0
    with pytest.raises(native.PiaError, match="initial cage of"):
        stencils.solve(moved, initial=before[:-1])
    bad = before.copy()
    bad[3, 0] = np.nan
    with pytest.raises(native.PiaError) as info:
        stencils.solve(moved, initial=bad)
    assert info.value.code == "NONFINITE" and info.value.index == 3


def test_mesh_arrays_are_not_copied(native):
    P, faces = grid()
    sizes = np.full(len(faces), 4, np.int32)
    fv = np.asarray(faces, np.int32).ravel()
    mesh = native.Mesh(P, sizes, fv)
    assert np.shares_memory(mesh.positions, P)
    assert np.shares_memory(mesh.face_sizes, sizes) and np.shares_memory(mesh.face_vertices, fv)
    assert mesh._c().positions[0] == P[0, 0]  # the C struct points at the same floats


def test_stencil_arrays_are_copied_only_when_asked(native):
    """A table that is only solved with holds no numpy copy of itself; the
    arrays, once asked for, are one copy, the same each time, and agree
    with the library's own solve."""
    P, faces = grid()
    mesh = native.Mesh(P, np.full(len(faces), 4, np.int32), np.asarray(faces, np.int32).ravel())
    stencils = native.limit_stencils(mesh)
    cage, report = stencils.solve(P, tolerance=1e-7)
    assert stencils._arrays is None and stencils.row_count == len(P)
    weights = stencils.weights
    assert stencils.weights is weights and len(stencils.offsets) == len(P) + 1
    assert stencils.offsets[-1] == len(weights) == len(stencils.indices)
    limit = stencils.apply(cage)
    assert np.abs(limit - P).max() <= 2e-7 * np.abs(P).max()


def test_binding_runs_without_blender():
    code = ("import sys; sys.path.insert(0, %r); from subdiv_pia import native; "
            "assert native.available(); assert 'bpy' not in sys.modules; print(native.version())" % ADDON_DIR)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().count(".") == 2


def test_the_package_holds_every_public_name_of_its_modules(native):
    # `from spia import X` for whatever a module of the binding defines, and
    # __all__ names only what the package holds.
    import importlib
    import os
    import types
    modules = sorted(n[:-3] for n in os.listdir(native.__path__[0]) if n.endswith(".py") and n != "__init__.py")
    assert {"library", "header", "mesh", "interpolation", "refinement", "usd", "fitting"} <= set(modules)
    missing = []
    for name in modules:
        module = importlib.import_module(native.__name__ + "." + name)
        for key, value in vars(module).items():
            if not key.startswith("_") and not isinstance(value, types.ModuleType) \
                    and getattr(native, key, None) is not value:
                missing.append("%s.%s" % (name, key))
    assert not missing, "not the package's: %s" % missing
    assert all(hasattr(native, name) for name in native.__all__)
