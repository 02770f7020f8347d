# SPDX-License-Identifier: GPL-3.0-or-later
"""How close a subdivided cage comes to the scan it was made from.

    blender -b --factory-startup --python-exit-code 1 --python bench/bench_fit.py -- \
        [--cases bunny dragon armadillo chinese_dragon] [--force] [--check] [--export-test-data]

For each case (a scan in tests/data and a QuadriFlow face count) the cage
is QuadriFlow + shrinkwrap (fit_cases.make_cage), cached as OBJ in
out/bench/ (--force rebuilds it).  Each entry of METHODS turns a copy of
the cage into an object whose Subdivision Surface (level 3, limit surface,
quality 3) is measured against the scan with fit_cases.measure: distances
from the subdivided surface's vertices to the scan relative to the scan's
bounding-box diagonal (samples farther than 2% ignored: the scan's holes)
and the mean angle to the scan's normal.  Prints a Markdown table and
writes it to out/bench/fit.md.

--check also runs the kd-tree closest-point path on a subset of the points
and prints how far it is from the BVH one.  --export-test-data copies the
cages to tests/data (bun_zipper_quadriflow_cage.obj, ...).
"""
import argparse
import os
import shutil
import sys
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import fit_cases  # noqa: E402
from harness import FIT_CASES as CASES, OUT, ROOT, ensure_addon, finish, script_args  # noqa: E402

LEVELS = 3
CUTOFF = 0.02
SEED = 0


# --------------------------------------------------------------------------
# Methods: function(cage_obj, scan_obj) -> the object whose subdivision
# surface is measured.  cage_obj is a fresh copy of the shrinkwrapped cage,
# without modifiers; measure() adds (or sets) its Subdivision Surface
# modifier to LEVELS, limit surface, quality 3.

def shrinkwrap_subdivision(cage_obj, scan_obj):
    """The baseline: the shrinkwrapped cage as it is."""
    return cage_obj


LIBRARY_SECONDS = {}  # method name -> the library's own time in the last call


def _fit(mode):
    def method(cage_obj, scan_obj):
        """The add-on's fit (the script API the operator calls), fit=mode."""
        pia = ensure_addon()
        new_obj, report = pia.api.interpolate(cage_obj, target=scan_obj, fit=mode, levels=LEVELS)
        LIBRARY_SECONDS[mode] = (report.stencil_seconds + report.query_seconds + report.solve_seconds,
                                 report.rounds)
        return new_obj
    method.__name__ = "fit_" + mode.lower()
    return method


def _native_fit(**fit_options):
    """The library's surface fit called directly with fit_options (for the
    settings the add-on does not expose); the cage's copy gets the result."""
    def method(cage_obj, scan_obj):
        pia = ensure_addon()
        mesh = pia.api.native_mesh(cage_obj.data)
        scan = pia.api.make_scan(scan_obj, cage_obj)
        out, report = pia.native.fit(mesh, scan, mode='SURFACE', **fit_options)
        cage_obj.data.vertices.foreach_set("co", np.ascontiguousarray(out, np.float32).ravel())
        cage_obj.data.update()
        LIBRARY_SECONDS['SURFACE'] = (report.stencil_seconds + report.query_seconds + report.solve_seconds,
                                      report.rounds)
        return cage_obj
    return method


METHODS = [
    ("shrinkwrap + subdivision", shrinkwrap_subdivision),
    ("the cage's vertices onto the scan (fit VERTICES)", _fit('VERTICES')),
    ("the limit surface fitted (fit SURFACE)", _fit('SURFACE')),
    ("SURFACE without fold guard and robust kernel", _native_fit(allow_folds=True, hard_cutoff=True)),
    ("SURFACE long run: 60 rounds, smoothing 1e-6, no fold guard",
     _native_fit(allow_folds=True, max_rounds=60, round_tolerance=1e-4, smoothing=1e-6)),
    ("SURFACE long run with the fold guard: 60 rounds, smoothing 1e-6",
     _native_fit(max_rounds=60, round_tolerance=1e-4, smoothing=1e-6)),
]


