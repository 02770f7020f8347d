# SPDX-License-Identifier: GPL-3.0-or-later
"""Loop subdivision: the library's stencils against the papers' formulas
built here (loop_oracle.py), interpolation, solvers, the staged procedure."""
import numpy as np
import pytest

import spheres
from conftest import load
from loop_oracle import hoppe_mask, loop_matrix, refine_boundary_vertex

SCANS = ["bunny", "elephant-with-holes", "bun_zipper", "teapot"]


def icosphere(subdivisions=2):
    P, F = spheres.icosphere(subdivisions)
    P *= 1 + 0.05 * np.sin(5 * P[:, :1])  # not a perfect sphere
    return P.astype(np.float32), F.tolist()


def torus(nu=16, nv=9):
    P = [((2 + 0.6 * np.cos(v)) * np.cos(u), (2 + 0.6 * np.cos(v)) * np.sin(u), 0.6 * np.sin(v))
         for v in np.linspace(0, 2 * np.pi, nv, endpoint=False) for u in np.linspace(0, 2 * np.pi, nu, endpoint=False)]
    F = []
    for j in range(nv):
        for i in range(nu):
            a, b = j * nu + i, j * nu + (i + 1) % nu
            c, d = ((j + 1) % nv) * nu + (i + 1) % nu, ((j + 1) % nv) * nu + i
            F += [[a, b, c], [a, c, d]]
    return np.array(P, np.float32), F


def bipyramid(n):
    """A ring of n vertices and two poles of valence n."""
    ring = [(np.cos(t), np.sin(t), 0.1 * np.cos(3 * t)) for t in np.linspace(0, 2 * np.pi, n, endpoint=False)]
    P = np.array(ring + [(0, 0, 1.2), (0, 0, -0.9)], np.float32)
    F = [[i, (i + 1) % n, n] for i in range(n)] + [[(i + 1) % n, i, n + 1] for i in range(n)]
    return P, F


def open_grid(n=6):
    P = np.array([(i, j, 0.2 * np.sin(i) * np.cos(j)) for j in range(n + 1) for i in range(n + 1)], np.float32)
    F = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            F += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]] if (i + j) % 2 else \
                 [[a, a + 1, a + n + 1], [a + 1, a + n + 2, a + n + 1]]
    return P, F


GENERATED = {"icosphere": icosphere, "torus": torus, "bipyramid3": lambda: bipyramid(3),
             "bipyramid14": lambda: bipyramid(14), "open grid": open_grid}


def mesh_named(name):
    if name in GENERATED:
        return GENERATED[name]()
    P, F, _ = load(name)
    return P, F


CASES = SCANS + list(GENERATED)


@pytest.mark.parametrize("rule", ["SMOOTH", "HOPPE"])
@pytest.mark.parametrize("name", CASES)
def test_stencils_match_the_papers_formulas_and_interpolate(native, name, rule):
    P, F = mesh_named(name)
    mesh = native.Mesh.from_faces(P, F)
    ours = native.limit_stencils(mesh, scheme="LOOP", boundary_rule=rule).to_scipy()
    oracle = loop_matrix(len(P), F, rule)
    assert abs(ours - oracle).max() < 1e-12
    cage, report = native.interpolate(mesh, scheme="LOOP", boundary_rule=rule)
    assert report.converged, report.summary()
    d = np.linalg.norm(P.max(0) - P.min(0))
    err = np.linalg.norm(oracle @ cage.astype(float) - P, axis=1).max() / d
    assert err <= 1e-5


@pytest.mark.parametrize("boundary_smooth", ["ALL", "PRESERVE_CORNERS"])
def test_smooth_rule_corners_follow_boundary_smooth(native, boundary_smooth):
    P, F = open_grid()
    ours = native.limit_stencils(native.Mesh.from_faces(P, F), scheme="LOOP",
                                 boundary_smooth=boundary_smooth).to_scipy()
    oracle = loop_matrix(len(P), F, "SMOOTH", boundary_smooth)
    assert abs(ours - oracle).max() < 1e-12


@pytest.mark.parametrize("types", [(True, True, True), (False, True, True), (False, True, False),
                                   (True, False, True), (False, False, True), (False, False, False)])
def test_hoppe_masks_are_the_limit_of_boundary_refinement(native, types):
    """The six masks against refining a boundary 60 times with the rules."""
    pts = np.random.default_rng(7).normal(size=(3, 3))
    limit = refine_boundary_vertex(*pts, types, 60)
    mask = hoppe_mask(*types)
    assert np.allclose(limit, mask @ pts, atol=1e-12)
    if types == (True, True, True):
        assert np.allclose(mask, [1 / 6, 2 / 3, 1 / 6])
    if types == (True, False, True):
        assert np.allclose(mask, [1 / 5, 3 / 5, 1 / 5])


@pytest.mark.parametrize("name", ["elephant-with-holes", "teapot", "open grid"])
def test_staged_reaches_the_same_cage(native, name):
    P, F = mesh_named(name)
    mesh = native.Mesh.from_faces(P, F)
    together, r1 = native.interpolate(mesh, scheme="LOOP", boundary_rule="HOPPE", tolerance=1e-7)
    staged, r2 = native.interpolate(mesh, scheme="LOOP", boundary_rule="HOPPE", tolerance=1e-7, staged=True)
    assert r1.converged and r2.converged
    assert r2.stage_iterations[0] > 0 and r2.stage_iterations[1] > 0
    assert sum(r2.stage_iterations) == r2.iterations
    d = np.linalg.norm(P.max(0) - P.min(0))
    assert np.abs(together - staged).max() / d < 1e-5


