# SPDX-License-Identifier: GPL-3.0-or-later
"""What a script driving Blender's window needs (tests/window/modal_fit.py,
tests/window/panel.py, bench/bench_cancel_window.py,
bench/screenshot_panel.py): the 3D Viewport to run operators in, a
generator of steps run from a timer while the window goes on, an exit with
a status (a script in a window cannot end Blender through an exception, so
it leaves with os._exit), moving the edges between editors, and a part of a
screenshot written as a PNG."""

import os
import sys
import traceback

import bpy
import numpy as np


def window_context():
    """The first window, its 3D Viewport and that area's main region."""
    window = bpy.context.window_manager.windows[0]
    area = next(a for a in window.screen.areas if a.type == 'VIEW_3D')
    region = next(r for r in area.regions if r.type == 'WINDOW')
    return dict(window=window, area=area, region=region)


def invoke_interpolate(**settings):
    """The add-on's operator as the panel or the menu starts it."""
    with bpy.context.temp_override(**window_context()):
        return bpy.ops.object.subdiv_pia_interpolate('INVOKE_DEFAULT', **settings)


def finish(code):
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def run_steps(steps, passed=None, failed=None):
    """Runs the generator `steps` from a timer: each value it yields is the
    wait, in seconds, before its next step, the window running meanwhile.
    Exits 0 when it ends (after passed()), 1 on an exception (printed, then
    failed())."""
    def advance():
        try:
            return next(steps)
        except StopIteration:
            if passed:
                passed()
            finish(0)
        except BaseException:
            traceback.print_exc()
            if failed:
                failed()
            finish(1)
    bpy.app.timers.register(advance, first_interval=0.5)


def find_area(window, kind):
    """The window's largest editor of that kind, or None."""
    areas = [a for a in window.screen.areas if a.type == kind]
    return max(areas, key=lambda a: a.width * a.height) if areas else None


def region(area, kind='WINDOW'):
    return next(r for r in area.regions if r.type == kind)


def edge_move(window, area, x, y, delta):
    """Drag the area edge at (x, y) by delta pixels (the operator's poll wants
    no active region, i.e. the mouse on an edge, so it is put there first;
    Blender must run with --enable-event-simulate)."""
    window.event_simulate('MOUSEMOVE', 'NOTHING', x=x, y=y)
    with bpy.context.temp_override(window=window, screen=window.screen, area=area):
        bpy.ops.screen.area_move(x=x, y=y, delta=delta)


def crop(full_path, out_path, x0, x1=None):
    """Columns x0 to x1 (window pixels; x1 None: to the right edge) of the
    screenshot at full_path, written to out_path as an 8-bit RGB PNG."""
    image = bpy.data.images.load(full_path)
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    part = np.ascontiguousarray(px.reshape(h, w, 4)[:, x0:x1, :])  # rows bottom to top
    bpy.data.images.remove(image)
    part[:, :, 3] = 1.0
    out = bpy.data.images.new("crop", width=part.shape[1], height=part.shape[0], alpha=False)
    out.pixels.foreach_set(part.reshape(-1))
    settings = bpy.context.scene.render.image_settings
    settings.file_format = 'PNG'
    settings.color_mode = 'RGB'
    settings.color_depth = '8'
    settings.compression = 100
    out.save_render(out_path)
    bpy.data.images.remove(out)
