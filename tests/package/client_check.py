# SPDX-License-Identifier: GPL-3.0-or-later
"""An installed spia checked against numpy computations of its own:

    python client_check.py [--from-path DIR] [--expect-prefix PREFIX]

Run in a clean virtual environment where the subdiv_pia wheel is installed
with pip (Python 3.9 to 3.13, numpy 1.19 to 2.x; nothing else needed).
spia must come from the environment's site-packages; with --from-path DIR
it is imported from DIR (put first on sys.path) and must come from there;
with --expect-prefix PREFIX its file must lie under PREFIX.  Without
either, the native library must be the package's own (not one that
SUBDIV_PIA_LIBRARY names).

Every figure is checked against formulas written here from the papers, not
against the library's own stencils:

a. Catmull-Clark interpolation (spia.interpolate, default scheme) of two
   closed all-quad meshes, a cube with 4 x 4 quads per side pushed to a
   bumpy sphere (valences 3 and 4) and a once-subdivided icosahedron cut
   into quads (valences 3, 4, 5 and 6): the limit point of a smooth
   interior vertex of valence n of a quad mesh is
       (n^2 V + 4 sum(edge neighbours) + sum(diagonal neighbours)) / (n (n + 5)),
   which must give back the input points within 1e-6 of the bounding-box
   diagonal, at quality 1, 3 (the default) and 10.  The library's surface
   at a control vertex does not depend on the quality there: at smooth
   interior vertices of manifold meshes it takes this closed form.
b. Loop interpolation (scheme='LOOP') of a bumpy once-subdivided
   icosahedron (valences 5 and 6): the limit mask with Loop's own weights,
       chi = 1 / (n + 3 / (8 beta)),  beta = (5/8 - (3/8 + cos(2 pi / n) / 4)^2) / n,
   chi on each neighbour and 1 - n chi on the vertex (OpenSubdiv's Loop
   limit), within 1e-6 of the diagonal.  Warren's beta = 3 / (8 n) is the
   same at n = 6 but not at n = 5, where it must miss.
c. A fit (spia.fit, mode 'SURFACE') of a 54-quad cage to a denser bumpy
   sphere scan (1,280 triangles).  The cage's limit surface is refined here
   three times with Catmull-Clark's rules (keeping each face's ptex (u, v)
   with its first corner at (0, 0) and its second at (1, 0)); every vertex
   of that mesh is then put at its limit point by the mask of (a).  The
   fit's samples (4 x 4 per quad, at ((i + 1/2) / 4, (j + 1/2) / 4)) are
   vertices of that mesh at odd multiples of 1/8, and the grid the report
   measures the scan's vertices against (8 x 8 quads per face, each split
   from its first corner) is made of its vertices too.  The distances,
   brute force over every triangle (pruned by bounding spheres, which
   cannot drop the nearest one), give the mean, nearest-rank 95th
   percentile and maximum within the cut-off, before and after the fit,
   both ways, which must match the report within 1e-7 of the scan's
   diagonal (they agree to about 1e-8, the float rounding of the
   library's samples; with the grid's quads split along their other
   diagonal, the fit at quality 2 or one cage vertex moved by 1e-4 of the
   diagonal, they are off by 2e-7 or more); and the fit
   must have brought the surface closer.  At
   quality 3 (the default) these are exact: the adaptive patches isolate
   each valence-3 corner to a patch of 1/8 of the face, and the end cap
   there meets the limit surface at its corners only; at quality 1 or 2
   the samples next to those corners lie on end caps, up to 6e-4 of the
   cage's radius off the limit surface, so the check uses quality 3.

With --save-cages FILE, the inputs and cages of (a), (b) and (c) are
written to FILE (.npz); with --compare-cages FILE, spia is run again on the
inputs saved there (another platform's run) with the same settings, and
every cage must equal the one saved, bit for bit.

Prints one line of figures and exits 0, or prints what failed and exits 1.
Runs in a few seconds.
"""
import argparse
import os
import platform
import site
import sys
import sysconfig
import time
import traceback

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
# The sphere meshes of the plain Python tests (tests/python/spheres.py, numpy
# alone), or the copy beside this file where it runs on its own.
sys.path.insert(0, HERE if os.path.isfile(os.path.join(HERE, "spheres.py")) else
                os.path.join(os.path.dirname(HERE), "python"))