@pytest.mark.parametrize("name", CASES)
def test_gs_pia_and_wpia_against_pia(native, name):
    """On real meshes, and on the generated ones with scan-like noise: a
    perfectly smooth target has its error in the eigenvalues near 1, where
    plain PIA is already fast (5 iterations on the clean torus, against 9
    for GS-PIA and 15 for WPIA), and AUTO covers that case (below)."""
    P, F = mesh_named(name)
    if name in GENERATED:
        d = np.linalg.norm(P.max(0) - P.min(0))
        P = P + np.random.default_rng(3).normal(scale=0.005 * d, size=P.shape).astype(np.float32)
    mesh = native.Mesh.from_faces(P, F)
    its = {}
    for method in ("PIA", "WPIA", "GS_PIA"):
        cage, report = native.interpolate(mesh, scheme="LOOP", method=method, tolerance=1e-6)
        assert report.converged, (method, report.summary())
        its[method] = report.iterations
    assert its["GS_PIA"] < its["PIA"], its
    assert its["WPIA"] <= its["PIA"], its


def test_wpia_weight_is_two_over_the_spectrum_ends(native):
    import scipy.sparse.linalg as sla
    P, F = mesh_named("bunny")
    mesh = native.Mesh.from_faces(P, F)
    L = native.limit_stencils(mesh, scheme="LOOP").to_scipy()
    lo = sla.eigs(L, k=1, sigma=0, return_eigenvectors=False).real[0]
    _, report = native.interpolate(mesh, scheme="LOOP", method="WPIA")
    best = 2 / (lo + 1.0)
    # Power iterations approach lambda_min from above: the weight errs small.
    assert 0.9 * best <= report.weight <= best * (1 + 1e-9)


def test_non_triangles_and_non_manifold_are_refused(native):
    P, F, _ = load("mushroom")
    with pytest.raises(native.PiaError) as info:
        native.interpolate(native.Mesh.from_faces(P, F), scheme="LOOP")
    assert info.value.code == "TOPOLOGY" and "208 of 240 faces are not" in str(info.value)
    # A fin: three triangles on one edge.
    P = np.array([(0, 0, 0), (1, 0, 0), (0.5, 1, 0), (0.5, -1, 0), (0.5, 0, 1)], np.float32)
    F = [[0, 1, 2], [1, 0, 3], [0, 1, 4]]
    with pytest.raises(native.PiaError) as info:
        native.interpolate(native.Mesh.from_faces(P, F), scheme="LOOP", boundary_rule="HOPPE")
    assert info.value.code == "TOPOLOGY" and "non-manifold" in str(info.value)
    cage, report = native.interpolate(native.Mesh.from_faces(P, F), scheme="LOOP")  # SMOOTH: sharp, as OpenSubdiv
    assert report.converged


@pytest.mark.parametrize("name", CASES)
def test_auto_is_never_behind_pia_or_gs_pia(native, name):
    P, F = mesh_named(name)
    mesh = native.Mesh.from_faces(P, F)
    its = {m: native.interpolate(mesh, scheme="LOOP", method=m)[1].iterations for m in ("AUTO", "PIA", "GS_PIA")}
    # Every method does one stencil product per iteration (GS-PIA's sweep
    # estimates its own error and computes the residual only when that
    # reaches the tolerance).  AUTO takes CG or Chebyshev on smooth targets
    # and GS-PIA on rough ones.
    assert its["AUTO"] <= its["PIA"] + 1, its
    assert its["AUTO"] <= its["GS_PIA"], its


@pytest.mark.parametrize("rule", ["SMOOTH", "HOPPE"])
@pytest.mark.parametrize("name", ["bunny", "elephant-with-holes", "teapot", "open grid"])
def test_refined_limit_surface_passes_through_the_points(native, name, rule):
    """The preview surface: refining with the subdivision rules and then
    taking limit positions must agree with the limit masks of the cage (for
    HOPPE that checks the derived masks against the rules once more), and a
    deeper refinement keeps the vertices of a shallower one in place."""
    P, F = mesh_named(name)
    cage, report = native.interpolate(native.Mesh.from_faces(P, F), scheme="LOOP", boundary_rule=rule)
    cage_mesh = native.Mesh.from_faces(cage, F)
    d = np.linalg.norm(P.max(0) - P.min(0))
    previous = None
    for levels in (0, 1, 2):
        pos, sizes, faces = native.refine(cage_mesh, levels, boundary_rule=rule)
        assert np.all(sizes == 3) and len(sizes) == len(F) * 4 ** levels
        assert len(faces) == 3 * len(sizes) and faces.min() >= 0 and faces.max() < len(pos)
        assert np.linalg.norm(pos[:len(P)] - P, axis=1).max() / d <= 1e-5
        if previous is not None:
            assert np.abs(pos[:len(previous)] - previous).max() / d <= 1e-6
        previous = pos


def test_refine_refuses_catmull_clark_and_loop_quads(native):
    P, F, _ = load("mushroom")
    with pytest.raises(native.PiaError, match="not triangles|are not"):
        native.refine(native.Mesh.from_faces(P, F), 1)
    with pytest.raises(native.PiaError, match="Catmull-Clark itself"):
        native.refine(native.Mesh.from_faces(P, F), 1, scheme="CATMULL_CLARK")
