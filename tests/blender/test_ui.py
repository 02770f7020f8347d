# SPDX-License-Identifier: GPL-3.0-or-later
"""Panel, presets and menu drawing (through a recording layout: background
mode has no UI to draw into), and progress/cancel through the script API.
tests/window/panel.py draws the same cases in Blender's window."""

import os

import bpy
import pytest

import panel_cases
import shapes
from layout import Recorder, fake_panel
import subdiv_pia
from subdiv_pia import native, preset_menu, ui
from subdiv_pia.properties import PRESET_NAMES


def subpanels():
    return [cls for cls in ui.classes if getattr(cls, "bl_parent_id", "") == ui.DATA_PT_subdiv_pia.__name__]


def shown_subpanels():
    return [cls for cls in subpanels() if cls.poll(bpy.context)]


def draw_panel():
    """The panel and every sub-panel it shows, as if all were opened: the log."""
    layout = Recorder()
    assert ui.DATA_PT_subdiv_pia.poll(bpy.context)
    ui.DATA_PT_subdiv_pia.draw(fake_panel(layout), bpy.context)
    for cls in shown_subpanels():
        if hasattr(cls, "draw_header"):
            cls.draw_header(fake_panel(layout), bpy.context)
        cls.draw(fake_panel(layout), bpy.context)
    return layout.log


def by_default():
    """What an artist sees before opening a sub-panel: the header's and the
    body's recorder, and the labels of the (closed) sub-panels shown."""
    layout = Recorder()
    assert ui.DATA_PT_subdiv_pia.poll(bpy.context)
    ui.DATA_PT_subdiv_pia.draw_header_preset(fake_panel(layout), bpy.context)
    ui.DATA_PT_subdiv_pia.draw(fake_panel(layout), bpy.context)
    return layout, [cls.bl_label for cls in shown_subpanels()]


@pytest.mark.parametrize("case", panel_cases.CASES, ids=[c.name for c in panel_cases.CASES])
def test_panel_shows_what_applies_at_the_top(case):
    panel_cases.clear()
    case.setup()
    layout, shown = by_default()
    labels = [text for kind, text in layout.log if kind == "label"]
    assert panel_cases.check(case, layout.controls, shown, labels, layout.icons) == []


def test_the_check_fails_when_a_control_comes_back_to_the_top():
    case = panel_cases.CASES[0]
    panel_cases.clear()
    case.setup()
    layout, shown = by_default()
    layout.prop(bpy.context.scene.subdiv_pia, "method")
    labels = [text for kind, text in layout.log if kind == "label"]
    problems = panel_cases.check(case, layout.controls, shown, labels, layout.icons)
    assert problems and "method" in problems[0]


def test_subpanels_are_closed_by_default_and_follow_blenders_conventions():
    assert 'DEFAULT_CLOSED' in ui.DATA_PT_subdiv_pia.bl_options
    labels = [cls.bl_label for cls in subpanels()]
    assert labels == ["Subdivision", "Loop", "Doo-Sabin", "Solver", "Scan Fit", "Cleanup", "Last Result"]
    for cls in subpanels():
        assert cls.bl_options == {'DEFAULT_CLOSED'}, cls
        assert (cls.bl_space_type, cls.bl_region_type, cls.bl_context) == ('PROPERTIES', 'WINDOW', "modifier")


def test_modifier_settings_replace_the_levels_with_one_line():
    shapes.open_grid()
    modifier = bpy.context.active_object.modifiers.new("Subdivision", 'SUBSURF')
    modifier.levels, modifier.render_levels, modifier.quality = 2, 3, 4
    log = draw_panel()
    assert ("label", "Levels 2, Render 3, Quality 4, from 'Subdivision'") in log
    for name in ("levels", "render_levels", "quality", "boundary_smooth", "use_creases"):
        assert ("prop", name) not in log, name
    bpy.context.scene.subdiv_pia.use_modifier_settings = False
    log = draw_panel()
    for name in ("levels", "render_levels", "quality", "boundary_smooth", "use_creases"):
        assert ("prop", name) in log, name


