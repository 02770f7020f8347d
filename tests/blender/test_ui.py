# SPDX-License-Identifier: GPL-3.0-or-later
"""Panel and menu drawing (through a recording layout: background mode has no
UI to draw into), and progress/cancel through the script API."""

import bpy
import pytest

import shapes
from layout import Recorder
import subdiv_pia
from subdiv_pia import native, ui


def draw_panel():
    layout = Recorder()
    panel = type("Panel", (), {"layout": layout})()
    assert ui.DATA_PT_subdiv_pia.poll(bpy.context)
    ui.DATA_PT_subdiv_pia.draw(panel, bpy.context)
    return layout.log


def test_panel_shows_settings_button_and_last_result():
    shapes.open_grid()
    assert ("operator", "object.subdiv_pia_interpolate") in draw_panel()
    assert bpy.ops.object.subdiv_pia_interpolate() == {'FINISHED'}
    log = draw_panel()
    for name in ("levels", "quality", "boundary_smooth", "use_creases", "method", "tolerance"):
        assert ("prop", name) in log
    labels = [text for kind, text in log if kind == "label"]
    assert any(text.startswith("Status: CONVERGED") for text in labels), labels
    assert any(text.startswith("Max error:") for text in labels)


def test_panel_without_library_shows_why(monkeypatch):
    shapes.open_grid()
    monkeypatch.setattr(native, "available", lambda: False)
    monkeypatch.setattr(native, "load_error", lambda: "libsubdiv_pia.so: not found")
    log = draw_panel()
    assert ("label", "libsubdiv_pia.so: not found") in log
    assert ("operator", "object.subdiv_pia_interpolate") not in log


def test_panel_hidden_for_non_mesh():
    shapes.link_and_activate(bpy.data.objects.new("Empty", None))
    assert not ui.DATA_PT_subdiv_pia.poll(bpy.context)


def test_object_menu_entry():
    layout = Recorder()
    ui.menu_func(type("Menu", (), {"layout": layout})(), bpy.context)
    assert layout.log == [("operator", "object.subdiv_pia_interpolate")]


def test_progress_reported_and_cancel_creates_nothing():
    source = shapes.open_grid()
    calls = []
    subdiv_pia.interpolate(source, method='PIA', progress=lambda i, e: calls.append((i, e)) and False)
    assert calls and calls[0][0] >= 0
    assert [i for i, _ in calls] == sorted(i for i, _ in calls)
    count = len(bpy.data.objects), len(bpy.data.meshes)
    with pytest.raises(native.PiaCancelled):
        subdiv_pia.interpolate(source, method='PIA', progress=lambda i, e: True)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == count
