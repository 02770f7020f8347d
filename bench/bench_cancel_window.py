# SPDX-License-Identifier: GPL-3.0-or-later
"""How soon Esc stops a production-scale fit in Blender's window.

    xvfb-run -a -s "-screen 0 1600x900x24" blender --factory-startup --enable-event-simulate \\
        --python bench/bench_cancel_window.py [-- --cage 50000 --scan dragon_s1t1 --delays 0.5 2 4 6]

The 50k-vertex cage and the 7.3M-triangle dragon scan of
bench_fit_scale.py (made there first: `make bench-fit-scale
FIT_SCALE_ARGS="--grid target"`; read from its cache for this Blender) are
loaded into a window; the add-on comes from SUBDIV_PIA_ADDON_DIR (default
build/addon).  For each delay the operator is started as an artist starts it
(INVOKE_DEFAULT, a Surface fit), Esc is pressed that many seconds after the
call returned (the scene loaded and drawn first), and a watcher thread notes, to the millisecond: when the
operator saw the Esc (the job's cancel flag set), when the library's thread
ended, and when the operator ended the run.  Prints a Markdown table; each
run must leave nothing behind.
"""

import os
import sys
import threading
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import OUT, ROOT, addon_on_path  # noqa: E402

addon_on_path()
import subdiv_pia  # noqa: E402
from subdiv_pia import api  # noqa: E402

sys.path.insert(0, os.path.join(ROOT, "tests", "window"))
from window import invoke_interpolate, run_steps, window_context  # noqa: E402

ARGS = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []


def argument(name, default, many=False):
    if name not in ARGS:
        return default
    at = ARGS.index(name) + 1
    if not many:
        return ARGS[at]
    values = []
    while at < len(ARGS) and not ARGS[at].startswith("--"):
        values.append(ARGS[at])
        at += 1
    return values


CAGE = int(argument("--cage", 50000))
SCAN = argument("--scan", "dragon_s1t1")
DELAYS = [float(d) for d in argument("--delays", ["0.5", "2", "4", "6"], many=True)]
CACHE = os.path.join(OUT, "fit_scale", "blender-%d.%d" % bpy.app.version[:2])
LIMIT = 120.0

JOBS = []


class WatchedJob(api.InterpolateJob):
    def __init__(self, *args, **kwargs):
        JOBS.append(self)
        super().__init__(*args, **kwargs)


api.InterpolateJob = WatchedJob


def load(path, name):
    with bpy.data.libraries.load(path) as (src, dst):
        dst.objects = [name]
    obj = dst.objects[0]
    bpy.context.scene.collection.objects.link(obj)
    obj.display_type = 'BOUNDS'  # software OpenGL draws millions of faces slowly
    return obj


class Watcher(threading.Thread):
    """Notes when the job's cancel flag is set, its library thread ends and it is done."""

    def __init__(self, job, pressed):
        super().__init__(daemon=True)
        self.job, self.pressed = job, pressed
        self.seen = self.stopped = self.ended = None
        self.round = None

    def run(self):
        job = self.job
        while time.perf_counter() - self.pressed < LIMIT:
            now = time.perf_counter()
            if self.seen is None and job.cancelled:
                self.seen, self.round = now, job.iteration
            if self.stopped is None and self.seen is not None and not job.working():
                self.stopped = now
            if job.done:
                self.ended = now
                if self.stopped is None:
                    self.stopped = now
                return
            time.sleep(0.001)


def script():
    subdiv_pia.register()
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scan = load(os.path.join(CACHE, "scan_%s.blend" % SCAN), "scan")
    cage = load(os.path.join(CACHE, "cage_%d.blend" % CAGE), "cage")
    for obj in bpy.context.scene.objects:
        obj.select_set(obj is cage)
    bpy.context.view_layer.objects.active = cage
    count = len(bpy.data.objects), len(bpy.data.meshes)
    yield 3.0  # the window draws the loaded scene first (a scene an artist already has on screen)
    rows = []
    for delay in DELAYS:
        result = invoke_interpolate(target=scan.name, fit='SURFACE', levels=1)
        returned = time.perf_counter()
        assert result == {'RUNNING_MODAL'}, result
        job = JOBS[-1]
        while time.perf_counter() - returned < delay and not job.done:
            yield 0.01
        assert not job.done, "the fit ended before Esc (%.1f s)" % delay
        pressed = time.perf_counter()
        watcher = Watcher(job, pressed)
        watcher.start()
        window = window_context()["window"]
        window.event_simulate(type='ESC', value='PRESS')
        window.event_simulate(type='ESC', value='RELEASE')
        while not job.done and time.perf_counter() - pressed < LIMIT:
            yield 0.01
        watcher.join()
        yield 0.2
        assert job.cancelled and watcher.ended is not None
        assert (len(bpy.data.objects), len(bpy.data.meshes)) == count, "the cancelled run left something"
        rows.append((delay, watcher.round, watcher.seen - pressed, watcher.stopped - watcher.seen,
                     watcher.ended - watcher.stopped, watcher.ended - pressed))
        print("bench_cancel_window: Esc %.1f s in: ended %.3f s later" % (delay, watcher.ended - pressed), flush=True)
    print("\nEsc during a Surface fit in Blender %s's window (Xvfb): %d-vertex cage, scan %s (%d faces)\n"
          % (bpy.app.version_string, len(cage.data.vertices), SCAN, len(scan.data.polygons)))
    print("| Esc after | round | Esc seen by the operator | library stopped | run ended | Esc to end |")
    print("|---:|---:|---:|---:|---:|---:|")
    for delay, round_, seen, stopped, ended, total in rows:
        print("| %.1f s | %d | %.3f s | +%.3f s | +%.3f s | %.3f s |" % (delay, round_, seen, stopped, ended, total))


run_steps(script())