def test_each_scheme_shows_only_its_settings():
    shapes.cube()
    settings = bpy.context.scene.subdiv_pia
    only = {'CATMULL_CLARK': {"render_levels", "quality"},
            'LOOP': {"boundary_rule", "triangulate", "staged"},
            'DOO_SABIN': {"shape_parameter", "shape_attribute"}}
    for scheme, own in only.items():
        settings.scheme = scheme
        drawn = {name for kind, name in draw_panel() if kind == "prop"}
        for other, names in only.items():
            assert (names <= drawn) == (other == scheme), (scheme, other, drawn)
    # Doo-Sabin has no boundary smoothing nor creases; Hoppe's Loop rules no Boundary Smooth.
    settings.scheme = 'DOO_SABIN'
    assert {"boundary_smooth", "use_creases"}.isdisjoint({n for k, n in draw_panel() if k == "prop"})
    settings.scheme, settings.boundary_rule = 'LOOP', 'HOPPE'
    drawn = {n for k, n in draw_panel() if k == "prop"}
    assert "boundary_smooth" not in drawn and "use_creases" in drawn


def test_scan_fit_settings_only_with_a_target_and_as_the_mode_needs():
    panel_cases.clear()
    shapes.cube()
    surface_only = {"fit_smoothing", "fit_samples", "fit_detail_levels"}
    drawn = {n for k, n in draw_panel() if k == "prop"}
    assert drawn.isdisjoint(surface_only | {"fit", "fit_cutoff", "fit_paint_scan"})
    panel_cases.scan_target()
    drawn = {n for k, n in draw_panel() if k == "prop"}
    assert surface_only | {"fit", "fit_cutoff", "fit_paint_scan"} <= drawn
    bpy.context.scene.subdiv_pia.fit = 'VERTICES'
    drawn = {n for k, n in draw_panel() if k == "prop"}
    assert drawn.isdisjoint(surface_only) and {"fit", "fit_cutoff", "fit_paint_scan"} <= drawn


def test_button_says_what_it_will_do():
    from subdiv_pia import sections
    settings = bpy.context.scene.subdiv_pia
    assert sections.action_label(settings, "") == "Make Interpolating Cage"
    assert sections.action_label(settings, "Scan") == "Fit Cage to 'Scan'"
    settings.fit_detail_levels = 3
    assert sections.action_label(settings, "Scan") == "Fit Cage to 'Scan', 3 Detail Levels"
    settings.fit = 'VERTICES'
    assert sections.action_label(settings, "Scan") == "Fit Cage Vertices to 'Scan'"


def test_panel_shows_settings_button_and_last_result():
    shapes.open_grid()
    log = draw_panel()
    for name in ("levels", "quality", "boundary_smooth", "use_creases", "method", "tolerance"):
        assert ("prop", name) in log
    assert bpy.ops.object.subdiv_pia_interpolate() == {'FINISHED'}
    log = draw_panel()  # the new cage's own modifier gives its settings
    assert ("operator", "object.subdiv_pia_interpolate") in log and ("prop", "method") in log
    labels = [text for kind, text in log if kind == "label"]
    assert any(text.startswith("Status: CONVERGED") for text in labels), labels
    assert any(text.startswith("Max error:") for text in labels)
    layout, _shown = by_default()
    status = [text for text, icon in layout.icons.items() if icon == 'CHECKMARK']
    assert len(status) == 1 and status[0].startswith("Converged in "), layout.icons


def test_result_line_says_what_went_wrong():
    source = shapes.open_grid()
    # a cage that stopped short of the tolerance: its line says so
    assert bpy.ops.object.subdiv_pia_interpolate(max_iterations=1, method='PIA', tolerance=1e-12) == {'FINISHED'}
    assert bpy.context.active_object is not source
    layout, _shown = by_default()
    errors = [text for text, icon in layout.icons.items() if icon == 'ERROR']
    assert len(errors) == 1 and "tolerance not reached" in errors[0], layout.icons
    # a run that made nothing: why, on the object it ran on, until a run on it succeeds
    bpy.context.view_layer.objects.active = source
    with pytest.raises(RuntimeError, match="closed mesh"):
        bpy.ops.object.subdiv_pia_interpolate(scheme='DOO_SABIN')
    layout, _shown = by_default()
    errors = [text for text, icon in layout.icons.items() if icon == 'ERROR']
    assert len(errors) == 1 and "closed mesh" in errors[0], layout.icons
    assert bpy.ops.object.subdiv_pia_interpolate(scheme='CATMULL_CLARK') == {'FINISHED'}
    bpy.context.view_layer.objects.active = source
    layout, _shown = by_default()
    assert 'ERROR' not in layout.icons.values(), layout.icons