from spheres import cube_sphere, icosphere  # noqa: E402

failures = []
# name -> {"points", "faces", "cage"[, "scan_points", "scan_faces"]}: what
# --save-cages writes and --compare-cages replays.
cages = {}


def check(ok, what):
    if not ok:
        failures.append(what)
    return ok


# --------------------------------------------------------------------------
# Meshes, made here
# --------------------------------------------------------------------------

def bump(points, amount=0.08):
    """Points on the unit sphere pushed in and out by a smooth deterministic
    function of their position."""
    p = points / np.linalg.norm(points, axis=1)[:, None]
    r = 1.0 + amount * np.sin(3.0 * p[:, 0] + 1.0) * np.cos(2.0 * p[:, 1]) + 0.3 * amount * p[:, 2] ** 2
    return p * r[:, None]


def quadrangulate(points, faces):
    """Every n-gon cut into n quads through its centroid and edge midpoints."""
    points = [np.asarray(p, np.float64) for p in points]
    middle, quads = {}, []

    def mid(a, b):
        key = (min(a, b), max(a, b))
        if key not in middle:
            middle[key] = len(points)
            points.append((points[a] + points[b]) / 2.0)
        return middle[key]
    for f in faces:
        centre = len(points)
        points.append(np.mean([points[v] for v in f], axis=0))
        n = len(f)
        for i in range(n):
            quads.append((f[i], mid(f[i], f[(i + 1) % n]), centre, mid(f[i - 1], f[i])))
    return np.asarray(points), np.asarray(quads, np.int64)


def require_closed_and_oriented(faces, vertex_count):
    """Every directed edge once, and its reverse too: a closed, consistently
    oriented manifold (what the masks below assume), every vertex used."""
    a = faces.ravel()
    b = np.roll(faces, -1, axis=1).ravel()
    directed = a * vertex_count + b
    reverse = b * vertex_count + a
    if len(np.unique(directed)) != len(directed) or not np.isin(reverse, directed).all():
        raise AssertionError("a test mesh is not closed and consistently oriented")
    if len(np.unique(a)) != vertex_count:
        raise AssertionError("a test mesh has unused vertices")


def diagonal_of(points):
    points = np.asarray(points, np.float64)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


# --------------------------------------------------------------------------
# Limit masks and Catmull-Clark refinement, from the papers
# --------------------------------------------------------------------------

def catmull_clark_quad_limit(points, quads):
    """Limit points of every vertex of a closed, oriented all-quad mesh:
    (n^2 V + 4 sum(edge neighbours) + sum(diagonal ones)) / (n (n + 5)).
    Going round a face, each vertex's next corner is one of its edge
    neighbours (each once, the mesh being oriented) and the corner after
    that the diagonal one."""
    points = np.asarray(points, np.float64)
    v = quads.ravel()
    nxt = np.roll(quads, -1, axis=1).ravel()
    opposite = np.roll(quads, -2, axis=1).ravel()
    n = np.bincount(v, minlength=len(points)).astype(np.float64)
    ring = np.zeros_like(points)
    np.add.at(ring, v, 4.0 * points[nxt] + points[opposite])
    return (n[:, None] ** 2 * points + ring) / (n * (n + 5.0))[:, None], n


def loop_beta(n):
    """Loop's vertex weight on each neighbour (his thesis, 1987)."""
    return (5.0 / 8.0 - (3.0 / 8.0 + np.cos(2.0 * np.pi / n) / 4.0) ** 2) / n


def warren_beta(n):
    return np.where(n == 3, 3.0 / 16.0, 3.0 / (8.0 * n))


