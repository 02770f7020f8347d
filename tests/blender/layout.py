# SPDX-License-Identifier: GPL-3.0-or-later
"""A stand-in for bpy.types.UILayout that records what a panel draws:
background mode has no interface to draw into."""


class Recorder:
    """Stands in for bpy.types.UILayout and records what is drawn."""

    def __init__(self, log=None):
        self.log = [] if log is None else log
        self.enabled = True
        self.use_property_split = False
        self.use_property_decorate = True

    def _child(self, *args, **kwargs):
        return Recorder(self.log)

    column = row = box = _child

    def prop(self, data, name, **kwargs):
        assert hasattr(data, name), name
        self.log.append(("prop", name))

    def label(self, text="", **kwargs):
        self.log.append(("label", text))

    def separator(self, **kwargs):
        pass

    def operator(self, idname, **kwargs):
        self.log.append(("operator", idname))
        return type("Props", (), {})()
