# SPDX-License-Identifier: GPL-3.0-or-later
"""The version is written in the manifest and repeated in bl_info, the CMake
project and the C header: they, and the built library, must agree (the
package's file name comes from the manifest)."""
import ast
import os
import re

from subdiv_pia import native

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def read(*parts):
    with open(os.path.join(ROOT, *parts)) as f:
        return f.read()


def test_every_place_that_names_the_version_agrees():
    manifest = re.search(r'^version\s*=\s*"([^"]+)"', read("addon", "blender_manifest.toml"), re.M).group(1)
    tree = ast.parse(read("addon", "__init__.py"))
    bl_info = next(ast.literal_eval(node.value) for node in tree.body
                   if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "bl_info")
    cmake = re.search(r"project\(subdiv_pia VERSION ([0-9.]+)", read("CMakeLists.txt")).group(1)
    header = read("csrc", "include", "subdiv_pia.h")
    macros = [re.search(r"#define SPIA_VERSION_%s (\d+)" % part, header).group(1)
              for part in ("MAJOR", "MINOR", "PATCH")]
    assert ".".join(map(str, bl_info["version"])) == manifest
    assert cmake == manifest
    assert ".".join(macros) == manifest
    assert native.version() == manifest
