# SPDX-License-Identifier: GPL-3.0-or-later
"""Closed meshes on a sphere, in numpy alone (the plain Python tests and
tests/package/client_check.py, which runs where only numpy and spia are
installed, build them the same way)."""
import numpy as np


def cube_sphere(k, radius=1.0):
    """A cube with a k x k grid of quads on each side, its vertices on the
    sphere of `radius`: valence 3 at the cube's corners, 4 elsewhere.
    (positions float64 (N, 3), quads int64 (F, 4))."""
    index, positions, faces = {}, [], []
    g = np.linspace(-1.0, 1.0, k + 1)

    def vertex(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(positions)
            positions.append(p)
        return index[key]
    for axis in range(3):
        for sign in (-1.0, 1.0):
            for i in range(k):
                for j in range(k):
                    quad = []
                    for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                        p = np.zeros(3)
                        p[axis], p[(axis + 1) % 3], p[(axis + 2) % 3] = sign, g[a], g[b]
                        quad.append(vertex(p))
                    faces.append(quad[::-1] if sign < 0 else quad)
    p = np.asarray(positions)
    return radius * p / np.linalg.norm(p, axis=1)[:, None], np.asarray(faces, np.int64)


def icosphere(levels):
    """An icosahedron split `levels` times into four triangles per
    triangle, on the unit sphere: valence 5 at its 12 corners, 6 elsewhere.
    (positions float64 (N, 3), triangles int64 (F, 3))."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    points = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
              (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.asarray(p, np.float64) for p in points]
    for _ in range(levels):
        middle, split = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in middle:
                middle[key] = len(points)
                points.append((points[a] + points[b]) / 2.0)
            return middle[key]
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            split += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = split
    p = np.asarray(points)
    return p / np.linalg.norm(p, axis=1)[:, None], np.asarray(faces, np.int64)
