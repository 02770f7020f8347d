# SPDX-License-Identifier: GPL-3.0-or-later
"""The operator in Blender's window, as an artist runs it (Make Interpolating
Cage from the panel or the menu): the fit works on a thread of its own, the
window stays live, the status bar says what it does, Esc cancels and leaves
nothing, and a fit let run makes the cage interpolate() makes.  Refresh
Limit Surface likewise: Esc leaves the limit surface as it was, and let run
it makes what refresh_limit() makes.

    xvfb-run -a -s "-screen 0 1600x900x24" blender --factory-startup --enable-event-simulate \\
        --python tests/window/modal_fit.py [-- --screenshot docs/status_fit.png]

(--enable-event-simulate: Blender takes its input from the script only, so
the Esc here is the only one; --screenshot writes the status bar during the
fit, for the README.)  The add-on comes from SUBDIV_PIA_ADDON_DIR
(default build/addon).  Prints what it checked and exits 0, or 1 with the
first failure: a script in a window cannot end Blender with an exception's
status, so it leaves with os._exit.
"""

import os
import re
import sys
import time

import bmesh
import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.environ.get("SUBDIV_PIA_ADDON_DIR", os.path.join(ROOT, "build", "addon")))
import subdiv_pia  # noqa: E402
from subdiv_pia import api  # noqa: E402
from subdiv_pia.properties import SETTING_NAMES  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from window import invoke_interpolate as invoke, run_steps, window_context  # noqa: E402

ARGS = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
SCREENSHOT = ARGS[ARGS.index("--screenshot") + 1] if "--screenshot" in ARGS else None
LIMIT = 60.0  # seconds any one wait may take before the check fails


T0 = time.perf_counter()


def say(text):
    print("modal_fit: %6.2f s: %s" % (time.perf_counter() - T0, text), flush=True)


# Every job the operator starts, to see its progress from here.
JOBS = []


class RecordedJob(api.InterpolateJob):
    """The operator's job, seen from here; with `pause` set, each progress
    call from a fitting round waits that long on the library's thread (a fit
    that takes its time, so that Esc comes while it works)."""
    pause = 0.0

    def __init__(self, *args, **kwargs):
        JOBS.append(self)
        pause = RecordedJob.pause

        def progress(iteration, value):
            if iteration >= 1 and pause:
                time.sleep(pause)
            return False
        super().__init__(*args, progress=progress, **kwargs)


api.InterpolateJob = RecordedJob


class RecordedRefreshJob(api.RefreshLimitJob):
    """Refresh Limit Surface's job, seen from here; with `pause` set, each
    progress call of the refinement waits that long on the library's
    thread."""
    pause = 0.0

    def __init__(self, *args, **kwargs):
        JOBS.append(self)
        pause = RecordedRefreshJob.pause

        def progress(level, share):
            if pause:
                time.sleep(pause)
            return False
        super().__init__(*args, progress=progress, **kwargs)


api.RefreshLimitJob = RecordedRefreshJob


def make_scene():
    """A fine UV sphere (the scan, 0.5M faces) and a 5.6k-vertex quad sphere
    on it (the cage), the cage active."""
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scan_mesh = uv_sphere("Scan", 1024, 512)
    cage_mesh = bpy.data.meshes.new("Cage")
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=30, use_grid_fill=True)
    for vert in bm.verts:
        vert.co = vert.co.normalized()
    bm.to_mesh(cage_mesh)
    bm.free()
    scene = bpy.context.scene
    scan = bpy.data.objects.new("Scan", scan_mesh)
    scan.display_type = 'BOUNDS'  # software OpenGL draws half a million faces slowly
    cage = bpy.data.objects.new("Cage", cage_mesh)
    scene.collection.objects.link(scan)
    scene.collection.objects.link(cage)
    for obj in scene.objects:
        obj.select_set(obj is cage)
    bpy.context.view_layer.objects.active = cage
    return cage, scan


