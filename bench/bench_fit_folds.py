# SPDX-License-Identifier: GPL-3.0-or-later
"""Folds a Surface fit makes, measured against the cage it started from.

    SUBDIV_PIA_LIBRARY=build/cmake/libsubdiv_pia.so python3 bench/bench_fit_folds.py [--cases ...]

For each of bench_fit.py's cases (a scan in tests/data and its QuadriFlow
cage) the cage is fitted (spia.fit, the add-on's settings) and both cages'
limit surfaces are sampled at the same points: 8 x 8 per ptex face, the
points of Blender's level 3 (spia.surface_stencils).  A point's normal is
the cross product of its neighbours' differences along the sample grid (in
numpy); the share of points whose normal the fit turned by more than 90
degrees against the starting cage's is printed beside the fit's own count
(samples facing away from the scan's normal, which counts the scan's own
folds too) and the mean distance, as a Markdown table; and the share of
those where the starting cage faced the scan (the rest are folds of the
starting cage that the fit turned back), and of those the folds (facing
away from the scan, or beyond FOLD_FAR of it).
"""
import argparse
import os
import sys
import time

import numpy as np

from harness import DATA, FIT_CASES as CASES, ROOT

sys.path.insert(0, os.path.join(ROOT, "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))
import spia  # noqa: E402
from meshio import read_obj  # noqa: E402

PER_EDGE = 8


def load(name):
    positions, faces, _creases = read_obj(os.path.join(DATA, name))
    return spia.Mesh.from_faces(positions, faces)


def grid_normals(points, k):
    """Per sample of k x k grids (rows along u), the cross product of its
    neighbours' differences along u and v (one-sided at the grid's edges)."""
    g = points.reshape(-1, k, k, 3)  # [ptex, j (v), i (u)]
    du = np.empty_like(g)
    dv = np.empty_like(g)
    du[:, :, 1:-1] = g[:, :, 2:] - g[:, :, :-2]
    du[:, :, 0] = g[:, :, 1] - g[:, :, 0]
    du[:, :, -1] = g[:, :, -1] - g[:, :, -2]
    dv[:, 1:-1] = g[:, 2:] - g[:, :-2]
    dv[:, 0] = g[:, 1] - g[:, 0]
    dv[:, -1] = g[:, -1] - g[:, -2]
    return np.cross(du, dv).reshape(-1, 3)


# A turned point farther than this share of the scan's diagonal from the
# scan follows nothing of it: a fold whichever way it faces (as
# detail_workflow.FOLD_FAR).
FOLD_FAR = 1e-3


def turned_share(cage, start, fitted, scan=None):
    """Share of the level-3 points whose normal turned by more than 90
    degrees from start to fitted; with scan, also the share of those where
    the start faced the scan's normal at its closest point as most of the
    start does (the others the fit turned back onto the scan), and of
    those the folds: points facing away from the scan's normal at their own
    closest point, or beyond FOLD_FAR of it (the others turned with the
    scan, into a groove or under an overhang)."""
    stencils = spia.surface_stencils(cage, samples_per_edge=PER_EDGE)
    p0 = stencils.limit_points(start)
    p1 = stencils.limit_points(fitted)
    n0 = grid_normals(p0, PER_EDGE)
    n1 = grid_normals(p1, PER_EDGE)
    turned = np.einsum("ij,ij->i", n0, n1) < 0.0
    if scan is None:
        return float(np.mean(turned))
    normals = scan.closest_points(p0)[1]
    facing = np.einsum("ij,ij->i", n0, normals)
    sign = 1.0 if facing.sum() >= 0.0 else -1.0
    made = turned & (sign * facing > 0.0)
    _closest, normals1, distances, _faces = scan.closest_points(p1)
    away = (sign * np.einsum("ij,ij->i", n1, normals1) <= 0.0) | (distances > FOLD_FAR * scan.diagonal)
    return float(np.mean(turned)), float(np.mean(made)), float(np.mean(made & away))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    args = parser.parse_args()
    print("| case | mean distance | facing away from the scan | turned against the start | of them where the start "
          "faced the scan | of those, folds | s |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name in args.cases:
        scan_file, _faces, cage_file = CASES[name]
        scan = spia.Scan(load(scan_file))
        cage = load(cage_file)
        t = time.perf_counter()
        fitted, report = spia.fit(cage, scan)
        seconds = time.perf_counter() - t
        turned, made, folds = turned_share(cage, cage.positions, fitted, scan)
        print("| %s | %.3e | %.3f%% | %.3f%% | %.3f%% | %.3f%% | %.1f |"
              % (name, report.after.mean, 100.0 * report.folded_after / report.sample_count, 100.0 * turned,
                 100.0 * made, 100.0 * folds, seconds), flush=True)


if __name__ == "__main__":
    main()
