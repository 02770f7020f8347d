# SPDX-License-Identifier: GPL-3.0-or-later
"""OpenSubdiv's regression shapes (read from OpenSubdiv's source package at
build/src/opensubdiv-3.6.0, never copied here: tools/osd_shapes.py) against
a dense least-squares solve.

Some of them have singular limit matrices (catmark_val2_interior,
catmark_val2_foldover, ...): no cage reaches every vertex there.  The
library then returns a least-squares cage; its residual P - L V is unique
even where L is singular, so it must equal that of numpy's
np.linalg.lstsq(L, P) vertex by vertex.  The vertices it flags unreachable
must be exactly those that miss by more than the tolerance.
"""
import os
import sys

import numpy as np
import pytest

from conftest import ROOT, load

sys.path.insert(0, os.path.join(ROOT, "tools"))
import osd_shapes  # noqa: E402

TOLERANCE = 1e-6       # the solve's (relative to the bounding-box diagonal)
RESIDUAL_MATCH = 1e-6  # residual vectors of the library and of lstsq, relative

# The shapes Blender can express, and those with faces that use a vertex
# twice (the quad poles, the nonman_edges ones) as cleanup leaves them.
SHAPES = osd_shapes.load_testable() if osd_shapes.available() else []
SHAPE_NAMES = [s.name for s in SHAPES]
BY_NAME = {s.name: s for s in SHAPES}
# Must stay in the set (with the singular ones the brief of the least-squares
# fallback names).
REQUIRED = ("catmark_val2_interior", "catmark_val2_foldover", "catmark_val2_back2back", "catmark_val2_nonman",
            "loop_val2_interior", "catmark_nonman_edges_dissolved", "catmark_nonman_verts",
            "catmark_nonman_edge100", "catmark_nonman_quadpole8_dissolved", "catmark_nonman_bareverts",
            "loop_nonman_edges_dissolved", "loop_nonman_verts", "loop_nonman_edge100")

CATMARK_SETTINGS = [dict(boundary_smooth=b, quality=q, use_creases=c)
                    for b in ("ALL", "PRESERVE_CORNERS") for q in (1, 3, 6) for c in (True, False)]
LOOP_SETTINGS = ([dict(boundary_rule="SMOOTH", boundary_smooth=b, use_creases=c)
                  for b in ("ALL", "PRESERVE_CORNERS") for c in (True, False)]
                 + [dict(boundary_rule="HOPPE")])


def _ids(settings):
    return "-".join("%s" % ("creases" if v is True else "nocreases" if v is False else v)
                    for v in settings.values())


# lstsq of one table is shared by the settings that give the same table
# (boundary and quality change nothing on many shapes).
_LSTSQ = {}


def lstsq_residual(L, P):
    """P - L x for numpy's dense least-squares solution x, computed per
    connected block of L (the problem splits over them, exactly)."""
    import scipy.sparse.csgraph
    key = (L.shape, L.indptr.tobytes(), L.indices.tobytes(), L.data.tobytes(), P.tobytes())
    if key in _LSTSQ:
        return _LSTSQ[key]
    n = L.shape[0]
    pattern = (abs(L) + abs(L).T).tocsr()
    count, label = scipy.sparse.csgraph.connected_components(pattern, directed=False)
    residual = np.zeros_like(P)
    for part in range(count):
        rows = np.flatnonzero(label == part)
        block = L[rows][:, rows].toarray()
        x = np.linalg.lstsq(block, P[rows], rcond=None)[0]
        residual[rows] = P[rows] - block @ x
    assert residual.shape == (n, 3)
    _LSTSQ[key] = residual
    return residual


