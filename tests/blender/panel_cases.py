# SPDX-License-Identifier: GPL-3.0-or-later
"""The panel in the cases an artist meets it, and what it must show in each
before any sub-panel is opened: the controls at the top (the header's
preset menu, then the panel's body above the result line), in order; the
sub-panels shown (all closed by default); the button's label; the result
line's icon.  Shared by test_ui.py (the panel drawn into a recorder) and
tests/window/panel.py (drawn in Blender's window, and photographed).

Each case's scene is built from an empty scene with the panel's settings
at their defaults (clear()).
"""

import bpy

from shapes import fine_sphere, quad_sphere

# The bound: a fresh mesh shows at most this many controls before a
# sub-panel is opened (26 before the panel was regrouped).
MAX_TOP_CONTROLS = 8

PRESETS = ("popover", "SUBDIV_PIA_PT_presets")
BUTTON = ("operator", "object.subdiv_pia_interpolate")
LIVE_SWITCH = ("operator", "object.subdiv_pia_live")


def prop(name):
    return ("prop", name)


def clear():
    """An empty scene, the panel's settings at their defaults, no failure kept."""
    from subdiv_pia import operators, preset_menu
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for mesh in list(bpy.data.meshes):
        bpy.data.meshes.remove(mesh)
    settings = bpy.context.scene.subdiv_pia
    preset_menu.reset_settings(settings)
    settings.target_object = None
    operators.LAST_FAILURES.clear()


class Case:
    def __init__(self, name, setup, top, subpanels, button, status=None):
        self.name, self.setup, self.top, self.subpanels = name, setup, top, subpanels
        self.button, self.status = button, status


def fresh_mesh():
    bpy.ops.mesh.primitive_cube_add()


def scan_target():
    """A cage with a Subdivision Surface modifier (Use Modifier Settings is
    on by default) and a scan picked as the target."""
    scan = fine_sphere("Scan", segments=32, rings=16)
    cage = quad_sphere("Cage", cuts=1)
    modifier = cage.modifiers.new("Subdivision", 'SUBSURF')
    modifier.levels = 2
    settings = bpy.context.scene.subdiv_pia
    settings.target_object = scan
    settings.fit_cutoff = 0.2  # the one-cut cage's surface is farther from the sphere than the default
    return cage


def loop_mesh():
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2)
    bpy.context.scene.subdiv_pia.scheme = 'LOOP'


def finished_fit():
    """scan_target(), fitted as the panel's button does: the result active."""
    from subdiv_pia import ui
    scan_target()
    layout = _Button()
    ui.draw_action(layout, bpy.context)
    result = bpy.ops.object.subdiv_pia_interpolate(**layout.settings)
    assert result == {'FINISHED'}, result
    assert bpy.context.active_object.name == "Cage_pia"


class _Button:
    """Takes the settings the panel's button would run the operator with."""

    def operator(self, idname, **kwargs):
        self.settings = {}
        button = self

        class Props:
            def __setattr__(self, name, value):
                button.settings[name] = value
        return Props()


CASES = (
    Case("mesh", fresh_mesh,
         [PRESETS, BUTTON, prop("scheme"), prop("levels"), prop("render_levels"), prop("target_object"),
          prop("live")],
         ["Subdivision", "Solver", "Cleanup"], "Make Interpolating Cage"),
    Case("scan", scan_target,
         [PRESETS, BUTTON, prop("use_modifier_settings"), prop("scheme"), prop("target_object"), prop("live")],
         ["Solver", "Scan Fit", "Cleanup"], "Fit Cage to 'Scan'"),
    Case("loop", loop_mesh,
         [PRESETS, BUTTON, prop("scheme"), prop("levels"), prop("target_object"), prop("live")],
         ["Subdivision", "Loop", "Solver", "Cleanup"], "Make Interpolating Cage"),
    Case("fitted", finished_fit,
         [PRESETS, BUTTON, prop("use_modifier_settings"), prop("scheme"), prop("target_object"), prop("live"),
          LIVE_SWITCH],
         ["Solver", "Scan Fit", "Cleanup", "Last Result"], "Fit Cage to 'Scan'", status='CHECKMARK'),
)


def check(case, controls, subpanels, labels, icons):
    """What the panel drew by default in `case` (controls: (kind, name,
    text) at the top in order; subpanels: labels of those shown; labels and
    icons of the panel's body) against what it must; a list of what differs."""
    problems = []
    top = [(kind, name) for kind, name, _text in controls]
    if top != case.top:
        problems.append("top controls %s, expected %s" % (top, case.top))
    if len(top) > MAX_TOP_CONTROLS:
        problems.append("%d controls at the top, more than %d" % (len(top), MAX_TOP_CONTROLS))
    buttons = [text for kind, name, text in controls if (kind, name) == BUTTON]
    if buttons != [case.button]:
        problems.append("button %s, expected %r" % (buttons, case.button))
    if list(subpanels) != case.subpanels:
        problems.append("sub-panels %s, expected %s" % (list(subpanels), case.subpanels))
    status = [icons.get(text) for text in labels if icons.get(text) in ('CHECKMARK', 'ERROR')]
    if status != ([case.status] if case.status else []):
        problems.append("result line icons %s, expected %s (labels %s)" % (status, case.status, labels))
    return problems