# --------------------------------------------------------------------------

def off_rim_mean(obj, scan):
    """The mean distance again, leaving out the measured points whose closest
    scan point is on the scan's boundary (they lie over a hole, where no fit
    may pull), by the library's closest points, in obj's object space."""
    import numpy as np
    pia = ensure_addon()
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    pts = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", pts)
    ev.to_mesh_clear()
    s = pia.api.make_scan(scan, obj)
    d, rim = s.closest_points(pts.reshape(-1, 3), with_boundary=True)[2::2]
    kept = d <= CUTOFF * s.diagonal
    return ("over holes (closest point on the scan's rim) %.2g of them; mean without them %s"
            % (np.mean(rim[kept]), sci(d[kept & ~rim].mean() / s.diagonal)))


def scan_to_surface(obj, scan):
    """Distances the other way: from each scan vertex (that a face uses) to
    obj's evaluated surface (as measure() left it: level 3, limit surface),
    by mathutils' BVH tree, relative to the scan's diagonal.  Returns
    (mean, p95, max over those within the cut-off, share beyond it)."""
    from mathutils import Vector
    from mathutils.bvhtree import BVHTree
    pts, _, tris = fit_cases.evaluated_surface(obj)
    bvh = BVHTree.FromPolygons([Vector(p) for p in pts], tris.tolist(), all_triangles=True, epsilon=0.0)
    verts, scan_tris = fit_cases.scan_geometry(scan)
    used = np.unique(scan_tris)
    diag = fit_cases.diagonal(verts)
    d = np.array([bvh.find_nearest(Vector(p))[3] for p in verts[used]]) / diag
    kept = d <= CUTOFF
    return float(d[kept].mean()), float(np.percentile(d[kept], 95)), float(d[kept].max()), float(1 - kept.mean())


def turned_triangles(verts, tris):
    """Scan triangles whose normal is against the sum of their corners'
    area-weighted vertex normals: where the scan folds on itself."""
    fn = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    return np.einsum("ij,ij->i", fn, vn[tris].sum(axis=1)) < 0


def triangle_areas(verts, tris):
    return 0.5 * np.linalg.norm(np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]]),
                                axis=1)


def patches(mask, tris):
    """Labels of the connected patches of the vertices in mask (joined by
    the edges of tris between two of them); -1 outside mask."""
    label = np.where(mask, np.arange(len(mask)), -1)
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    edges = edges[mask[edges[:, 0]] & mask[edges[:, 1]]]
    while len(edges):
        low = np.minimum(label[edges[:, 0]], label[edges[:, 1]])
        new = label.copy()
        np.minimum.at(new, edges[:, 0], low)
        np.minimum.at(new, edges[:, 1], low)
        new[mask] = new[new[mask]]  # jump to the label's own label
        if np.array_equal(new, label):
            break
        label = new
    return label


def fold_breakdown(r, verts, turned):
    """Where the points facing away are: on scan triangles turned against
    their own corners (the scan folded on itself), and the rest's largest
    connected patch on the surface with its extent."""
    away = r["facing_away"]
    on_turned = away & turned[r["nearest_triangle"]]
    rest = away & ~on_turned
    text = "%d facing away, %d of them closest to scan triangles turned against their own corners' normals" % (
        away.sum(), on_turned.sum())
    if rest.any():
        label = patches(rest, r["surface_triangles"])
        ids, counts = np.unique(label[rest], return_counts=True)
        big = label == ids[np.argmax(counts)]
        pts = r["points"][big]
        extent = np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)) / fit_cases.diagonal(verts)
        text += ("; the other %d in %d patches on the surface, the largest %d points across %s of the diagonal"
                 % (rest.sum(), len(ids), counts.max(), sci(extent)))
    return text


