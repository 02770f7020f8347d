# SPDX-License-Identifier: GPL-3.0-or-later
"""Modifiers-tab panel and Object-menu entry.

The panel follows Blender's modifier panels: at the top what everyone
touches (the action, Use Modifier Settings while the object has a
Subdivision Surface modifier, scheme, levels, target scan, Live), then the
result in one line; the rest in sub-panels, closed by default, each shown
only while it applies (addon/sections.py says when), and the full report of
the last run in its own closed sub-panel.  The header holds the presets.
"""

import textwrap

import bpy

from . import api, live, native, reports, sections
from .operators import (LAST_FAILURES, OBJECT_OT_subdiv_pia_interpolate, OBJECT_OT_subdiv_pia_live,
                        OBJECT_OT_subdiv_pia_refresh_limit)
from .preset_menu import SUBDIV_PIA_PT_presets
from .properties import SCENE_SETTING_NAMES


def library_error_lines(width=60):
    """native.load_error() in lines short enough for a panel: what is needed
    first, then the files tried."""
    lines = []
    for line in str(native.load_error() or "unknown reason").splitlines() or [""]:
        lines.extend(textwrap.wrap(line, width, break_long_words=False, break_on_hyphens=False) or [""])
    return lines


def used_modifier(settings, obj):
    """The Subdivision Surface modifier whose settings a run takes, or None."""
    return api.find_subsurf(obj) if settings.use_modifier_settings else None


def draw_action(layout, context):
    """The operator's button, labelled with what it will do, set to the
    panel's settings (the modifier's where they are used)."""
    settings = context.scene.subdiv_pia
    target = settings.target_object
    op = layout.operator(OBJECT_OT_subdiv_pia_interpolate.bl_idname, icon='MOD_SUBSURF',
                         text=sections.action_label(settings, target.name if target is not None else ""))
    op.live = settings.live
    modifier_names = set(api.MODIFIER_SETTINGS) if used_modifier(settings, context.object) else set()
    for name in SCENE_SETTING_NAMES:
        if name not in modifier_names:
            setattr(op, name, getattr(settings, name))
    op.target = target.name if target is not None else ""


def result_object(obj):
    """The object whose result the panel shows: the cage, for its `_limit` child."""
    return api.limit_cage_of(obj) or obj


class _ModifierTab:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "modifier"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH'


class DATA_PT_subdiv_pia(_ModifierTab, bpy.types.Panel):
    bl_label = "Interpolating Subdivision Cage"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header_preset(self, context):
        SUBDIV_PIA_PT_presets.draw_panel_header(self.layout)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        obj = context.object
        settings = context.scene.subdiv_pia

        if not native.available():
            box = layout.box()
            box.label(text="Native library not loaded:", icon='ERROR')
            for line in library_error_lines():
                box.label(text=line)
            return

        draw_action(layout, context)
        if api.find_subsurf(obj) is not None:
            layout.prop(settings, "use_modifier_settings")
        layout.prop(settings, "scheme")
        sections.draw_levels(layout, settings, used_modifier(settings, obj))
        layout.prop(settings, "target_object")
        layout.prop(settings, "live")
        cage = result_object(obj)
        if "pia_scheme" in cage:
            draw_live(layout, cage)
        if api.limit_cage_of(obj) is not None:
            layout.operator(OBJECT_OT_subdiv_pia_refresh_limit.bl_idname, icon='FILE_REFRESH')
        draw_status(layout, obj)


def draw_status(layout, obj):
    """The last run in one line with its icon: why it made nothing, or how
    close its result came."""
    failure = LAST_FAILURES.get(obj.name)
    line = ('ERROR', failure) if failure else reports.status_line(result_object(obj))
    if line is not None:
        layout.label(text=line[1], icon=line[0])


def draw_live(layout, cage):
    """The cage's own Live switch, what it follows, and why it stopped or did not follow."""
    box = layout.box()
    on = live.is_live(cage)
    row = box.row()
    op = row.operator(OBJECT_OT_subdiv_pia_live.bl_idname, text="%s: Live %s" % (cage.name, "On" if on else "Off"),
                      icon='LINKED' if on else 'UNLINKED', depress=on)
    op.enable = not on
    source = cage.get(live.SOURCE, "")
    if source:
        box.label(text="Follows '%s'" % source if on else "Source: '%s'" % source)
    message = cage.get(live.MESSAGE, "")
    if message:
        for line in textwrap.wrap(message, 60) or [message]:
            box.label(text=line, icon='ERROR')


def _subpanel_state(context):
    """(settings, has_target, from_modifier) for the sub-panels' polls, or
    None where they have nothing to show."""
    if not DATA_PT_subdiv_pia.poll(context) or not native.available():
        return None
    settings = context.scene.subdiv_pia
    return settings, settings.target_object is not None, used_modifier(settings, context.object) is not None


