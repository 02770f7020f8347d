# SPDX-License-Identifier: GPL-3.0-or-later
"""The panel as an artist sees it, in Blender's window: for each case of
tests/blender/panel_cases.py (a fresh mesh, a scan as target, Loop, a
finished fit) the Modifiers tab is drawn by Blender itself and this checks
that the panel drew without an error, that the controls at its top are
those the case expects (and no others), that the sub-panels shown are those
that apply, all closed, and writes a screenshot of the Properties editor.

    xvfb-run -a -s "-screen 0 1600x900x24" blender --factory-startup --enable-event-simulate \\
        --python tests/window/panel.py [-- --screenshots DIR]

The screenshots go to DIR as panel_<case>.png (default build/window/panel;
`--screenshots docs` writes the manual's pictures).  What the panel draws
is recorded on its way into Blender's real layout (tests/blender/layout.py's
Tee), so a control put back at the top fails here as in test_ui.py.  The
panel itself is opened (it is closed by default); its sub-panels keep their
default state.  The add-on comes from SUBDIV_PIA_ADDON_DIR (default
build/addon).  Exits 0, or 1 with what failed.
"""

import os
import sys
import tempfile
import time
import traceback

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.environ.get("SUBDIV_PIA_ADDON_DIR", os.path.join(ROOT, "build", "addon")))
sys.path.insert(0, os.path.join(ROOT, "tests", "blender"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import subdiv_pia  # noqa: E402
from subdiv_pia import ui  # noqa: E402
from layout import Tee, fake_panel  # noqa: E402
import panel_cases  # noqa: E402
from window import crop, edge_move, find_area, run_steps  # noqa: E402

ARGS = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
OUT = os.path.abspath(ARGS[ARGS.index("--screenshots") + 1] if "--screenshots" in ARGS
                      else os.path.join(ROOT, "build", "window", "panel"))
PROPERTIES_WIDTH = 520  # pixels: the Properties editor, widened
OUTLINER_HEIGHT = 60    # pixels: the Outliner above it, lowered
T0 = time.perf_counter()

# What the last redraw drew: (class name, function) -> Tee; class name -> poll's answer.
DRAWN = {}
POLLED = {}
ERRORS = []


def say(text):
    print("panel: %6.2f s: %s" % (time.perf_counter() - T0, text), flush=True)


def recording(cls, name, function):
    """function (a draw function of cls) drawing through a Tee into Blender's
    layout; what it drew is kept in DRAWN, an exception in ERRORS."""
    def draw(self, context):
        tee = DRAWN[(cls.__name__, name)] = Tee(self.layout)
        try:
            function(fake_panel(tee, cls), context)
        except Exception:
            ERRORS.append("%s.%s: %s" % (cls.__name__, name, traceback.format_exc()))
            raise
    return draw


def recording_poll(cls):
    poll = cls.poll  # bound to cls

    def recorded(_cls, context):
        try:
            POLLED[cls.__name__] = answer = poll(context)
        except Exception:
            ERRORS.append("%s.poll: %s" % (cls.__name__, traceback.format_exc()))
            raise
        return answer
    return classmethod(recorded)


def record_panels():
    """Every panel class of the add-on draws and polls through the recorders
    (set before registering, so that Blender calls these)."""
    for cls in ui.classes:
        for name in ("draw", "draw_header", "draw_header_preset"):
            function = getattr(cls, name, None)
            if function is not None:
                setattr(cls, name, recording(cls, name, function))
        cls.poll = recording_poll(cls)


SUBPANELS = [cls for cls in ui.classes if getattr(cls, "bl_parent_id", "") == ui.DATA_PT_subdiv_pia.__name__]


def drawn_by_default(case):
    """What differs from the case's expectation in the last redraw."""
    main = ui.DATA_PT_subdiv_pia.__name__
    header, body = DRAWN.get((main, "draw_header_preset")), DRAWN.get((main, "draw"))
    if header is None or body is None:
        return ["the panel was not drawn (header %s, body %s)" % (header is not None, body is not None)]
    shown = [cls.bl_label for cls in SUBPANELS if POLLED.get(cls.__name__)]
    problems = panel_cases.check(case, header.controls + body.controls, shown,
                                 [text for kind, text in body.log if kind == "label"], body.icons)
    opened = [cls.bl_label for cls in SUBPANELS if (cls.__name__, "draw") in DRAWN]
    if opened:
        problems.append("sub-panels open by default: %s" % opened)
    return problems


def arrange(window):
    """A wider and taller Properties editor on its Modifiers tab (a generator:
    the window goes on between the steps)."""
    view3d, props = find_area(window, 'VIEW_3D'), find_area(window, 'PROPERTIES')
    outliner = find_area(window, 'OUTLINER')
    edge_x, y = view3d.x + view3d.width, view3d.y + view3d.height // 2
    window.event_simulate('MOUSEMOVE', 'NOTHING', x=edge_x, y=y)
    yield 0.3
    edge_move(window, view3d, edge_x, y, (window.width - PROPERTIES_WIDTH) - edge_x)
    yield 0.3
    if outliner is not None:
        edge_y, x = props.y + props.height, props.x + props.width // 2
        window.event_simulate('MOUSEMOVE', 'NOTHING', x=x, y=edge_y)
        yield 0.3
        edge_move(window, props, x, edge_y, (outliner.y + outliner.height - OUTLINER_HEIGHT) - edge_y)
        yield 0.3
    window.event_simulate('MOUSEMOVE', 'NOTHING', x=window.width // 4, y=window.height // 2)
    props.spaces.active.context = 'MODIFIER'


def screenshot(window, name):
    full = os.path.join(tempfile.gettempdir(), "subdiv_pia_panel_window.png")
    with bpy.context.temp_override(window=window, screen=window.screen, area=find_area(window, 'VIEW_3D')):
        bpy.ops.screen.screenshot(filepath=full)
    props = find_area(window, 'PROPERTIES')
    path = os.path.join(OUT, "panel_%s.png" % name)
    crop(full, path, props.x, props.x + props.width)
    image = bpy.data.images.load(path)
    rgb = [value for i, value in enumerate(image.pixels[:]) if i % 4 != 3]
    blank = max(rgb) == min(rgb)
    bpy.data.images.remove(image)
    # Debian 13's Blender 4.3.2 under Xvfb reads its window as black: said, not failed (the drawing is checked).
    return path + (" (blank: this Blender's screenshot under Xvfb is empty)" if blank else "")


def script():
    ui.DATA_PT_subdiv_pia.bl_options = set()  # the panel open; its sub-panels as they come
    record_panels()
    subdiv_pia.register()
    bpy.context.preferences.view.show_splash = False
    window = bpy.context.window_manager.windows[0]
    yield from arrange(window)
    os.makedirs(OUT, exist_ok=True)
    failed = []
    for case in panel_cases.CASES:
        panel_cases.clear()
        case.setup()
        find_area(window, 'PROPERTIES').spaces.active.context = 'MODIFIER'
        DRAWN.clear()
        POLLED.clear()
        for area in window.screen.areas:
            area.tag_redraw()
        yield 1.0
        problems = drawn_by_default(case) + ERRORS
        del ERRORS[:]
        main = DRAWN.get((ui.DATA_PT_subdiv_pia.__name__, "draw"))
        count = len(main.controls) + len(DRAWN[(ui.DATA_PT_subdiv_pia.__name__, "draw_header_preset")].controls) \
            if main is not None else -1
        path = screenshot(window, case.name)
        say("%s: %d controls at the top, sub-panels %s; %s; %s" % (
            case.name, count, [c.bl_label for c in SUBPANELS if POLLED.get(c.__name__)], path,
            "FAILED: " + "; ".join(problems) if problems else "as expected"))
        if problems:
            failed.append(case.name)
    assert not failed, "cases that failed: %s" % failed


run_steps(script(), passed=lambda: say("all passed"), failed=lambda: say("FAILED"))
