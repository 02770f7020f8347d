# SPDX-License-Identifier: GPL-3.0-or-later
"""Command line: make an interpolating cage and save it to a .blend file.

    blender -b --python <add-on folder>/cli.py -- INPUT OUTPUT.blend [options]
    python <add-on folder>/cli.py -- INPUT OUTPUT.blend [options]   (Blender as the bpy module)

INPUT is .obj, .ply, .stl or .blend. Run with -- --help for the options.
Exit status 0 on success (also when the tolerance was not reached: the
report says so), 1 with the message on error.

The add-on folder may be anywhere: the build, an installed legacy add-on or
an installed extension. A copy of the package already loaded from this
folder (an enabled add-on or extension) is used as it is; otherwise the
package is imported from here and registered.
"""

import argparse
import importlib.util
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
if __name__ == "__main__" and sys.path and os.path.abspath(sys.path[0] or ".") == HERE:
    del sys.path[0]  # run by plain Python: the package's modules are not top-level modules

import bpy  # noqa: E402


def _same_file(a, b):
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _loaded_package():
    """The copy of this package already imported from this folder, or None."""
    init = os.path.join(HERE, "__init__.py")
    for module in list(sys.modules.values()):
        path = getattr(module, "__file__", None)
        if path and os.path.basename(path) == "__init__.py" and _same_file(path, init):
            return module
    return None


def _import_package():
    """The add-on package that contains this file: the copy already loaded
    (as an add-on or extension, or by an earlier call), else imported from
    this folder and registered, once."""
    package = _loaded_package()
    if package is None:
        name = os.path.basename(HERE)
        if name in sys.modules:  # another copy holds the name
            name = "_subdiv_pia_cli_" + name
        spec = importlib.util.spec_from_file_location(
            name, os.path.join(HERE, "__init__.py"), submodule_search_locations=[HERE])
        package = importlib.util.module_from_spec(spec)
        sys.modules[name] = package
        try:
            spec.loader.exec_module(package)
        except BaseException:
            del sys.modules[name]
            raise
    if getattr(bpy.types, "OBJECT_OT_subdiv_pia_interpolate", None) is None:
        package.register()
    return package


def finish(code=0):
    """End the script with exit status code. The bpy module is left at once:
    in Blender 4.2 and 4.3 it crashes on exit once an add-on's classes were
    registered (even after unregistering them), in 4.5 it never exits while
    they are registered."""
    sys.stdout.flush()
    sys.stderr.flush()
    if _is_module():
        os._exit(code)
    if code:
        sys.exit(code)