def group_panel(group):
    """The sub-panel of one of sections.GROUPS: closed by default, shown
    while the group applies."""

    def poll(cls, context):
        state = _subpanel_state(context)
        return state is not None and group.applies(*state)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        group.draw(layout, context.scene.subdiv_pia)

    namespace = dict(bl_label=group.label, bl_parent_id=DATA_PT_subdiv_pia.__name__,
                     bl_options={'DEFAULT_CLOSED'}, poll=classmethod(poll), draw=draw)
    if group.draw_header is not None:
        namespace["draw_header"] = lambda self, context: group.draw_header(self.layout, context.scene.subdiv_pia)
    return type("DATA_PT_subdiv_pia_" + group.key, (_ModifierTab, bpy.types.Panel), namespace)


GROUP_PANELS = tuple(group_panel(group) for group in sections.GROUPS)


def has_result(obj):
    return any(key in obj for key in ("pia_status", "pia_fit")) or bool(api.format_cleanup(obj))


class DATA_PT_subdiv_pia_result(_ModifierTab, bpy.types.Panel):
    """The full report of the run that made the active object."""
    bl_label = "Last Result"
    bl_parent_id = DATA_PT_subdiv_pia.__name__
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and has_result(result_object(context.object))

    def draw(self, context):
        draw_last_result(self.layout.column(align=True), result_object(context.object))


def draw_last_result(col, obj):
    """Every figure the run stored on obj, a line each."""
    if "pia_fit" in obj:
        draw_fit_result(col, obj)
    elif "pia_status" in obj:
        col.label(text="Status: %s (%s)" % (obj.get("pia_status"), obj.get("pia_method", "?")))
        col.label(text="Iterations: %d" % int(obj.get("pia_iterations", 0)))
        col.label(text="Max error: %.3g of bbox diagonal" % float(obj.get("pia_max_error", 0.0)))
        col.label(text="Mean error: %.3g of bbox diagonal" % float(obj.get("pia_mean_error", 0.0)))
        unreachable = api.format_unreachable(int(obj.get(api.UNREACHABLE_COUNT, 0)),
                                             float(obj.get(api.REACHABLE_MAX_ERROR, 0.0)))
        for line in textwrap.wrap(unreachable, 60):
            col.label(text=line)
    cleaned = api.format_cleanup(obj)
    if cleaned:
        col.label(text="Cleanup:")
        for line in textwrap.wrap(cleaned[len("cleanup: "):], 60):
            col.label(text=line)


def draw_fit_result(col, obj):
    col.label(text="%s fit to '%s', %d rounds" % (api.FIT_NAMES.get(obj["pia_fit"], obj["pia_fit"]),
                                                  obj.get("pia_fit_target", "?"),
                                                  int(obj.get("pia_fit_rounds", 0))))
    for label, key in (("Mean", "mean"), ("95th percentile", "p95"), ("Max", "max")):
        col.label(text="%s distance: %.2g (was %.2g)"
                  % (label, float(obj.get("pia_fit_%s_after" % key, 0.0)),
                     float(obj.get("pia_fit_%s_before" % key, 0.0))))
    if obj.get("pia_fit_scan_points"):
        col.label(text="Scan to surface: mean %.2g, max %.2g (was %.2g, %.2g)"
                  % (float(obj.get("pia_fit_scan_mean_after", 0.0)),
                     float(obj.get("pia_fit_scan_max_after", 0.0)),
                     float(obj.get("pia_fit_scan_mean_before", 0.0)),
                     float(obj.get("pia_fit_scan_max_before", 0.0))))
        col.label(text="Scan not reached: %.2g%% (was %.2g%%)"
                  % (100.0 * float(obj.get("pia_fit_scan_unreached_after", 0.0)),
                     100.0 * float(obj.get("pia_fit_scan_unreached_before", 0.0))))
    if "pia_fit_folded_after" in obj:
        col.label(text="Facing away from the scan: %.2g%% (was %.2g%%)"
                  % (100.0 * float(obj["pia_fit_folded_after"]),
                     100.0 * float(obj.get("pia_fit_folded_before", 0.0))))
    if obj.get("pia_fit_detail_levels"):
        col.label(text="Detail: %d levels, finest mean %.2g, 95th percentile %.2g"
                  % (int(obj["pia_fit_detail_levels"]), float(obj["pia_fit_detail_mean"]),
                     float(obj["pia_fit_detail_p95"])))
        if "pia_fit_detail_scan_mean" in obj:
            col.label(text="Scan to the finest level: mean %.2g, 95th percentile %.2g"
                      % (float(obj["pia_fit_detail_scan_mean"]), float(obj["pia_fit_detail_scan_p95"])))
    col.label(text="Of the scan's diagonal; heat map red at %.2g"
              % float(obj.get("pia_distance_scale", api.HEAT_SCALE)))
    col.label(text="(Viewport Shading > Color > Attribute)")
    not_painted = obj.get("pia_fit_scan_not_painted")
    if not_painted:
        for line in textwrap.wrap(not_painted, 60):
            col.label(text=line, icon='ERROR')


def menu_func(self, context):
    """Object > the same action as the panel's button, with the panel's settings."""
    draw_action(self.layout, context)


# Sub-panels after their parent, in the order they are shown.
classes = (DATA_PT_subdiv_pia,) + GROUP_PANELS + (DATA_PT_subdiv_pia_result,)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.VIEW3D_MT_object.append(menu_func)


def unregister():
    bpy.types.VIEW3D_MT_object.remove(menu_func)
    _unregister()
