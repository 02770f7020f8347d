# SPDX-License-Identifier: GPL-3.0-or-later
"""Modifiers-tab panel and Object-menu entry."""

import textwrap

import bpy

from . import api, live, native
from .operators import (OBJECT_OT_subdiv_pia_interpolate, OBJECT_OT_subdiv_pia_live, OBJECT_OT_subdiv_pia_refresh_limit,
                        draw_cleanup_settings, draw_fit_settings, draw_settings, menu_func)
from .properties import SCENE_SETTING_NAMES

RESULT_KEYS = ("pia_status", "pia_method", "pia_iterations", "pia_max_error", "pia_mean_error",
               api.UNREACHABLE_COUNT)


def library_error_lines(width=60):
    """native.load_error() in lines short enough for a panel: what is needed
    first, then the files tried."""
    lines = []
    for line in str(native.load_error() or "unknown reason").splitlines() or [""]:
        lines.extend(textwrap.wrap(line, width, break_long_words=False, break_on_hyphens=False) or [""])
    return lines


class DATA_PT_subdiv_pia(bpy.types.Panel):
    bl_label = "Interpolating Subdivision Cage"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "modifier"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH'

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

        from_modifier = settings.use_modifier_settings and api.find_subsurf(obj) is not None
        layout.prop(settings, "use_modifier_settings")
        draw_settings(layout, settings, from_modifier=from_modifier)
        layout.prop(settings, "method")
        layout.prop(settings, "tolerance")
        layout.prop(settings, "max_iterations")
        draw_cleanup_settings(layout, settings)

        layout.separator()
        layout.prop(settings, "target_object")
        target = settings.target_object
        draw_fit_settings(layout, settings, target is not None)

        layout.prop(settings, "live")
        op = layout.operator(OBJECT_OT_subdiv_pia_interpolate.bl_idname, icon='MOD_SUBSURF')
        op.live = settings.live
        modifier_names = set(api.MODIFIER_SETTINGS) if from_modifier else set()
        for name in SCENE_SETTING_NAMES:
            if name not in modifier_names:
                setattr(op, name, getattr(settings, name))
        op.target = target.name if target is not None else ""

        if api.limit_cage_of(obj) is not None:
            layout.operator(OBJECT_OT_subdiv_pia_refresh_limit.bl_idname, icon='FILE_REFRESH')

        cage = api.limit_cage_of(obj) or obj
        if "pia_scheme" in cage:
            draw_live(layout, cage)

        if "pia_fit" in obj:
            box = layout.box()
            box.label(text="Last fit", icon='INFO')
            col = box.column(align=True)
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
        elif "pia_status" in obj:
            box = layout.box()
            box.label(text="Last result", icon='INFO')
            col = box.column(align=True)
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
            box = layout.box()
            box.label(text="Cleanup", icon='INFO')
            col = box.column(align=True)
            for line in textwrap.wrap(cleaned[len("cleanup: "):], 60):
                col.label(text=line)


def draw_live(layout, cage):
    """The cage's Live switch, what it follows, and why it stopped or did not follow."""
    box = layout.box()
    on = live.is_live(cage)
    row = box.row()
    op = row.operator(OBJECT_OT_subdiv_pia_live.bl_idname, text="Live: On" if on else "Live: Off",
                      icon='LINKED' if on else 'UNLINKED', depress=on)
    op.enable = not on
    source = cage.get(live.SOURCE, "")
    if source:
        box.label(text="Follows '%s'" % source if on else "Source: '%s'" % source)
    message = cage.get(live.MESSAGE, "")
    if message:
        for line in textwrap.wrap(message, 60) or [message]:
            box.label(text=line, icon='ERROR')


classes = (DATA_PT_subdiv_pia,)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.VIEW3D_MT_object.append(menu_func)


def unregister():
    bpy.types.VIEW3D_MT_object.remove(menu_func)
    _unregister()