def expected_refusal(mesh, stencil_options):
    """Why a scheme must refuse the mesh ('' if it must not): two-phase
    Doo-Sabin needs a closed manifold mesh (every edge on two faces), Loop
    with Hoppe's rules a manifold one (no edge on more than two faces, each
    vertex's faces one fan)."""
    scheme = stencil_options.get("scheme", "CATMULL_CLARK")
    hoppe = scheme == "LOOP" and stencil_options.get("boundary_rule") == "HOPPE"
    if scheme != "DOO_SABIN" and not hoppe:
        return ""
    sizes = np.asarray(mesh.face_sizes)
    corners = np.asarray(mesh.face_vertices)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    faces = [corners[a:a + k].tolist() for a, k in zip(starts, sizes)]
    edge_faces = {}
    for f, face in enumerate(faces):
        for a, b in zip(face, face[1:] + face[:1]):
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(f)
    counts = np.array([len(v) for v in edge_faces.values()])
    if (counts > 2).any():
        return "an edge on more than two faces"
    if scheme == "DOO_SABIN" and (counts < 2).any():
        return "a boundary"
    # Each vertex's faces, joined through the edges they share at it, one fan.
    around = {}
    for f, face in enumerate(faces):
        for v in face:
            around.setdefault(v, set()).add(f)
    for v, mine in around.items():
        seen, todo = set(), [next(iter(mine))]
        while todo:
            f = todo.pop()
            if f in seen:
                continue
            seen.add(f)
            for (a, b), fs in edge_faces.items():
                if v in (a, b) and f in fs:
                    todo.extend(g for g in fs if g in mine)
        if seen != mine:
            return "vertex %d joins separate fans" % v
    return ""


def check_least_squares(native, what, mesh, positions, stencil_options, solve_options=None):
    """Builds the table, solves, and checks the result against lstsq: the
    residual vectors, the unreachable flags and the report's figures."""
    try:
        stencils = native.limit_stencils(mesh, **stencil_options)
    except native.PiaError as error:
        # Only a refusal the scheme's own rules call for, with its reason.
        reason = expected_refusal(mesh, stencil_options)
        assert error.code == "TOPOLOGY" and reason and len(str(error)) > 20, (what, error.code, str(error), reason)
        return None
    assert not expected_refusal(mesh, stencil_options), (what, expected_refusal(mesh, stencil_options))
    L = stencils.to_scipy()
    P = positions.astype(np.float64)
    cage, report = stencils.solve(positions, tolerance=TOLERANCE, **(solve_options or {}))
    d = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    assert abs(report.diagonal - d) <= 1e-6 * d, (report.diagonal, d)
    ours = P - L @ cage.astype(np.float64)
    theirs = lstsq_residual(L, P)
    apart = np.linalg.norm(ours - theirs, axis=1) / d
    worst = int(np.argmax(apart))
    err = np.linalg.norm(ours, axis=1) / d
    flagged = np.asarray(report.unreachable, bool)
    summary = "%s: %s; residual %.3g vs lstsq's %.3g at vertex %d" % (
        what, report.summary(), err[worst], np.linalg.norm(theirs[worst]) / d, worst)
    assert apart[worst] <= RESIDUAL_MATCH, "residuals %.3g of the diagonal apart; %s" % (apart[worst], summary)
    assert report.unreachable_count == int(flagged.sum()), summary
    assert np.array_equal(report.unreachable_indices, np.flatnonzero(flagged)), summary
    reached = err[~flagged]
    assert reached.size == 0 or reached.max() <= TOLERANCE * (1 + 1e-6), (
        "vertex %d not flagged misses by %.3g; %s" % (np.flatnonzero(~flagged)[np.argmax(reached)], reached.max(),
                                                     summary))
    if flagged.any():
        assert err[flagged].min() > TOLERANCE * (1 - 1e-6), (
            "vertex %d flagged but within the tolerance (%.3g); %s" % (
                np.flatnonzero(flagged)[np.argmin(err[flagged])], err[flagged].min(), summary))
        assert report.status == "STAGNATED" and not report.converged, summary
        assert report.method == "LEAST_SQUARES", summary
        assert report.reachable_max_error_relative <= TOLERANCE * (1 + 1e-6), summary
        assert report.reachable_max_error_relative == pytest.approx(reached.max() if reached.size else 0.0,
                                                                    rel=1e-3, abs=1e-12), summary
    else:
        assert report.unreachable_count == 0
    assert report.max_error_relative == pytest.approx(err.max(), rel=1e-3, abs=1e-12), summary
    return report, err, flagged