def test_panel_without_library_shows_why(monkeypatch):
    shapes.open_grid()
    monkeypatch.setattr(native, "available", lambda: False)
    monkeypatch.setattr(native, "load_error", lambda: "libsubdiv_pia.so: not found")
    log = draw_panel()
    assert ("label", "libsubdiv_pia.so: not found") in log
    assert ("operator", "object.subdiv_pia_interpolate") not in log
    assert shown_subpanels() == []


def test_panel_hidden_for_non_mesh():
    shapes.link_and_activate(bpy.data.objects.new("Empty", None))
    assert not ui.DATA_PT_subdiv_pia.poll(bpy.context)
    assert shown_subpanels() == []


def test_object_menu_entry_takes_the_panels_action():
    layout = Recorder()
    shapes.open_grid()
    ui.menu_func(fake_panel(layout), bpy.context)
    assert layout.controls == [("operator", "object.subdiv_pia_interpolate", "Make Interpolating Cage")]
    panel_cases.clear()
    panel_cases.scan_target()
    layout = Recorder()
    ui.menu_func(fake_panel(layout), bpy.context)
    assert layout.controls == [("operator", "object.subdiv_pia_interpolate", "Fit Cage to 'Scan'")]


def redo_panel_props(**settings):
    """The properties and labels the operator's redo panel draws for these settings."""
    from subdiv_pia.operators import OBJECT_OT_subdiv_pia_interpolate as Operator
    from subdiv_pia.properties import SETTING_NAMES
    layout = Recorder()
    rna = bpy.ops.object.subdiv_pia_interpolate.get_rna_type().properties
    values = {name: getattr(rna[name], "default", "") for name in SETTING_NAMES + ("live",)}
    values.update(settings, layout=layout)
    Operator.draw(type("Redo", (), values)(), bpy.context)
    return [name for kind, name in layout.log if kind == "prop"], [t for k, t in layout.log if k == "label"]


def test_redo_panel_follows_the_panels_grouping():
    shapes.cube()
    props, labels = redo_panel_props()
    assert props[:5] == ["scheme", "levels", "render_levels", "target", "live"], props
    assert [label for label in labels if label] == ["Subdivision", "Solver", "Cleanup"]
    assert "shape_parameter" not in props and "fit_cutoff" not in props
    props, labels = redo_panel_props(scheme='DOO_SABIN', target="Scan", fit='VERTICES')
    assert [label for label in labels if label] == ["Doo-Sabin", "Solver", "Scan Fit", "Cleanup"]
    assert "shape_parameter" in props and "fit_cutoff" in props and "quality" not in props


def registered_properties():
    """{owner: RNA properties} of every property group and operator the add-on registers."""
    from subdiv_pia import operators
    owners = {"scene.subdiv_pia": bpy.context.scene.subdiv_pia.bl_rna.properties}
    for cls in operators.classes + preset_menu.classes:
        if issubclass(cls, bpy.types.Operator):
            category, name = cls.bl_idname.split(".")
            owners[cls.bl_idname] = getattr(getattr(bpy.ops, category), name).get_rna_type().properties
    return owners


def test_every_registered_property_says_what_it_does():
    owners = registered_properties()
    assert {"scene.subdiv_pia", "object.subdiv_pia_interpolate", "object.subdiv_pia_live",
            "object.subdiv_pia_refresh_limit", "object.subdiv_pia_preset_add"} <= set(owners), owners
    missing, checked = [], 0
    for owner, properties in owners.items():
        for prop in properties:
            if prop.identifier == "rna_type" or prop.is_hidden:
                continue
            checked += 1
            if len(prop.description.strip()) < 20:
                missing.append("%s.%s: %r" % (owner, prop.identifier, prop.description))
    assert checked >= 50
    assert missing == []


def test_settings_measured_in_a_unit_name_it():
    # The settings measured against the mesh's or the scan's size say so.
    rna = bpy.context.scene.subdiv_pia.bl_rna.properties
    for name in ("tolerance", "cleanup_distance", "fit_cutoff"):
        assert "diagonal" in rna[name].description, name
    for name in ("levels", "render_levels"):
        assert "steps" in rna[name].description, name
    assert "iterations" in rna["max_iterations"].description
    assert "no unit" in rna["fit_smoothing"].description and "no unit" in rna["shape_parameter"].description


# --- presets ----------------------------------------------------------------------

def apply_preset(path):
    assert bpy.ops.script.execute_preset(filepath=path, menu_idname=preset_menu.SUBDIV_PIA_PT_presets.__name__) \
        == {'FINISHED'}


