# SPDX-License-Identifier: GPL-2.0-or-later
"""Command line: make an interpolating cage and save it to a .blend file.

    blender -b --python <add-on folder>/cli.py -- INPUT OUTPUT.blend [options]

INPUT is .obj, .ply, .stl or .blend. Run with -- --help for the options.
Exit status 0 on success (also when the tolerance was not reached: the
report says so), 1 with the message on error.
"""

import argparse
import importlib
import os
import sys

import bpy


def _import_package():
    """Import the add-on package that contains this file, also when run as a file."""
    here = os.path.dirname(os.path.abspath(__file__))
    parent, package = os.path.split(here)
    if parent not in sys.path:
        sys.path.insert(0, parent)
    return importlib.import_module(package)


def pkg_methods():
    return _import_package().api.METHODS


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog="blender -b --python cli.py --",
        description="Make a control cage whose subdivision limit surface passes through the "
                    "vertices of INPUT. Catmull-Clark (default): the limit surface of Blender's "
                    "Subdivision Surface modifier with Use Limit Surface; the cage is saved with "
                    "that modifier. Loop: the cage is saved without a modifier, with its limit "
                    "surface (refined --levels times) as a child object <cage>_limit. DOO_SABIN "
                    "(two-phase Doo-Sabin, closed meshes): likewise, the child holds the cage "
                    "refined --levels times.")
    parser.add_argument("input", help="input mesh: .obj, .ply, .stl or .blend")
    parser.add_argument("output", help="output .blend file")
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
    return parser.parse_args(argv)


def operator_exists(module_name, op_name):
    """bpy.ops.<module>.<name> exists (hasattr on bpy.ops is always True)."""
    try:
        getattr(getattr(bpy.ops, module_name), op_name).get_rna_type()
        return True
    except (AttributeError, KeyError):
        return False


def _call_first(names, **kwargs):
    for module_name, op_name in names:
        if operator_exists(module_name, op_name):
            return getattr(getattr(bpy.ops, module_name), op_name)(**kwargs)
    raise RuntimeError("No importer available (%s)" % ", ".join("%s.%s" % n for n in names))


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

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return import_mesh_file(path, object_name)


def import_mesh_file(path, object_name=None):
    """Import a .obj, .ply or .stl file into the current scene; return its mesh object."""
    if not os.path.isfile(path):
        raise ValueError("File not found: %s" % path)
    ext = os.path.splitext(path)[1].lower()
    before = set(bpy.data.objects)
    if ext == ".obj":
        if operator_exists("wm", "obj_import"):  # C++ importer (3.3+): keeps vertex order
            known = bpy.ops.wm.obj_import.get_rna_type().properties.keys()
            options = {k: False for k in ("use_split_objects", "use_split_groups") if k in known}
            bpy.ops.wm.obj_import(filepath=path, **options)
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
    obj = load_input(os.path.abspath(args.input), args.object)
    settings = {}
    if args.levels is not None:
        settings["levels"] = args.levels
        settings["render_levels"] = args.levels
    if args.render_levels is not None:
        settings["render_levels"] = args.render_levels
    for name in ("scheme", "boundary_rule", "quality", "boundary_smooth", "method", "tolerance",
                 "max_iterations", "shape_parameter", "shape_attribute"):
        value = getattr(args, name)
        if value is not None:
            settings[name] = value
    if args.no_creases:
        settings["use_creases"] = False
    if args.triangulate:
        settings["triangulate"] = True
    if args.staged:
        settings["staged"] = True
    if args.target:
        if os.path.splitext(args.target)[1].lower() in (".obj", ".ply", ".stl"):
            target = import_mesh_file(os.path.abspath(args.target))
        else:
            target = bpy.data.objects.get(args.target)
            if target is None:
                raise ValueError("Target %r is neither a mesh file (.obj, .ply, .stl) nor an object "
                                 "in %s" % (args.target, args.input))
        settings["target"] = target.name
    for name in ("fit", "fit_cutoff", "fit_smoothing", "fit_samples"):
        value = getattr(args, name)
        if value is not None:
            settings[name] = value

    progress = None
    if sys.stdout.isatty():
        def progress(iteration, error):
            sys.stdout.write("\riteration %d: max error %.3g" % (iteration, error))
            sys.stdout.flush()
            return False

    new_obj, report = package.interpolate(obj, progress=progress, **settings)
    if progress is not None:
        sys.stdout.write("\n")
    if "target" in settings:
        print("subdiv_pia: %s: %s" % (new_obj.name, package.api.format_fit_report(report, settings["target"])))
        print("subdiv_pia: stencils %.3f s, closest points %.3f s, solve %.3f s"
              % (report.stencil_seconds, report.query_seconds, report.solve_seconds))
    else:
        print("subdiv_pia: %s: %s" % (new_obj.name, package.api.format_report(report)))
        print("subdiv_pia: stencils %.3f s, solve %.3f s" % (report.stencil_seconds, report.solve_seconds))
    limit = package.api.find_limit_object(new_obj)
    if limit is not None:
        print("subdiv_pia: limit surface %s: %d vertices, %d faces"
              % (limit.name, len(limit.data.vertices), len(limit.data.polygons)))
    output = os.path.abspath(args.output)
    os.makedirs(os.path.dirname(output) or ".", exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=output, check_existing=False)
    print("subdiv_pia: saved %s" % output)


def _argv():
    return sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []


if __name__ == "__main__":
    try:
        main(_argv())
    except SystemExit:
        raise
    except Exception as error:  # message for the user, non-zero exit
        print("subdiv_pia: error: %s" % error, file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        sys.exit(1)