def loop_limit(points, triangles, beta=loop_beta):
    """Limit points of a closed, oriented triangle mesh: chi = 1 / (n + 3 /
    (8 beta)) on each neighbour, 1 - n chi on the vertex."""
    points = np.asarray(points, np.float64)
    v = triangles.ravel()
    nxt = np.roll(triangles, -1, axis=1).ravel()
    n = np.bincount(v, minlength=len(points)).astype(np.float64)
    ring = np.zeros_like(points)
    np.add.at(ring, v, points[nxt])
    chi = 1.0 / (n + 3.0 / (8.0 * beta(n)))
    return (1.0 - n * chi)[:, None] * points + chi[:, None] * ring, n


def catmull_clark_refine(points, quads, levels):
    """`levels` Catmull-Clark steps (Catmull and Clark 1978) of a closed,
    oriented all-quad mesh.  Returns the refined points, for each original
    quad the (2^levels + 1)^2 grid of refined vertex indices in its (u, v)
    (first corner at u = v = 0, second at u = 1), and the refined quads."""
    points = np.asarray(points, np.float64)
    quads = np.asarray(quads, np.int64)
    root = np.arange(len(quads))
    origin = np.zeros((len(quads), 2), np.int64)  # each quad's (u, v) corner, in its root's grid steps
    for _ in range(levels):
        nv, nf = len(points), len(quads)
        face_points = points[quads].mean(axis=1)
        a = quads.ravel()
        b = np.roll(quads, -1, axis=1).ravel()
        keys, edge_of = np.unique(np.minimum(a, b) * nv + np.maximum(a, b), return_inverse=True)
        edge_of = edge_of.reshape(nf, 4)
        ends_a, ends_b = keys // nv, keys % nv
        faces_of_edge = np.zeros((len(keys), 3))
        np.add.at(faces_of_edge, edge_of.ravel(), np.repeat(face_points, 4, axis=0))
        edge_points = (points[ends_a] + points[ends_b] + faces_of_edge) / 4.0
        n = np.bincount(a, minlength=nv).astype(np.float64)[:, None]
        neighbours = np.zeros_like(points)
        np.add.at(neighbours, a, points[b])
        around = np.zeros_like(points)
        np.add.at(around, a, np.repeat(face_points, 4, axis=0))
        # (F + 2 R + (n - 3) V) / n, R the mean of the edges' midpoints
        vertex_points = ((n - 2.0) * points + (neighbours + around) / n) / n
        e = nv + edge_of
        f = nv + len(keys) + np.arange(nf)
        va, vb, vc, vd = quads.T
        eab, ebc, ecd, eda = e.T
        children = np.stack([np.stack([va, eab, f, eda], 1), np.stack([eab, vb, ebc, f], 1),
                             np.stack([f, ebc, vc, ecd], 1), np.stack([eda, f, ecd, vd], 1)], axis=1)
        step = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
        origin = (2 * origin[:, None, :] + step[None]).reshape(-1, 2)
        root = np.repeat(root, 4)
        quads = children.reshape(-1, 4)
        points = np.vstack([vertex_points, edge_points, face_points])
    side = 2 ** levels + 1
    grid = np.full((int(root.max()) + 1, side, side), -1, np.int64)
    u, v = origin[:, 0], origin[:, 1]
    grid[root, v, u] = quads[:, 0]
    grid[root, v, u + 1] = quads[:, 1]
    grid[root, v + 1, u + 1] = quads[:, 2]
    grid[root, v + 1, u] = quads[:, 3]
    return points, grid, quads


# --------------------------------------------------------------------------
# Distances, brute force
# --------------------------------------------------------------------------

