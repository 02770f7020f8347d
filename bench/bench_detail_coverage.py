# SPDX-License-Identifier: GPL-3.0-or-later
"""Where the detail levels' distances come from: the scan's holes and the
cage's own.

    SUBDIV_PIA_LIBRARY=build/cmake/libsubdiv_pia.so python3 bench/bench_detail_coverage.py [--cases ...] [--levels 3]

For each of bench_fit.py's cases (a scan in tests/data and its QuadriFlow
cage) the cage is fitted (spia.fit) and given detail levels
(spia.fit_detail).  Both directions of bench_detail.py's distances are
then split, with the library's closest points and their rim flags:

  surface to scan    the finest level's face centres (its flat faces, as
                     Multires draws them) to the scan; "over holes" are the
                     faces whose closest scan point is on the scan's rim,
                     where the surface spans a hole of the scan
  scan to surface    the scan's vertices used by a face to the finest
                     level; "uncovered" are those whose closest point is on
                     the finest level's open edge, scan the cage does not
                     reach

Each as mean / 95th percentile over all and over the rest, relative to the
scan's diagonal, with the share split off.  Prints a Markdown table.
"""
import argparse
import time

import numpy as np

from bench_fit_folds import CASES, load, spia


def split(distances, flagged, diagonal):
    """'mean / p95' over all and over the unflagged, and the flagged share."""
    d = distances / diagonal
    rest = d[~flagged]

    def stats(x):
        return "%.2e / %.2e" % (x.mean(), np.percentile(x, 95)) if len(x) else "-"
    return stats(d), stats(rest), "%.1f%%" % (100.0 * flagged.mean())


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--levels", type=int, default=3)
    args = parser.parse_args()
    print("| case | surface to scan: all | over holes | the rest | scan to surface: all | uncovered | the rest | s |")
    print("|---|---|---:|---|---|---:|---|---:|")
    for name in args.cases:
        scan_file, _faces, cage_file = CASES[name]
        scan_mesh = load(scan_file)
        scan = spia.Scan(scan_mesh)
        cage = load(cage_file)
        t = time.perf_counter()
        fitted, _report = spia.fit(cage, scan)
        detail = spia.fit_detail(spia.Mesh(fitted, cage.face_sizes, cage.face_vertices), scan, args.levels)
        seconds = time.perf_counter() - t
        centres = detail.points[detail.mesh.face_vertices.reshape(-1, 4)].mean(axis=1)
        _, _, to_scan, _, over_hole = scan.closest_points(centres, with_boundary=True)
        surface = spia.Scan(spia.Mesh(detail.points, detail.mesh.face_sizes, detail.mesh.face_vertices))
        scan_points = scan_mesh.positions[np.unique(scan_mesh.face_vertices)]
        _, _, to_surface, _, uncovered = surface.closest_points(scan_points, with_boundary=True)
        s_all, s_rest, s_share = split(to_scan, over_hole, scan.diagonal)
        t_all, t_rest, t_share = split(to_surface, uncovered, scan.diagonal)
        print("| %s | %s | %s | %s | %s | %s | %s | %.1f |"
              % (name, s_all, s_share, s_rest, t_all, t_share, t_rest, seconds), flush=True)


if __name__ == "__main__":
    main()
