# SPDX-License-Identifier: GPL-3.0-or-later
"""Finding and loading the native library, and what to tell the user when
it cannot be loaded.

The library is looked up next to the package (``libsubdiv_pia.so``,
``subdiv_pia.dll`` or ``libsubdiv_pia.dylib``), or at the path in the
environment variable ``SUBDIV_PIA_LIBRARY``, on first use; the functions
of the other modules take it from :func:`_library`."""

import ctypes
import os
import platform
import re
import sys

from .errors import PiaError
from .header import _declare

_lib = None
_lib_path = None
_load_error = None

# The library's file name on each operating system (sys.platform's start).
LIBRARY_NAMES = {"linux": "libsubdiv_pia.so", "win32": "subdiv_pia.dll", "darwin": "libsubdiv_pia.dylib"}
_SYSTEM_OF_PLATFORM = {"linux": "linux", "win32": "windows", "darwin": "macos"}
_SYSTEM_NAMES = {"linux": "Linux", "windows": "Windows", "macos": "macOS"}
_MACHINES = {"x86_64": "x64", "amd64": "x64", "x64": "x64", "aarch64": "arm64", "arm64": "arm64"}


def _system():
    for prefix, system in _SYSTEM_OF_PLATFORM.items():
        if sys.platform.startswith(prefix):
            return system
    return sys.platform


def platform_tag():
    """This system as extension platforms are named: 'linux-x64', 'windows-x64',
    'windows-arm64', 'macos-x64', 'macos-arm64' (other systems: their own names)."""
    machine = platform.machine()
    return "%s-%s" % (_system(), _MACHINES.get(machine.lower(), machine.lower() or "unknown"))


def _platform_name(tag):
    system, _, machine = tag.partition("-")
    return "%s %s" % (_SYSTEM_NAMES.get(system, system), machine)


def library_name():
    """The library's file name on this system."""
    for prefix, name in LIBRARY_NAMES.items():
        if sys.platform.startswith(prefix):
            return name
    return LIBRARY_NAMES["linux"]


def glibc_version():
    """(major, minor) of this system's GNU C library, or None (not glibc)."""
    try:
        text = os.confstr("CS_GNU_LIBC_VERSION")  # "glibc 2.36"
    except (AttributeError, ValueError, OSError):
        return None
    match = re.search(r"(\d+)\.(\d+)", text or "")
    return (int(match.group(1)), int(match.group(2))) if match else None


def _package_dir():
    return os.path.dirname(os.path.abspath(__file__))


def _manifest(folder):
    """The Blender add-on's blender_manifest.toml in `folder` or, where this
    package is bundled inside the add-on, its parent; None outside one."""
    for path in (os.path.join(folder, "blender_manifest.toml"),
                 os.path.join(os.path.dirname(folder), "blender_manifest.toml")):
        if os.path.isfile(path):
            return path
    return None


def package_info(folder=None):
    """(version, platforms) of the Blender package this binding is part of,
    from its blender_manifest.toml (None, () outside one: installed with pip,
    or the extension's wheel)."""
    path = _manifest(folder or _package_dir())
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except (OSError, TypeError):
        return None, ()
    version = re.search(r'^version\s*=\s*"([^"]*)"', text, re.M)
    platforms = re.search(r"^platforms\s*=\s*\[([^\]]*)\]", text, re.M)
    return (version.group(1) if version else None,
            tuple(re.findall(r'"([^"]+)"', platforms.group(1))) if platforms else ())


def _library_candidates():
    env = os.environ.get("SUBDIV_PIA_LIBRARY")
    if env:  # named explicitly: that one or none
        yield env
        return
    yield os.path.join(_package_dir(), library_name())


