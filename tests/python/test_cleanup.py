# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's mesh cleanup (subdiv_pia.cleanup) on plain arrays."""

import numpy as np
import pytest

from subdiv_pia import cleanup

CUBE_POINTS = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
# Outward quads of the cube above (vertex 4x + 2y + z for x, y, z in {0, 1}).
CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def flat(faces):
    return (np.array([len(f) for f in faces], np.int32),
            np.array([v for f in faces for v in f], np.int32))


def faces_of(result):
    sizes, fv = result["face_sizes"], result["face_vertices"]
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    return [tuple(int(v) for v in fv[s:s + k]) for s, k in zip(starts, sizes)]


def normals(points, faces):
    p = np.asarray(points, np.float64)
    out = []
    for f in faces:
        n = np.zeros(3)
        for a, b in zip(f, f[1:] + f[:1]):
            n += np.cross(p[a], p[b])
        out.append(n / np.linalg.norm(n))
    return np.array(out)


def signed_volume(points, faces):
    p = np.asarray(points, np.float64)
    return sum(np.dot(p[f[0]], np.cross(p[f[i]], p[f[i + 1]])) for f in faces
               for i in range(1, len(f) - 1)) / 6.0


def run(points, faces, **kwargs):
    sizes, fv = flat(faces)
    return cleanup.clean(np.asarray(points, np.float32), sizes, fv, **kwargs)


def test_clean_cube_is_unchanged():
    r = run(CUBE_POINTS, CUBE_FACES)
    assert not cleanup.changed(r["stats"])
    assert cleanup.format_stats(r["stats"]) == "nothing to clean"
    np.testing.assert_array_equal(r["positions"], CUBE_POINTS)
    assert faces_of(r) == CUBE_FACES
    assert len(r["edges"]) == 12
    np.testing.assert_array_equal(r["vertex_map"], np.arange(8))


def test_merge_close_vertices_keeps_the_first_position():
    # Two quads side by side whose shared edge is doubled, 1e-9 apart.
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0),
              (1 + 1e-9, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1 - 1e-9, 0)]
    r = run(points, [(0, 1, 2, 3), (4, 5, 6, 7)])
    assert r["stats"]["merged_vertices"] == 2
    assert len(r["positions"]) == 6
    assert r["vertex_map"][4] == r["vertex_map"][1] and r["vertex_map"][7] == r["vertex_map"][2]
    np.testing.assert_array_equal(r["positions"][r["vertex_map"][1]], np.float32((1, 0, 0)))
    assert len(r["edges"]) == 7  # the shared edge once
    assert "merged 2 vertices" in cleanup.format_stats(r["stats"])


def test_vertices_beyond_the_distance_stay_apart():
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (1 + 1e-3, 0, 0), (2, 0, 0), (2, 1, 0)]
    r = run(points, [(0, 1, 2), (3, 4, 5)])
    assert r["stats"]["merged_vertices"] == 0
    r = run(points, [(0, 1, 2), (3, 4, 5)], distance=1e-3)
    assert r["stats"]["merged_vertices"] == 1


def test_merge_matches_brute_force():
    rng = np.random.default_rng(7)
    base = rng.uniform(-1, 1, (300, 3))
    copies = base[rng.integers(0, 300, 200)] + rng.normal(0, 1e-7, (200, 3))
    points = np.concatenate((base, copies)).astype(np.float32)
    tol = 1e-6 * float(np.linalg.norm(points.max(0) - points.min(0)))
    labels = cleanup.merge_groups(points, tol)
    p = points.astype(np.float64)
    close = np.linalg.norm(p[:, None] - p[None], axis=2) <= tol
    expected = np.arange(len(p))
    for _ in range(len(p)):  # the smallest index reachable through close pairs
        new = np.where(close, expected[None, :], len(p)).min(axis=1)
        if np.array_equal(new, expected):
            break
        expected = new
    np.testing.assert_array_equal(labels, expected)
    assert len(np.unique(labels)) == 300


def test_repeated_vertex_is_dissolved():
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    r = run(points, [(0, 1, 2, 3), (1, 4, 4, 2)])
    assert r["stats"]["dissolved_corners"] == 1
    assert r["stats"]["degenerate_faces"] == 0
    assert faces_of(r) == [(0, 1, 2, 3), (1, 4, 2)]


def test_faces_left_without_three_vertices_or_folding_back_are_removed():
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)]
    faces = [(0, 1, 2, 3), (1, 1, 4, 4), (2, 2, 2), (1, 4, 1, 5)]
    r = run(points, faces)
    assert r["stats"]["degenerate_faces"] == 3
    assert faces_of(r) == [(0, 1, 2, 3)]
    np.testing.assert_array_equal(r["face_map"], [0])
    assert r["stats"]["loose_vertices"] == 2  # 4 and 5 are used by no face left
    assert len(r["positions"]) == 4


