# SPDX-License-Identifier: GPL-3.0-or-later
"""Picture of a fitting case: the scan, then each surface coloured by its
distance to the scan (Workbench, background mode).

    blender -b --factory-startup --python-exit-code 1 --python bench/render_fit.py -- \
        [--case bunny|dragon] [--scale 5e-3] [--force] [OUTPUT.png]

Left to right: the scan (grey), then one panel per entry of PANELS: the
level-3 limit subdivision surface of the cage (bench_fit's cases and cached
cages), each vertex coloured by its distance to the scan relative to the
scan's bounding-box diagonal on a fixed scale from 0 (dark blue) to
--scale (red); vertices farther than bench_fit.CUTOFF (over the scan's
holes, not measured) are grey.  The legend bar and the scale are in the
picture and in the default file name, out/bench/fit_<case>_heat0-<scale>.png.
"""
import argparse
import math
import os
import sys

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import bench_fit  # noqa: E402
import fit_cases  # noqa: E402


PANELS = [
    ("shrinkwrap + subdivision", bench_fit.shrinkwrap_subdivision),
    ("fitted (fit SURFACE)", dict(bench_fit.METHODS)["the limit surface fitted (fit SURFACE)"]),
]

# Colour scale stops (linear RGB) from 0 to 1 of the scale.
STOPS = np.array([0.0, 0.33, 0.66, 1.0])
COLOURS = np.array([[0.02, 0.05, 0.45], [0.02, 0.55, 0.75], [1.0, 0.8, 0.05], [0.8, 0.02, 0.02]])
GREY = np.array([0.5, 0.5, 0.5])


def heat(values, scale):
    t = np.clip(values / scale, 0.0, 1.0)
    return np.stack([np.interp(t, STOPS, COLOURS[:, i]) for i in range(3)], axis=1)


def set_colours(mesh, rgb):
    attr = mesh.color_attributes.new("distance", 'FLOAT_COLOR', 'POINT')
    rgba = np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1).astype(np.float32)
    attr.data.foreach_set("color", rgba.ravel())
    mesh.color_attributes.active_color = attr
    return attr


def applied_copy(obj, name):
    """A new object holding obj's evaluated mesh (modifiers applied), world
    transform baked in, vertex order as measure() saw it."""
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    mesh = bpy.data.meshes.new_from_object(obj.evaluated_get(dg))
    mesh.transform(obj.matrix_world)
    mesh.name = name
    new = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(new)
    return new


def text(body, location, size):
    curve = bpy.data.curves.new(body[:20], 'FONT')
    curve.body = body
    curve.size = size
    curve.align_x = 'CENTER'
    obj = bpy.data.objects.new(body[:20], curve)
    obj.location = location
    obj.rotation_euler = (math.pi / 2, 0.0, 0.0)  # stand up, facing -Y (the camera)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def legend(x0, x1, z, height, scale, size, caption=None):
    """A colour bar from x0 to x1 at height z, with its scale and caption written under it."""
    n = 64
    xs = np.linspace(x0, x1, n + 1)
    verts = [(x, 0.0, zz) for x in xs for zz in (z, z + height)]
    faces = [(2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1) for i in range(n)]
    mesh = bpy.data.meshes.new("legend")
    mesh.from_pydata(verts, [], faces)
    set_colours(mesh, heat(np.repeat(xs, 2) - x0, (x1 - x0)))
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("legend", mesh))
    for frac in (0.0, 0.5, 1.0):
        text("%.3g" % (frac * scale), (x0 + frac * (x1 - x0), 0.0, z - 1.6 * size), size)
    if caption is None:
        caption = ("distance to the scan / bounding-box diagonal (grey: beyond %g, not measured)"
                   % bench_fit.CUTOFF)
    text(caption, ((x0 + x1) / 2, 0.0, z - 3.4 * size), size)


