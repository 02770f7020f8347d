# SPDX-License-Identifier: GPL-3.0-or-later
"""The numpy binding to the native library, as the add-on's modules name it
(``from . import native``): the ``spia`` package.

Where it comes from depends on how the add-on was installed:
- the legacy add-on (Blender 3.4 to 4.1) and the development build carry it
  in this folder, as ``spia/`` with the library inside;
- an extension (Blender 4.2 and newer) carries the ``subdiv_pia`` wheel for
  its platform, which Blender's installer puts on ``sys.path``: ``import spia``.

This module then *is* that package (``sys.modules`` holds it under this
name too), so ``subdiv_pia.native.interpolate`` and ``spia.interpolate``
are one function.  It imports no ``bpy``.
"""
import importlib
import importlib.util
import sys


def _binding():
    bundled = __name__.rpartition(".")[0] + ".spia"
    if importlib.util.find_spec(bundled) is not None:
        return importlib.import_module(bundled)
    try:
        return importlib.import_module("spia")
    except ImportError as exc:
        raise ImportError(
            "subdiv_pia needs its native library's package `spia`, which is neither in the add-on's folder "
            "nor installed: install the extension again from its zip for this platform (Blender installs "
            "the wheel inside it), or, outside Blender, `pip install subdiv_pia` (%s)" % exc) from exc


sys.modules[__name__] = _binding()