def test_zero_area_face_is_removed():
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 1, 0)]
    r = run(points, [(0, 1, 2, 3), (3, 4, 2)])  # 3, 4, 2 lie on one line
    assert r["stats"]["zero_area_faces"] == 1
    assert faces_of(r) == [(0, 1, 2, 3)]
    assert r["stats"]["loose_vertices"] == 1
    np.testing.assert_array_equal(r["vertex_map"], [0, 1, 2, 3, -1])


def test_loose_vertices_and_edges_are_removed():
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (5, 5, 5), (6, 5, 5), (7, 7, 7)]
    sizes, fv = flat([(0, 1, 2)])
    edges = np.array([(0, 1), (1, 2), (2, 0), (3, 4), (0, 3)], np.int32)
    r = cleanup.clean(np.float32(points), sizes, fv, edges=edges)
    assert r["stats"]["loose_vertices"] == 3
    assert r["stats"]["loose_edges"] == 2
    assert len(r["positions"]) == 3 and len(r["edges"]) == 3
    np.testing.assert_array_equal(r["vertex_map"], [0, 1, 2, -1, -1, -1])


def test_creases_follow_their_vertex_pair_through_the_merge():
    # The two triangles' shared edge is doubled (3, 4 are copies of 1, 2).
    points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]
    sizes, fv = flat([(0, 1, 2), (3, 5, 4)])
    edges = np.array([(0, 1), (1, 2), (2, 0), (3, 5), (5, 4), (4, 3)], np.int32)
    creases = np.float32([0.0, 0.3, 0.0, 0.0, 0.5, 0.8])
    vertex_creases = np.float32([0, 0, 0.25, 0, 0.75, 1.0])
    r = cleanup.clean(np.float32(points), sizes, fv, edges=edges, edge_creases=creases,
                      vertex_creases=vertex_creases)
    vm = r["vertex_map"]
    got = {tuple(sorted(map(int, e))): float(c) for e, c in zip(r["edges"], r["edge_creases"])}
    assert got[tuple(sorted((vm[1], vm[2])))] == pytest.approx(0.8)  # max of 0.3 and 0.8
    assert got[tuple(sorted((vm[5], vm[4])))] == pytest.approx(0.5)
    assert got[tuple(sorted((vm[0], vm[1])))] == 0.0
    assert r["vertex_creases"][vm[2]] == pytest.approx(0.75)
    assert r["vertex_creases"][vm[5]] == pytest.approx(1.0)


@pytest.mark.parametrize("seed", range(5))
def test_cube_with_faces_reversed_comes_back_outward(seed):
    rng = np.random.default_rng(seed)
    faces = [list(f) for f in CUBE_FACES]
    order = rng.permutation(6)
    reversed_faces = order[:2]  # a minority: the majority is outward
    for i in reversed_faces:
        faces[i] = faces[i][::-1]
    faces = [tuple(faces[i]) for i in order]  # the first face may be a reversed one
    r = run(CUBE_POINTS, faces)
    assert r["stats"]["flipped_faces"] == 2
    assert sorted(np.flatnonzero(r["flipped"])) == sorted(np.flatnonzero(np.isin(order, reversed_faces)))
    got = faces_of(r)
    want = [CUBE_FACES[i] for i in order]
    np.testing.assert_allclose(normals(r["positions"], got), normals(CUBE_POINTS, want), atol=1e-12)
    assert signed_volume(r["positions"], got) > 0


def test_majority_orientation_is_kept():
    faces = [f[::-1] if i < 4 else f for i, f in enumerate(CUBE_FACES)]
    r = run(CUBE_POINTS, faces)
    assert r["stats"]["flipped_faces"] == 2
    assert signed_volume(r["positions"], faces_of(r)) < 0  # all inward now, consistently


def test_tie_keeps_the_first_face():
    faces = [f[::-1] if i % 2 else f for i, f in enumerate(CUBE_FACES)]
    r = run(CUBE_POINTS, faces)
    assert r["stats"]["flipped_faces"] == 3
    assert faces_of(r)[0] == CUBE_FACES[0]
    assert signed_volume(r["positions"], faces_of(r)) > 0


def test_components_are_oriented_apart():
    shifted = CUBE_POINTS + np.float32(5)
    points = np.concatenate((CUBE_POINTS, shifted))
    faces = list(CUBE_FACES) + [tuple(v + 8 for v in f[::-1]) for f in CUBE_FACES]
    faces[1] = faces[1][::-1]
    faces[7] = faces[7][::-1]
    r = run(points, faces)
    assert r["stats"]["flipped_faces"] == 2
    got = faces_of(r)
    assert signed_volume(r["positions"], got[:6]) > 0  # first cube outward (its majority)
    assert signed_volume(r["positions"], got[6:]) < 0  # second inward (its majority)


