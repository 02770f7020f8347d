# SPDX-License-Identifier: GPL-3.0-or-later
"""The whole operator in Blender on a big quad sphere, from the call to the new
object, with the time split between the add-on, the library and Blender.

    blender -b --factory-startup --python-exit-code 1 --python bench/bench_operator.py -- [--k 408] [--repeats 3]

Builds a quad sphere of 6 k^2 + 2 vertices (bench/meshes.py, 0.2% radial
noise, seed 1) with foreach_set, enables the add-on from build/addon (or
SUBDIV_PIA_ADDON_DIR), runs bpy.ops.object.subdiv_pia_interpolate() on it
`repeats` times unprofiled (each new object is deleted before the next run),
then once under cProfile.  Prints a readable summary and one line
"BENCH_JSON {...}" for bench/bench_scale.py.

Each unprofiled run is split by clocks around the add-on's functions (any
version of the add-on: the functions are looked up by name):

- the library: native.interpolate, the whole call;
- the add-on's own part: the operator's execute() without the library,
  itself split into reading the mesh (api.native_mesh, api.mesh_arrays,
  api.check_memory, outermost calls only), writing the new object
  (api.build_object) and the rest (settings, checks, the report);
- Blender: the rest of the bpy.ops call (view-layer updates before and
  after, the undo push; Blender 3.x evaluates the new object's modifier
  there), and the evaluation of the new object's Subdivision Surface
  modifier that the first look at its evaluated mesh after the call does
  (Blender 4.x and 5.x defer the subdivision until then).
The figures printed are those of the fastest run, all from that one run.
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
sys.path.insert(0, HERE)
from harness import addon_on_path, replace_everywhere, script_args  # noqa: E402


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


class Clocks:
    """Wall-clock seconds spent in named groups of functions, outermost calls only."""

    def __init__(self):
        self.seconds = {}
        self.depth = {}

    def reset(self):
        for group in self.seconds:
            self.seconds[group] = 0.0

    def wrap(self, group, owner, *names):
        """Times owner.name for each name, in owner and in every module of
        the add-on that imported the same function (a module calls what it
        imported, not owner's attribute)."""
        self.seconds.setdefault(group, 0.0)
        self.depth.setdefault(group, 0)
        for name in names:
            function = getattr(owner, name, None)
            if function is None:  # not in this version of the add-on
                continue

            def timed(*a, _function=function, **kw):
                self.depth[group] += 1
                t0 = time.perf_counter()
                try:
                    return _function(*a, **kw)
                finally:
                    self.depth[group] -= 1
                    if self.depth[group] == 0:
                        self.seconds[group] += time.perf_counter() - t0
            if isinstance(owner, type):
                setattr(owner, name, self._method(timed))
                continue
            replace_everywhere(owner, name, timed)

    @staticmethod
    def _method(timed):
        # Blender calls an operator's methods with as many arguments as they name.
        def method(operator, context):
            return timed(operator, context)
        return method

    def parts(self, call, evaluation):
        s = self.seconds
        own = s["execute"] - s["library"]
        return dict(read=s["read"], write=s["write"], other=own - s["read"] - s["write"], addon=own,
                    library=s["library"], blender_call=call - s["execute"], blender_evaluation=evaluation,
                    blender_total=call - s["execute"] + evaluation, call=call)


PART_LABELS = [
    ("addon", "the add-on's own part (execute() without the library)"),
    ("read", "  reading the mesh"),
    ("write", "  writing the new object"),
    ("other", "  the rest (settings, checks, the report)"),
    ("library", "the library (native.interpolate)"),
    ("blender_call", "Blender: the rest of the bpy.ops call (view-layer updates, undo push)"),
    ("blender_evaluation", "Blender: evaluating the new object's modifier, after the call"),
    ("blender_total", "Blender, both"),
    ("call", "the bpy.ops call"),
]


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
    addon_on_path()
    import subdiv_pia
    from subdiv_pia import api, native, operators
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
    clocks = Clocks()
    clocks.wrap("library", native, "interpolate")
    clocks.wrap("read", api, "native_mesh", "mesh_arrays", "check_memory")
    clocks.wrap("write", api, "build_object")
    clocks.wrap("execute", operators.OBJECT_OT_subdiv_pia_interpolate, "execute")

    runs = []
    for _ in range(args.repeats):
        select_only(src)
        reports.clear()
        clocks.reset()
        t = time.perf_counter()
        result = bpy.ops.object.subdiv_pia_interpolate()
        call = time.perf_counter() - t
        if result != {'FINISHED'}:
            print("operator returned", result, file=sys.stderr)
            sys.exit(1)
        new = bpy.context.view_layer.objects.active
        t = time.perf_counter()
        len(new.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices)  # subdivides (4.x, 5.x)
        evaluation = time.perf_counter() - t
        assert new is not src and len(new.data.vertices) == len(src.data.vertices)
        runs.append((call, list(reports), clocks.parts(call, evaluation)))
        remove_results(src)
    best_s, best_reports, parts = min(runs, key=lambda r: r[0])
    call_s, report = best_reports[-1]

    select_only(src)
    t = time.perf_counter()
    bpy.context.view_layer.update()  # what bpy.ops would otherwise do first, after the removals above
    pre_update_s = time.perf_counter() - t
    clocks.reset()
    reports.clear()
    profiler = cProfile.Profile()
    t = time.perf_counter()
    profiler.enable()
    bpy.ops.object.subdiv_pia_interpolate()
    profiler.disable()
    profiled_call_s = time.perf_counter() - t
    new = bpy.context.view_layer.objects.active
    modifiers = [f"{m.type} levels {m.levels}" for m in new.modifiers if m.type == 'SUBSURF']
    t = time.perf_counter()
    evaluated = new.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    evaluated_vertices = len(evaluated.vertices)  # evaluates the new object's Subdivision Surface modifier
    evaluation_s = time.perf_counter() - t
    p_parts = clocks.parts(profiled_call_s, evaluation_s)
    t = time.perf_counter()
    bpy.context.view_layer.update()  # nothing left to evaluate
    depsgraph_s = time.perf_counter() - t
    stream = io.StringIO()
    stats = pstats.Stats(profiler, stream=stream)
    stats.sort_stats("cumulative").print_stats(20)
    profile = "\n".join(ln for ln in stream.getvalue().splitlines() if ln.strip())

    profiled_s = profiled_call_s
    p_report = reports[-1][1]
    split = [("library: stencils (report.stencil_seconds)", p_report.stencil_seconds),
             ("library: solve (report.solve_seconds)", p_report.solve_seconds),
             ("native.interpolate, rest (validation, ctypes, buffers, report)",
              p_parts["library"] - p_report.stencil_seconds - p_report.solve_seconds),
             ("add-on: reading the Blender mesh (foreach_get, creases)", p_parts["read"]),
             ("add-on: api.build_object: new mesh and object, writing the cage, modifier", p_parts["write"]),
             ("add-on: rest of the operator's execute (settings, checks, report)", p_parts["other"]),
             ("Blender: rest of bpy.ops (view-layer updates before and after, undo push; Blender 3.x "
              "evaluates the new object's Subdivision Surface modifier here)", p_parts["blender_call"])]
    out = dict(vertices=len(src.data.vertices), repeats=args.repeats, build_s=build_s, operator_s=best_s,
               profiled_s=profiled_s,
               all_runs_s=[r[0] for r in runs], native_call_s=call_s, split=split, profile=profile,
               first_evaluation_s=evaluation_s, later_update_s=depsgraph_s, pre_update_s=pre_update_s,
               modifiers=modifiers,
               evaluated_vertices=evaluated_vertices, new_object=new.name, iterations=report.iterations,
               max_error=report.max_error_relative, method=report.method)
    out["parts"] = parts
    out["part_labels"] = PART_LABELS
    print(f"{out['vertices']:,} vertices: operator {best_s:.3f} s (runs {', '.join(f'{r[0]:.3f}' for r in runs)}), "
          f"native.interpolate {call_s:.3f} s (stencils {report.stencil_seconds:.3f}, solve "
          f"{report.solve_seconds:.3f})")
    print(f"Blender {bpy.app.version_string}, add-on from {os.path.dirname(subdiv_pia.__file__)}; "
          f"the fastest run, every part from that run:")
    for key, label in PART_LABELS:
        print(f"  {label:<78} {parts[key]:7.3f} s")
    print("BENCH_PARTS " + json.dumps(dict(version=bpy.app.version_string, vertices=out["vertices"], **parts)))
    print(profile)
    print("BENCH_JSON " + json.dumps(out), flush=True)
    subdiv_pia.unregister()
    from subdiv_pia import cli
    cli.finish()  # the bpy module of 4.2-4.5 does not exit cleanly after registering


if __name__ == "__main__":
    main()
