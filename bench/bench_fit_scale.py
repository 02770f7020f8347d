# SPDX-License-Identifier: GPL-3.0-or-later
"""How the surface fit's time and memory grow with the cage and the scan.

    blender -b --factory-startup --python-exit-code 1 --python bench/bench_fit_scale.py -- \
        [--grid cross|full|target] [--cages 6000 12000 ...] [--scans dragon dragon_s2 ...] \
        [--repeat N] [--force] [--json out/bench/fit_scale.json]
    /work/.../bpy/5.2/bin/python bench/bench_fit_scale.py [same arguments]

Scans (cached as .blend under out/bench/fit_scale/blender-<version>/,
--force remakes them):
tests/data/dragon_res2.obj as it is and refined by Blender's Subdivision
Surface modifier, SIMPLE (the surface stays the same, only denser: every fit
does the same work per sample, whatever the scan's size), applied:

    dragon       202k triangles
    dragon_s1    1 level: 607k quads (1.2M triangles)
    dragon_s2    2 levels: 2.43M quads (4.9M triangles)
    dragon_s1t1  1 level, triangulated, 1 level: 3.6M quads (7.3M triangles)

Cages: Blender's voxel remesher on the dragon, the voxel size searched for
about 6k, 12k, 25k, 50k and 100k vertices, then a Shrinkwrap (nearest
surface point) onto the dragon, applied; cached likewise.

Each (cage, scan) pair runs in a process of its own (the bpy module's
Python, or this Blender): the scene holds the two objects, the peak
resident size is reset (/proc/self/clear_refs), and
subdiv_pia.api.interpolate(cage, target=scan, fit='SURFACE', levels=1) is
timed from the call to the new object, split into: the add-on reading the
scan (api.scan_arrays), spia_scan_create (native.Scan), the library's fit
(the report's stencil, query and solve seconds; "fit other" is the rest of
compute_cage: reading the cage, the library's own set-up) and writing the
object (the rest of the call).  Memory: the process's peak resident size
during the call (VmHWM) and its growth over the resident size before it.
Progress: the longest time between the call and the progress calls (how
long a cancel could wait), and when it began.

--grid cross (the default) sweeps the cage sizes on the largest scan and
the scans under the 50k cage; full runs every pair; target the 50k cage on
the 4.9M- and 7.3M-triangle scans only.  Prints a Markdown table and the
log-log slopes of time against cage size and against scan size, writes
out/bench/fit_scale.md and the figures as .json; bench/plot_fit_scale.py
draws the log-log plot from that .json (out/bench/fit_scale.png).
"""
import argparse
import json
import os
import subprocess
import sys
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import fit_cases  # noqa: E402
# (bench_detail_scale.py takes these from here too.)
from harness import OUT, ROOT, ensure_addon, finish, proc_status, replace_everywhere, reset_peak, script_args  # noqa: E402

# Per Blender version: a .blend written by one cannot always be read by an
# older one (5.0 changed the file header).
CACHE = os.path.join(OUT, "fit_scale", "blender-%d.%d" % bpy.app.version[:2])
LEVELS = 1
CAGE_SIZES = [6000, 12000, 25000, 50000, 100000]
TARGET_CAGE = 50000
# name: (levels of SIMPLE subdivision, triangulated after the first level)
SCANS = {
    "dragon": (0, False),
    "dragon_s1": (1, False),
    "dragon_s2": (2, False),
    "dragon_s1t1": (2, True),
}
LARGEST_SCAN = "dragon_s1t1"


# --------------------------------------------------------------------------
# Scans and cages, cached as .blend files of one object each

def _save_alone(obj, path):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    bpy.data.libraries.write(path, {obj}, compress=False)


def _load(path, name):
    with bpy.data.libraries.load(path) as (src, dst):
        dst.objects = [name]
    obj = dst.objects[0]
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _apply(obj, mod):
    for other in bpy.context.scene.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.modifier_apply(modifier=mod.name)


def scan_path(name):
    return os.path.join(CACHE, "scan_%s.blend" % name)


def cage_path(size):
    return os.path.join(CACHE, "cage_%d.blend" % size)


