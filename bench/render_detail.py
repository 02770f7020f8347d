# SPDX-License-Identifier: GPL-3.0-or-later
"""Pictures of detail levels beside Blender's own workflow (Workbench,
background mode).

    blender -b --factory-startup --python-exit-code 1 --python bench/render_detail.py -- \
        [--case bunny] [--levels 3] [--scale 5e-4] [--out docs]

Writes two pictures of one of bench_fit.py's cases (the scan in tests/data
and its QuadriFlow cage):

  detail_<case>.png       left to right: the scan; the fitted cage (its
                          own faces, flat); Blender's workflow (Multires
                          subdivided `levels` times, Shrinkwrap Project
                          along the normals both ways); the fit with
                          `levels` detail levels.  The last two are their
                          finest level, flat shaded, as Multires shows it.
  detail_<case>_heat.png  the scan coloured by each scan vertex's distance
                          to Blender's workflow's result (left) and to the
                          detail levels (right), relative to the scan's
                          diagonal, 0 (dark blue) to --scale (red);
                          measured with mathutils' BVH tree.
"""
import argparse
import os
import sys

import bpy
import numpy as np
from mathutils.bvhtree import BVHTree

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import bench_fit  # noqa: E402
import detail_workflow  # noqa: E402
import fit_cases  # noqa: E402
import render_fit  # noqa: E402

GREY = (0.72, 0.72, 0.74)


def place(panels, lo, hi, labels_under=True):
    """Lays the objects out along x with their labels; returns the picture's bounds."""
    width = float(hi[0] - lo[0])
    step = 1.12 * width
    size = 0.04 * width
    for i, (obj, label) in enumerate(panels):
        obj.location.x += i * step
        render_fit.text(label, (lo[0] + width / 2 + i * step, 0.0, lo[2] - 2.0 * size), size)
    total = (len(panels) - 1) * step + width
    return total, size


def render(path, lo, hi, total, bottom, resolution, flat):
    scene = bpy.context.scene
    centre = np.array([lo[0] + total / 2, 0.0, (hi[2] + bottom) / 2])
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type = 'ORTHO'
    camera_data.ortho_scale = 1.05 * max(total, float(hi[2] - bottom))
    camera = bpy.data.objects.new("camera", camera_data)
    camera.location = (centre[0], float(lo[1]) - 3.0 * total, centre[2])
    camera.rotation_euler = (np.pi / 2, 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.render.engine = 'BLENDER_WORKBENCH'
    scene.display.shading.light = 'STUDIO'
    scene.display.shading.color_type = 'VERTEX'
    scene.display.render_aa = '8'
    world = bpy.data.worlds.new("world")
    world.color = (1.0, 1.0, 1.0)
    scene.world = world
    scene.view_settings.view_transform = 'Standard'
    scene.render.resolution_x = resolution
    scene.render.resolution_y = int(resolution * min(1.0, 1.05 * float(hi[2] - bottom) / total + 0.02))
    scene.render.filepath = os.path.abspath(path)
    bpy.ops.render.render(write_still=True)
    print("render_detail: wrote %s" % os.path.relpath(path, bench_fit.ROOT))
    bpy.data.objects.remove(camera)


def shown(obj, name, smooth):
    copy = render_fit.applied_copy(obj, name)
    copy.data.polygons.foreach_set("use_smooth", np.full(len(copy.data.polygons), smooth, bool))
    copy.data.update()
    return copy


def scan_distances(scan_copy, result_copy):
    """Each scan vertex's distance to result_copy's faces (both with transforms applied)."""
    verts = [v.co.copy() for v in result_copy.data.vertices]
    tree = BVHTree.FromPolygons(verts, [tuple(p.vertices) for p in result_copy.data.polygons], epsilon=0.0)
    return np.array([tree.find_nearest(v.co)[3] for v in scan_copy.data.vertices])


def main(argv):
    parser = argparse.ArgumentParser(prog="render_detail.py")
    parser.add_argument("--case", default="bunny", choices=list(bench_fit.CASES))
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--scale", type=float, default=5e-4)
    parser.add_argument("--out", default=os.path.join(bench_fit.ROOT, "docs"))
    parser.add_argument("--resolution", type=int, default=1400)
    args = parser.parse_args(argv)
    scan_file, _faces, cage_file = bench_fit.CASES[args.case]
    bpy.ops.wm.read_homefile(use_empty=True)
    api = bench_fit.ensure_addon().api
    scan = fit_cases.import_obj(os.path.join(fit_cases.DATA, scan_file), "scan")
    cage = fit_cases.import_obj(os.path.join(fit_cases.DATA, cage_file), "cage")
    blender = detail_workflow.blender_workflow(cage, scan, levels=args.levels, method='PROJECT')
    detailed, _report = api.interpolate(cage, target=scan.name, fit_detail_levels=args.levels)
    fitted_cage = bench_fit.fresh_copy(detailed, "fitted cage")
    verts, _ = fit_cases.scan_geometry(scan)
    lo, hi = verts.min(0), verts.max(0)
    diagonal = float(np.linalg.norm(hi - lo))

    # The shapes.
    panels = [(shown(scan, "scan shown", True), "scan"),
              (shown(fitted_cage, "cage shown", False), "fitted cage"),
              (shown(blender, "blender shown", False), "Multires + Shrinkwrap Project\n(Blender's workflow)"),
              (shown(detailed, "detail shown", False), "fit + %d detail levels" % args.levels)]
    for obj in list(bpy.context.scene.objects):
        obj.hide_render = obj not in [p[0] for p in panels]
    for obj, _ in panels:
        render_fit.set_colours(obj.data, np.tile(np.array(GREY), (len(obj.data.vertices), 1)))
    total, size = place(panels, lo, hi)
    render(os.path.join(args.out, "detail_%s.png" % args.case), lo, hi, total, lo[2] - 4.0 * size,
           args.resolution, True)

    # The scan coloured by its distance to each result.
    for obj, _ in panels:
        obj.hide_render = True
    for obj in [o for o in bpy.data.objects if o.type == 'FONT']:
        bpy.data.objects.remove(obj)
    heat_panels = []
    for result, label in ((panels[2][0], "scan to Blender's workflow"), (panels[3][0], "scan to the detail levels")):
        copy = shown(scan, "scan heat " + label, True)
        distances = scan_distances(copy, result) / diagonal
        rgb = render_fit.heat(distances, args.scale)
        render_fit.set_colours(copy.data, rgb)
        heat_panels.append((copy, "%s\nmean %s, median %s, 95%% %s" % (
            label, bench_fit.sci(distances.mean()), bench_fit.sci(np.median(distances)),
            bench_fit.sci(np.quantile(distances, 0.95)))))
        print("render_detail: %s: mean %.3g, median %.3g, p95 %.3g" % (
            label, distances.mean(), np.median(distances), np.quantile(distances, 0.95)))
    total, size = place(heat_panels, lo, hi)
    bar_z = lo[2] - 7.0 * size
    render_fit.legend(lo[0] + 0.2 * total, lo[0] + 0.8 * total, bar_z, 1.2 * size, args.scale, size,
                      caption="scan vertex to the finest level / the scan's bounding-box diagonal (red: %g or more)"
                      % args.scale)
    render(os.path.join(args.out, "detail_%s_heat.png" % args.case), lo, hi, total, bar_z - 4.5 * size,
           args.resolution, True)


if __name__ == "__main__":
    main(bench_fit.script_args())
    bench_fit.finish()
