# SPDX-License-Identifier: GPL-3.0-or-later
"""Builds the native library with CMake and assembles the Blender add-on.

    python3 setup.py build     ->  build/addon/subdiv_pia/ with spia/ inside (for development: the library links
                                   OpenSubdiv 3.6.0 built from the same source package as the
                                   shipped one, so it computes what the package computes)
    python3 setup.py package   ->  dist/subdiv_pia-<version>-linux-x64.zip and dist/repo/
                                   (the self-contained package: tools/package.py)

Only the standard library is used, so this runs with Blender's Python as
well as the system one.
"""
import os
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.abspath(__file__))
BUILD = os.path.join(ROOT, "build")
CMAKE_BUILD = os.path.join(BUILD, "cmake")
ADDON_OUT = os.path.join(BUILD, "addon", "subdiv_pia")
DIST = os.path.join(ROOT, "dist")
LIBRARY = {"win32": "subdiv_pia.dll", "darwin": "libsubdiv_pia.dylib"}.get(sys.platform, "libsubdiv_pia.so")


def run(cmd):
    print("+", " ".join(cmd), flush=True)
    subprocess.check_call(cmd, cwd=ROOT)


def build_library(build_type="Release"):
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    import package  # noqa: E402  (tools/package.py: OpenSubdiv from its source package)
    run(["cmake", "-S", ROOT, "-B", CMAKE_BUILD, f"-DCMAKE_BUILD_TYPE={build_type}"] +
        package.opensubdiv_cmake_args(sys.stdout))
    run(["cmake", "--build", CMAKE_BUILD, "--parallel", str(os.cpu_count() or 2)])
    return os.path.join(CMAKE_BUILD, LIBRARY)


def assemble(library):
    if os.path.isdir(ADDON_OUT):
        shutil.rmtree(ADDON_OUT)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.dll", "*.dylib")
    shutil.copytree(os.path.join(ROOT, "addon"), ADDON_OUT, ignore=ignore)
    # The numpy binding (python/spia) inside the add-on, the library inside it,
    # as the legacy package carries them.
    shutil.copytree(os.path.join(ROOT, "python", "spia"), os.path.join(ADDON_OUT, "spia"), ignore=ignore)
    shutil.copy2(library, os.path.join(ADDON_OUT, "spia", LIBRARY))
    print(f"add-on: {ADDON_OUT}")


def main(argv):
    command = argv[1] if len(argv) > 1 else "build"
    if command == "build":
        assemble(build_library())
    elif command == "package":
        sys.exit(subprocess.call([sys.executable, os.path.join(ROOT, "tools", "package.py"), "linux"]))
    elif command == "clean":
        for path in (BUILD, DIST):
            shutil.rmtree(path, ignore_errors=True)
    else:
        sys.exit(f"usage: {argv[0]} [build|package|clean]")


if __name__ == "__main__":
    main(sys.argv)