def pkg_methods():
    return _import_package().api.METHODS


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog="python cli.py --" if _is_module() else "blender -b --python cli.py --",
        description="Make a control cage whose subdivision limit surface passes through the "
                    "vertices of INPUT. Catmull-Clark (default): the limit surface of Blender's "
                    "Subdivision Surface modifier with Use Limit Surface; the cage is saved with "
                    "that modifier. Loop: the cage is saved without a modifier, with its limit "
                    "surface (refined --levels times) as a child object <cage>_limit. DOO_SABIN "
                    "(two-phase Doo-Sabin, closed meshes): likewise, the child holds the cage "
                    "refined --levels times.")
    parser.add_argument("--version", action="store_true",
                        help="print the version, the package's folder and its library, and exit")
    parser.add_argument("input", nargs="?" if "--version" in argv else None,
                        help="input mesh: .obj, .ply, .stl or .blend")
    parser.add_argument("output", nargs="?" if "--version" in argv else None, help="output .blend file")
    parser.add_argument("--object", help="object name to use from a .blend input "
                                         "(default: the active mesh object, else the first)")
    parser.add_argument("--scheme", choices=("CATMULL_CLARK", "LOOP", "DOO_SABIN"),
                        help="subdivision scheme (default CATMULL_CLARK; LOOP needs triangles; "
                             "DOO_SABIN needs a closed mesh)")
    parser.add_argument("--shape-parameter", type=float,
                        help="Doo-Sabin: shape parameter in (0, 1) of every face in the first "
                             "step (default 0.5; close to 1 hugs the mesh)")
    parser.add_argument("--shape-attribute",
                        help="Doo-Sabin: float face attribute whose per-face values replace "
                             "--shape-parameter where the mesh has it (default pia_shape)")
    parser.add_argument("--boundary-rule", choices=("SMOOTH", "HOPPE"),
                        help="Loop boundary rules: OpenSubdiv's (SMOOTH, default) or Hoppe et al. "
                             "1994 (HOPPE, manifold meshes only, ignores --boundary-smooth)")
    parser.add_argument("--triangulate", action="store_true",
                        help="Loop: split quads and n-gons into triangles (Beauty method) "
                             "instead of refusing the mesh")
    parser.add_argument("--staged", action="store_true",
                        help="Loop: solve the boundary first, then the interior (the open-mesh paper's way)")
    parser.add_argument("--levels", type=int, help="viewport levels of the modifier, or the Loop "
                                                   "limit surface's levels (default 2)")
    parser.add_argument("--render-levels", type=int, help="render levels (default: --levels)")
    parser.add_argument("--quality", type=int, help="modifier quality 1..10 (default 3)")
    parser.add_argument("--boundary-smooth", choices=("ALL", "PRESERVE_CORNERS"))
    parser.add_argument("--no-creases", action="store_true", help="ignore edge and vertex creases")
    parser.add_argument("--opensubdiv-version", metavar="X.Y.Z",
                        help="Catmull-Clark: make the cage for Blenders with this OpenSubdiv (5.1 and "
                             "later have 3.7.0, 4.1 to 5.0 have 3.6.0), which differ at some "
                             "non-manifold vertices (default: this Blender's, %s)"
                        % (".".join(map(str, bpy.app.opensubdiv.version))
                           if getattr(bpy.app, "opensubdiv", None) else "unknown"))
    parser.add_argument("--cleanup", action="store_true",
                        help="interpolate a cleaned copy of the mesh: merge close vertices, dissolve "
                             "repeated vertices in faces, remove zero-area faces and loose geometry, "
                             "turn the faces to one orientation (the cage gets the cleaned topology)")
    parser.add_argument("--cleanup-distance", type=float,
                        help="--cleanup: merge vertices closer than this, relative to the "
                             "bounding-box diagonal (default 1e-6)")
    parser.add_argument("--method", choices=pkg_methods())
    parser.add_argument("--tolerance", type=float,
                        help="max error relative to the bounding-box diagonal (default 1e-6)")
    parser.add_argument("--max-iterations", type=int, help="iteration limit (default 1000)")
    fit = parser.add_argument_group(
        "fitting to a scan",
        "With --target, the cage (INPUT) is fitted to the target's surface instead of "
        "interpolating its own vertices; distances are relative to the target's bounding-box "
        "diagonal, and the new object gets the attributes pia_distance and pia_distance_color.")
    fit.add_argument("--target", help="the scan: a mesh file (.obj, .ply, .stl) or the name of a "
                                      "mesh object in a .blend INPUT")
    fit.add_argument("--fit", choices=("SURFACE", "VERTICES"),
                     help="SURFACE (default; Catmull-Clark): the whole limit surface; VERTICES: "
                          "the limit points of the control vertices (any scheme)")
    fit.add_argument("--fit-cutoff", type=float,
                     help="samples farther than this from the scan do not pull (default 0.02)")
    fit.add_argument("--fit-smoothing", type=float, help="fairness weight (default 1e-5)")
    fit.add_argument("--fit-samples", type=int, help="samples per face edge (default 4)")
    fit.add_argument("--fit-detail-levels", type=int, metavar="LEVELS",
                     help="SURFACE: a Multires modifier with this many levels (1 to 6), each fitted "
                          "to the scan, the finest on it (default 0: none)")
    fit.add_argument("--fit-paint-scan", action="store_true",
                     help="also write each scan vertex's distance to the fitted surface onto the "
                          "target (attributes pia_scan_distance and pia_scan_distance_color), saved "
                          "with it in OUTPUT")
    return parser.parse_args(argv)


def _is_module():
    """Blender runs as the bpy Python module (no blender executable)."""
    return bool(getattr(bpy.app, "module", False)) or not bpy.app.binary_path


