# SPDX-License-Identifier: GPL-3.0-or-later
"""Plain-Python tests of the binding: the built add-on package is imported
from build/addon (or SUBDIV_PIA_ADDON_DIR) without Blender."""
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.join(ROOT, "tests", "data")
ADDON_DIR = os.path.join(ROOT, os.environ.get("SUBDIV_PIA_ADDON_DIR", os.path.join("build", "addon")))
sys.path.insert(0, ADDON_DIR)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from meshio import read_obj  # noqa: E402

MESHES = sorted(f[:-4] for f in os.listdir(DATA) if f.endswith(".obj"))


@pytest.fixture(scope="session")
def native():
    from subdiv_pia import native as module
    assert module.available(), module.load_error()
    return module


def load(name):
    return read_obj(os.path.join(DATA, name + ".obj"))
