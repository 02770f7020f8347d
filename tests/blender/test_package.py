# SPDX-License-Identifier: GPL-3.0-or-later
"""The tests use the package they are meant to: the installed copy when
run.py installed SUBDIV_PIA_PACKAGE (an extension in Blender 4.2 and newer,
whose wheel brings the binding and the library; a legacy add-on before,
with both inside), else the build."""

import os
import sys

import bpy

import subdiv_pia
from subdiv_pia import (api, cleanup, cli, compute, jobs, live, mesh_io, native, objects, operators, properties,
                        reports, settings, steps, ui)

FOLDER = os.path.dirname(os.path.abspath(subdiv_pia.__file__))


def _under(path, folder):
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return os.path.commonpath([path, folder]) == folder


def _native_files(folder):
    return sorted(os.path.relpath(os.path.join(d, n), folder) for d, _dirs, names in os.walk(folder)
                  for n in names if n.endswith((".so", ".dll", ".dylib", ".pyd")))


def test_every_module_and_the_library_come_from_one_folder():
    for module in (api, cleanup, cli, compute, jobs, live, mesh_io, objects, operators, properties, reports, settings,
                   steps, ui):
        assert os.path.dirname(os.path.abspath(module.__file__)) == FOLDER, module.__file__
    assert native.available(), native.load_error()
    binding = os.path.dirname(os.path.abspath(native.__file__))
    assert native.library_path() == os.path.join(binding, native.library_name())
    if bpy.app.version >= (4, 2, 0) and os.environ.get("SUBDIV_PIA_PACKAGE"):
        # The extension: the binding and the library are the wheel's, which
        # Blender's installer put in the extensions' own site-packages; the
        # add-on's folder holds no native file.
        assert native.__name__ == "spia" and sys.modules["spia"] is native
        site = os.path.join(bpy.utils.user_resource('EXTENSIONS'), ".local")
        assert _under(binding, site), (binding, site)
        assert os.path.basename(binding) == "spia" and os.path.basename(os.path.dirname(binding)) == "site-packages"
        assert _native_files(FOLDER) == []
    else:
        # The legacy add-on and the development build: spia/ inside the add-on.
        assert native.__name__ == subdiv_pia.__name__ + ".spia"
        assert binding == os.path.join(FOLDER, "spia")
        assert _native_files(FOLDER) == [os.path.join("spia", native.library_name())]
    assert sys.modules[subdiv_pia.__name__ + ".native"] is native
    assert bpy.types.OBJECT_OT_subdiv_pia_interpolate.execute.__module__ == operators.__name__


def test_the_installed_package_is_in_use():
    package = os.environ.get("SUBDIV_PIA_PACKAGE")
    if not package:
        addon_dir = os.environ["SUBDIV_PIA_ADDON_DIR"]
        assert FOLDER == os.path.join(os.path.abspath(addon_dir), "subdiv_pia")
        return
    import addon_utils
    user_dir = os.environ["SUBDIV_PIA_USER_DIR"]
    assert _under(FOLDER, user_dir), (FOLDER, user_dir)
    name = os.environ["SUBDIV_PIA_ADDON_MODULE"]
    if bpy.app.version >= (4, 2, 0):
        assert name == "bl_ext.user_default.subdiv_pia"
        assert _under(FOLDER, bpy.utils.user_resource('EXTENSIONS'))
    else:
        assert name == "subdiv_pia"
        assert _under(FOLDER, bpy.utils.user_resource('SCRIPTS'))
    assert sys.modules[name] is subdiv_pia
    assert addon_utils.check(name) == (True, True)  # enabled in the preferences, and loaded
    assert name in bpy.context.preferences.addons


def test_cli_uses_the_copy_already_loaded():
    """cli.py inside Blender, with its package loaded (enabled as an add-on or
    extension, or registered by run.py): that copy, registered once."""
    registered = bpy.types.OBJECT_OT_subdiv_pia_interpolate
    assert cli._import_package() is subdiv_pia
    assert bpy.types.OBJECT_OT_subdiv_pia_interpolate is registered