def moebius(n=12):
    points, faces = [], []
    for i in range(n):
        t = 2 * np.pi * i / n
        for s in (-0.3, 0.3):
            w = s * np.array([np.cos(t / 2) * np.cos(t), np.cos(t / 2) * np.sin(t), np.sin(t / 2)])
            points.append(np.array([np.cos(t), np.sin(t), 0.0]) + w)
    for i in range(n - 1):
        faces.append((2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1))
    faces.append((2 * n - 2, 1, 0, 2 * n - 1))  # the half twist joins the strip's ends
    return np.array(points, np.float32), faces


def test_moebius_strip_is_left_as_it_is():
    points, faces = moebius()
    r = run(points, faces)
    assert r["stats"]["non_orientable_parts"] == 1
    assert r["stats"]["flipped_faces"] == 0
    assert faces_of(r) == faces
    assert not cleanup.changed(r["stats"])
    assert "non-orientable" in cleanup.format_stats(r["stats"])


def test_idempotent_and_input_untouched():
    # 8, 9, 10: copies of 0, 1, 2 (10 used by no face); 11 loose.
    points = np.concatenate((CUBE_POINTS, CUBE_POINTS[:3] + np.float32(1e-8), [(9, 9, 9)]))
    faces = [list(f) for f in CUBE_FACES]
    faces[0] = [8, 9, 3, 2]          # uses copies of 0 and 1
    faces[2] = [0, 4, 5, 5, 1]       # repeats 5
    faces[3] = faces[3][::-1]        # reversed
    faces.append((0, 1, 0))          # degenerate: its last corner dissolves, two are left
    sizes, fv = flat(faces)
    inputs = (points.copy(), sizes.copy(), fv.copy())
    first = cleanup.clean(points, sizes, fv, distance=1e-6)
    for a, b in zip(inputs, (points, sizes, fv)):
        np.testing.assert_array_equal(a, b)
    s = first["stats"]
    assert (s["merged_vertices"], s["dissolved_corners"], s["degenerate_faces"],
            s["loose_vertices"], s["flipped_faces"]) == (3, 2, 1, 1, 1)
    assert len(first["positions"]) == 8 and len(first["face_sizes"]) == 6
    assert signed_volume(first["positions"], faces_of(first)) > 0
    second = cleanup.clean(first["positions"], first["face_sizes"], first["face_vertices"],
                           edges=first["edges"])
    assert not cleanup.changed(second["stats"]), second["stats"]
    for key in ("positions", "face_sizes", "face_vertices", "edges"):
        np.testing.assert_array_equal(second[key], first[key])


def test_bad_arrays_are_refused():
    sizes, fv = flat([(0, 1, 2)])
    with pytest.raises(ValueError, match="outside"):
        cleanup.clean(CUBE_POINTS[:2], sizes, fv)
    with pytest.raises(ValueError, match="corners"):
        cleanup.clean(CUBE_POINTS, np.int32([4]), fv)
    with pytest.raises(ValueError, match="cleanup_distance"):
        cleanup.clean(CUBE_POINTS, sizes, fv, distance=-1.0)
    bad = CUBE_POINTS.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        cleanup.clean(bad, sizes, fv)


def test_cleaned_flipped_cube_passes_doo_sabin(native):
    # The Doo-Sabin refinement (the `_limit` child) refuses a face turned the other way.
    faces = [f[::-1] if i == 2 else f for i, f in enumerate(CUBE_FACES)]
    sizes, fv = flat(faces)
    with pytest.raises(native.PiaError, match="oriented"):
        native.refine(native.Mesh(CUBE_POINTS, sizes, fv), 1, scheme="DOO_SABIN")
    r = cleanup.clean(CUBE_POINTS, sizes, fv)
    mesh = native.Mesh(r["positions"], r["face_sizes"], r["face_vertices"])
    cage, report = native.interpolate(mesh, scheme="DOO_SABIN")
    assert report.converged
    points, _, _ = native.refine(native.Mesh(cage, r["face_sizes"], r["face_vertices"]), 1, scheme="DOO_SABIN")
    assert len(points) == 24


def test_cleaned_repeated_vertex_passes_the_library(native):
    points = np.float32([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)])
    sizes, fv = flat([(0, 1, 2, 3), (1, 4, 4, 5, 2)])
    with pytest.raises(native.PiaError, match="more than once"):
        native.interpolate(native.Mesh(points, sizes, fv))
    r = cleanup.clean(points, sizes, fv)
    cage, report = native.interpolate(native.Mesh(r["positions"], r["face_sizes"], r["face_vertices"]))
    assert report.converged and report.max_error_relative <= 1e-6
