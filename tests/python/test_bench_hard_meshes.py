# SPDX-License-Identifier: GPL-3.0-or-later
"""The hard set's meshes (bench/hard_meshes.py) have what they claim: the
feature counts on small meshes made by hand, every generated mesh of the
set against its claims, the shuffle, the random creases, and the STL
reader of tools/debian_meshes.py on binary and ASCII files written here.
Nothing is downloaded: Debian's files are left to the benchmark."""
import os
import struct
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))
sys.path.insert(0, os.path.join(ROOT, "tools"))

import debian_meshes  # noqa: E402
import hard_meshes as hm  # noqa: E402

GENERATED = [name for name in hm.CATALOGUE if name not in debian_meshes.MESHES]


def flat(faces):
    return (np.array([len(f) for f in faces], np.int32), np.array([v for f in faces for v in f], np.int32))


def feats(n, faces, edges=None, creases=None):
    sizes, fv = flat(faces)
    return hm.features(n, sizes, fv, edges, creases)


def grid(n):
    """An n x n quad grid: (vertex count, faces), vertex (i, j) at i * (n + 1) + j."""
    return (n + 1) ** 2, [tuple(int(v) for v in q) for q in hm.grid_faces(n, n)]


def test_features_of_a_regular_grid():
    n, faces = grid(4)
    f = feats(n, faces)
    assert f["max_valence"] == 4 and f["boundary_edges"] == 16 and f["edges"] == 40
    assert f["nonmanifold_edges"] == 0 and f["multi_fan_vertices"] == 0 and f["misoriented_edges"] == 0
    assert f["min_face_size"] == f["max_face_size"] == 4


def test_bowtie_vertex_has_two_fans():
    f = feats(5, [(0, 1, 2), (0, 3, 4)])
    assert f["multi_fan_vertices"] == 1 and f["max_fans"] == 2 and f["nonmanifold_edges"] == 0


def test_three_faces_on_an_edge():
    f = feats(5, [(0, 1, 2), (1, 0, 3), (0, 1, 4)])
    assert f["nonmanifold_edges"] == 1 and f["max_faces_per_edge"] == 3
    # the edge joins no fans: both of its ends have three
    assert f["multi_fan_vertices"] == 2 and f["max_fans"] == 3


def test_fan_valence_and_ngon():
    m = 30
    f = feats(m + 1, [(m, i, (i + 1) % m) for i in range(m)])
    assert f["max_valence"] == m and f["multi_fan_vertices"] == 0
    f = feats(m, [tuple(range(m))])
    assert f["max_face_size"] == m and f["ngons_20"] == 1


def test_misoriented_edge():
    assert feats(4, [(0, 1, 2), (0, 1, 3)])["misoriented_edges"] == 1
    assert feats(4, [(0, 1, 2), (1, 0, 3)])["misoriented_edges"] == 0


def test_darts_at_the_ends_of_an_inner_crease_chain():
    n, faces = grid(6)
    sizes, fv = flat(faces)
    edges = hm.mesh_edges(sizes, fv)
    chain = [(i * 7 + 3, (i + 1) * 7 + 3) for i in (2, 3)]  # (2,3)-(3,3)-(4,3), inside the grid
    creases = np.zeros(len(edges), np.float32)
    for a, b in chain:
        creases[np.flatnonzero((edges[:, 0] == min(a, b)) & (edges[:, 1] == max(a, b)))] = 1.0
    assert (creases == 1).sum() == 2
    assert hm.features(n, sizes, fv, edges, creases)["darts"] == 2
    # a semi-sharp chain makes no dart, and a chain reaching the boundary has one
    assert hm.features(n, sizes, fv, edges, creases * 0.5)["darts"] == 0
    for a in (4 * 7 + 3, 5 * 7 + 3):  # on to (6, 3), on the boundary
        creases[np.flatnonzero((edges[:, 0] == a) & (edges[:, 1] == a + 7))] = 1.0
    assert hm.features(n, sizes, fv, edges, creases)["darts"] == 1


def test_a_false_claim_is_refused():
    n, faces = grid(3)
    sizes, fv = flat(faces)
    mesh = hm.HardMesh("grid", "test", "grid", np.zeros((n, 3)), sizes, fv, expect=dict(max_valence=("==", 5)))
    with pytest.raises(AssertionError, match="max_valence is 4, expected == 5"):
        mesh.finish()