def point_triangle_pairs(p, a, b, c):
    """Distance from each point p[i] to the triangle (a[i], b[i], c[i])."""
    ab, ac = b - a, c - a
    normal = np.cross(ab, ac)
    nn = (normal * normal).sum(1)
    flat = nn > 0
    safe = np.where(flat, nn, 1.0)
    # barycentric weights of p's projection (components along the normal cancel)
    wa = (np.cross(b - p, c - p) * normal).sum(1) / safe
    wb = (np.cross(c - p, a - p) * normal).sum(1) / safe
    wc = 1.0 - wa - wb
    inside = flat & (wa >= 0) & (wb >= 0) & (wc >= 0)
    best = np.abs(((p - a) * normal).sum(1)) / np.sqrt(safe)
    edges = np.full(len(p), np.inf)
    for s, e in ((a, b), (b, c), (c, a)):
        d = e - s
        dd = (d * d).sum(1)
        t = np.clip(((p - s) * d).sum(1) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        q = p - s - t[:, None] * d
        edges = np.minimum(edges, np.sqrt((q * q).sum(1)))
    return np.where(inside, np.minimum(best, edges), edges)


def distances_to_triangles(points, corners, chunk=64):
    """Distance from every point to the nearest of the triangles corners
    (T, 3, 3).  A triangle lies within the sphere about its centroid through
    its farthest corner, and its centroid on it: one whose sphere is
    farther than the nearest centroid cannot be the nearest and is skipped;
    the others are measured."""
    points = np.asarray(points, np.float64)
    corners = np.asarray(corners, np.float64)
    centre = corners.mean(axis=1)
    radius = np.sqrt(((corners - centre[:, None, :]) ** 2).sum(2)).max(axis=1)
    out = np.empty(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        to_centre = np.sqrt(((p[:, None, :] - centre[None, :, :]) ** 2).sum(2))
        upper = to_centre.min(axis=1)
        rows, cols = np.nonzero(to_centre - radius[None, :] <= upper[:, None] * (1 + 1e-9) + 1e-12)
        d = point_triangle_pairs(p[rows], corners[cols, 0], corners[cols, 1], corners[cols, 2])
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
        if len(starts) != len(p):  # only with NaNs about
            raise AssertionError("distances: a point with no triangle to measure")
        out[s:s + chunk] = np.minimum.reduceat(d, starts)
    return out


def distance_stats(d, cutoff, diagonal):
    """(mean, nearest-rank 95th percentile, max) of the distances within
    cutoff * diagonal, relative to diagonal, and how many lie beyond."""
    within = np.sort(d[d <= cutoff * diagonal])
    if len(within) == 0:
        return 0.0, 0.0, 0.0, len(d)
    rank = max(int(np.ceil(0.95 * len(within))), 1)
    return (float(within.mean()) / diagonal, float(within[rank - 1]) / diagonal,
            float(within[-1]) / diagonal, int(len(d) - len(within)))


# --------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------

def check_catmull_clark(spia):
    cube_p, cube_f = cube_sphere(4)
    ico_p, ico_t = icosphere(1)
    quad_p, quad_f = quadrangulate(ico_p, ico_t)
    cases = [("cube", bump(cube_p), cube_f, {3, 4}), ("quadrangulated icosphere", bump(quad_p), quad_f, {3, 4, 5, 6})]
    worst, moved = 0.0, []
    for name, points, quads, valences in cases:
        points = points.astype(np.float32)
        require_closed_and_oriented(quads, len(points))
        mesh = spia.Mesh.from_faces(points, quads)
        diagonal = diagonal_of(points)
        for quality in (1, 3, 10):
            cage, report = spia.interpolate(mesh, quality=quality)
            cages["catmull-clark %s quality %d" % (name, quality)] = {"points": points, "faces": quads, "cage": cage}
            limit, n = catmull_clark_quad_limit(cage, quads)
            error = float(np.linalg.norm(limit - points, axis=1).max()) / diagonal
            shift = float(np.linalg.norm(cage.astype(np.float64) - points, axis=1).max()) / diagonal
            where = "Catmull-Clark, %s, quality %d" % (name, quality)
            check(set(np.unique(n).astype(int).tolist()) == valences,
                  "%s: valences %s, expected %s" % (where, sorted(set(n.astype(int))), sorted(valences)))
            check(report.status == "CONVERGED", "%s: %s" % (where, report.summary()))
            check(error <= 1e-6, "%s: the cage's limit points are %.3g of the diagonal off the input" % (where, error))
            check(shift > 1e-3, "%s: the cage moved only %.3g of the diagonal" % (where, shift))
            check(abs(report.max_error_relative - error) <= 1e-9,
                  "%s: the report's max error %.6g, computed here %.6g" % (where, report.max_error_relative, error))
            worst = max(worst, error)
            moved.append(shift)
    return ("Catmull-Clark limit within %.1e of the diagonal (cages moved %.1e to %.1e)"
            % (worst, min(moved), max(moved)))


def check_loop(spia):
    points, triangles = icosphere(1)
    points = bump(points).astype(np.float32)
    require_closed_and_oriented(triangles, len(points))
    mesh = spia.Mesh.from_faces(points, triangles)
    diagonal = diagonal_of(points)
    cage, report = spia.interpolate(mesh, scheme="LOOP")
    cages["loop"] = {"points": points, "faces": triangles, "cage": cage}
    limit, n = loop_limit(cage, triangles)
    error = float(np.linalg.norm(limit - points, axis=1).max()) / diagonal
    warren, _ = loop_limit(cage, triangles, beta=warren_beta)
    warren_error = float(np.linalg.norm(warren - points, axis=1).max()) / diagonal
    shift = float(np.linalg.norm(cage.astype(np.float64) - points, axis=1).max()) / diagonal
    check(sorted(set(n.astype(int).tolist())) == [5, 6], "Loop: valences %s, expected 5 and 6" % sorted(set(n)))
    check(report.status == "CONVERGED", "Loop: %s" % report.summary())
    check(error <= 1e-6, "Loop: the cage's limit points are %.3g of the diagonal off the input" % error)
    check(shift > 1e-3, "Loop: the cage moved only %.3g of the diagonal" % shift)
    check(warren_error > 1e-4, "Loop: Warren's weights fit too (%.3g): the check cannot tell them apart" % warren_error)
    check(abs(report.max_error_relative - error) <= 1e-9,
          "Loop: the report's max error %.6g, computed here %.6g" % (report.max_error_relative, error))
    return "Loop %.1e (Warren's weights %.1e)" % (error, warren_error)


def check_fit(spia):
    scan_p, scan_t = icosphere(3)
    scan_p = bump(scan_p, 0.06).astype(np.float32)
    cage_p, cage_f = cube_sphere(3)
    cage_p = (1.1 * cage_p).astype(np.float32)  # its limit surface within the cut-off of the scan everywhere
    require_closed_and_oriented(scan_t, len(scan_p))
    require_closed_and_oriented(cage_f, len(cage_p))
    scan = spia.Scan(spia.Mesh.from_faces(scan_p, scan_t))
    cage = spia.Mesh.from_faces(cage_p, cage_f)
    cutoff, per_edge = 0.05, 4
    fitted, report = spia.fit(cage, scan, cutoff=cutoff, samples_per_edge=per_edge)
    cages["fit"] = {"points": cage_p, "faces": cage_f, "scan_points": scan_p, "scan_faces": scan_t, "cage": fitted}
    diagonal = diagonal_of(scan_p)
    check(abs(scan.diagonal - diagonal) <= 1e-9 * diagonal and abs(report.diagonal - diagonal) <= 1e-9 * diagonal,
          "fit: the scan's diagonal %.9g (report %.9g), computed here %.9g" % (scan.diagonal, report.diagonal,
                                                                                diagonal))
    check(report.status == "CONVERGED", "fit: %s (%s)" % (report.status, report.message))
    check(report.sample_count == len(cage_f) * per_edge ** 2,
          "fit: %d samples, expected %d" % (report.sample_count, len(cage_f) * per_edge ** 2))
    scan_triangles = scan_p[scan_t]
    used = np.unique(scan_t)
    figures = {}
    for when, positions, surface_side, scan_side in (("before", cage_p, report.before, report.scan_before),
                                                     ("after", fitted, report.after, report.scan_after)):
        points, grid, quads = catmull_clark_refine(positions, cage_f, 3)
        limit, _ = catmull_clark_quad_limit(points, quads)
        samples = limit[grid[:, 1::2, 1::2]].reshape(-1, 3)
        mine = distance_stats(distances_to_triangles(samples, scan_triangles), cutoff, diagonal)
        g00, g10 = grid[:, :-1, :-1].ravel(), grid[:, :-1, 1:].ravel()
        g11, g01 = grid[:, 1:, 1:].ravel(), grid[:, 1:, :-1].ravel()
        surface_triangles = limit[np.concatenate([np.stack([g00, g10, g11], 1), np.stack([g00, g11, g01], 1)])]
        mine_scan = distance_stats(distances_to_triangles(scan_p[used], surface_triangles), cutoff, diagonal)
        for side, theirs, ours in (("surface to scan", surface_side, mine), ("scan to surface", scan_side, mine_scan)):
            reported = (theirs.mean, theirs.p95, theirs.max, theirs.ignored)
            off = max(abs(x - y) for x, y in zip(reported[:3], ours[:3]))
            check(off <= 1e-7 and reported[3] == ours[3],
                  "fit, %s %s: the report says mean %.6g, p95 %.6g, max %.6g, %d beyond the cut-off; brute force "
                  "%.6g, %.6g, %.6g, %d" % (side, when, *(reported + ours)))
            figures[(side, when)] = (ours, off)
    (before, _), (after, _) = figures[("surface to scan", "before")], figures[("surface to scan", "after")]
    (scan_before, _), (scan_after, _) = figures[("scan to surface", "before")], figures[("scan to surface", "after")]
    check(before[3] == 0 and scan_before[3] == 0,
          "fit: the cage given is not within the cut-off everywhere (%d samples, %d scan vertices beyond)"
          % (before[3], scan_before[3]))
    check(after[0] < before[0] / 10 and after[2] < before[2] / 5,
          "fit: the surface did not come closer: mean %.3g -> %.3g, max %.3g -> %.3g" % (before[0], after[0],
                                                                                      before[2], after[2]))
    check(scan_after[0] < scan_before[0] / 5,
          "fit: the scan's vertices did not come closer: mean %.3g -> %.3g" % (scan_before[0], scan_after[0]))
    worst = max(off for _, off in figures.values())
    return ("fit mean %.1e -> %.1e, max %.1e -> %.1e (scan side mean %.1e -> %.1e), report within %.0e of brute "
            "force" % (before[0], after[0], before[2], after[2], scan_before[0], scan_after[0], worst))


def replay(spia, name, case):
    """The cage spia makes of a saved case's inputs, with its settings."""
    mesh = spia.Mesh.from_faces(case["points"], case["faces"])
    if name == "fit":
        scan = spia.Scan(spia.Mesh.from_faces(case["scan_points"], case["scan_faces"]))
        return spia.fit(mesh, scan, cutoff=0.05, samples_per_edge=4)[0]
    if name == "loop":
        return spia.interpolate(mesh, scheme="LOOP")[0]
    return spia.interpolate(mesh, quality=int(name.rsplit(" ", 1)[1]))[0]


def save_cages(path):
    np.savez(path, **{"%s/%s" % (name, key): np.asarray(value) for name, case in cages.items()
                      for key, value in case.items()})


def compare_cages(spia, path):
    """Every saved case run again here: the cages must be the saved ones'
    bytes.  Returns a summary."""
    saved = {}
    with np.load(path) as data:
        for key in data.files:
            name, field = key.split("/")
            saved.setdefault(name, {})[field] = data[key]
    check(sorted(saved) == sorted(cages), "compare: %s holds %s, this run made %s" % (path, sorted(saved),
                                                                                   sorted(cages)))
    same_inputs, equal = 0, 0
    for name, case in sorted(saved.items()):
        ours = cages.get(name, {})
        if all(k in ours and np.array_equal(ours[k], case[k]) for k in case if k != "cage"):
            same_inputs += 1
        cage = np.asarray(replay(spia, name, case))
        theirs = case["cage"]
        if cage.dtype == theirs.dtype and cage.shape == theirs.shape and cage.tobytes() == theirs.tobytes():
            equal += 1
        else:
            off = (float(np.abs(cage.astype(np.float64) - theirs).max()) if cage.shape == theirs.shape
                   else float("inf"))
            check(False, "compare: %s: the cage differs from %s's (%s %s here, %s %s there; largest difference "
                  "%.3g of the input's diagonal)" % (name, os.path.basename(path), cage.dtype, cage.shape,
                                                     theirs.dtype, theirs.shape,
                                                     off / diagonal_of(case["points"])))
    return "%d of %d cages equal to %s's bit for bit (%d inputs made the same here)" % (
        equal, len(saved), os.path.basename(path), same_inputs)


# --------------------------------------------------------------------------

def site_directories():
    paths = set()
    for key in ("purelib", "platlib"):
        path = sysconfig.get_paths().get(key)
        if path:
            paths.add(path)
    if hasattr(site, "getsitepackages"):
        paths.update(site.getsitepackages())
    return sorted(os.path.realpath(p) for p in paths)


def under(path, folder):
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    try:
        return os.path.commonpath([path, folder]) == folder
    except ValueError:  # on different drives
        return False


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--from-path", metavar="DIR", help="import spia from DIR (put first on sys.path)")
    parser.add_argument("--expect-prefix", metavar="PREFIX", help="spia's file must lie under PREFIX")
    parser.add_argument("--save-cages", metavar="FILE", help="write the inputs and cages to FILE (.npz)")
    parser.add_argument("--compare-cages", metavar="FILE",
                        help="run spia again on the inputs in FILE: the cages must equal FILE's bit for bit")
    args = parser.parse_args(argv[1:])
    start = time.time()
    if args.from_path:
        sys.path.insert(0, os.path.abspath(args.from_path))
    try:
        import spia
    except Exception as exc:  # noqa: BLE001 (what failed, in one line)
        print("client_check: FAILED: import spia: %s: %s" % (type(exc).__name__, exc))
        return 1
    location = os.path.dirname(os.path.realpath(spia.__file__))
    expected = args.expect_prefix or args.from_path
    if expected:
        check(under(location, expected), "spia was imported from %s, not from under %s" % (location, expected))
    else:
        sites = site_directories()
        check(any(under(location, s) for s in sites),
              "spia was imported from %s, not from this environment's site-packages (%s)" % (location,
                                                                                        ", ".join(sites)))
    library_version, library = "?", ""
    parts = []
    if not spia.available():
        check(False, "the library does not load: %s" % spia.load_error())
    else:
        library_version = spia.version()
        library_folder = os.path.dirname(os.path.realpath(spia.library_path()))
        if library_folder != location:
            library = ", library from %s" % spia.library_path()
            check(expected, "the library was loaded from %s (SUBDIV_PIA_LIBRARY), not the package's own"
                  % spia.library_path())
        for step in (check_catmull_clark, check_loop, check_fit):
            try:
                parts.append(step(spia))
            except Exception:  # noqa: BLE001 (a failure to report, not to stop at)
                check(False, "%s raised:\n%s" % (step.__name__, traceback.format_exc().rstrip()))
        if args.save_cages:
            save_cages(args.save_cages)
        if args.compare_cages:
            try:
                parts.append(compare_cages(spia, args.compare_cages))
            except Exception:  # noqa: BLE001
                check(False, "compare_cages raised:\n%s" % traceback.format_exc().rstrip())
    head = "spia %s from %s%s (Python %s, numpy %s, %s)" % (library_version, location, library,
                                                           platform.python_version(), np.__version__,
                                                           platform.machine())
    if failures:
        print("client_check: FAILED: %s" % head)
        for what in failures:
            print("  " + what)
        return 1
    print("client_check: %s: %s; %.1f s" % (head, "; ".join(parts), time.time() - start))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
