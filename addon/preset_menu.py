# SPDX-License-Identifier: GPL-3.0-or-later
"""Presets of the panel's settings through Blender's preset system: the
menu in the panel's header lists the add-on's built-in presets (the files
in its presets/ folder, which may be read-only: an installed extension) and
then the user's own, which Blender's AddPresetBase writes to the user's
scripts/presets/subdiv_pia/ and removes from there.

Each preset sets what it names on scene.subdiv_pia; every other setting of
a preset goes back to its default first, so that a preset gives the same
settings whatever was set before (the target scan is kept: a preset names
no object).
"""

import os

import bpy
from bl_operators.presets import AddPresetBase
from bl_ui.utils import PresetPanel

from .properties import PRESET_NAMES

PRESET_SUBDIR = "subdiv_pia"
BUILTIN_PRESETS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "presets")
PRESET_EXTENSION = ".py"
SETTINGS_PATH = "bpy.context.scene.subdiv_pia"


def reset_settings(settings):
    """Every setting a preset holds back to its default."""
    for name in PRESET_NAMES:
        settings.property_unset(name)


def builtin_preset_files():
    return sorted(os.path.join(BUILTIN_PRESETS, name) for name in os.listdir(BUILTIN_PRESETS)
                  if name.endswith(PRESET_EXTENSION))


def user_preset_folders():
    """The user's preset folders for these settings (Blender's preset paths,
    less the add-on's own folder should a Blender list it)."""
    builtin = os.path.realpath(BUILTIN_PRESETS)
    return [path for path in bpy.utils.preset_paths(PRESET_SUBDIR)
            if os.path.realpath(path) != builtin]


class SUBDIV_PIA_PT_presets(PresetPanel, bpy.types.Panel):
    bl_label = "Interpolating Cage Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    preset_add_operator = "object.subdiv_pia_preset_add"

    @staticmethod
    def reset_cb(context, filepath=None):
        # Called by script.execute_preset before it runs a preset's file.
        reset_settings(context.scene.subdiv_pia)

    def draw(self, context):
        layout = self.layout
        layout.emboss = 'PULLDOWN_MENU'
        layout.operator_context = 'EXEC_DEFAULT'
        # The built-in presets, without the remove button: they ship with the add-on.
        self.path_menu([BUILTIN_PRESETS], self.preset_operator, filter_ext=self.is_preset,
                       display_name=preset_display_name)
        folders = user_preset_folders()
        if folders:
            layout.separator()
            self.path_menu(folders, self.preset_operator, filter_ext=self.is_preset,
                           display_name=preset_display_name, add_operator=self.preset_add_operator)
        else:  # no preset of the user's yet: only the field to name a new one
            layout.separator()
            row = layout.row()
            field = row.row()
            field.emboss = 'NORMAL'
            field.prop(context.window_manager, "preset_name", text="")
            row.operator(self.preset_add_operator, text="", icon='ADD').name = context.window_manager.preset_name

    @staticmethod
    def is_preset(extension):
        return extension.lower() == PRESET_EXTENSION


def preset_display_name(path):
    return bpy.path.display_name(path, title_case=False)


class OBJECT_OT_subdiv_pia_preset_add(AddPresetBase, bpy.types.Operator):
    """Add a preset of the Interpolating Subdivision Cage settings, or remove one of yours"""
    bl_idname = "object.subdiv_pia_preset_add"
    bl_label = "Add Interpolating Cage Preset"
    preset_menu = SUBDIV_PIA_PT_presets.__name__
    preset_subdir = PRESET_SUBDIR
    # Full paths, no preset_defines: where Blender runs on Python 3.13 with a
    # presets.py that exec()s the defines inside a function (Debian's 4.3.2),
    # the names they define are not seen by the eval() of the values.
    preset_values = [SETTINGS_PATH + "." + name for name in PRESET_NAMES]


classes = (SUBDIV_PIA_PT_presets, OBJECT_OT_subdiv_pia_preset_add)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()


def unregister():
    _unregister()
