# SPDX-License-Identifier: GPL-3.0-or-later
"""Screenshot of the add-on's panel after fitting a cage to a scan (for the README).

    xvfb-run -a -s "-screen 0 1600x1100x24" blender --factory-startup \
        --python bench/screenshot_fit.py -- docs/panel_fit.png

Imports the Stanford bunny scan (tests/data/bun_zipper.obj) and its
QuadriFlow cage (tests/data/bun_zipper_quadriflow_cage.obj), picks the scan
as the panel's Target with a Surface fit, runs the add-on's operator on the
cage, hides the scan and the cage, and shows the new `<cage>_pia` object
coloured by its `pia_distance_color` heat map (Solid shading, colour
Attribute) beside the Modifiers tab with the panel as an artist sees it
after the fit: open, its one-line status under the controls, and its "Scan
Fit" and "Last Result" sub-panels opened (the others closed, as they come).
With --detail N the fit makes N detail levels (the panel's Detail, the
result's Multires shown at its finest level; docs/panel_detail.png).
With --paint-scan (after the output path) the fit runs with Paint Scan on
and the scan is shown instead, coloured by its pia_scan_distance_color:
where the surface does not reach the scan.
The window layout, the screenshot and the crop are those of
screenshot_panel.py, whose functions this script loads and runs with its
own scene; the whole window is kept as subdiv_pia_panel_full.png in the
temporary directory.  Needs a display (Xvfb), not background mode.
"""
import ast
import os
import sys
import types

import bpy
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from fit_cases import import_obj  # noqa: E402

SCAN = os.path.join(ROOT, "tests", "data", "bun_zipper.obj")
CAGE = os.path.join(ROOT, "tests", "data", "bun_zipper_quadriflow_cage.obj")
VIEW_DISTANCE_SCALE = 0.95  # on top of screenshot_panel's framing: a larger bunny


def load_panel_script():
    """screenshot_panel.py as a module, without its closing main() call."""
    path = os.path.join(HERE, "screenshot_panel.py")
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    tree.body = [node for node in tree.body
                 if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
                         and getattr(node.value.func, "id", None) == "main")]
    module = types.ModuleType("screenshot_panel")
    module.__file__ = path
    exec(compile(tree, path, "exec"), module.__dict__)
    return module


panel = load_panel_script()
panel_arrange_steps = panel.arrange_steps
# A shorter Outliner (its header only) leaves the Properties editor room for
# the whole panel down to the end of its "Last Result" sub-panel.
panel.OUTLINER_HEIGHT = 26
# A wider one, so that the panel's one-line status is read whole.
panel.PROPERTIES_WIDTH = 600
# The sub-panels an artist opens after a fit: what the fit used and what it
# did.  A sub-panel registered without DEFAULT_CLOSED is drawn open the
# first time the editor shows it; the others stay closed.
OPENED = ("Scan Fit", "Last Result")
for cls in panel.subdiv_pia.ui.classes:
    if getattr(cls, "bl_parent_id", "") == panel.subdiv_pia.ui.DATA_PT_subdiv_pia.__name__ \
            and cls.bl_label in OPENED:
        cls.bl_options = set()
if sorted(c.bl_label for c in panel.subdiv_pia.ui.classes if c.bl_label in OPENED and not c.bl_options) \
        != sorted(OPENED):
    raise SystemExit("screenshot_fit: the panel has no sub-panels %s to open" % (OPENED,))


ARGV = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
PAINT_SCAN = "--paint-scan" in ARGV
# --detail N: the fit with N detail levels (the panel's Detail), the result's Multires shown.
DETAIL = int(ARGV[ARGV.index("--detail") + 1]) if "--detail" in ARGV else 0


def output_path():
    paths = [a for i, a in enumerate(ARGV) if not a.startswith("--") and (i == 0 or ARGV[i - 1] != "--detail")]
    return os.path.abspath(paths[0] if paths else os.path.join(ROOT, "docs", "panel_fit.png"))


def setup_scene():
    for name in ("Cube", "Camera", "Light"):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            bpy.data.objects.remove(obj)
    scan = import_obj(SCAN)
    cage = import_obj(CAGE)  # leaves the cage active and selected
    settings = bpy.context.scene.subdiv_pia
    settings.target_object = scan
    settings.fit = 'SURFACE'
    settings.fit_paint_scan = PAINT_SCAN
    settings.fit_detail_levels = DETAIL
    result = bpy.ops.object.subdiv_pia_interpolate(target=scan.name, fit='SURFACE', fit_paint_scan=PAINT_SCAN,
                                                   fit_detail_levels=DETAIL)
    if result != {'FINISHED'}:
        raise RuntimeError("operator returned %s" % result)
    new_obj = bpy.context.view_layer.objects.active
    if new_obj.name != cage.name + "_pia" or "pia_fit" not in new_obj:
        raise RuntimeError("expected a fitted %s_pia, got %s" % (cage.name, new_obj.name))
    for obj in bpy.context.view_layer.objects:
        obj.select_set(False)
    scan.hide_set(not PAINT_SCAN)
    cage.hide_set(True)
    new_obj.hide_set(PAINT_SCAN)
    # The view frames what is selected; the panel shows the active object's fit.
    (scan if PAINT_SCAN else new_obj).select_set(True)
    bpy.context.view_layer.objects.active = new_obj
    # The modifier's own panel folded to its header, so that little is left
    # below the add-on's panel when the editor is scrolled to its end.
    for mod in new_obj.modifiers:
        mod.show_expanded = False
    return new_obj


def arrange_steps(window):
    """screenshot_panel's layout and framing, then the heat map and a closer view."""
    yield from panel_arrange_steps(window)
    view3d = panel.find_area(window, 'VIEW_3D')
    space = view3d.spaces.active
    space.shading.type = 'SOLID'
    space.shading.color_type = 'VERTEX'  # "Attribute": the active colour attribute
    # Closer, keeping the bunny where screenshot_panel put it on the screen:
    # its offset from the view centre, in world units, scales with the distance.
    obj = bpy.context.view_layer.objects.active
    centre = obj.matrix_world @ (sum((Vector(c) for c in obj.bound_box), Vector()) / 8.0)
    r3d = space.region_3d
    r3d.view_distance *= VIEW_DISTANCE_SCALE
    r3d.view_location = centre + (r3d.view_location - centre) * VIEW_DISTANCE_SCALE
    # Scroll the Properties editor to its end, the "Last Result" sub-panel.
    # (Scrolling is limited to the extent of the last redraw: a few rounds.)
    props = panel.find_area(window, 'PROPERTIES')
    for _ in range(4):
        with bpy.context.temp_override(window=window, screen=window.screen, area=props,
                                       region=panel.region(props)):
            bpy.ops.view2d.scroll_down(deltax=0, deltay=2000)
        for a in window.screen.areas:
            a.tag_redraw()
        yield


# screenshot_panel's main() (restart with simulated events, register the
# add-on with its panel open, timers, screenshot, crop) looks these up in its
# module when it runs, so it runs this script's scene.
panel.output_path = output_path
panel.setup_scene = setup_scene
panel.arrange_steps = arrange_steps
panel.main()
