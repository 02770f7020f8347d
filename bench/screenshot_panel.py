# SPDX-License-Identifier: GPL-3.0-or-later
"""Screenshot of the add-on's panel in Blender's interface beside the
result in the 3D viewport (the manual's pictures of the panel alone come
from tests/window/panel.py, which checks what they show).

    xvfb-run -a -s "-screen 0 1600x1500x24" blender --factory-startup \
        --python bench/screenshot_panel.py -- out/panel.png
    xvfb-run -a -s "-screen 0 1600x1500x24" blender --factory-startup \
        --python bench/screenshot_panel.py -- --live          (out/panel_live.png)

Imports tests/data/mushroom.obj, gives it a Subdivision Surface modifier
(levels 2, limit surface), runs the add-on's operator, and with the new
object active shows the Modifiers tab of the Properties editor (the
modifier and the add-on's panel, expanded) beside the 3D viewport.  OUTPUT
is the right part of the window (3D viewport with the mesh, Outliner and
Properties editor); the whole window is kept as subdiv_pia_panel_full.png
in the temporary directory.  Needs a display (Xvfb), not background mode;
Blender is restarted with --enable-event-simulate if it was not given
(resizing the editors needs simulated mouse events).
"""
import math
import os
import sys
import tempfile
import traceback

import bpy
from mathutils import Euler, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import DATA, ROOT, addon_on_path  # noqa: E402

addon_on_path()
import subdiv_pia  # noqa: E402
sys.path.insert(0, os.path.join(ROOT, "tests", "window"))
from window import crop, edge_move, find_area, region  # noqa: E402,F401  (screenshot_fit.py uses them too)

MESH = os.path.join(DATA, "mushroom.obj")
PROPERTIES_WIDTH = 500   # pixels, Properties/Outliner column
OUTLINER_HEIGHT = 110    # pixels
CROP_VIEW_WIDTH = 600    # pixels of 3D viewport kept left of the Properties editor


def script_args():
    return sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []


# --live: the cage made with Live on (docs/panel_live.png), then a vertex of
# the source moved, which the cage follows.
LIVE = "--live" in script_args()


def output_path():
    argv = [a for a in script_args() if not a.startswith("--")]
    default = "panel_live.png" if LIVE else "panel.png"
    return os.path.abspath(argv[0] if argv else os.path.join(ROOT, "out", default))


def setup_scene():
    for name in ("Cube", "Camera", "Light"):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            bpy.data.objects.remove(obj)
    bpy.ops.wm.obj_import(filepath=MESH)
    source = bpy.context.selected_objects[0]
    bpy.context.view_layer.objects.active = source
    for poly in source.data.polygons:
        poly.use_smooth = True
    mod = source.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = 2
    mod.render_levels = 2
    mod.use_limit_surface = True
    result = bpy.ops.object.subdiv_pia_interpolate(live=LIVE)
    if result != {'FINISHED'}:
        raise RuntimeError("operator returned %s" % result)
    new_obj = bpy.context.view_layer.objects.active
    assert new_obj is not source and "pia_status" in new_obj
    if LIVE:
        top = max(range(len(source.data.vertices)), key=lambda i: source.data.vertices[i].co.z)
        before = new_obj.data.vertices[top].co.copy()
        source.data.vertices[top].co.z += 0.15
        source.data.update()
        bpy.context.view_layer.update()
        assert (new_obj.data.vertices[top].co - before).length > 0, "the live cage did not follow"
    source.hide_set(True)  # both occupy the same place; show the result
    new_obj.select_set(True)
    return new_obj


