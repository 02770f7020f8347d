# SPDX-License-Identifier: GPL-3.0-or-later
"""What the benchmark scripts share: where things are (the repository, the
built add-on, out/bench/), a script's arguments under Blender, the add-on
registered, leaving Blender, this process's memory (Linux), and the scans
and QuadriFlow cages the fit and detail benchmarks run on.

A script in bench/ imports it after putting bench/ on sys.path (Blender's
--python does not).  It imports no bpy but where a function needs it, so
that plain-Python scripts use it too.
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(ROOT, "tests", "data")
OUT = os.path.join(ROOT, "out", "bench")
# The add-on the benchmarks import (`subdiv_pia`, its binding as
# subdiv_pia.native): the build's, or the folder SUBDIV_PIA_ADDON_DIR names.
ADDON_DIR = os.path.abspath(os.path.join(ROOT, os.environ.get("SUBDIV_PIA_ADDON_DIR")
                                         or os.path.join("build", "addon")))

# The fit and detail benchmarks' cases: name: (scan in tests/data,
# QuadriFlow's target face count, the cage made from it in tests/data).
FIT_CASES = {
    "bunny": ("bun_zipper.obj", 3000, "bun_zipper_quadriflow_cage.obj"),
    "dragon": ("dragon_res2.obj", 10000, "dragon_res2_quadriflow_cage.obj"),
    "armadillo": ("armadillo.obj", 3000, "armadillo_quadriflow_cage.obj"),
    "chinese_dragon": ("ChineseDragon-10kv.obj", 3000, "ChineseDragon-10kv_quadriflow_cage.obj"),
    "elephant": ("elephant-with-holes.obj", 3000, "elephant-with-holes_quadriflow_cage.obj"),
}


def addon_on_path():
    """Puts ADDON_DIR first on sys.path, so that `import subdiv_pia` (and
    `from subdiv_pia import native`) finds the add-on there."""
    if sys.path[:1] != [ADDON_DIR]:
        sys.path.insert(0, ADDON_DIR)
    return ADDON_DIR


def script_args():
    """The script's arguments: after "--" (blender -b --python SCRIPT -- ARGS), or
    all of them where Blender is the bpy module (python SCRIPT [--] ARGS)."""
    import bpy
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1:]
    return sys.argv[1:] if getattr(bpy.app, "module", False) else []


def ensure_addon():
    """Registers subdiv_pia from ADDON_DIR (for what calls its operator or
    its script API); returns the package."""
    import bpy
    addon_on_path()
    import subdiv_pia
    if not hasattr(bpy.types, "OBJECT_OT_subdiv_pia_interpolate"):
        subdiv_pia.register()
    return subdiv_pia


def replace_everywhere(owner, name, replacement):
    """Sets owner.name to replacement, in owner and in every module of the
    same package that imported the same function (a module calls what it
    imported, not owner's attribute); returns the function replaced."""
    function = getattr(owner, name)
    package = owner.__name__.split(".")[0]
    for module in list(sys.modules.values()):
        if (getattr(module, "__name__", "").split(".")[0] == package and
                getattr(module, name, None) is function):
            setattr(module, name, replacement)
    return function


def finish(code=0):
    """Exit; the bpy module at once (Blender 4.2 and 4.3 crash on exit after
    an add-on registered classes, 4.5 does not exit while they are)."""
    import bpy
    sys.stdout.flush()
    sys.stderr.flush()
    if getattr(bpy.app, "module", False) or code:
        os._exit(code)


def proc_status(field):
    """A /proc/self/status field in bytes (VmRSS, VmHWM), or None."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def reset_peak():
    """Sets the peak resident size (VmHWM) to the current one and returns
    that (VmRSS, bytes); None where the kernel does not allow it."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return None
    return proc_status("VmRSS")
