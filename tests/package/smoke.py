# SPDX-License-Identifier: GPL-3.0-or-later
"""The installed package loads and works, outside Blender:

    python3 smoke.py PACKAGE_PARENT MESH.obj

PACKAGE_PARENT is the folder holding the unpacked `subdiv_pia/` of a zip.
Loads its library through the binding inside it (spia), interpolates MESH.obj with
Catmull-Clark and checks the cage with the library's stencils applied in
numpy (L V = P to 1e-6 of the diagonal), and checks closest points on the
mesh against a brute-force search over its triangles in numpy.  Prints one
line and exits 0, or says what failed and exits 1.  Runs on the Python
and numpy of Debian 11 (3.9, 1.19) and newer.
"""
import os
import sys

import numpy as np


def read_obj(path):
    positions, faces = [], []
    with open(path) as fh:
        for line in fh:
            p = line.split()
            if p and p[0] == "v":
                positions.append([float(x) for x in p[1:4]])
            elif p and p[0] == "f":
                faces.append([int(x.split("/")[0]) - 1 for x in p[1:]])
    return np.asarray(positions, np.float32), faces


def closest_brute_force(points, corners):
    """Distance from each point to the nearest of the triangles corners (T, 3, 3), in numpy."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    best = np.full(len(points), np.inf)
    for i, p in enumerate(points):
        # Closest point on every triangle (Ericson's Voronoi-region walk, vectorised).
        ab, ac, ap = b - a, c - a, p - a
        d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
        bp = p - b
        d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
        cp = p - c
        d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        denom = va + vb + vc
        with np.errstate(divide="ignore", invalid="ignore"):
            v = vb / denom
            w = vc / denom
        q = a + ab * v[:, None] + ac * w[:, None]
        candidates = [q]
        for s, e in ((a, b), (b, c), (c, a)):
            se = e - s
            t = np.clip(((p - s) * se).sum(1) / np.maximum((se * se).sum(1), 1e-300), 0.0, 1.0)
            candidates.append(s + se * t[:, None])
        inside = (va >= 0) & (vb >= 0) & (vc >= 0) & np.isfinite(v) & np.isfinite(w)
        dist = np.min([np.linalg.norm(x - p, axis=1) for x in candidates[1:]], axis=0)
        dist = np.where(inside, np.minimum(dist, np.linalg.norm(q - p, axis=1)), dist)
        best[i] = dist.min()
    return best


def main(argv):
    parent, mesh_path = argv[1], argv[2]
    sys.path.insert(0, os.path.abspath(parent))
    from subdiv_pia import native

    here = os.path.realpath(os.path.dirname(native.__file__))
    if not here.startswith(os.path.realpath(parent)):
        print("smoke: imported subdiv_pia from %s, not from %s" % (here, parent))
        return 1
    if not native.available():
        print("smoke: the library does not load: %s" % native.load_error())
        return 1
    positions, faces = read_obj(mesh_path)
    mesh = native.Mesh.from_faces(positions, faces)
    cage, report = native.interpolate(mesh, quality=3)
    stencils = native.limit_stencils(mesh, quality=3)
    limit = stencils.apply(cage)
    diagonal = float(np.linalg.norm(positions.max(0) - positions.min(0)))
    miss = float(np.abs(limit - positions).max()) / diagonal
    moved = float(np.abs(cage - positions).max()) / diagonal
    if report.status != "CONVERGED" or not miss <= 1e-6 or not moved > 1e-3:
        print("smoke: interpolation failed: %s, limit points %.2e of the diagonal off, cage moved %.2e"
              % (report.summary(), miss, moved))
        return 1

    triangles = np.array([[f[0], f[k], f[k + 1]] for f in faces for k in range(1, len(f) - 1)])
    rng = np.random.default_rng(7)
    lo, hi = positions.min(0), positions.max(0)
    queries = (rng.random((200, 3)) * 1.4 - 0.2) * (hi - lo) + lo
    scan = native.Scan(mesh)
    _closest, _normals, distances, _faces = scan.closest_points(queries)
    expected = closest_brute_force(queries.astype(np.float64), positions[triangles].astype(np.float64))
    worst = float(np.abs(distances - expected).max()) / diagonal
    if not worst <= 1e-6:
        print("smoke: closest points differ from a brute-force search by %.2e of the diagonal" % worst)
        return 1
    print("smoke: library %s loaded from %s; %s (limit points within %.1e of the diagonal); "
          "%d closest points match a brute-force search" % (native.version(), here, report.summary(), miss,
                                                           len(queries)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
