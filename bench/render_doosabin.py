# SPDX-License-Identifier: GPL-3.0-or-later
"""The README's two-phase Doo-Sabin picture, after the paper's Figure 1,
rendered by Blender (Cycles, CPU) in background mode:

    blender -b --factory-startup --python bench/render_doosabin.py -- INPUT OUTPUT.png

One mesh, three interpolating surfaces: every shape parameter 0.8, every
one 0.4, and 0.8 on the upper half of the faces with 0.4 on the rest.  Each
is the cage solved by the library for those parameters, refined four times
with the same parameters; the red spheres are the original vertices, which
all three surfaces pass through.
"""
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import addon_on_path, script_args  # noqa: E402
from render_comparison import material, point_markers, render_row  # noqa: E402

addon_on_path()
from subdiv_pia import api, cli, native  # noqa: E402

LEVELS = 4


def main(argv):
    source = cli.load_input(os.path.abspath(argv[0]))
    arrays = api.mesh_arrays(source.data)
    P, sizes, fv = arrays["positions"], arrays["face_sizes"], arrays["face_vertices"]
    M = np.array(source.matrix_world)
    W = P @ M[:3, :3].T + M[:3, 3]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    centroid_z = np.array([W[fv[starts[f]:starts[f + 1]]].mean(0)[2] for f in range(len(sizes))])
    upper = centroid_z > np.median(centroid_z)
    settings = {"all 0.8": np.full(len(sizes), 0.8, np.float32),
                "all 0.4": np.full(len(sizes), 0.4, np.float32),
                "upper 0.8, lower 0.4": np.where(upper, 0.8, 0.4).astype(np.float32)}
    mesh = native.Mesh(W.astype(np.float32), sizes, fv)
    grey, red = material("surface", (0.75, 0.75, 0.78, 1.0)), material("points", (0.85, 0.05, 0.03, 1.0), 0.3)
    step = 1.15 * float((W.max(0) - W.min(0))[0])
    source.hide_render = True
    for i, (label, w) in enumerate(settings.items()):
        cage, report = native.interpolate(mesh, scheme="DOO_SABIN", face_shape_parameters=w)
        pos, fs, fvs = native.refine(native.Mesh(cage, sizes, fv), LEVELS, scheme="DOO_SABIN",
                                     face_shape_parameters=w)
        print("subdiv_pia: %s: %s" % (label, report.summary()))
        offset = np.array([i * step, 0.0, 0.0])
        me = api.limit_mesh(label, pos + offset, fs, fvs, materials=[grey])  # smooth shaded
        bpy.context.scene.collection.objects.link(bpy.data.objects.new(label, me))
        point_markers("points " + label, W, 0.006 * float(np.linalg.norm(W.max(0) - W.min(0))), red, offset)
    render_row(W, 2 * step, argv[1])
    print("subdiv_pia: wrote %s" % argv[1])


if __name__ == "__main__":
    main(script_args())
    cli.finish()