def explain_load_failure(errors, folder=None, tag=None, glibc=None):
    """What the user needs, in a few lines, for a library that did not load.

    errors: [(path, loader's message or None when the file is missing)].
    The first line says what is needed (the package for this platform, a
    newer glibc, a missing library); the lines after it give the details.
    """
    folder = folder or _package_dir()
    tag = tag or platform_tag()
    version, platforms = package_info(folder)
    if _manifest(folder):  # inside the add-on: Blender 4.2 and newer take the extension
        app = getattr(sys.modules.get("bpy"), "app", None)
        extension = app is not None and tuple(app.version) >= (4, 2, 0)
        package = "subdiv_pia-%s-%s%s.zip" % (version or "<version>", "" if extension else "legacy-",
                                              tag.replace("-", "_"))
    else:  # pip's wheel (or the extension's, which Blender installed from it)
        package = "the subdiv_pia wheel for %s" % _platform_name(tag)
    here = _platform_name(tag)
    details = ["%s: %s" % (path, message or "not found") for path, message in errors]
    texts = " ".join(message for _, message in errors if message)
    present = sorted(name for name in LIBRARY_NAMES.values() if os.path.exists(os.path.join(folder, name)))

    needed = re.findall(r"GLIBC_(\d+)\.(\d+)", texts)
    missing = re.findall(r"([\w.+-]+\.so[\w.]*): cannot open shared object file", texts)
    missing = sorted(set(m for m in missing if not m.startswith(("libsubdiv_pia", "subdiv_pia"))))
    if needed:
        need = max((int(a), int(b)) for a, b in needed)
        have = glibc_version() if glibc is None else glibc
        head = "The native library needs glibc %d.%d or newer; this system has %s" % (
            need + ("glibc %d.%d" % have if have else "an older one",))
    elif missing:
        head = "The native library needs %s, which this system lacks" % ", ".join(missing)
    elif os.environ.get("SUBDIV_PIA_LIBRARY"):
        head = ("The library that SUBDIV_PIA_LIBRARY names is %s"
                % ("missing" if not texts else "not a library for this system (%s)" % here))
    elif platforms and tag not in platforms:
        head = ("This package is for %s; this system is %s: install %s"
                % (" and ".join(_platform_name(p) for p in platforms), here, package))
    elif not texts and present:
        head = ("This package has the native library for another system (%s); this system is %s: "
                "install %s" % (", ".join(present), here, package))
    elif not texts:
        head = ("The native library (%s) is missing from the package: install %s again"
                % (library_name(), package))
    elif re.search(r"wrong ELF class|invalid ELF header|not a valid Win32|mach-o|"
                   r"incompatible architecture|file too short", texts, re.I):
        head = "The native library is not built for this system (%s): install %s" % (here, package)
    else:
        head = "The native library could not be loaded"
    return "\n".join([head] + details)


def _library():
    global _lib, _lib_path, _load_error
    if _lib is not None:
        return _lib
    errors = []
    for path in _library_candidates():
        if not os.path.exists(path):
            errors.append((path, None))
            continue
        try:
            lib = ctypes.CDLL(path)
            _declare(lib)
        except (OSError, AttributeError) as exc:
            errors.append((path, str(exc)))
            continue
        _lib, _lib_path, _load_error = lib, os.path.abspath(path), None
        return lib
    _load_error = explain_load_failure(errors)
    raise PiaError("LIBRARY", _load_error)


def available():
    """True when the native library can be loaded."""
    try:
        _library()
        return True
    except PiaError:
        return False


def load_error():
    """Why the native library could not be loaded, or None: a first line that
    says what is needed, then one line per file tried."""
    available()
    return _load_error


def library_path():
    """The file the native library was loaded from, or None."""
    available()
    return _lib_path


def available_memory():
    """Bytes of memory the machine can give the library now (the default
    ``memory_budget`` of every call), or None where it cannot be told."""
    value = int(_library().spia_available_memory())
    return value if value >= 0 else None


def version():
    """The library's version as a string, e.g. '0.1.0'."""
    v = _library().spia_version()
    return f"{v // 10000}.{v // 100 % 100}.{v % 100}"
