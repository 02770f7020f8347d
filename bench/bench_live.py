# SPDX-License-Identifier: GPL-3.0-or-later
"""Update times of a Live cage: one source vertex moved, then the view
layer updated; the time is the Live handler's own work (reading the source,
the solve with the cached stencils, writing the cage), not Blender's
evaluation of the modifier or a redraw.

    blender -b --factory-startup --python bench/bench_live.py [-- --edits 10]
    python bench/bench_live.py [--edits 10]          (Blender as the bpy module)

The add-on comes from build/addon (or SUBDIV_PIA_ADDON_DIR). Sources: open
grids and closed quad spheres (a subdivided cube, vertices projected on the
sphere) of about 1k, 10k and 50k vertices, Catmull-Clark, the defaults.
"""

import argparse
import math
import os
import statistics
import sys
import time

import bpy
import bmesh
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import addon_on_path  # noqa: E402

TARGETS = {10000: 0.030, 50000: 0.150}  # seconds, per update


def _argv():
    return sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else (
        [] if bpy.app.binary_path and "blender" in os.path.basename(sys.argv[0]) else sys.argv[1:])


def load_addon():
    addon_on_path()
    import subdiv_pia
    subdiv_pia.register()
    return subdiv_pia


def grid(vertices):
    side = max(2, round(math.sqrt(vertices)))
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=side - 1, y_segments=side - 1, size=1.0)
    return _object("Grid%d" % vertices, bm)


def quad_sphere(vertices):
    # a cube cut c times per edge has 6 c^2 + 12 c + 8 vertices (c + 1 segments)
    cuts = max(1, round((-12 + math.sqrt(144 - 24 * (8 - vertices))) / 12))
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    for v in bm.verts:
        v.co.normalize()
    return _object("Sphere%d" % vertices, bm)


def _object(name, bm):
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return obj


def measure(subdiv_pia, source, edits):
    from subdiv_pia import live
    started = time.perf_counter()
    cage, _ = subdiv_pia.interpolate(source, live=True)
    first = time.perf_counter() - started
    rng = np.random.default_rng(1)
    n = len(source.data.vertices)
    handler, whole, iterations = [], [], []
    for _ in range(edits):
        i = int(rng.integers(n))
        source.data.vertices[i].co.z += 0.01
        source.data.update()
        started = time.perf_counter()
        bpy.context.view_layer.update()
        whole.append(time.perf_counter() - started)
        handler.append(live.last_seconds[cage.name])
        iterations.append(int(cage["pia_iterations"]))
        assert cage.get("pia_live_message", "") == "", cage["pia_live_message"]
    live.set_live(cage, False)
    return first, statistics.median(handler), max(handler), statistics.median(whole), statistics.median(iterations)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--edits", type=int, default=10)
    parser.add_argument("--sizes", default="1000,10000,50000")
    args = parser.parse_args(_argv())
    subdiv_pia = load_addon()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if getattr(bpy.types, "OBJECT_OT_subdiv_pia_interpolate", None) is None:
        subdiv_pia.register()
    print("Blender %s; median of %d edits (one vertex moved each)" % (bpy.app.version_string, args.edits))
    print("| source | vertices | make + first solve (s) | update: handler (ms) | max (ms) "
          "| view_layer.update (ms) | iterations | target |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    failed = False
    for size in (int(s) for s in args.sizes.split(",")):
        for kind in (grid, quad_sphere):
            source = kind(size)
            n = len(source.data.vertices)
            first, median, worst, whole, iterations = measure(subdiv_pia, source, args.edits)
            target = TARGETS.get(size)
            verdict = ""
            if target is not None:
                ok = median <= target
                failed |= not ok
                verdict = "%s <= %d ms" % ("met" if ok else "MISSED", target * 1000)
            print("| %s | %d | %.2f | %.1f | %.1f | %.1f | %d | %s |"
                  % (kind.__name__, n, first, median * 1e3, worst * 1e3, whole * 1e3, iterations, verdict),
                  flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    if "bpy" in sys.modules and not bpy.app.binary_path.endswith("blender"):
        os._exit(code)
    sys.exit(code)