def sci(x, digits=2):
    """1.21e-3 style; 0 as 0."""
    if x == 0:
        return "0"
    m, e = ("%.*e" % (digits, x)).split("e")
    return "%se%d" % (m, int(e))


def cache_path(case):
    scan_file, faces, _ = CASES[case]
    return os.path.join(OUT, "%s_quadriflow%d_seed%d.obj"
                        % (os.path.splitext(scan_file)[0], faces, SEED))


def load_case(case, force=False):
    """Empty scene with the scan and its cage (from the cache, or made and
    cached).  Returns (scan, cage, info) where info has the cage's vertex and
    face counts and, when made now, the cleanup steps and remesh seconds."""
    scan_file, faces, _ = CASES[case]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scan = fit_cases.import_obj(os.path.join(fit_cases.DATA, scan_file), "scan")
    path = cache_path(case)
    info = {}
    if force or not os.path.isfile(path):
        cage = fit_cases.make_cage(scan, faces, SEED, name="cage", report=info)
        fit_cases.export_obj(cage, path)
        info["made"] = True
    else:
        cage = fit_cases.import_obj(path, "cage")
        cage.data.polygons.foreach_set("use_smooth", np.ones(len(cage.data.polygons), bool))
        info["made"] = False
    info.setdefault("vertices", len(cage.data.vertices))
    info.setdefault("faces", len(cage.data.polygons))
    return scan, cage, info


def fresh_copy(obj, name):
    new = obj.copy()
    new.data = obj.data.copy()
    new.modifiers.clear()
    new.name = new.data.name = name
    bpy.context.scene.collection.objects.link(new)
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    new.select_set(True)
    bpy.context.view_layer.objects.active = new
    return new


def check_closest(cage, scan, step=10):
    """BVH against kd-tree closest points on every step-th subdivided vertex."""
    fit_cases.subdivide(cage, LEVELS)
    pts, _, _ = fit_cases.evaluated_surface(cage)
    verts, tris = fit_cases.scan_geometry(scan)
    sub = pts[::step]
    t0 = time.perf_counter()
    a, _ = fit_cases.closest_bvh(sub, verts, tris)
    t1 = time.perf_counter()
    b, _ = fit_cases.closest_kdtree(sub, verts, tris)
    t2 = time.perf_counter()
    da, db = np.linalg.norm(sub - a, axis=1), np.linalg.norm(sub - b, axis=1)
    diag = fit_cases.diagonal(verts)
    return ("%d points: BVH %.2f s, kd-tree %.2f s (with its build); "
            "|distance difference| max %.2g of the diagonal, kd-tree farther on %d"
            % (len(sub), t1 - t0, t2 - t1, np.abs(da - db).max() / diag,
               int(((db - da) > 1e-7 * diag).sum())))


