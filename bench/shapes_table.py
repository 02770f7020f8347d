# SPDX-License-Identifier: GPL-3.0-or-later
"""OpenSubdiv's Catmull-Clark regression shapes in one Blender, as a table:
shape, setting, status, the solver that gave the cage, how many vertices
no cage can reach, and the worst miss of the others, as Blender's own
modifier shows them (relative to the bounding-box diagonal).

    /usr/bin/python3 bench/shapes_table.py [BLENDER COMMAND...]

runs tests/blender/test_shapes.py (the add-on of build/addon, or of the
zip in SUBDIV_PIA_PACKAGE) in the Blender given (default: `blender`; a bpy
venv's python works too) and prints the table in Markdown.
"""
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(argv):
    command = argv or ["blender"]
    if os.path.basename(command[0]).startswith("blender"):
        command = command + ["-b", "--factory-startup", "--python-exit-code", "1", "--python"]
    with tempfile.TemporaryDirectory() as tmp:
        table = os.path.join(tmp, "shapes.tsv")
        env = dict(os.environ, SUBDIV_PIA_SHAPES_TABLE=table)
        env.setdefault("SUBDIV_PIA_ADDON_DIR", os.path.join(ROOT, "build", "addon"))
        status = subprocess.call(command + [os.path.join(ROOT, "tests", "blender", "run.py"), "--", "-q",
                                            os.path.join(ROOT, "tests", "blender", "test_shapes.py")],
                                 env=env, cwd=ROOT)
        rows = [line.rstrip("\n").split("\t") for line in open(table)] if os.path.exists(table) else []
    if rows:
        print("\n%s\n" % rows[0][0])
        print("| shape | boundary | quality | creases | status | solver | unreachable | worst miss of the others |")
        print("|---|---|---:|---|---|---|---:|---:|")
        for row in rows:
            print("| %s |" % " | ".join(row[1:]))
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
