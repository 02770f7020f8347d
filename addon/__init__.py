# SPDX-License-Identifier: GPL-3.0-or-later
"""Subdivision PIA: make a control cage whose Catmull-Clark limit surface
(as Blender's Subdivision Surface modifier evaluates it with
"Use Limit Surface") passes through the vertices of a mesh.

Script use (background or foreground)::

    import subdiv_pia
    new_obj, report = subdiv_pia.interpolate(obj, levels=2, quality=3)
    cage, report = subdiv_pia.interpolate(tri_obj, scheme='LOOP', boundary_rule='HOPPE')
    limit = subdiv_pia.find_limit_object(cage)   # child "<cage>_limit": the Loop limit surface
    subdiv_pia.refresh_limit(cage)               # after editing the cage
    cage, report = subdiv_pia.interpolate(obj, live=True)  # follows every edit of obj
    subdiv_pia.set_live(cage, False)             # Live off (subdiv_pia.is_live(cage))
    cage, report = subdiv_pia.interpolate(closed_obj, scheme='DOO_SABIN', shape_parameter=0.8,
                                          shape_attribute="pia_shape")  # per-face values win
    fitted, report = subdiv_pia.interpolate(cage_obj, target="Scan", fit='SURFACE')  # fit to a scan
    cage, report = subdiv_pia.interpolate(scan_obj, cleanup=True)  # a cleaned copy (merged, reoriented)

The numeric core (``native``) imports no ``bpy``; everything else is loaded
only inside Blender so that ``subdiv_pia.native`` stays importable outside it.
"""

bl_info = {
    "name": "Subdivision PIA (interpolating cage)",
    "author": "subdiv_pia contributors",
    "version": (0, 2, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Modifiers > Interpolating Subdivision Cage; View3D > Object menu",
    "description": "New cage whose subdivision limit surface passes through the mesh vertices",
    "category": "Mesh",
}

try:
    import bpy  # noqa: F401
except ImportError:  # outside Blender: only `native` is usable
    bpy = None

if bpy is not None:
    from . import properties, operators, preset_menu, ui, live
    from .api import (interpolate, refresh_limit, find_limit_object,  # noqa: F401
                      settings_from_modifier, DEFAULT_SETTINGS)
    from .live import set_live, is_live  # noqa: F401

    _modules = (properties, operators, preset_menu, ui, live)

    def register():
        for module in _modules:
            module.register()

    def unregister():
        for module in reversed(_modules):
            module.unregister()