def preset_values(path):
    """name: value of every `settings.name = value` line of a preset file."""
    values = {}
    for line in open(path, encoding="utf-8"):
        for prefix in ("settings.", preset_menu.SETTINGS_PATH + "."):
            if line.startswith(prefix) and "=" in line:
                name, value = line[len(prefix):].split("=", 1)
                values[name.strip()] = eval(value.strip())
    return values


def test_the_four_builtin_presets_exist_and_apply():
    files = preset_menu.builtin_preset_files()
    assert [os.path.basename(f) for f in files] == [
        "Fit_Cage_to_Scan.py", "Fit_with_3_Detail_Levels.py", "Interpolate_for_Display.py",
        "Interpolate_for_Render.py"]
    panel_cases.clear()
    scan = panel_cases.fine_sphere("Scan", segments=16, rings=8)
    settings = bpy.context.scene.subdiv_pia
    defaults = {name: getattr(settings, name) for name in PRESET_NAMES}
    for path in files:
        values = preset_values(path)
        assert values and set(values) <= set(PRESET_NAMES), path
        # whatever was set before: what the preset names, the rest at its default
        settings.method, settings.max_iterations, settings.fit_smoothing = 'CG', 7, 0.5
        settings.target_object = scan
        apply_preset(path)
        for name in PRESET_NAMES:
            want = values.get(name, defaults[name])
            got = getattr(settings, name)
            assert got == pytest.approx(want) if isinstance(want, float) else got == want, (path, name, got)
        assert settings.target_object == scan, "a preset keeps the target"
    settings.fit_detail_levels = 0
    apply_preset(files[1])
    assert settings.fit_detail_levels == 3 and settings.fit == 'SURFACE'


def test_the_preset_menu_lists_builtins_and_the_users_own(tmp_path, monkeypatch):
    # The user's preset folder, here a temporary one: where AddPresetBase writes and Blender looks.
    folder = tmp_path / "presets" / preset_menu.PRESET_SUBDIR

    def user_resource(kind, path="", create=False):
        target = tmp_path / path
        if create:
            target.mkdir(parents=True, exist_ok=True)
        return str(target)
    monkeypatch.setattr(bpy.utils, "user_resource", user_resource)
    monkeypatch.setattr(bpy.utils, "preset_paths",
                        lambda subdir: [str(folder)] if subdir == preset_menu.PRESET_SUBDIR and folder.is_dir()
                        else [])

    def menu():
        layout = Recorder()
        panel = type("Presets", (), dict(layout=layout, bl_idname="SUBDIV_PIA_PT_presets",
                                         path_menu=bpy.types.Menu.path_menu,
                                         **{k: v for k, v in vars(preset_menu.SUBDIV_PIA_PT_presets).items()
                                            if k.startswith("preset_") or k == "is_preset"}))()
        preset_menu.SUBDIV_PIA_PT_presets.draw(panel, bpy.context)
        return layout.controls

    controls = menu()
    builtins = [text for kind, name, text in controls if name == "script.execute_preset"]
    assert builtins == ["Fit Cage to Scan", "Fit with 3 Detail Levels", "Interpolate for Display",
                        "Interpolate for Render"]
    assert [c for c in controls if c[1] == "object.subdiv_pia_preset_add"] == [
        ("operator", "object.subdiv_pia_preset_add", "")], "only the add button: no built-in can be removed"

    settings = bpy.context.scene.subdiv_pia
    settings.scheme, settings.tolerance, settings.levels = 'LOOP', 1e-3, 3
    assert bpy.ops.object.subdiv_pia_preset_add(name="My Loop") == {'FINISHED'}
    written = folder / "My_Loop.py"
    assert written.is_file()
    assert set(preset_values(str(written))) == set(PRESET_NAMES), "a preset of yours holds every setting"
    panel_cases.clear()
    apply_preset(str(written))
    assert (settings.scheme, settings.levels) == ('LOOP', 3) and settings.tolerance == pytest.approx(1e-3)
    controls = menu()
    assert [text for kind, name, text in controls if name == "script.execute_preset"][-1] == "My Loop"
    assert len([c for c in controls if c[1] == "object.subdiv_pia_preset_add"]) == 2  # its remove, and add
    assert bpy.ops.object.subdiv_pia_preset_add(name="My Loop", remove_name=True) == {'FINISHED'}
    assert not written.exists()


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
