# SPDX-License-Identifier: GPL-3.0-or-later
"""Detail levels at production scale: a 50k-vertex cage of the dragon with
3 detail levels (3.2M faces at the finest) on the dragon refined to 4.9M
triangles.

    build/bpy/5.3/bin/python bench/bench_detail_scale.py [--levels 3] [--cage 50000] [--scan dragon_s2]
    blender -b --factory-startup --python-exit-code 1 --python bench/bench_detail_scale.py -- [...]

The scan and the cage are bench_fit_scale.py's (made and cached by it under
out/bench/fit_scale/).  subdiv_pia.api.interpolate(cage, target=scan,
fit_detail_levels=levels) is timed from the call to the new object evaluated
(its Multires as Blender shows it), split into: reading the scan and
building its hierarchy, the fit of the cage, each detail level's subdivision
and fit (the finest level's flat positions within its fit, counted in its
solves, where the fit gives them; on a line of their own where
flat_positions computes them), and Blender's share (Blender's order computed
from the levels, or where it cannot be, its Subdivision Surface for the
order and the match; Multires subdivided; Reshape; the evaluation).  Also the
process's peak resident size.  Prints a Markdown table.

Then, in the same process on the same cage, Blender's hand workflow
(detail_workflow.blender_workflow: Multires subdivided `levels` times,
Shrinkwrap Project both ways, evaluated), timed by its two stages with its
own peak, and the ratio of the two workflows' times (ours over Blender's).
--order blender-first runs Blender's first (the second run finds the
scan's data warm).
"""
import argparse
import os
import sys
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import bench_fit_scale as scale  # noqa: E402
import detail_workflow  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--cage", type=int, default=scale.TARGET_CAGE)
    parser.add_argument("--scan", default="dragon_s2", choices=list(scale.SCANS))
    parser.add_argument("--order", default="ours-first", choices=("ours-first", "blender-first"))
    args = parser.parse_args(scale.script_args())
    scale.prepare([args.scan], [args.cage], False)
    pia = scale.ensure_addon()
    api = pia.api
    from subdiv_pia import compute, detail, native, steps
    bpy.ops.wm.read_homefile(use_empty=True)
    scan = scale._load(scale.scan_path(args.scan), "scan")
    cage = scale._load(scale.cage_path(args.cage), "cage")
    seconds = {}

    def timed(key, fn):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - t0
        return wrapper

    native.Scan = timed("scan: hierarchy", native.Scan)
    native.subdivide = timed("subdivide (levels)", native.subdivide)
    native.flat_positions = timed("finest level's flat positions", native.flat_positions)
    def timed_steps(key, steps_fn):  # a generator's time from its first step to its return
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return (yield from steps_fn(*a, **k))
            finally:
                seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - t0
        return wrapper

    steps.apply_detail_steps = timed_steps("Blender's share, all", steps.apply_detail_steps)
    order_work = detail.order_work
    detail.order_work = lambda *a, **k: timed("  Blender's order, computed", order_work(*a, **k))
    detail._subsurf_topology = timed("  Blender: Subdivision Surface for the order", detail._subsurf_topology)
    detail.match_order = timed("  matching the order", detail.match_order)
    detail._subdivide_multires = timed("  Blender: Multires subdivided", detail._subdivide_multires)
    detail._reshape = timed("  Blender: Reshape", detail._reshape)
    levels_seen = []
    fit = native.fit

    fit_reports = {}

    def fit_timed(mesh, *a, **k):
        t0 = time.perf_counter()
        key = "fit, cage" if not levels_seen else "fit, level %d" % len(levels_seen)
        try:
            result = fit(mesh, *a, **k)
            fit_reports[key] = result[1]
            return result
        finally:
            seconds[key] = time.perf_counter() - t0
            levels_seen.append(len(mesh.positions))
    native.fit = fit_timed
    hand = {}

    def blender_hand():
        rss = scale.proc_status("VmRSS")
        scale.reset_peak()
        t0 = time.perf_counter()
        obj = detail_workflow.blender_workflow(cage, scan, levels=args.levels, method='PROJECT', report=hand)
        hand.update(total=time.perf_counter() - t0, peak=scale.proc_status("VmHWM"), rss0=rss)
        mesh = obj.data
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)
    if args.order == "blender-first":
        blender_hand()
    rss0 = scale.proc_status("VmRSS")
    scale.reset_peak()
    t0 = time.perf_counter()
    new_obj, report = api.interpolate(cage, target=scan.name, fit_detail_levels=args.levels)
    # The new object as Blender shows it: its Multires evaluated (the hand
    # workflow's time holds its own evaluation too).
    t1 = time.perf_counter()
    new_obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    seconds["Blender: the new object evaluated"] = time.perf_counter() - t1
    total = time.perf_counter() - t0
    peak = scale.proc_status("VmHWM")
    if args.order == "ours-first":
        blender_hand()
    faces = len(cage.data.polygons) * 4 ** args.levels
    print("Blender %s, %d processors; cage %d vertices, scan %d triangles, %d levels (%d faces at the finest)\n"
          % (bpy.app.version_string, os.cpu_count() or 1, len(cage.data.vertices),
             sum(len(p.vertices) - 2 for p in scan.data.polygons), args.levels, faces))
    print("| step | s |\n|---|---:|")
    for key, value in seconds.items():
        print("| %s | %.1f |" % (key, value))
    print("| **total** (interpolate, call to object evaluated) | **%.1f** |" % total)
    print("\nThe fits' own split (their reports):\n\n| fit | samples | rounds | stencils s | queries s | solve s |"
          "\n|---|---:|---:|---:|---:|---:|")
    for key, rep in fit_reports.items():
        print("| %s | %d | %d | %.1f | %.1f | %.1f |" % (key, rep.sample_count, rep.rounds, rep.stencil_seconds,
                                                       rep.query_seconds, rep.solve_seconds))
    print("\npeak resident size %.1f GB (%.1f GB before the call)" % (peak / 2**30, rss0 / 2**30))
    print("\nBlender's hand workflow on the same cage, the same process (%s):\n" % args.order)
    print("| workflow | s | peak GB | above the start GB |\n|---|---:|---:|---:|")
    print("| ours: interpolate with %d detail levels | %.1f | %.1f | %.1f |"
          % (args.levels, total, peak / 2**30, (peak - rss0) / 2**30))
    print("| Blender: Multires subdivided %d times | %.1f | | |" % (args.levels, hand["subdivide_s"]))
    print("| Blender: Shrinkwrap (Project, both ways) evaluated | %.1f | | |" % hand["evaluate_s"])
    print("| Blender: all | %.1f | %.1f | %.1f |" % (hand["total"], hand["peak"] / 2**30,
                                                   (hand["peak"] - hand["rss0"]) / 2**30))
    print("\nratio (ours / Blender's): **%.2f**" % (total / hand["total"]))
    print("finest level: mean %.3g, p95 %.3g of the diagonal from the scan; scan to it: mean %.3g, p95 %.3g"
          % (new_obj["pia_fit_detail_mean"], new_obj["pia_fit_detail_p95"],
             new_obj.get("pia_fit_detail_scan_mean", float("nan")),
             new_obj.get("pia_fit_detail_scan_p95", float("nan"))))
    scale.finish()


if __name__ == "__main__":
    main()