@pytest.mark.parametrize("name", GENERATED)
def test_generated_mesh_has_its_feature(name):
    mesh = hm.build(name)  # checks the mesh's own claims
    f = mesh.features
    assert f["vertices"] == len(mesh.points) and np.isfinite(mesh.points).all()
    assert mesh.face_vertices.min() >= 0 and mesh.face_vertices.max() < len(mesh.points)
    if not mesh.provenance:  # made here, not a scan: no loose vertices
        assert np.bincount(mesh.face_vertices, minlength=len(mesh.points)).min() >= 1
    assert len(mesh.creases) == len(mesh.edges)
    # no face uses a vertex twice (the library refuses those)
    starts = np.cumsum(mesh.face_sizes) - mesh.face_sizes
    for s, k in zip(starts, mesh.face_sizes):
        assert len(set(mesh.face_vertices[s:s + k].tolist())) == k
    category = {
        "high-valence fan": lambda: f["max_valence"] >= 100,
        "several fans": lambda: f["multi_fan_vertices"] >= 1 and f["nonmanifold_edges"] == 0,
        "non-manifold edges": lambda: f["nonmanifold_edges"] >= 1 and f["max_faces_per_edge"] >= 3,
        "n-gons": lambda: f["max_face_size"] >= 20,
        "darts": lambda: f["darts"] >= 1,
        "semi-sharp creases": lambda: True,
        "shuffled": lambda: f["index_spread"] > 0.25,
    }[mesh.category]
    assert category(), f
    if mesh.own_creases is None:
        c = mesh.creases
        assert abs((c > 0).mean() - hm.CREASE_FRACTION) < 1e-3 and c.max() < 1 and c[c > 0].min() > 0


def test_fan_valences_of_the_set():
    for valence in (100, 200, 400):
        assert hm.build(f"cone-in-grid-{valence}").features["max_valence"] == valence


def test_random_creases_are_seeded():
    a, b = hm.random_creases(1000), hm.random_creases(1000)
    np.testing.assert_array_equal(a, b)
    assert (a > 0).sum() == 300 and 0 < a[a > 0].min() and a.max() < 1
    assert not np.array_equal(a, hm.random_creases(1000, seed=1))


def canonical(P, sizes, fv):
    """The faces as sets of positions in cyclic order, up to rotation."""
    starts = np.cumsum(sizes) - sizes
    out = []
    for s, k in zip(starts, sizes):
        ring = [tuple(P[v]) for v in fv[s:s + k]]
        i = ring.index(min(ring))
        out.append(tuple(ring[i:] + ring[:i]))
    return sorted(out)


def test_shuffle_keeps_the_mesh():
    P, quads = hm.box_grid(5)
    sizes, fv = np.full(len(quads), 4, np.int32), quads.ravel().astype(np.int32)
    P2, sizes2, fv2 = hm.shuffled(P, sizes, fv, seed=3)
    assert canonical(P, sizes, fv) == canonical(P2, sizes2, fv2)
    assert not np.array_equal(fv, fv2)
    before, after = hm.features(len(P), sizes, fv), hm.features(len(P2), sizes2, fv2)
    assert after["index_spread"] > 0.25 > before["index_spread"]
    assert after["misoriented_edges"] == before["misoriented_edges"] == 0


TRIANGLES = np.array([[(0, 0, 0), (1, 0, 0), (0, 1, 0)],
                      [(1, 0, 0), (1, 1, 0), (0, 1, 0)],
                      [(-0.0, 0, 0), (0, 0, 1), (1, 0, 0)],      # -0.0 is the first vertex
                      [(0, 0, 1), (0, 0, 1), (1, 1, 1)]], np.float32)  # repeats a vertex


def write_binary(path, triangles, header=b"binary STL"):
    with open(path, "wb") as fh:
        fh.write(header.ljust(80, b" ") + struct.pack("<I", len(triangles)))
        for t in triangles:
            fh.write(struct.pack("<3f", 0, 0, 0) + t.astype("<f4").tobytes() + b"\0\0")


def write_ascii(path, triangles):
    with open(path, "w") as fh:
        fh.write("solid test\n")
        for t in triangles:
            fh.write("  facet normal 0 0 0\n    outer loop\n")
            for p in t:
                fh.write("      vertex %r %r %r\n" % tuple(float(x) for x in p))
            fh.write("    endloop\n  endfacet\n")
        fh.write("endsolid test\n")


@pytest.mark.parametrize("kind", ["binary", "binary-solid-header", "ascii"])
def test_stl_reading_and_welding(tmp_path, kind):
    path = str(tmp_path / "t.stl")
    if kind == "ascii":
        write_ascii(path, TRIANGLES)
    else:
        write_binary(path, TRIANGLES, b"solid but binary" if kind == "binary-solid-header" else b"binary STL")
    np.testing.assert_array_equal(debian_meshes.read_stl_triangles(path), TRIANGLES)
    P, faces, dropped = debian_meshes.read_stl(path)
    assert dropped == 1
    assert len(P) == 5  # (0,0,0) (1,0,0) (0,1,0) (1,1,0) (0,0,1); (1,1,1) only in the dropped one
    np.testing.assert_array_equal(P[faces], TRIANGLES[:3] + np.float32(0))
    np.testing.assert_array_equal(faces[0], [0, 1, 2])  # numbered in the file's order


def test_a_file_that_is_no_stl_is_refused(tmp_path):
    path = tmp_path / "x.stl"
    path.write_bytes(b"\x01" * 200)
    with pytest.raises(ValueError, match="neither"):
        debian_meshes.read_stl_triangles(str(path))
