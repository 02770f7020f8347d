# SPDX-License-Identifier: GPL-3.0-or-later
"""What a panel draws, recorded: Recorder stands in for
bpy.types.UILayout (background mode has no interface to draw into); Tee
wraps a real one in Blender's window, draws into it and records the same.

The log holds ("prop", name), ("operator", idname), ("label", text),
("popover", panel) and ("menu", menu) in drawing order; `controls` the
same for the controls alone, with the text each shows."""

# What an artist can click: the entries of the log that are controls.
CONTROL_KINDS = ("prop", "operator", "popover", "menu")


class Recorder:
    """Stands in for bpy.types.UILayout and records what is drawn."""

    def __init__(self, log=None, controls=None, icons=None):
        self.log = [] if log is None else log
        self.controls = [] if controls is None else controls
        self.icons = {} if icons is None else icons  # label text: its icon
        self.enabled = True
        self.active = True
        self.use_property_split = False
        self.use_property_decorate = True

    def _child(self, *args, **kwargs):
        return type(self)(self.log, self.controls, self.icons)

    column = row = box = split = _child

    def _record(self, kind, name, text=None):
        self.log.append((kind, name))
        if kind in CONTROL_KINDS:
            self.controls.append((kind, name, text))

    def prop(self, data, name, text=None, **kwargs):
        assert hasattr(data, name), name
        self._record("prop", name, text)

    def prop_search(self, data, name, search_data, search_name, text=None, **kwargs):
        assert hasattr(data, name), name
        self._record("prop", name, text)

    def label(self, text="", icon='NONE', **kwargs):
        self.log.append(("label", text))
        self.icons[text] = icon

    def separator(self, **kwargs):
        pass

    def operator(self, idname, text=None, **kwargs):
        self._record("operator", idname, text)
        return type("Props", (), {})()

    def popover(self, panel, text=None, **kwargs):
        self._record("popover", panel, text)

    def menu(self, menu, text=None, **kwargs):
        self._record("menu", menu, text)


class Tee(Recorder):
    """Draws into the real layout it wraps, and records what it draws."""

    def __init__(self, layout, log=None, controls=None, icons=None):
        # The recorder's own state, without touching the real layout's.
        object.__setattr__(self, "_layout", layout)
        object.__setattr__(self, "log", [] if log is None else log)
        object.__setattr__(self, "controls", [] if controls is None else controls)
        object.__setattr__(self, "icons", {} if icons is None else icons)

    def __getattr__(self, name):  # what the real layout says (enabled, active, ...)
        return getattr(self._layout, name)

    def __setattr__(self, name, value):
        setattr(self._layout, name, value)

    def column(self, *args, **kwargs):
        return Tee(self._layout.column(*args, **kwargs), self.log, self.controls, self.icons)

    def row(self, *args, **kwargs):
        return Tee(self._layout.row(*args, **kwargs), self.log, self.controls, self.icons)

    def box(self, *args, **kwargs):
        return Tee(self._layout.box(*args, **kwargs), self.log, self.controls, self.icons)

    def split(self, *args, **kwargs):
        return Tee(self._layout.split(*args, **kwargs), self.log, self.controls, self.icons)

    def prop(self, data, name, *args, **kwargs):
        super().prop(data, name, **kwargs)
        self._layout.prop(data, name, *args, **kwargs)

    def prop_search(self, data, name, search_data, search_name, *args, **kwargs):
        super().prop_search(data, name, search_data, search_name, **kwargs)
        self._layout.prop_search(data, name, search_data, search_name, *args, **kwargs)

    def label(self, *args, **kwargs):
        super().label(*args, **kwargs)
        self._layout.label(*args, **kwargs)

    def separator(self, *args, **kwargs):
        self._layout.separator(*args, **kwargs)

    def operator(self, idname, *args, **kwargs):
        super().operator(idname, **kwargs)
        return self._layout.operator(idname, *args, **kwargs)

    def popover(self, panel, *args, **kwargs):
        super().popover(panel, **kwargs)
        self._layout.popover(panel, *args, **kwargs)

    def menu(self, menu, *args, **kwargs):
        super().menu(menu, **kwargs)
        self._layout.menu(menu, *args, **kwargs)


def fake_panel(layout, cls=None):
    """An object to call a panel class's draw functions with (their `self`)."""
    attributes = {"layout": layout}
    if cls is not None:
        attributes["bl_idname"] = cls.__name__
    return type("Panel", (), attributes)()