def uv_sphere(name, segments, rings):
    """A unit UV sphere's mesh: quads, and triangle fans at the poles."""
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2.0 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.outer(np.sin(theta), np.cos(phi)), np.outer(np.sin(theta), np.sin(phi)),
                     np.repeat(np.cos(theta)[:, None], segments, 1)], -1).reshape(-1, 3)
    points = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    south = len(points) - 1
    at = lambda r, s: 1 + r * segments + s % segments  # noqa: E731
    faces = [(0, at(0, s + 1), at(0, s)) for s in range(segments)]
    faces += [(at(r, s), at(r, s + 1), at(r + 1, s + 1), at(r + 1, s))
              for r in range(rings - 2) for s in range(segments)]
    faces += [(at(rings - 2, s), at(rings - 2, s + 1), south) for s in range(segments)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(points.tolist(), [], faces)
    return mesh


def reports():
    """The session's reports, as the Info editor copies them."""
    window = window_context()["window"]
    area = next(a for a in window.screen.areas if a.type not in ('VIEW_3D', 'STATUSBAR', 'TOPBAR'))
    old = area.type
    area.type = 'INFO'
    region = next(r for r in area.regions if r.type == 'WINDOW')
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.info.select_all(action='SELECT')
        bpy.ops.info.report_copy()
    area.type = old
    return bpy.context.window_manager.clipboard


def status_bar_picture(path, width=640, height=24):
    """The status bar's left part, from a screenshot of the window."""
    full = path + ".window.png"
    with bpy.context.temp_override(window=window_context()["window"]):
        bpy.ops.screen.screenshot(filepath=full)
    shot = bpy.data.images.load(full)
    w, h = shot.size
    pixels = np.empty(w * h * 4, np.float32)
    shot.pixels.foreach_get(pixels)
    crop = pixels.reshape(h, w, 4)[:height, :width]  # rows run from the bottom
    out = bpy.data.images.new("status_bar", width, height)
    out.pixels.foreach_set(np.ascontiguousarray(crop).ravel())
    out.filepath_raw = path
    out.file_format = 'PNG'
    out.save()
    bpy.data.images.remove(shot)
    bpy.data.images.remove(out)
    os.remove(full)


def run_to_end(**settings):
    """Starts the operator with settings and waits (window running) until its
    run ends; returns its job."""
    result = invoke(**settings)
    assert result == {'RUNNING_MODAL'}, result
    job = JOBS[-1]
    started = time.perf_counter()
    while not job.done and time.perf_counter() - started < LIMIT:
        yield 0.02
    assert job.done, "the run did not end"
    yield 0.1
    return job


def press_esc(job):
    """Esc in the window, then a wait (window running) until job's run ends;
    returns the seconds from the key to the end."""
    window = window_context()["window"]
    pressed = time.perf_counter()
    window.event_simulate(type='ESC', value='PRESS')
    window.event_simulate(type='ESC', value='RELEASE')
    while not job.done and time.perf_counter() - pressed < LIMIT:
        yield 0.01
    return time.perf_counter() - pressed


def last_settings():
    """The settings the last finished run of the operator passed on (its
    float properties are single precision)."""
    operator = bpy.context.window_manager.operators[-1]
    assert operator.bl_idname == "OBJECT_OT_subdiv_pia_interpolate", operator.bl_idname
    return {name: getattr(operator.properties, name) for name in SETTING_NAMES}


def positions(obj):
    return api.read_positions(obj.data).astype(np.float64)


def script():
    """The steps, as a generator: each yield waits (seconds) with Blender's
    window running, so the operator's modal run goes on meanwhile."""
    subdiv_pia.register()
    cage, scan = make_scene()
    before = positions(cage), positions(scan)
    count = len(bpy.data.objects), len(bpy.data.meshes)

    # 1. Started from the window (from Edit Mode), the operator runs modal:
    # it returns at once.
    RecordedJob.pause = 1.0
    with bpy.context.temp_override(**window_context()):
        bpy.ops.object.mode_set(mode='EDIT')
    result = invoke(target=scan.name, fit='SURFACE')
    assert result == {'RUNNING_MODAL'}, result
    assert len(JOBS) == 1
    job = JOBS[0]
    started = time.perf_counter()
    while job.iteration < 1 and not job.done and time.perf_counter() - started < LIMIT:
        yield 0.01
    # This script's timer ran (the window's main loop went on) while the
    # library's thread fitted.
    assert not job.done and job.working(), "the fit ended before its first round was seen"
    say("fit under way (round %d) while the window runs this script's timer" % job.iteration)
    if SCREENSHOT:
        status_bar_picture(SCREENSHOT)
        say("the status bar written to %s" % SCREENSHOT)

    # 2. Esc cancels within the fit: nothing made, nothing changed, the cage
    # back in Edit Mode.
    took = yield from press_esc(job)
    assert job.done and job.cancelled, "Esc did not end the fit"
    say("Esc at round %d: the operator ended %.2f s later" % (job.iteration, took))
    yield 0.1
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count, "something was made"
    assert np.array_equal(positions(cage), before[0]) and np.array_equal(positions(scan), before[1])
    text = reports()
    assert "Cancelled: 'Cage' is unchanged and nothing was made" in text, text
    assert cage.mode == 'EDIT'
    say("cancelled: nothing made, the cage and scan unchanged and back in Edit Mode, the report says so")

    # 3. The library refusing the fit (nothing within the cut-off) on its
    # thread: the run ends with the library's words, nothing made, the cage
    # in Edit Mode still.
    RecordedJob.pause = 0.0
    job = yield from run_to_end(target=scan.name, fit='SURFACE', fit_cutoff=1e-6)
    assert not job.cancelled
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count, "something was made"
    text = reports()
    assert re.search(r"'Cage': no .* within the cut-off .* nothing to fit", text), text
    assert cage.mode == 'EDIT'
    say("refused by the library: reported, nothing made, still in Edit Mode")
    with bpy.context.temp_override(**window_context()):
        bpy.ops.object.mode_set(mode='OBJECT')

    # 4. Let run, it makes what interpolate() makes, with its report.
    job = yield from run_to_end(target=scan.name, fit='SURFACE', fit_cutoff=0.02)
    assert not job.cancelled
    made = bpy.data.objects.get("Cage_pia")
    assert made is not None, [o.name for o in bpy.data.objects]
    assert made.modifiers[0].type == 'SUBSURF'
    assert bpy.context.view_layer.objects.active == made
    plain, report = api.interpolate(cage, name="Cage_script", **last_settings())
    assert np.array_equal(positions(made), positions(plain)), "the window's cage differs from interpolate()'s"
    assert made["pia_fit_mean_after"] == report.after.mean
    text = reports()
    assert "Cage_pia: Surface fit to 'Scan'" in text, text
    say("let run: the cage made is interpolate()'s (%d rounds, mean %.3g), reported" % (
        report.rounds, report.after.mean))

    # 4b. With detail levels: the Multires is made and reshaped when the run
    # ends, in the window's own context, as interpolate() makes it.
    for obj in bpy.context.scene.objects:
        obj.select_set(obj is cage)
    bpy.context.view_layer.objects.active = cage
    job = yield from run_to_end(target=scan.name, fit='SURFACE', fit_cutoff=0.02, fit_detail_levels=1)
    assert not job.cancelled
    detailed = bpy.data.objects.get("Cage_pia.001")
    assert detailed is not None, [o.name for o in bpy.data.objects]
    assert [m.type for m in detailed.modifiers] == ['MULTIRES'] and detailed.modifiers[0].total_levels == 1
    scripted, _report = api.interpolate(cage, name="Cage_detail", **last_settings())
    depsgraph = bpy.context.evaluated_depsgraph_get()
    shown = [api.read_positions(o.evaluated_get(depsgraph).to_mesh()).astype(np.float64)
             for o in (detailed, scripted)]
    assert np.abs(shown[0] - shown[1]).max() < 1e-6, "the window's detail levels differ from interpolate()'s"
    text = reports()
    assert "1 detail level in Multires" in text, text
    say("with a detail level: the Multires made in the window is interpolate()'s, reported")
    for obj in (detailed, scripted):
        bpy.data.objects.remove(obj)

    # 5. Without a target (interpolating the cage's own vertices), from Edit
    # Mode: the same, the source left in Object Mode as the menu leaves it.
    for obj in bpy.context.scene.objects:
        obj.select_set(obj is cage)
    bpy.context.view_layer.objects.active = cage
    with bpy.context.temp_override(**window_context()):
        bpy.ops.object.mode_set(mode='EDIT')
    yield from run_to_end(target="")
    assert cage.mode == 'OBJECT'
    made = bpy.data.objects.get("Cage_pia.001")
    assert made is not None, [o.name for o in bpy.data.objects]
    plain, report = api.interpolate(cage, name="Cage_plain", **last_settings())
    assert np.array_equal(positions(made), positions(plain))
    assert made["pia_status"] == report.status == "CONVERGED"
    assert np.array_equal(positions(cage), before[0])
    say("interpolating from Edit Mode: the cage made is interpolate()'s (%s, %d iterations)" % (
        report.status, report.iterations))

    # 6. Refresh Limit Surface on an edited Loop cage: modal too; Esc leaves
    # the limit surface as it was; let run, it is refresh_limit()'s.
    loop, _ = api.interpolate(cage, scheme='LOOP', triangulate=True, levels=3, name="Loop")
    child = api.find_limit_object(loop)
    co = positions(loop).astype(np.float32)
    co[0] *= np.float32(1.1)
    loop.data.vertices.foreach_set("co", co.ravel())
    loop.data.update()
    for obj in bpy.context.scene.objects:
        obj.select_set(obj is loop)
    bpy.context.view_layer.objects.active = loop
    stale, mesh, count = positions(child), child.data, (len(bpy.data.objects), len(bpy.data.meshes))
    RecordedRefreshJob.pause = 1.0
    with bpy.context.temp_override(**window_context()):
        result = bpy.ops.object.subdiv_pia_refresh_limit('INVOKE_DEFAULT')
    assert result == {'RUNNING_MODAL'}, result
    job = JOBS[-1]
    assert isinstance(job, RecordedRefreshJob)
    started = time.perf_counter()
    while job.calls < 1 and time.perf_counter() - started < LIMIT:
        yield 0.01
    assert not job.done, "the refinement ended before its first progress call was seen"
    took = yield from press_esc(job)
    assert job.done and job.cancelled, "Esc did not end the refresh"
    yield 0.1
    assert child.data == mesh and np.array_equal(positions(child), stale)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count, "something was made"
    text = reports()
    assert "Cancelled: the limit surface of 'Loop' is as it was" in text, text
    say("Refresh Limit Surface: Esc ended it %.2f s later, the limit surface as it was" % took)
    RecordedRefreshJob.pause = 0.0
    with bpy.context.temp_override(**window_context()):
        result = bpy.ops.object.subdiv_pia_refresh_limit('INVOKE_DEFAULT')
    assert result == {'RUNNING_MODAL'}, result
    job = JOBS[-1]
    started = time.perf_counter()
    while not job.done and time.perf_counter() - started < LIMIT:
        yield 0.02
    assert job.done and not job.cancelled, "the refresh did not end"
    yield 0.1
    refreshed = positions(child)
    assert not np.array_equal(refreshed, stale), "the edit does not show"
    assert api.refresh_limit(loop) is child and np.array_equal(positions(child), refreshed)
    assert "Loop_limit: %d vertices" % len(child.data.vertices) in reports()
    say("Refresh Limit Surface let run: refresh_limit()'s limit surface (%d vertices), reported"
        % len(child.data.vertices))


run_steps(script(), passed=lambda: say("all passed"), failed=lambda: say("FAILED"))
