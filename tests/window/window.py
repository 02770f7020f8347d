# SPDX-License-Identifier: GPL-3.0-or-later
"""What a script driving Blender's window needs (tests/window/modal_fit.py,
bench/bench_cancel_window.py): the 3D Viewport to run operators in, a
generator of steps run from a timer while the window goes on, and an exit
with a status (a script in a window cannot end Blender through an
exception, so it leaves with os._exit)."""

import os
import sys
import traceback

import bpy


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
