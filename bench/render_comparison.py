# SPDX-License-Identifier: GPL-3.0-or-later
"""Renders the README picture with Blender in background mode (Cycles, CPU).

    blender -b --factory-startup --python bench/render_comparison.py -- INPUT OUTPUT.png

Left: the mesh with a plain Subdivision Surface modifier (limit surface),
which shrinks away from the original vertices (red).  Right: the cage
computed by subdiv_pia with the same modifier, whose surface passes through
them.  The distances are measured on Blender's evaluated meshes and printed.
"""
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import addon_on_path, script_args  # noqa: E402

addon_on_path()
import subdiv_pia  # noqa: E402
from subdiv_pia import api, cli  # noqa: E402

LEVELS = 3


def material(name, rgba, roughness=0.5):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # before 5.0 nodes are switched on; since, always there
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = rgba
    bsdf.inputs["Roughness"].default_value = roughness
    return mat


def evaluated_points(obj, n):
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)[:n]


def point_markers(name, points, radius, mat, offset):
    """Small spheres at the points: one icosphere instanced on a vertex cloud."""
    cloud = bpy.data.meshes.new(name)
    cloud.from_pydata((points + offset).tolist(), [], [])
    holder = bpy.data.objects.new(name, cloud)
    bpy.context.collection.objects.link(holder)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=radius)
    ball = bpy.context.active_object
    ball.data.materials.append(mat)
    ball.parent = holder
    holder.instance_type = 'VERTS'
    return holder


def render_row(P, shift_x, out_path):
    """Cycles render, from the front (-Y), of a row of objects: the first
    spans the world-space points P, the others follow along +X, shift_x
    apart in all."""
    scene = bpy.context.scene
    centre = (P.min(0) + P.max(0) + np.array([shift_x, 0.0, 0.0])) / 2
    span = float((P.max(0) - P.min(0))[0] + shift_x)
    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = 'ORTHO'
    cam_data.ortho_scale = 1.08 * span
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    height = float((P.max(0) - P.min(0))[2])
    cam.location = (centre[0], centre[1] - 3 * span, centre[2] + 0.6 * span)
    direction = np.array(centre) - np.array(cam.location)
    cam.rotation_euler = (np.arctan2(np.hypot(direction[0], direction[1]), -direction[2]), 0.0, 0.0)
    scene.camera = cam
    for loc, energy in (((centre[0] - span, centre[1] - 2 * span, centre[2] + 2 * span), 4.0),
                        ((centre[0] + span, centre[1] - span, centre[2] + span), 2.0)):
        light = bpy.data.objects.new("sun", bpy.data.lights.new("sun", 'SUN'))
        light.data.energy = energy
        light.location = loc
        d = np.array(centre) - np.array(loc)
        light.rotation_euler = (np.arctan2(np.hypot(d[0], d[1]), -d[2]), 0.0, np.arctan2(d[1], d[0]) + np.pi / 2)
        scene.collection.objects.link(light)
    world = bpy.data.worlds.new("world")
    if world.node_tree is None:
        world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.6
    scene.world = world
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = 32
    scene.cycles.use_denoising = False  # Debian's Blender has no OpenImageDenoise
    scene.render.resolution_x = 1400
    scene.render.resolution_y = int(1400 * min(1.0, max(0.3, 1.3 * height / span)))
    scene.render.film_transparent = False
    scene.view_settings.view_transform = 'Standard'
    scene.render.filepath = os.path.abspath(out_path)
    bpy.ops.render.render(write_still=True)


def main(argv):
    src_path, out_path = argv[0], argv[1]
    subdiv_pia.register()
    source = cli.load_input(os.path.abspath(src_path))
    mesh = source.data
    n = len(mesh.vertices)
    P = np.empty(3 * n, np.float32)
    mesh.vertices.foreach_get("co", P)
    P = P.reshape(-1, 3)
    diag = float(np.linalg.norm(P.max(0) - P.min(0)))

    new, report = subdiv_pia.interpolate(source, levels=LEVELS, render_levels=LEVELS)
    mod = source.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = mod.render_levels = LEVELS
    mod.use_limit_surface = True
    for obj in (source, new):
        obj.data.polygons.foreach_set("use_smooth", np.ones(len(obj.data.polygons), bool))
        obj.data.update()
    # World-space points (the importer turns Y-up files to Blender's Z-up).
    M = np.array(source.matrix_world)
    W = P @ M[:3, :3].T + M[:3, 3]
    shift = np.array([1.15 * (W.max(0) - W.min(0))[0], 0.0, 0.0])
    new.location = (np.array(new.location) + shift).tolist()

    plain = np.linalg.norm(evaluated_points(source, n) - P, axis=1) / diag
    fitted = np.linalg.norm(evaluated_points(new, n) - P, axis=1) / diag
    print("subdiv_pia: %s" % api.format_report(report))
    print("subdiv_pia: plain modifier misses the vertices by max %.3g, mean %.3g of the diagonal"
          % (plain.max(), plain.mean()))
    print("subdiv_pia: interpolated cage:                        max %.3g, mean %.3g" % (fitted.max(), fitted.mean()))

    grey = material("surface", (0.75, 0.75, 0.78, 1.0))
    for obj in (source, new):
        obj.data.materials.clear()
        obj.data.materials.append(grey)
    red = material("points", (0.85, 0.05, 0.03, 1.0), 0.3)
    radius = 0.006 * diag * float(np.abs(np.linalg.det(M[:3, :3]))) ** (1 / 3)
    point_markers("points_plain", W, radius, red, np.zeros(3))
    point_markers("points_fitted", W, radius, red, shift)
    P = W

    render_row(P, float(shift[0]), out_path)
    print("subdiv_pia: wrote %s" % out_path)


if __name__ == "__main__":
    main(script_args())
    cli.finish()
