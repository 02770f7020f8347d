# SPDX-License-Identifier: GPL-3.0-or-later
"""Run the Blender test suite inside Blender:

    blender -b --factory-startup --python-exit-code 1 --python tests/blender/run.py -- [pytest args]
    python tests/blender/run.py [--] [pytest args]      (Blender as the bpy module)

By default the built add-on is used (build/addon/subdiv_pia, or the folder
containing subdiv_pia named by SUBDIV_PIA_ADDON_DIR): it is put on sys.path
and registered.

With SUBDIV_PIA_PACKAGE naming a zip (`make package` writes them to dist/),
the package is installed as a user installs it, into a fresh temporary user
directory (BLENDER_USER_* set before Blender starts, so the suite runs in a
child process): Blender 4.2 and newer as an extension of the user
repository (its installer installs the wheel inside), older ones as a
legacy add-on, from SUBDIV_PIA_LEGACY_PACKAGE when that names one (Blender
3.4 to 4.1 take no wheels); the tests then import that installed copy as
`subdiv_pia`.

Exits with pytest's status (1 when no test ran).
"""

import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
# The blender executable imports bpy before it runs a script; the module is
# imported only below, once the environment is in place.
IN_EXECUTABLE = "bpy" in sys.modules
PACKAGE_NAME = "subdiv_pia"
SUBMODULES = ("native", "cleanup", "settings", "mesh_io", "compute", "objects", "reports", "detail", "live", "steps", "jobs",
              "api", "properties", "sections", "operators", "preset_menu", "ui", "cli")


def _argv():
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1:]
    return [] if IN_EXECUTABLE else sys.argv[1:]


def user_environment(user_dir):
    """Blender's user folders, all inside user_dir (read when Blender starts)."""
    return {
        "BLENDER_USER_RESOURCES": user_dir,  # 4.2+: the parent of the others
        "BLENDER_USER_CONFIG": os.path.join(user_dir, "config"),
        "BLENDER_USER_SCRIPTS": os.path.join(user_dir, "scripts"),
        "BLENDER_USER_EXTENSIONS": os.path.join(user_dir, "extensions"),
        "BLENDER_USER_DATAFILES": os.path.join(user_dir, "datafiles"),
    }


def run_in_fresh_user_dir(package, argv):
    """Run this script again in a new Blender whose user folders are new."""
    user_dir = tempfile.mkdtemp(prefix="subdiv_pia_user_")
    env = dict(os.environ, SUBDIV_PIA_USER_DIR=user_dir, SUBDIV_PIA_PACKAGE=os.path.abspath(package),
               **user_environment(user_dir))
    if IN_EXECUTABLE:
        import bpy
        command = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
                   "--python", os.path.abspath(__file__), "--"] + argv
    else:
        command = [sys.executable, os.path.abspath(__file__), "--"] + argv
    try:
        return subprocess.call(command, env=env)
    finally:
        shutil.rmtree(user_dir, ignore_errors=True)


def _under(path, folder):
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return os.path.commonpath([path, folder]) == folder


def install_package(package, user_dir):
    """Install the zip as a user does; return the module name it is enabled as."""
    import bpy
    extensions = bpy.app.version >= (4, 2, 0) and hasattr(bpy.ops, "extensions")
    if extensions:
        # The user repository, as a new user directory has it.
        repo = next((r for r in bpy.context.preferences.extensions.repos
                     if r.module == "user_default"), None)
        if repo is None:
            raise RuntimeError("no user_default extension repository")
        result = bpy.ops.extensions.package_install_files(
            filepath=package, repo=repo.module, enable_on_install=True)
        name = "bl_ext.%s.%s" % (repo.module, PACKAGE_NAME)
    else:
        result = bpy.ops.preferences.addon_install(filepath=package)
        if result == {'FINISHED'}:
            result = bpy.ops.preferences.addon_enable(module=PACKAGE_NAME)
        name = PACKAGE_NAME
    if result != {'FINISHED'}:
        raise RuntimeError("installing %s returned %s" % (package, result))
    module = sys.modules.get(name)
    if module is None or not _under(module.__file__, user_dir):
        raise RuntimeError("%s is not the installed copy: %s" % (name, getattr(module, "__file__", None)))
    return name


def alias_installed(name):
    """Make `import subdiv_pia` and its submodules give the installed copy."""
    import importlib
    package = importlib.import_module(name)
    sys.modules[PACKAGE_NAME] = package
    for sub in SUBMODULES:
        module = importlib.import_module(name + "." + sub)
        sys.modules[PACKAGE_NAME + "." + sub] = module
    return package


def main():
    argv = _argv()
    package_zip = os.environ.get("SUBDIV_PIA_PACKAGE")
    user_dir = os.environ.get("SUBDIV_PIA_USER_DIR")
    if package_zip and not user_dir:
        if not os.path.isfile(package_zip):
            print("run.py: SUBDIV_PIA_PACKAGE=%s is not a file (run `make build` first)" % package_zip,
                  file=sys.stderr)
            return 1
        return run_in_fresh_user_dir(package_zip, argv)

    import bpy
    import pytest

    legacy_zip = os.environ.get("SUBDIV_PIA_LEGACY_PACKAGE")
    if package_zip and legacy_zip and bpy.app.version < (4, 2, 0):
        package_zip = os.environ["SUBDIV_PIA_PACKAGE"] = legacy_zip
    if package_zip:
        name = install_package(os.path.abspath(package_zip), user_dir)
        subdiv_pia = alias_installed(name)
        # conftest enables it again after each factory reset, by this name.
        os.environ["SUBDIV_PIA_ADDON_MODULE"] = name
        os.environ.pop("SUBDIV_PIA_ADDON_DIR", None)
    else:
        addon_dir = os.path.abspath(os.environ.get("SUBDIV_PIA_ADDON_DIR")
                                    or os.path.join(ROOT, "build", "addon"))
        if not os.path.isdir(os.path.join(addon_dir, PACKAGE_NAME)):
            print("run.py: no subdiv_pia package in %s (run `make build` first)" % addon_dir,
                  file=sys.stderr)
            return 1
        sys.path.insert(0, addon_dir)
        os.environ["SUBDIV_PIA_ADDON_DIR"] = addon_dir  # for subprocess tests
        os.environ.pop("SUBDIV_PIA_ADDON_MODULE", None)
        import subdiv_pia
        subdiv_pia.register()
    print("run.py: Blender %s%s, subdiv_pia from %s" % (
        bpy.app.version_string, " (bpy module)" if not IN_EXECUTABLE else "",
        os.path.dirname(subdiv_pia.__file__)), flush=True)

    if not any(os.path.exists(a.split("::")[0]) for a in argv if not a.startswith("-")):
        argv = [HERE] + argv  # no test paths given: the whole Blender suite
    try:
        code = pytest.main(["-p", "no:cacheprovider", "-q", "--rootdir", ROOT] + argv)
    finally:
        try:
            if package_zip:
                import addon_utils
                addon_utils.disable(os.environ["SUBDIV_PIA_ADDON_MODULE"])
            else:
                subdiv_pia.unregister()
        except Exception:  # registration state after the last factory reset
            pass
    code = int(code)
    if code == 5:  # no tests collected
        code = 1
    return code


def finish(code):
    """Exit with code. The bpy module is left at once: Blender 4.2 and 4.3
    crash on exit once add-on classes were registered, 4.5 never exits while
    they are."""
    sys.stdout.flush()
    sys.stderr.flush()
    if "bpy" in sys.modules and not IN_EXECUTABLE:
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    sys.stdout.flush()
    finish(main())