def make_scan_object(name):
    levels, triangulate = SCANS[name]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    obj = fit_cases.import_obj(os.path.join(fit_cases.DATA, "dragon_res2.obj"), "scan")
    for level in range(levels):
        mod = obj.modifiers.new("Subdivision", 'SUBSURF')
        mod.subdivision_type = 'SIMPLE'
        mod.levels = 1
        _apply(obj, mod)
        if triangulate and level == 0:
            mod = obj.modifiers.new("Triangulate", 'TRIANGULATE')
            _apply(obj, mod)
    obj.name = obj.data.name = "scan"
    return obj


def make_cage_object(size, report):
    """The voxel remesher's cage of the dragon nearest `size` vertices
    (a few tries, the voxel size scaled by the square root of the miss),
    shrinkwrapped onto the dragon."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scan = fit_cases.import_obj(os.path.join(fit_cases.DATA, "dragon_res2.obj"), "dragon")
    diag = fit_cases.diagonal(fit_cases.world_positions(scan.data, scan.matrix_world))
    voxel = diag * 0.4 / np.sqrt(size)  # a first guess, refined below
    best = None
    for attempt in range(5):
        cage = scan.copy()
        cage.data = scan.data.copy()
        bpy.context.scene.collection.objects.link(cage)
        cage.data.remesh_voxel_size = voxel
        cage.data.remesh_voxel_adaptivity = 0.0
        for other in bpy.context.scene.objects:
            other.select_set(False)
        cage.select_set(True)
        bpy.context.view_layer.objects.active = cage
        bpy.ops.object.voxel_remesh()
        n = len(cage.data.vertices)
        if best is None or abs(np.log(n / size)) < abs(np.log(len(best.data.vertices) / size)):
            if best is not None:
                bpy.data.objects.remove(best)
            best = cage
        else:
            bpy.data.objects.remove(cage)
        if abs(n / size - 1) < 0.03:
            break
        voxel *= np.sqrt(n / size)
    cage = best
    mod = cage.modifiers.new("Shrinkwrap", 'SHRINKWRAP')
    mod.wrap_method = 'NEAREST_SURFACEPOINT'
    mod.wrap_mode = 'ON_SURFACE'
    mod.target = scan
    _apply(cage, mod)
    cage.data.polygons.foreach_set("use_smooth", np.ones(len(cage.data.polygons), bool))
    cage.name = cage.data.name = "cage"
    report["voxel_size"] = float(voxel)
    return cage


def prepare(scans, cages, force):
    """Makes the cached scans and cages that are missing."""
    for name in scans:
        path = scan_path(name)
        if force or not os.path.isfile(path):
            t0 = time.perf_counter()
            obj = make_scan_object(name)
            _save_alone(obj, path)
            print("made %s: %d vertices, %d faces, %.1f s" % (os.path.relpath(path, ROOT), len(obj.data.vertices),
                                                             len(obj.data.polygons), time.perf_counter() - t0),
                  flush=True)
    for size in cages:
        path = cage_path(size)
        if force or not os.path.isfile(path):
            t0 = time.perf_counter()
            info = {}
            obj = make_cage_object(size, info)
            _save_alone(obj, path)
            print("made %s: %d vertices, %d faces (voxel size %.3g), %.1f s"
                  % (os.path.relpath(path, ROOT), len(obj.data.vertices), len(obj.data.polygons),
                     info["voxel_size"], time.perf_counter() - t0), flush=True)


# --------------------------------------------------------------------------
# One case, in this process

class RssSampler:
    """The resident size every 20 ms on a thread of its own: when the peak
    was reached, to tell which phase sets it."""

    def __init__(self):
        import threading
        self.samples = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            self.samples.append((time.perf_counter(), proc_status("VmRSS") or 0))
            self._stop.wait(0.02)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def run_case(cage_size, scan_name):
    pia = ensure_addon()
    api, native = pia.api, pia.api.native
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scan = _load(scan_path(scan_name), "scan")
    cage = _load(cage_path(cage_size), "cage")
    for other in bpy.context.scene.objects:
        other.select_set(False)
    cage.select_set(True)
    bpy.context.view_layer.objects.active = cage
    tris = int(np.sum(api.read_face_sizes(scan.data) - 2))
    seconds = {}

    starts = {}

    def timed(key, fn):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            starts.setdefault(key, t0)
            try:
                return fn(*a, **k)
            finally:
                seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - t0
        return wrapper

    replace_everywhere(api, "scan_arrays", timed("read_scan", api.scan_arrays))
    native.Scan = timed("scan_create", native.Scan)
    # interpolate() reads the cage (prepare_cage) and then runs the library
    # (the run it returns): both count as compute_cage.
    prepare_cage = api.prepare_cage

    def timed_prepare(*a, **k):
        run, explain = timed("compute_cage", prepare_cage)(*a, **k)
        return timed("compute_cage", run), explain
    replace_everywhere(api, "prepare_cage", timed_prepare)
    bpy.context.view_layer.update()
    rss = proc_status("VmRSS")
    peak_reset = reset_peak()
    calls = []

    def progress(round_, mean):
        calls.append(time.perf_counter())
        return False
    with RssSampler() as sampler:
        t0 = time.perf_counter()
        new_obj, report = api.interpolate(cage, target=scan, fit='SURFACE', levels=LEVELS, progress=progress)
        total = time.perf_counter() - t0
    # How long a cancel could wait: the longest time without a progress
    # call, from the call to the last progress call (writing the object
    # after it cannot be cancelled).
    marks = [t0] + calls
    gaps = np.diff(marks) if len(marks) > 1 else np.array([total])
    longest = int(np.argmax(gaps))
    hwm = proc_status("VmHWM")
    # Where the sampled peak fell: after the scan was made (so in the fit),
    # and within the fit's first stencil_seconds (the stencils) or later.
    peak_t, peak_rss = max(sampler.samples, key=lambda x: x[1]) if sampler.samples else (t0, 0)
    fit_start = starts.get("compute_cage", t0)
    scan_end = starts.get("scan_create", t0) + seconds.get("scan_create", 0.0)
    rss_after_scan = max([r for t, r in sampler.samples if t <= fit_start] or [0])
    fit = report.stencil_seconds + report.query_seconds + report.solve_seconds
    return {
        "cage": cage_size, "scan": scan_name,
        "cage_vertices": len(cage.data.vertices), "cage_faces": len(cage.data.polygons),
        "scan_vertices": len(scan.data.vertices), "scan_faces": len(scan.data.polygons), "scan_triangles": tris,
        "samples": report.sample_count, "rounds": report.rounds,
        "mean_before": report.before.mean, "mean_after": report.after.mean,
        "total": total,
        "read_scan": seconds["read_scan"],
        "scan_create": seconds["scan_create"],
        "stencil": report.stencil_seconds, "query": report.query_seconds, "solve": report.solve_seconds,
        "fit_other": seconds["compute_cage"] - fit,
        "write": total - seconds["read_scan"] - seconds["scan_create"] - seconds["compute_cage"],
        "rss_before": rss, "peak": hwm if peak_reset else None,
        "peak_growth": (hwm - rss) if (peak_reset and hwm and rss) else None,
        "new_object": new_obj.name,
        "progress_calls": len(calls), "longest_gap": float(gaps[longest]),
        "longest_gap_at": float(marks[longest] - t0),
        "sampled_peak": peak_rss, "sampled_peak_after_fit_start": peak_t - fit_start,
        "peak_in_scan_build": bool(peak_t <= scan_end), "rss_peak_before_fit": rss_after_scan,
    }


def child_command(args):
    script = os.path.abspath(__file__)
    if getattr(bpy.app, "module", False):
        return [sys.executable, script] + args
    return [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1", "--python", script,
            "--"] + args


def run_in_child(cage_size, scan_name, addon_dir=None):
    out = os.path.join(CACHE, "case_%d_%s.json" % (cage_size, scan_name))
    if os.path.exists(out):
        os.remove(out)
    cmd = child_command(["--child", str(cage_size), scan_name, out])
    env = dict(os.environ)
    if addon_dir:
        env["SUBDIV_PIA_ADDON_DIR"] = os.path.abspath(addon_dir)
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    if proc.returncode != 0 or not os.path.isfile(out):
        sys.stdout.write(proc.stdout[-4000:])
        raise RuntimeError("case %d / %s failed (exit %d)" % (cage_size, scan_name, proc.returncode))
    with open(out) as f:
        return json.load(f)


# --------------------------------------------------------------------------
# Table and slopes

COLUMNS = [("total", "total s"), ("read_scan", "read scan"), ("scan_create", "scan create"),
           ("stencil", "stencils"), ("query", "queries"), ("solve", "solve"), ("fit_other", "fit other"),
           ("write", "write object")]


def gb(x):
    return "%.2f" % (x / 2.0 ** 30) if x else "-"


def table(rows):
    head = ("| cage v | scan tris | samples | rounds | " + " | ".join(c[1] for c in COLUMNS)
            + " | peak GB | growth GB | longest progress gap s (at s) |")
    lines = [head, "|" + "---:|" * (head.count("|") - 1)]
    for r in rows:
        gap = "%.2f (%.1f)" % (r["longest_gap"], r["longest_gap_at"]) if "longest_gap" in r else "-"
        lines.append("| %d | %.2fM | %dk | %d | %s | %s | %s | %s |"
                     % (r["cage_vertices"], r["scan_triangles"] / 1e6, r["samples"] // 1000, r["rounds"],
                        " | ".join("%.2f" % r[c[0]] for c in COLUMNS), gb(r["peak"]), gb(r["peak_growth"]), gap))
    return lines


def slope(xs, ys):
    if len(xs) < 2:
        return None
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def slopes(rows):
    """Log-log slopes of each phase against cage size (rows on one scan) and
    against scan size (rows under one cage)."""
    out = {}
    by_scan, by_cage = {}, {}
    # The number of rounds differs from case to case (the fit stops when
    # they stop paying): per round (and the two evaluations besides) too.
    extra = [("query_per_round", ""), ("solve_per_round", "")]
    for r in rows:
        r["query_per_round"] = r["query"] / (r["rounds"] + 2)
        r["solve_per_round"] = r["solve"] / max(r["rounds"], 1)
    for r in rows:
        by_scan.setdefault(r["scan"], []).append(r)
        by_cage.setdefault(r["cage"], []).append(r)
    for label, groups, xkey in (("cage", by_scan, "cage_vertices"), ("scan", by_cage, "scan_triangles")):
        for key, group in groups.items():
            if len(group) < 2:
                continue
            xs = [r[xkey] for r in group]
            out["%s sizes (%s %s)" % (label, "scan" if label == "cage" else "cage", key)] = {
                c: slope(xs, [max(r[c], 1e-4) for r in group]) for c, _ in COLUMNS + extra + [("peak_growth", "")]
                if all(r[c] is not None for r in group)}
    return out


def export_scan_data(scans, cage_size=TARGET_CAGE):
    """Raw arrays for bench/bench_scan_scale.c (make bench-scan): each scan
    as out/bench/fit_scale/<scan>.bin and the level-2 Catmull-Clark vertices
    of the cage (about the fit's samples) as queries_<cage>.bin."""
    prepare(scans, [cage_size], False)
    for name in scans:
        path = os.path.join(CACHE, name + ".bin")
        if os.path.isfile(path) and os.path.getmtime(path) > os.path.getmtime(scan_path(name)):
            continue
        bpy.ops.wm.read_factory_settings(use_empty=True)
        me = _load(scan_path(name), "scan").data
        pos = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", pos)
        offsets = np.empty(len(me.polygons) + 1, np.int32)
        me.polygons.foreach_get("loop_start", offsets[:-1])
        offsets[-1] = len(me.loops)
        corners = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", corners)
        with open(path, "wb") as f:
            np.array([len(me.vertices), len(me.polygons), len(corners)], np.int64).tofile(f)
            pos.tofile(f)
            np.diff(offsets).astype(np.int32).tofile(f)
            corners.tofile(f)
    path = os.path.join(CACHE, "queries_%d.bin" % cage_size)
    if not os.path.isfile(path):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        cage = _load(cage_path(cage_size), "cage")
        mod = cage.modifiers.new("Subdivision", 'SUBSURF')
        mod.levels = 2
        evaluated = cage.evaluated_get(bpy.context.evaluated_depsgraph_get())
        me = evaluated.to_mesh()
        pts = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", pts)
        evaluated.to_mesh_clear()
        with open(path, "wb") as f:
            np.array([len(pts) // 3], np.int64).tofile(f)
            pts.tofile(f)


def main(argv):
    parser = argparse.ArgumentParser(prog="bench_fit_scale.py")
    parser.add_argument("--child", nargs=3, metavar=("CAGE", "SCAN", "JSON"), help=argparse.SUPPRESS)
    parser.add_argument("--grid", choices=("cross", "full", "target"), default="cross")
    parser.add_argument("--cages", nargs="+", type=int, default=None)
    parser.add_argument("--scans", nargs="+", default=None, choices=list(SCANS))
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (the fastest is kept)")
    parser.add_argument("--force", action="store_true", help="remake the cached scans and cages")
    parser.add_argument("--prepare-only", action="store_true")
    parser.add_argument("--json", default=os.path.join(OUT, "fit_scale.json"))
    parser.add_argument("--compare", metavar="ADDON_DIR", default=None,
                        help="also run every case with the add-on in ADDON_DIR (a folder holding subdiv_pia, "
                             "e.g. an earlier build), alternating with this one; its figures go to "
                             "<json>_before.json and the table gets a column of its totals")
    parser.add_argument("--export-scan-data", nargs="+", metavar="SCAN", choices=list(SCANS),
                        help="write the scans and queries bench/bench_scan_scale.c reads, and stop")
    args = parser.parse_args(argv)
    if args.export_scan_data:
        export_scan_data(args.export_scan_data)
        return
    if args.child:
        result = run_case(int(args.child[0]), args.child[1])
        with open(args.child[2], "w") as f:
            json.dump(result, f)
        return
    cages = args.cages or CAGE_SIZES
    scans = args.scans or list(SCANS)
    if args.grid == "full":
        pairs = [(c, s) for s in scans for c in cages]
    elif args.grid == "target":
        pairs = [(TARGET_CAGE, s) for s in ("dragon_s2", "dragon_s1t1")]
    else:
        largest = LARGEST_SCAN if LARGEST_SCAN in scans else scans[-1]
        cage = TARGET_CAGE if TARGET_CAGE in cages else cages[-1]
        pairs = [(c, largest) for c in cages] + [(cage, s) for s in scans if s != largest]
    prepare(sorted({s for _, s in pairs}), sorted({c for c, _ in pairs}), args.force)
    if args.prepare_only:
        return
    rows, before_rows = [], []
    lines = table([])
    print("\n".join(lines), flush=True)
    for cage_size, scan_name in pairs:
        runs, before = [], []
        for _ in range(max(1, args.repeat)):
            if args.compare:
                before.append(run_in_child(cage_size, scan_name, args.compare))
                print(table([before[-1]])[2] + " before", flush=True)
            runs.append(run_in_child(cage_size, scan_name))
            print(table([runs[-1]])[2], flush=True)
        rows.append(min(runs, key=lambda x: x["total"]))
        if before:
            before_rows.append(min(before, key=lambda x: x["total"]))
    rows.sort(key=lambda r: (r["scan_triangles"], r["cage_vertices"]))
    before_rows.sort(key=lambda r: (r["scan_triangles"], r["cage_vertices"]))
    fitted = slopes(rows)
    lines = table(rows)
    if before_rows:
        lines += ["", "The same cases with the add-on in %s, run alternately with the above:" % args.compare, ""]
        lines += table(before_rows)
    slope_lines = ["", "Log-log slopes (time ~ size^slope):", ""]
    for group, values in fitted.items():
        slope_lines.append("- %s: %s" % (group, ", ".join("%s %.2f" % (k, v) for k, v in values.items()
                                                           if v is not None)))
    if before_rows:
        slope_lines += ["", "Before (%s):" % args.compare, ""]
        for group, values in slopes(before_rows).items():
            slope_lines.append("- %s: %s" % (group, ", ".join("%s %.2f" % (k, v) for k, v in values.items()
                                                               if v is not None)))
    print("\n".join(slope_lines))
    text = "\n".join(["Surface fit (subdiv_pia.api.interpolate, fit='SURFACE', levels=%d) from the call to the "
                      "new object, seconds, on %d threads, Blender %s; peak: the process's peak resident size "
                      "during the call, growth: over the resident size before it.  Made by "
                      "bench/bench_fit_scale.py." % (LEVELS, os.cpu_count() or 1, bpy.app.version_string), ""]
                     + lines + slope_lines) + "\n"
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, "fit_scale.md"), "w") as f:
        f.write(text)
    with open(args.json, "w") as f:
        json.dump({"rows": rows, "slopes": fitted, "blender": bpy.app.version_string}, f, indent=1)
    if before_rows:
        with open(os.path.splitext(args.json)[0] + "_before.json", "w") as f:
            json.dump({"rows": before_rows, "slopes": slopes(before_rows), "addon": args.compare,
                       "blender": bpy.app.version_string}, f, indent=1)
    print("wrote %s and %s" % (os.path.relpath(os.path.join(OUT, "fit_scale.md"), ROOT),
                               os.path.relpath(args.json, ROOT)))


if __name__ == "__main__":
    try:
        main(script_args())
    except Exception:
        import traceback
        traceback.print_exc()
        finish(1)
    finish()
