# SPDX-License-Identifier: GPL-3.0-or-later
"""spia outside Blender, with trimesh reading and writing the files:

    python trimesh_client.py MESH OUT_CAGE.obj

Reads a closed triangle mesh (e.g. tests/data/armadillo.obj), computes the
Loop cage whose limit surface passes through its vertices, writes the cage
to OUT_CAGE.obj, reads that file back and checks, in numpy and without the
library, that the limit points of the cage as written are the mesh's
vertices within 1e-6 of its bounding-box diagonal.  The limit point of a
vertex of valence n (every vertex of a closed mesh is interior) is
1 - n chi on itself and chi = 1 / (n + 3 / (8 beta)) on each neighbour,
beta = (5/8 - (3/8 + cos(2 pi / n) / 4)^2) / n being Loop's weight.
Needs numpy, trimesh and spia.  Prints one line of figures; exits 1 when a
check fails.
"""
import os
import sys
import time

import numpy as np
import trimesh

import spia


def main(argv):
    if len(argv) != 3:
        print("usage: python trimesh_client.py MESH OUT_CAGE.obj")
        return 2
    source, target = argv[1], argv[2]
    start = time.time()

    mesh = trimesh.load(source, process=False, force="mesh")
    cage, report = spia.interpolate(spia.Mesh.from_faces(mesh.vertices, mesh.faces), scheme="LOOP")
    trimesh.Trimesh(cage, mesh.faces, process=False).export(target)

    written = trimesh.load(target, process=False, force="mesh")
    return check(source, target, mesh, written, report, time.time() - start)


def loop_limit(points, triangles):
    """Limit points of every vertex of a closed triangle mesh (Loop 1987)."""
    points = np.asarray(points, np.float64)
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    n = np.bincount(edges.ravel(), minlength=len(points)).astype(np.float64)
    ring = np.zeros_like(points)
    np.add.at(ring, edges[:, 0], points[edges[:, 1]])
    np.add.at(ring, edges[:, 1], points[edges[:, 0]])
    beta = (5.0 / 8.0 - (3.0 / 8.0 + np.cos(2.0 * np.pi / n) / 4.0) ** 2) / n
    chi = 1.0 / (n + 3.0 / (8.0 * beta))
    return (1.0 - n * chi)[:, None] * points + chi[:, None] * ring, n


def open_edges(triangles):
    """Edges not shared by exactly two triangles."""
    pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(pairs, axis=0, return_counts=True)
    return int((counts != 2).sum())


def check(source, target, mesh, written, report, seconds):
    name = os.path.basename(source)
    points = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    failures = []
    if faces.ndim != 2 or faces.shape[1] != 3:
        failures.append("%s is not a triangle mesh" % name)
    elif open_edges(faces):
        failures.append("%s has %d edges not shared by two triangles: this check takes closed meshes"
                        % (name, open_edges(faces)))
    elif written.vertices.shape != points.shape or not np.array_equal(np.asarray(written.faces), faces):
        failures.append("%s read back has %d vertices and %d faces (or other faces) where %s has %d and %d"
                        % (target, len(written.vertices), len(written.faces), name, len(points), len(faces)))
    else:
        diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        written_cage = np.asarray(written.vertices, np.float64)
        limit, valence = loop_limit(written_cage, faces)
        error = float(np.linalg.norm(limit - points, axis=1).max()) / diagonal
        moved = float(np.linalg.norm(written_cage - points, axis=1).max()) / diagonal
        if not report.converged:
            failures.append("the interpolation did not converge: %s" % report.summary())
        if not error <= 1e-6:
            failures.append("the limit points of the cage in %s are %.3g of the diagonal off the vertices of %s"
                            % (target, error, name))
        if not moved > 1e-3:
            failures.append("the cage moved only %.3g of the diagonal" % moved)
    if failures:
        print("trimesh_client: FAILED: " + "; ".join(failures))
        return 1
    print("trimesh_client: %s, %d vertices (valence %d to %d), %d triangles: Loop cage written to %s (moved up to "
          "%.1e of the diagonal); read back, its limit points are within %.1e of the diagonal of the vertices; "
          "%s; spia %s, trimesh %s, numpy %s, Python %s; %.1f s"
          % (name, len(points), valence.min(), valence.max(), len(faces), target, moved, error, report.summary(),
             spia.version(), trimesh.__version__, np.__version__, sys.version.split()[0], seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
