# SPDX-License-Identifier: GPL-3.0-or-later
"""The settings in the groups an artist reads them in, shared by the
Modifiers-tab panel (one sub-panel a group), the operator's redo panel (F9)
and the Object menu: what the top shows, which group applies to the
settings at hand, and what each group draws.

A group that does not apply is not drawn at all (Blender's modifier panels
hide what does not apply rather than greying it).  The settings object is
either the scene's (scene.subdiv_pia) or the operator itself: both have the
same property names.  Touches no object.
"""

from .settings import LIMIT_SCHEMES


def action_label(settings, target_name):
    """The operator's button text: the action the settings will take."""
    if not target_name:
        return "Make Interpolating Cage"
    if settings.fit == 'VERTICES':
        return "Fit Cage Vertices to '%s'" % target_name
    levels = int(settings.fit_detail_levels)
    if levels:
        return "Fit Cage to '%s', %d Detail Level%s" % (target_name, levels, "" if levels == 1 else "s")
    return "Fit Cage to '%s'" % target_name


def modifier_line(modifier, scheme):
    """The one line that stands for the settings taken from `modifier`."""
    if scheme in LIMIT_SCHEMES:  # no modifier on the cage: only its levels count
        return "Levels %d, from '%s'" % (modifier.levels, modifier.name)
    return "Levels %d, Render %d, Quality %d, from '%s'" % (
        modifier.levels, modifier.render_levels, modifier.quality, modifier.name)


def draw_levels(layout, settings, modifier=None):
    """The levels, as the Subdivision Surface modifier shows them; with
    `modifier` (its settings are used) one line saying what they are."""
    if modifier is not None:
        layout.label(text=modifier_line(modifier, settings.scheme), icon='MOD_SUBSURF')
        return
    col = layout.column(align=True)
    if settings.scheme in LIMIT_SCHEMES:  # the `_limit` child's levels; no render levels
        col.prop(settings, "levels", text="Levels")
    else:
        col.prop(settings, "levels")
        col.prop(settings, "render_levels")


def subdivision_applies(settings, has_target, from_modifier):
    return not from_modifier and settings.scheme != 'DOO_SABIN'


def draw_subdivision(layout, settings):
    """Quality (Catmull-Clark: the modifier's), boundary smooth (not with
    Hoppe's Loop rules, which have their own) and creases."""
    if settings.scheme == 'CATMULL_CLARK':
        layout.prop(settings, "quality")
    if not (settings.scheme == 'LOOP' and settings.boundary_rule == 'HOPPE'):
        layout.prop(settings, "boundary_smooth")
    layout.prop(settings, "use_creases")


def scheme_is(scheme):
    """When a group applies: while the settings' scheme is `scheme`."""
    return lambda settings, has_target, from_modifier: settings.scheme == scheme


def always(settings, has_target, from_modifier):
    return True


def drawing(*names):
    """A group's body that draws these properties, one a row."""
    def draw(layout, settings):
        for name in names:
            layout.prop(settings, name)
    return draw


def scan_fit_applies(settings, has_target, from_modifier):
    return has_target


def draw_scan_fit(layout, settings):
    """The fit's settings; those of the Surface fit only with it, which
    works on Catmull-Clark only."""
    layout.prop(settings, "fit")
    layout.prop(settings, "fit_cutoff")
    if settings.fit == 'SURFACE':
        if settings.scheme != 'CATMULL_CLARK':
            layout.label(text="Surface works on Catmull-Clark only: fit Vertices", icon='ERROR')
        else:
            layout.prop(settings, "fit_smoothing")
            layout.prop(settings, "fit_samples")
            layout.prop(settings, "fit_detail_levels")
    layout.prop(settings, "fit_paint_scan")


def draw_cleanup_header(layout, settings):
    layout.prop(settings, "cleanup", text="")


def draw_cleanup(layout, settings):
    """The merge distance, inactive while cleanup is off (as Blender's
    panels with a switch in their header)."""
    layout.active = settings.cleanup
    layout.prop(settings, "cleanup_distance")


class Group:
    """One group of settings: its label, when it applies (settings,
    has_target, from_modifier), what its body draws, and what its header
    draws beside the label (None: the label alone)."""

    def __init__(self, key, label, applies, draw, draw_header=None):
        self.key, self.label, self.applies, self.draw, self.draw_header = key, label, applies, draw, draw_header


# In the order the panel and the redo panel show them.
GROUPS = (
    Group("subdivision", "Subdivision", subdivision_applies, draw_subdivision),
    Group("loop", "Loop", scheme_is('LOOP'), drawing("boundary_rule", "triangulate", "staged")),
    Group("doo_sabin", "Doo-Sabin", scheme_is('DOO_SABIN'), drawing("shape_parameter", "shape_attribute")),
    Group("solver", "Solver", always, drawing("method", "tolerance", "max_iterations")),
    Group("scan_fit", "Scan Fit", scan_fit_applies, draw_scan_fit),
    Group("cleanup", "Cleanup", always, draw_cleanup, draw_cleanup_header),
)


def draw_groups_inline(layout, settings, has_target, from_modifier=False):
    """Every group that applies, one after the other under its label (the
    redo panel, which has no sub-panels in every Blender)."""
    for group in GROUPS:
        if not group.applies(settings, has_target, from_modifier):
            continue
        layout.separator()
        heading = layout.row()
        if group.draw_header is not None:
            group.draw_header(heading, settings)
        heading.label(text=group.label)
        group.draw(layout.column(), settings)
