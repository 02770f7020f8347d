"""Builds the native library with CMake and assembles the Blender add-on.

    python3 setup.py build     ->  build/addon/subdiv_pia/  (add-on with the library inside)
                                   dist/subdiv_pia.zip       (installable from Blender's Preferences)

Only the standard library is used, so this runs with Blender's Python as
well as the system one.
"""
import os
import shutil
import subprocess
import sys
import zipfile

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
    run(["cmake", "-S", ROOT, "-B", CMAKE_BUILD, f"-DCMAKE_BUILD_TYPE={build_type}"])
    run(["cmake", "--build", CMAKE_BUILD, "--parallel", str(os.cpu_count() or 2)])
    return os.path.join(CMAKE_BUILD, LIBRARY)


def assemble(library):
    if os.path.isdir(ADDON_OUT):
        shutil.rmtree(ADDON_OUT)
    shutil.copytree(os.path.join(ROOT, "addon"), ADDON_OUT,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.dll", "*.dylib"))
    shutil.copy2(library, os.path.join(ADDON_OUT, LIBRARY))
    os.makedirs(DIST, exist_ok=True)
    archive = os.path.join(DIST, "subdiv_pia.zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        for folder, _dirs, files in os.walk(ADDON_OUT):
            for name in sorted(files):
                path = os.path.join(folder, name)
                zf.write(path, os.path.relpath(path, os.path.dirname(ADDON_OUT)))
    print(f"add-on: {ADDON_OUT}\narchive: {archive}")


def main(argv):
    command = argv[1] if len(argv) > 1 else "build"
    if command == "build":
        assemble(build_library())
    elif command == "clean":
        for path in (BUILD, DIST):
            shutil.rmtree(path, ignore_errors=True)
    else:
        sys.exit(f"usage: {argv[0]} [build|clean]")


if __name__ == "__main__":
    main(sys.argv)
