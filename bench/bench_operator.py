# SPDX-License-Identifier: GPL-3.0-or-later
"""The whole operator in Blender on a big quad sphere, from the call to the new
object, with the time split between the library and the Blender side.

    blender -b --factory-startup --python-exit-code 1 --python bench/bench_operator.py -- [--k 408] [--repeats 3]

Builds a quad sphere of 6 k^2 + 2 vertices (bench/meshes.py, 0.2% radial
noise, seed 1) with foreach_set, enables the add-on from build/addon (or
SUBDIV_PIA_ADDON_DIR), runs bpy.ops.object.subdiv_pia_interpolate() on it
`repeats` times unprofiled (each new object is deleted before the next run),
then once under cProfile.  Prints a readable summary and one line
"BENCH_JSON {...}" for bench/bench_scale.py.
"""
import argparse
import cProfile
import io
import json
import os
import pstats
import sys
import time

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def script_args():
    """The script's arguments: after "--" (blender -b --python SCRIPT -- ARGS), or
    all of them where Blender is the bpy module (python SCRIPT [--] ARGS)."""
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1:]
    return sys.argv[1:] if getattr(bpy.app, "module", False) else []


def build_sphere(k):
    sys.path.insert(0, HERE)
    from meshes import quad_sphere
    P, fv = quad_sphere(k, noise=0.002, seed=1)
    mesh = bpy.data.meshes.new("sphere")
    mesh.vertices.add(len(P))
    mesh.vertices.foreach_set("co", P.ravel())
    mesh.loops.add(fv.size)
    mesh.loops.foreach_set("vertex_index", fv.ravel())
    mesh.polygons.add(len(fv))
    mesh.polygons.foreach_set("loop_start", np.arange(0, fv.size, 4, dtype=np.int32))
    if not bpy.types.MeshPolygon.bl_rna.properties["loop_total"].is_readonly:  # 4.0+: from loop_start
        mesh.polygons.foreach_set("loop_total", np.full(len(fv), 4, np.int32))
    mesh.update(calc_edges=True)
    obj = bpy.data.objects.new("sphere", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def select_only(obj):
    for o in bpy.context.scene.objects:
        o.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def remove_results(keep):
    for o in list(bpy.data.objects):
        if o is not keep:
            data = o.data
            bpy.data.objects.remove(o)
            if data is not None and data.users == 0:
                bpy.data.meshes.remove(data)


def main():
    argv = script_args()
    ap = argparse.ArgumentParser()
    ap.add_argument("--k", type=int, default=408)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    addon_dir = os.path.abspath(os.environ.get("SUBDIV_PIA_ADDON_DIR") or os.path.join(ROOT, "build", "addon"))
    sys.path.insert(0, addon_dir)
    import subdiv_pia
    from subdiv_pia import native
    subdiv_pia.register()

    t = time.perf_counter()
    src = build_sphere(args.k)
    build_s = time.perf_counter() - t

    # The library's own clocks, from every report the operator gets.
    reports = []
    original = native.interpolate

    def timed_interpolate(*a, **kw):
        t0 = time.perf_counter()
        cage, report = original(*a, **kw)
        reports.append((time.perf_counter() - t0, report))
        return cage, report
    native.interpolate = timed_interpolate

    runs = []
    for _ in range(args.repeats):
        select_only(src)
        reports.clear()
        t = time.perf_counter()
        result = bpy.ops.object.subdiv_pia_interpolate()
        runs.append((time.perf_counter() - t, list(reports)))
        if result != {'FINISHED'}:
            print("operator returned", result, file=sys.stderr)
            sys.exit(1)
        new = bpy.context.view_layer.objects.active
        assert new is not src and len(new.data.vertices) == len(src.data.vertices)
        remove_results(src)
    best_s, best_reports = min(runs, key=lambda r: r[0])
    call_s, report = best_reports[-1]

    select_only(src)
    t = time.perf_counter()
    bpy.context.view_layer.update()  # what bpy.ops would otherwise do first, after the removals above
    pre_update_s = time.perf_counter() - t
    profiler = cProfile.Profile()
    profiler.enable()
    bpy.ops.object.subdiv_pia_interpolate()
    profiler.disable()
    new = bpy.context.view_layer.objects.active
    modifiers = [f"{m.type} levels {m.levels}" for m in new.modifiers if m.type == 'SUBSURF']
    evaluated = new.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    evaluated_vertices = len(evaluated.vertices)
    t = time.perf_counter()
    bpy.context.view_layer.update()  # evaluates the new object's Subdivision Surface modifier
    depsgraph_s = time.perf_counter() - t
    stream = io.StringIO()
    stats = pstats.Stats(profiler, stream=stream)
    stats.sort_stats("cumulative").print_stats(20)
    profile = "\n".join(ln for ln in stream.getvalue().splitlines() if ln.strip())

    def cumulative(filename_end, function):
        return sum(v[3] for k, v in stats.stats.items() if k[0].endswith(filename_end) and k[2] == function)
    profiled_s = cumulative("bpy/ops.py", "__call__")
    view_layer_s = cumulative("bpy/ops.py", "_view_layer_update")
    execute_s = cumulative("operators.py", "execute")
    reading_s = cumulative("api.py", "native_mesh")
    building_s = cumulative("api.py", "build_object")
    native_s = cumulative("bench_operator.py", "timed_interpolate")
    p_report = reports[-1][1]
    split = [("library: stencils (report.stencil_seconds)", p_report.stencil_seconds),
             ("library: solve (report.solve_seconds)", p_report.solve_seconds),
             ("native.interpolate, rest (ctypes, buffers, report)",
              native_s - p_report.stencil_seconds - p_report.solve_seconds),
             ("api.native_mesh: reading the Blender mesh (foreach_get, creases)", reading_s),
             ("api.build_object: new mesh and object, writing the cage, modifier", building_s),
             ("rest of the operator's execute (settings, report)", execute_s - native_s - reading_s - building_s),
             ("bpy.ops view-layer updates before and after (depsgraph: the new object's "
              "Subdivision Surface modifier is evaluated here)", view_layer_s),
             ("rest of bpy.ops (undo push, ...)", profiled_s - execute_s - view_layer_s)]
    out = dict(vertices=len(src.data.vertices), repeats=args.repeats, build_s=build_s, operator_s=best_s,
               profiled_s=profiled_s,
               all_runs_s=[r[0] for r in runs], native_call_s=call_s, split=split, profile=profile,
               first_evaluation_s=depsgraph_s, pre_update_s=pre_update_s, modifiers=modifiers,
               evaluated_vertices=evaluated_vertices, new_object=new.name, iterations=report.iterations,
               max_error=report.max_error_relative, method=report.method)
    print(f"{out['vertices']:,} vertices: operator {best_s:.3f} s (runs {', '.join(f'{s:.3f}' for s, _ in runs)}), "
          f"native.interpolate {call_s:.3f} s (stencils {report.stencil_seconds:.3f}, solve "
          f"{report.solve_seconds:.3f}), first evaluation of the new object {depsgraph_s:.3f} s")
    print(profile)
    print("BENCH_JSON " + json.dumps(out), flush=True)
    subdiv_pia.unregister()
    from subdiv_pia import cli
    cli.finish()  # the bpy module of 4.2-4.5 does not exit cleanly after registering


if __name__ == "__main__":
    main()