def test_the_shapes_are_there():
    assert osd_shapes.available(), osd_shapes.missing_message()
    missing = [name for name in REQUIRED if name not in BY_NAME]
    assert not missing, missing
    assert len(SHAPES) > 90, len(SHAPES)


def test_tags_are_read_as_opensubdiv_does():
    """Creases and corners (sharpness 10 c^2), the boundary tag, and what Blender cannot show."""
    assert osd_shapes.available(), osd_shapes.missing_message()
    cube = osd_shapes.load("catmark_cube_creases1")
    assert cube.scheme == "CATMULL_CLARK" and cube.vertex_count == 8 and len(cube.faces) == 6
    assert len(cube.edges) == 12 and (cube.edge_sharpness > 0).sum() == 12
    s = cube.edge_sharpness[cube.edge_sharpness > 0]
    np.testing.assert_allclose(10 * cube.edge_creases[cube.edge_sharpness > 0].astype(np.float64) ** 2,
                               np.minimum(s, 10), rtol=1e-6)
    corners = osd_shapes.load("catmark_pyramid_creases1")
    assert (corners.vertex_sharpness > 0).sum() == 2
    assert osd_shapes.load("catmark_val2_interior").boundary == "EDGE_AND_CORNER"
    assert osd_shapes.load("catmark_edgenone").boundary == "NONE"
    assert osd_shapes.load("catmark_cube").boundary == "EDGE_ONLY"
    for name, why in (("catmark_hole_test1", "holes"), ("catmark_square_hedit4", "faceedit"),
                      ("catmark_chaikin1", "Chaikin"), ("catmark_smoothtris1", "smooth triangles"),
                      ("catmark_square_hedit0", "hierarchical edits"), ("bilinear_cube", "bilinear")):
        shape = osd_shapes.load(name)
        assert not shape.expressible and why in ", ".join(shape.inexpressible), (name, shape.inexpressible)
    for name in ("catmark_chaikin0", "catmark_smoothtris0", "catmark_val2_foldover", "loop_val2_interior"):
        assert osd_shapes.load(name).expressible, name
    # Faces that use a vertex twice: OpenSubdiv's degenerate polygons, which a
    # Blender mesh cannot hold; dissolved as the add-on's cleanup does.
    edges = osd_shapes.load("catmark_nonman_edges")
    assert not edges.expressible and edges.degenerate_face_count == 14
    dissolved = edges.dissolved()
    assert dissolved.expressible and dissolved.degenerate_face_count == 0
    assert [40, 41, 51] in dissolved.faces and [80, 72, 73] in dissolved.faces
    # 66 66 67 67, 80 80 80 81 and 109 109 109 109 keep two corners or fewer,
    # 94 95 94 96 repeats no corner in a row: the four go.
    assert len(dissolved.faces) == len(edges.faces) - 4
    # A pair that is not an edge: OpenSubdiv refuses the shape.
    with pytest.raises(ValueError, match="no edge"):
        osd_shapes.parse_obj("catmark_x", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nt crease 2/1/0 0 2 1.0\n")
    # Pairs, one sharpness each where there are several (indexed as OpenSubdiv does).
    quad = osd_shapes.parse_obj("catmark_x", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
                                             "t crease 4/3/0 0 1 2 3 2.5 7.0 12.0\nt corner 2/1/0 0 2 20\n")
    assert quad.creases_by_edge() == pytest.approx({frozenset((0, 1)): np.sqrt(0.25),
                                                    frozenset((2, 3)): 1.0})
    np.testing.assert_array_equal(quad.vertex_creases, [1, 0, 1, 0])


def _mesh(native, shape):
    return native.Mesh(**shape.mesh_arrays())


CATMARK = [n for n in SHAPE_NAMES if BY_NAME[n].scheme == "CATMULL_CLARK"]
TRIANGLES = [n for n in SHAPE_NAMES if BY_NAME[n].all_triangles]


@pytest.mark.parametrize("settings", CATMARK_SETTINGS, ids=_ids)
@pytest.mark.parametrize("name", CATMARK)
def test_catmull_clark_least_squares(native, name, settings):
    shape = BY_NAME[name]
    check_least_squares(native, "%s %s" % (name, _ids(settings)), _mesh(native, shape), shape.positions,
                        dict(scheme="CATMULL_CLARK", **settings))


@pytest.mark.parametrize("settings", LOOP_SETTINGS, ids=_ids)
@pytest.mark.parametrize("name", TRIANGLES)
def test_loop_least_squares(native, name, settings):
    shape = BY_NAME[name]
    check_least_squares(native, "%s loop %s" % (name, _ids(settings)), _mesh(native, shape), shape.positions,
                        dict(scheme="LOOP", **settings))


@pytest.mark.parametrize("name", SHAPE_NAMES)
def test_doo_sabin_least_squares(native, name):
    shape = BY_NAME[name]
    check_least_squares(native, "%s doo-sabin" % name, _mesh(native, shape), shape.positions,
                        dict(scheme="DOO_SABIN"))


@pytest.mark.parametrize("name, settings", [
    ("catmark_val2_interior", dict(use_creases=False)), ("catmark_val2_back2back", {}),
    ("catmark_val2_nonman", {})])
def test_singular_shapes_are_reported(native, name, settings):
    """Shapes whose limit matrices are singular with targets out of their
    range (lstsq leaves a residual beyond the tolerance; with OpenSubdiv
    3.6.0's rules, in every setting above): vertices must be flagged."""
    assert osd_shapes.available(), osd_shapes.missing_message()
    shape = BY_NAME[name]
    report, err, flagged = check_least_squares(native, name, _mesh(native, shape), shape.positions,
                                               dict(scheme="CATMULL_CLARK", **settings))
    assert flagged.any() and report.status == "STAGNATED", report.summary()


def without_degenerate(faces):
    return [f for f in faces if len(set(f)) == len(f)]


def test_dragon_least_squares(native):
    """The 100k-vertex scan with double-sided triangles, at quality 1: the
    library's residual against scipy's LSQR (tight tolerances)."""
    import scipy.sparse.linalg
    P32, faces, _ = load("dragon_res2")
    mesh = native.Mesh.from_faces(P32, without_degenerate(faces))
    stencils = native.limit_stencils(mesh, quality=1)
    L = stencils.to_scipy()
    P = P32.astype(np.float64)
    cage, report = stencils.solve(P32, tolerance=TOLERANCE)
    d = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    theirs = np.empty_like(P)
    for k in range(3):
        x = scipy.sparse.linalg.lsqr(L, P[:, k], atol=1e-14, btol=1e-14, iter_lim=20000)
        assert x[1] in (1, 2, 4, 5), "LSQR stopped with istop %d after %d iterations" % (x[1], x[2])
        theirs[:, k] = P[:, k] - L @ x[0]
    ours = P - L @ cage.astype(np.float64)
    apart = np.linalg.norm(ours - theirs, axis=1) / d
    err = np.linalg.norm(ours, axis=1) / d
    flagged = np.asarray(report.unreachable, bool)
    worst = int(np.argmax(apart))
    summary = "%s; residual %.3g vs LSQR's %.3g at vertex %d" % (
        report.summary(), err[worst], np.linalg.norm(theirs[worst]) / d, worst)
    assert apart[worst] <= RESIDUAL_MATCH, "residuals %.3g of the diagonal apart; %s" % (apart[worst], summary)
    assert flagged.any() and report.unreachable_count == int(flagged.sum()), summary
    assert report.status == "STAGNATED" and report.method == "LEAST_SQUARES", summary
    assert err[~flagged].max() <= TOLERANCE * (1 + 1e-6), summary
    assert err[flagged].min() > TOLERANCE * (1 - 1e-6), summary