def arrange_steps(window):
    """Generator: one layout step per timer tick (events run in between)."""
    view3d = find_area(window, 'VIEW_3D')
    props = find_area(window, 'PROPERTIES')
    outliner = find_area(window, 'OUTLINER')
    # Wider right column: move the edge between the 3D view and it.
    edge_x = view3d.x + view3d.width
    y = view3d.y + view3d.height // 2
    window.event_simulate('MOUSEMOVE', 'NOTHING', x=edge_x, y=y)
    yield
    edge_move(window, view3d, edge_x, y, (window.width - PROPERTIES_WIDTH) - edge_x)
    yield
    # Taller Properties editor: move the edge between it and the Outliner up.
    if outliner is not None:
        edge_y = props.y + props.height
        x = props.x + props.width // 2
        window.event_simulate('MOUSEMOVE', 'NOTHING', x=x, y=edge_y)
        yield
        edge_move(window, props, x, edge_y, (outliner.y + outliner.height - OUTLINER_HEIGHT) - edge_y)
        yield
    window.event_simulate('MOUSEMOVE', 'NOTHING', x=window.width // 2, y=window.height // 2)

    props.spaces.active.context = 'MODIFIER'
    space = view3d.spaces.active
    space.shading.type = 'SOLID'
    r3d = space.region_3d
    r3d.view_perspective = 'PERSP'
    r3d.view_rotation = Euler((math.radians(70), 0.0, math.radians(35))).to_quaternion()
    with bpy.context.temp_override(window=window, screen=window.screen, area=view3d,
                                   region=region(view3d)):
        bpy.ops.view3d.view_selected()
    yield  # view_selected animates (smooth view)
    # Centre the mesh in the part of the viewport that the crop keeps.
    r3d.view_distance *= 1.5
    win_region = region(view3d)
    shift_px = (view3d.x + view3d.width) - CROP_VIEW_WIDTH / 2 - (win_region.x + win_region.width / 2)
    # The viewport's horizontal field of view: a 72 mm wide sensor behind space.lens.
    world_per_px = r3d.view_distance * 72.0 / space.lens / win_region.width
    right = r3d.view_rotation @ Vector((1.0, 0.0, 0.0))
    r3d.view_location = r3d.view_location - right * (shift_px * world_per_px)
    for a in window.screen.areas:
        a.tag_redraw()


def main():
    if getattr(bpy.app, "module", False) or bpy.app.background:
        # The bpy module and background mode have no window to take a picture of.
        sys.exit("screenshot: needs Blender's window: run the blender executable, not in "
                 "background mode (under Xvfb without a display)")
    if not bpy.app.use_event_simulate:
        # Resizing areas needs simulated mouse events: start again with them.
        argv = [a for a in sys.argv if a != "--enable-event-simulate"]
        os.execv(bpy.app.binary_path, [bpy.app.binary_path, "--enable-event-simulate"] + argv[1:])
    out_path = output_path()
    full_path = os.path.join(tempfile.gettempdir(), "subdiv_pia_panel_full.png")
    os.makedirs(os.path.dirname(out_path), exist_ok=True)

    bpy.context.preferences.view.show_splash = False
    subdiv_pia.ui.DATA_PT_subdiv_pia.bl_options = set()  # open, not DEFAULT_CLOSED
    subdiv_pia.register()
    try:
        setup_scene()
    except Exception:
        traceback.print_exc()
        sys.exit(1)  # a window is open: do not wait there

    def quit_on_error(fn):
        def wrapped():
            try:
                return fn()
            except Exception:
                traceback.print_exc()
                bpy.ops.wm.quit_blender()
                return None
        return wrapped

    @quit_on_error
    def shoot():
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window, screen=window.screen,
                                       area=find_area(window, 'VIEW_3D')):
            bpy.ops.screen.screenshot(filepath=full_path)
        crop(full_path, out_path, max(find_area(window, 'PROPERTIES').x - CROP_VIEW_WIDTH, 0))
        print("screenshot_panel: wrote", full_path, "and", out_path)
        bpy.ops.wm.quit_blender()
        return None

    steps = []

    @quit_on_error
    def layout():
        window = bpy.context.window_manager.windows[0]
        if not steps:
            steps.append(arrange_steps(window))
        try:
            next(steps[0])
            return 0.3
        except StopIteration:
            bpy.app.timers.register(shoot, first_interval=2.0)
            return None

    bpy.app.timers.register(layout, first_interval=1.0)


main()