def main(argv):
    parser = argparse.ArgumentParser(prog="render_fit.py")
    parser.add_argument("output", nargs="?")
    parser.add_argument("--case", default="bunny", choices=list(bench_fit.CASES))
    parser.add_argument("--scale", type=float, default=5e-3,
                        help="distance (relative to the diagonal) shown red")
    parser.add_argument("--force", action="store_true", help="rebuild the cached cage")
    parser.add_argument("--resolution", type=int, default=1800)
    args = parser.parse_args(argv)
    out = args.output or os.path.join(bench_fit.OUT, "fit_%s_heat0-%g.png" % (args.case, args.scale))

    scan, cage, _ = bench_fit.load_case(args.case, args.force)
    verts, _ = fit_cases.scan_geometry(scan)
    lo, hi = verts.min(0), verts.max(0)
    width = float(hi[0] - lo[0])
    step = 1.15 * width

    scan_shown = applied_copy(scan, "scan shown")
    set_colours(scan_shown.data, np.tile(np.array([0.7, 0.7, 0.72]), (len(scan_shown.data.vertices), 1)))
    panels = [(scan_shown, "scan")]
    for name, method in PANELS:
        result = method(bench_fit.fresh_copy(cage, name), scan)
        r = fit_cases.measure(result, scan, levels=bench_fit.LEVELS, cutoff=bench_fit.CUTOFF)
        shown = applied_copy(result, name + " shown")
        assert len(shown.data.vertices) == len(r["distances"])
        rgb = heat(r["distances"], args.scale)
        rgb[~r["kept"]] = GREY
        set_colours(shown.data, rgb)
        result.hide_render = True
        panels.append((shown, "%s\nmean %s, 95%% %s" % (name, bench_fit.sci(r["mean"]),
                                                       bench_fit.sci(r["p95"]))))
        print("render_fit: %s: mean %.3g, p95 %.3g, max %.3g of the diagonal"
              % (name, r["mean"], r["p95"], r["max"]))
    for obj in (scan, cage):
        obj.hide_render = True
    for i, (obj, _) in enumerate(panels):
        obj.location.x += i * step
        obj.data.polygons.foreach_set("use_smooth", np.ones(len(obj.data.polygons), bool))
        obj.data.update()

    size = 0.035 * width
    total = (len(panels) - 1) * step + width
    for i, (_, label) in enumerate(panels):
        text(label, (lo[0] + width / 2 + i * step, 0.0, lo[2] - 2.0 * size), size)
    bar_z = lo[2] - 7.0 * size
    legend(lo[0] + 0.25 * total, lo[0] + 0.75 * total, bar_z, 1.2 * size, args.scale, size)

    scene = bpy.context.scene
    bottom = bar_z - 4.5 * size
    centre = np.array([lo[0] + total / 2, 0.0, (hi[2] + bottom) / 2])
    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = 'ORTHO'
    cam_data.ortho_scale = 1.05 * max(total, float(hi[2] - bottom))
    cam = bpy.data.objects.new("camera", cam_data)
    cam.location = (centre[0], float(lo[1]) - 3.0 * total, centre[2])
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)  # looking along +Y
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.engine = 'BLENDER_WORKBENCH'
    scene.display.shading.light = 'STUDIO'
    scene.display.shading.color_type = 'VERTEX'
    scene.display.render_aa = '8'
    world = bpy.data.worlds.new("world")
    world.color = (1.0, 1.0, 1.0)
    scene.world = world
    scene.view_settings.view_transform = 'Standard'
    scene.render.resolution_x = args.resolution
    scene.render.resolution_y = int(args.resolution * min(1.0, 1.05 * float(hi[2] - bottom) / total + 0.02))
    scene.render.filepath = os.path.abspath(out)
    bpy.ops.render.render(write_still=True)
    print("render_fit: wrote %s" % os.path.relpath(out, bench_fit.ROOT))


if __name__ == "__main__":
    main(bench_fit.script_args())
    bench_fit.finish()
