# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels side by side with Blender's own workflow, same cage, same levels.

    blender -b --factory-startup --python-exit-code 1 --python bench/bench_detail.py -- \
        [--cases bunny dragon armadillo chinese_dragon] [--levels 3]
    build/bpy/5.3/bin/python bench/bench_detail.py [--cases ...]

For each case (a scan in tests/data and its QuadriFlow cage, as bench_fit.py
uses them) every method gives a mesh of the cage's topology subdivided
`levels` times, in the same vertex order (a Multires modifier's finest
level), which detail_workflow.measure_detail measures against the scan
with mathutils' BVH tree, independently of the library:

  start          the QuadriFlow cage's own surface (Multires, no detail)
  Project        Blender's workflow: Multires, Shrinkwrap Project along the
                 normals both ways, Above Surface
  Nearest        the same with Shrinkwrap Nearest Surface Point
  fit            the Surface fit alone (its Multires without detail)
  fit + detail   the Surface fit with fit_detail_levels = levels

Columns: surface to scan at face centres and scan to surface at the scan's
vertices (mean, 95th percentile, max; and the median from the scan,
relative to the scan's diagonal), the scan to surface mean over the scan
the start covers (its vertices whose closest point on the start's finest
level is off its open edge: the rest lie beyond the cage's rims), the share of faces turned over against
the start's same face and, in brackets, of those where the start's face
faced the scan (the rest are the start's own folds turned back onto the
scan) and of those the folds: faces now facing away from the scan or
beyond detail_workflow.FOLD_FAR of it (the rest turned with the scan, in a
groove or an overhang), and the seconds each took.  Prints a Markdown table and writes out/bench/detail.md.
"""
import argparse
import os
import sys
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import detail_workflow  # noqa: E402
import fit_cases  # noqa: E402
from harness import DATA, FIT_CASES as CASES, OUT, ensure_addon, finish, script_args  # noqa: E402
HEADER = ["| case | method | surface to scan mean / p95 / max | scan to surface mean / median / p95 / max "
          "| scan the start covers: mean | faces turned (where the start faced the scan / folds) | s |",
          "|---|---|---|---|---:|---:|---:|"]


def plain_levels(obj, levels):
    """A copy of obj with a Multires of `levels` and no detail: its surface at that level."""
    copy = obj.copy()
    copy.data = obj.data.copy()
    for modifier in list(copy.modifiers):
        copy.modifiers.remove(modifier)
    bpy.context.scene.collection.objects.link(copy)
    fit_cases._activate(copy)
    detail_workflow.multires_levels(copy, levels)
    return copy


def row(name, method, seconds, m, covered):
    s, t = m["surface_to_scan"], m["scan_to_surface"]
    turned = m.get("turned")
    return ("| %s | %s | %.2e / %.2e / %.2e | %.2e / %.2e / %.2e / %.2e | %.2e | %s | %.1f |"
            % (name, method, s["mean"], s["p95"], s["max"], t["mean"], float(np.median(m["scan_distances"])),
               t["p95"], t["max"], float(m["scan_distances"][covered].mean()),
               "-" if turned is None else "%.3f%% (%.3f%% / %.3f%%)" % (100.0 * turned, 100.0 * m["turned_facing"],
                                                                   100.0 * m["turned_folded"]),
               seconds))


def start_facing(start, scan):
    """Per face of the start's finest level: whether it faces the scan's
    normal at its centre's closest point as most faces do (mathutils)."""
    from mathutils import Vector
    from mathutils.bvhtree import BVHTree
    normals, centres = detail_workflow.newell_normals(*start)
    verts, tris = fit_cases.scan_geometry(scan)
    # Plain Python numbers and Vectors: Blender 3.4's BVHTree crashes on numpy's.
    tree = BVHTree.FromPolygons([Vector(v) for v in verts.tolist()], tris.tolist(), all_triangles=True)
    scan_normals = np.array([tuple(tree.find_nearest(Vector(c))[1]) for c in centres.tolist()])
    dots = np.einsum("ij,ij->i", normals, scan_normals)
    return dots * (1.0 if dots.sum() >= 0.0 else -1.0) > 0.0


def start_covers(start, scan, native):
    """Per scan vertex used by a face (measure_detail's order): whether its
    closest point on the start's finest level is off that level's open
    edge.  Those that are not lie beyond the cage's rims, where no method
    puts a surface of this cage (the library's closest points, rim flags)."""
    positions, sizes, corners = start
    surface = native.Scan(native.Mesh(np.asarray(positions, np.float32), np.asarray(sizes, np.int32),
                                      np.asarray(corners, np.int32)))
    verts, tris = fit_cases.scan_geometry(scan)
    points = np.asarray(verts, np.float32)[np.unique(tris)]
    return ~np.asarray(surface.closest_points(points, with_boundary=True)[4], bool)


def run_case(name, levels):
    scan_file, _faces, cage_file = CASES[name]
    bpy.ops.wm.read_homefile(use_empty=True)
    api = ensure_addon().api
    scan = fit_cases.import_obj(os.path.join(DATA, scan_file), "Scan")
    cage = fit_cases.import_obj(os.path.join(DATA, cage_file), "Cage")
    start_obj = plain_levels(cage, levels)
    start = detail_workflow.top_level_mesh(start_obj)
    facing = start_facing(start, scan)
    covered = start_covers(start, scan, api.native)
    lines = []

    def measure(method, obj, seconds):
        positions, sizes, corners = detail_workflow.top_level_mesh(obj)
        assert np.array_equal(corners, start[2]), "not the start's topology"
        m = detail_workflow.measure_detail(positions, sizes, corners, scan, start_positions=start[0],
                                           start_facing=facing)
        lines.append(row(name, method, seconds, m, covered))
        print(lines[-1], flush=True)
    measure("start", start_obj, 0.0)
    for method in ("PROJECT", "NEAREST"):
        t = time.perf_counter()
        result = detail_workflow.blender_workflow(cage, scan, levels=levels, method=method)
        measure(method.title(), result, time.perf_counter() - t)
    t = time.perf_counter()
    fitted, _report = api.interpolate(cage, target=scan.name)
    fit_seconds = time.perf_counter() - t
    measure("fit", plain_levels(fitted, levels), fit_seconds)
    t = time.perf_counter()
    detailed, _report = api.interpolate(cage, target=scan.name, fit_detail_levels=levels)
    measure("fit + detail", detailed, time.perf_counter() - t)
    return lines


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--levels", type=int, default=3)
    args = parser.parse_args(script_args())
    header = HEADER
    print("\n".join(header), flush=True)
    lines = []
    for name in args.cases:
        lines += run_case(name, args.levels)
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, "detail.md"), "w") as f:
        f.write("Blender %s, %d levels\n\n" % (bpy.app.version_string, args.levels))
        f.write("\n".join(header + lines) + "\n")
    finish()


if __name__ == "__main__":
    main()