def main(argv):
    parser = argparse.ArgumentParser(prog="bench_fit.py")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--force", action="store_true", help="rebuild the cached cages")
    parser.add_argument("--check", action="store_true", help="compare BVH and kd-tree closest points")
    parser.add_argument("--export-test-data", action="store_true",
                        help="copy the cages to tests/data")
    parser.add_argument("--detail", type=int, default=LEVELS, metavar="LEVELS",
                        help="also the detail levels beside Blender's Multires + Shrinkwrap workflow, same cage "
                             "and levels (bench_detail.py's table; 0: not)")
    args = parser.parse_args(argv)

    header = ["| method | cage | mean | 95th percentile | max | facing away | scan to surface: mean | p95 | max "
              "| scan not reached | time s |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    rows, notes = [], []
    print("\n".join(header), flush=True)
    for case in args.cases:
        scan_file, faces, test_file = CASES[case]
        t0 = time.perf_counter()
        scan, cage, info = load_case(case, args.force)
        if info["made"]:
            notes.append("%s: QuadriFlow %d faces, seed %d, %.1f s (cleanup: %s), shrinkwrap %.2f s"
                         % (scan_file, faces, SEED, info["remesh_s"],
                            "; ".join(info["cleanup"]) or "none", info["shrinkwrap_s"]))
        else:
            notes.append("%s: cage read from %s (made in an earlier run; --force remakes it)"
                         % (scan_file, os.path.relpath(cache_path(case), ROOT)))
        if args.export_test_data:
            shutil.copyfile(cache_path(case), os.path.join(fit_cases.DATA, test_file))
        label = "%s, %d v, %d quads" % (scan_file, info["vertices"], info["faces"])
        verts, tris = fit_cases.scan_geometry(scan)
        turned = turned_triangles(verts, tris)
        area = triangle_areas(verts, tris)
        notes.append("%s: %d of %d triangles (%.2f%% of the area) turned against their own corners' normals"
                     % (scan_file, turned.sum(), len(tris), 100 * area[turned].sum() / area.sum()))
        for name, method in METHODS:
            work = fresh_copy(cage, "%s %s" % (case, name))
            t0 = time.perf_counter()
            LIBRARY_SECONDS.clear()
            result = method(work, scan)
            seconds = time.perf_counter() - t0
            if LIBRARY_SECONDS:
                library, rounds = next(iter(LIBRARY_SECONDS.values()))
                notes.append("%s, %s: library %.2f s of the %.2f s (%d rounds); the rest is the "
                             "add-on reading the scan and making the object"
                             % (scan_file, name, library, seconds, rounds))
            r = fit_cases.measure(result, scan, levels=LEVELS, cutoff=CUTOFF)
            back = scan_to_surface(result, scan)
            row = ("| %s | %s | %s | %s | %s | %.3f%% | %s | %s | %s | %.2f%% | %.2f |"
                   % (name, label, sci(r["mean"]), sci(r["p95"]), sci(r["max"]), 100 * r["flipped"],
                      sci(back[0]), sci(back[1]), sci(back[2]), 100 * back[3], seconds))
            rows.append(row)
            print(row, flush=True)
            notes.append("%s, %s: %d samples, closest points (%s) %.1f s, mean angle to the scan's normal "
                         "%.1f deg, samples beyond the cut-off %s; %s"
                         % (scan_file, name, r["samples"], r["method"], r["seconds"], r["angle_deg"],
                            sci(r["ignored"], 1), off_rim_mean(result, scan)))
            notes.append("%s, %s, folds: %s" % (scan_file, name, fold_breakdown(r, verts, turned)))
        if args.check:
            notes.append("%s check: %s" % (scan_file, check_closest(fresh_copy(cage, "check"), scan)))
    text = "\n".join(
        ["Distances from the vertices of the level-%d subdivision surface (Blender %s, "
         "limit surface, quality 3) to the scan, relative to the scan's bounding-box "
         "diagonal; samples farther than %g ignored; facing away: the share of them whose "
         "vertex normal is more than 90 degrees from the scan triangle's normal; scan to "
         "surface: from the scan's vertices to that surface, and the share of them farther "
         "than the cut-off. Made by bench/bench_fit.py." %
         (LEVELS, bpy.app.version_string, CUTOFF), ""] + header + rows + [""]
        + ["- " + n for n in notes]) + "\n"
    print("\n".join("- " + n for n in notes))
    if args.detail:
        import bench_detail
        detail_rows = []
        print("\n".join(bench_detail.HEADER), flush=True)
        for case in args.cases:
            detail_rows += bench_detail.run_case(case, args.detail)
        text += "\n" + "\n".join(
            ["Detail levels (%d) beside Blender's workflow, the same cages, their finest level measured with "
             "mathutils (bench/bench_detail.py):" % args.detail, ""] + bench_detail.HEADER + detail_rows) + "\n"
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, "fit.md"), "w") as f:
        f.write(text)
    print("wrote %s" % os.path.relpath(os.path.join(OUT, "fit.md"), ROOT))


if __name__ == "__main__":
    main(script_args())
    finish()
