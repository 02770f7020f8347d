# SPDX-License-Identifier: GPL-3.0-or-later
"""Run by test_no_library.py in a Blender whose SUBDIV_PIA_LIBRARY names a
missing or bogus file:

    blender -b --factory-startup --python no_library.py -- ADDON_FOLDER
    python no_library.py -- ADDON_FOLDER                  (the bpy module)

Loads the add-on in ADDON_FOLDER through its cli.py, draws the panel into a
recording layout, runs the operator and the script API on a grid, and
prints one JSON line (prefix RESULT) with what happened.
"""

import importlib.util
import json
import os
import sys

import bpy

folder = sys.argv[sys.argv.index("--") + 1]
spec = importlib.util.spec_from_file_location("subdiv_pia_cli_check", os.path.join(folder, "cli.py"))
cli = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cli)
package = cli._import_package()
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from layout import Recorder  # noqa: E402

bpy.ops.wm.read_factory_settings(use_empty=True)
package = cli._import_package()
bpy.ops.mesh.primitive_grid_add(x_subdivisions=4, y_subdivisions=4)
source = bpy.context.active_object
counts = [len(bpy.data.objects), len(bpy.data.meshes)]

log = []
panel = type("Panel", (), {"layout": Recorder(log)})()
package.ui.DATA_PT_subdiv_pia.draw(panel, bpy.context)

try:
    operator = sorted(bpy.ops.object.subdiv_pia_interpolate())
    operator_error = None
except RuntimeError as error:  # the operator's ERROR report
    operator, operator_error = None, str(error)

try:
    package.interpolate(source)
    api_error = None
except RuntimeError as error:
    api_error = str(error)

print("RESULT " + json.dumps({
    "package": os.path.dirname(os.path.abspath(package.__file__)),
    "available": package.native.available(),
    "load_error": package.native.load_error(),
    "log": log,
    "operator": operator,
    "operator_error": operator_error,
    "api_error": api_error,
    "counts_before": counts,
    "counts_after": [len(bpy.data.objects), len(bpy.data.meshes)],
    "active": bpy.context.view_layer.objects.active.name,
    "source": source.name,
}), flush=True)
cli.finish(0)