def operator_exists(module_name, op_name):
    """bpy.ops.<module>.<name> exists (hasattr on bpy.ops is always True)."""
    try:
        getattr(getattr(bpy.ops, module_name), op_name).get_rna_type()
        return True
    except (AttributeError, KeyError):
        return False


def load_input(path, object_name=None):
    """Load INPUT into the current (empty) scene and return the mesh object to use."""
    if not os.path.isfile(path):
        raise ValueError("Input file not found: %s" % path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".blend":
        bpy.ops.wm.open_mainfile(filepath=path)
        if object_name:
            obj = bpy.data.objects.get(object_name)
            if obj is None:
                raise ValueError("No object named %r in %s" % (object_name, path))
            return obj
        obj = bpy.context.view_layer.objects.active
        if obj is not None and obj.type == 'MESH':
            return obj
        meshes = [o for o in bpy.context.scene.objects if o.type == 'MESH']
        if not meshes:
            raise ValueError("No mesh object in %s" % path)
        return meshes[0]

    # An empty scene, the preferences kept: read_factory_settings would reset
    # them, and with them disable an extension that is not enabled there
    # (this one, run as a script) and have Blender remove its wheel.
    bpy.ops.wm.read_homefile(use_empty=True)
    return import_mesh_file(path, object_name)


# Importer options that would change the mesh: off where this Blender has
# them. Since 4.2 the OBJ and STL importers validate by default, which drops
# duplicate faces (scans have them) and so changes what is interpolated.
_AS_IS = {"use_split_objects": False, "use_split_groups": False,
          "validate_meshes": False, "use_mesh_validate": False}


def _options(module_name, op_name):
    known = getattr(getattr(bpy.ops, module_name), op_name).get_rna_type().properties.keys()
    return {k: v for k, v in _AS_IS.items() if k in known}


def _call_first(names, **kwargs):
    for module_name, op_name in names:
        if operator_exists(module_name, op_name):
            options = dict(_options(module_name, op_name), **kwargs)
            return getattr(getattr(bpy.ops, module_name), op_name)(**options)
    raise RuntimeError("No importer available (%s)" % ", ".join("%s.%s" % n for n in names))


def import_mesh_file(path, object_name=None):
    """Import a .obj, .ply or .stl file into the current scene, as the file has
    it (no validation, no splitting); return its mesh object."""
    if not os.path.isfile(path):
        raise ValueError("File not found: %s" % path)
    ext = os.path.splitext(path)[1].lower()
    before = set(bpy.data.objects)
    if ext == ".obj":
        if operator_exists("wm", "obj_import"):  # C++ importer (3.3+): keeps vertex order
            _call_first((("wm", "obj_import"),), filepath=path)
        else:
            bpy.ops.import_scene.obj(filepath=path, split_mode='OFF')
    elif ext == ".ply":
        _call_first((("wm", "ply_import"), ("import_mesh", "ply")), filepath=path)
    elif ext == ".stl":
        _call_first((("wm", "stl_import"), ("import_mesh", "stl")), filepath=path)
    else:
        raise ValueError("Unsupported mesh file type %r (use .obj, .ply or .stl; INPUT may also "
                         "be .blend)" % ext)
    new = [o for o in bpy.data.objects if o not in before and o.type == 'MESH']
    if object_name:
        new = [o for o in new if o.name == object_name]
    if not new:
        raise ValueError("No mesh object was imported from %s" % path)
    return sorted(new, key=lambda o: o.name)[0]


def main(argv):
    args = parse_args(argv)
    package = _import_package()
    if args.version:
        from_file = package.native.library_path() if package.native.available() else None
        version = package.native.package_info()[0] or ".".join(map(str, package.bl_info["version"]))
        print("subdiv_pia %s: %s" % (version, os.path.dirname(os.path.abspath(package.__file__))))
        print("subdiv_pia: library %s" % (from_file or package.native.load_error()))
        return
    obj = load_input(os.path.abspath(args.input), args.object)
    package = _import_package()  # a factory reset disables add-ons of the preferences
    settings = {}
    if args.levels is not None:
        settings["levels"] = args.levels
        settings["render_levels"] = args.levels
    if args.render_levels is not None:
        settings["render_levels"] = args.render_levels
    for name in ("scheme", "boundary_rule", "quality", "boundary_smooth", "method", "tolerance",
                 "max_iterations", "shape_parameter", "shape_attribute", "opensubdiv_version",
                 "cleanup_distance"):
        value = getattr(args, name)
        if value is not None:
            settings[name] = value
    if args.no_creases:
        settings["use_creases"] = False
    if args.triangulate:
        settings["triangulate"] = True
    if args.staged:
        settings["staged"] = True
    if args.cleanup:
        settings["cleanup"] = True
    if args.target:
        if os.path.splitext(args.target)[1].lower() in (".obj", ".ply", ".stl"):
            target = import_mesh_file(os.path.abspath(args.target))
        else:
            target = bpy.data.objects.get(args.target)
            if target is None:
                raise ValueError("Target %r is neither a mesh file (.obj, .ply, .stl) nor an object "
                                 "in %s" % (args.target, args.input))
        settings["target"] = target.name
    for name in ("fit", "fit_cutoff", "fit_smoothing", "fit_samples", "fit_detail_levels"):
        value = getattr(args, name)
        if value is not None:
            settings[name] = value
    if args.fit_paint_scan:
        settings["fit_paint_scan"] = True

    progress = None
    if sys.stdout.isatty():  # one line, rewritten: a Surface fit's rounds, or the solver's iterations
        surface = "target" in settings and settings.get("fit", package.api.DEFAULT_SETTINGS["fit"]) == 'SURFACE'
        line = "\rround %d: mean distance %.3g of the scan's diagonal" if surface else "\riteration %d: max error %.3g"

        def progress(iteration, value):
            sys.stdout.write(line % (iteration, value))
            sys.stdout.flush()
            return False

    new_obj, report = package.interpolate(obj, progress=progress, **settings)
    if progress is not None:
        sys.stdout.write("\n")
    if "target" in settings:
        print("subdiv_pia: %s: %s" % (new_obj.name, package.api.format_fit_report(report, settings["target"])))
        detail = package.api.format_detail(new_obj)
        if detail:
            print("subdiv_pia: %s: %s" % (new_obj.name, detail))
        print("subdiv_pia: stencils %.3f s, closest points %.3f s, solve %.3f s"
              % (report.stencil_seconds, report.query_seconds, report.solve_seconds))
    else:
        print("subdiv_pia: %s: %s" % (new_obj.name, package.api.format_report(report)))
        print("subdiv_pia: stencils %.3f s, solve %.3f s" % (report.stencil_seconds, report.solve_seconds))
    cleaned = package.api.format_cleanup(new_obj)
    if cleaned:
        print("subdiv_pia: %s" % cleaned)
    if new_obj.get("pia_fit_scan_painted"):
        print("subdiv_pia: distances to the surface written onto '%s' (%s, %s)"
              % (settings["target"], package.api.SCAN_DISTANCE_ATTRIBUTE, package.api.SCAN_COLOR_ATTRIBUTE))
    elif new_obj.get("pia_fit_scan_not_painted"):
        print("subdiv_pia: %s" % new_obj["pia_fit_scan_not_painted"])
    limit = package.api.find_limit_object(new_obj)
    if limit is not None:
        print("subdiv_pia: limit surface %s: %d vertices, %d faces"
              % (limit.name, len(limit.data.vertices), len(limit.data.polygons)))
    output = os.path.abspath(args.output)
    os.makedirs(os.path.dirname(output) or ".", exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=output, check_existing=False)
    print("subdiv_pia: saved %s" % output)


def _argv():
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1:]
    return sys.argv[1:] if _is_module() else []  # plain Python: python cli.py ARGS


if __name__ == "__main__":
    status = 0
    try:
        main(_argv())
    except SystemExit as exit_:  # argparse: --help, bad options
        if isinstance(exit_.code, str):
            print(exit_.code, file=sys.stderr)
        status = exit_.code if isinstance(exit_.code, int) else int(exit_.code is not None)
    except Exception as error:  # message for the user, non-zero exit
        print("subdiv_pia: error: %s" % error, file=sys.stderr)
        status = 1
    finish(status)
