# SPDX-License-Identifier: GPL-3.0-or-later
"""Settings shared by the operator and the panel (scene.subdiv_pia)."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .settings import DEFAULT_SETTINGS

SCHEME_ITEMS = (
    ('CATMULL_CLARK', "Catmull-Clark",
     "Catmull-Clark limit surface as the Subdivision Surface modifier evaluates it"),
    ('LOOP', "Loop",
     "Loop subdivision of triangle meshes, as OpenSubdiv and USD define it (the library's limit "
     "surface, shown by a child object: Blender's modifier has no Loop scheme)"),
    ('DOO_SABIN', "Doo-Sabin (two-phase)",
     "Two-phase Doo-Sabin with a shape parameter per face; closed meshes"),
)
BOUNDARY_RULE_ITEMS = (
    ('SMOOTH', "Smooth",
     "OpenSubdiv's and USD's boundary rules; corners follow Boundary Smooth"),
    ('HOPPE', "Hoppe",
     "Boundary rules of Hoppe et al. 1994 (piecewise smooth surface reconstruction), as in the "
     "open-mesh paper; ignores Boundary Smooth; needs a manifold mesh"),
)
BOUNDARY_SMOOTH_ITEMS = (
    ('ALL', "All", "Smooth boundaries, including corners (as the modifier)"),
    ('PRESERVE_CORNERS', "Keep Corners", "Smooth boundaries, but corners are kept sharp (as the modifier)"),
)
METHOD_ITEMS = (
    ('AUTO', "Automatic", "The fastest solver for this mesh, chosen by a probe: conjugate gradients "
                        "(or Chebyshev-accelerated PIA) on smooth targets, fast Gauss-Seidel PIA on rough "
                        "ones such as scans"),
    ('PIA', "PIA", "Plain progressive iterative approximation (Jacobi-like)"),
    ('GS_PIA', "Gauss-Seidel PIA", "Progressive iterative approximation with Gauss-Seidel updates"),
    ('CHEBYSHEV', "Chebyshev PIA", "PIA accelerated with Chebyshev polynomials over the estimated spectrum"),
    ('WPIA', "Weighted PIA", "PIA with the best constant weight, estimated from the spectrum"),
    ('CG', "Conjugate Gradients", "Conjugate gradients: closed meshes only (a symmetrizable limit matrix)"),
    ('GS_PIA_FAST', "Gauss-Seidel PIA (Fast)",
     "Gauss-Seidel PIA in an order laid out for it, in float32 with the error measured in double, "
     "on all threads on large meshes"),
    ('LEAST_SQUARES', "Least Squares",
     "Conjugate gradients on the normal equations: converges on any mesh, and where no cage passes "
     "through every point puts the rest as close as the surface allows (every other method switches "
     "to it by itself when it stalls)"),
)

FIT_ITEMS = (
    ('SURFACE', "Surface",
     "Move the whole Catmull-Clark limit surface onto the target (least squares over samples "
     "of every face)"),
    ('VERTICES', "Vertices",
     "Move the limit point of each control vertex to its closest point on the target and "
     "interpolate those (any scheme)"),
)


def settings_annotations():
    """Property definitions used by both the operator and the PropertyGroup."""
    d = DEFAULT_SETTINGS
    return {
        "scheme": EnumProperty(name="Scheme", items=SCHEME_ITEMS, default=d["scheme"],
                               description="Subdivision scheme whose limit surface must interpolate"),
        "boundary_rule": EnumProperty(name="Boundary Rule", items=BOUNDARY_RULE_ITEMS,
                                      default=d["boundary_rule"],
                                      description="Which boundary rules Loop subdivision follows (Loop scheme only)"),
        "triangulate": BoolProperty(name="Triangulate", default=d["triangulate"],
                                    description="Loop scheme: make the cage from a copy of the mesh "
                                                "with quads and n-gons split into triangles (Beauty "
                                                "method); off: such meshes are refused"),
        "staged": BoolProperty(name="Boundary First", default=d["staged"],
                               description="Loop scheme: solve the boundary vertices first, then the "
                                           "interior with the boundary fixed, as the open-mesh paper "
                                           "does (same cage; the report gives both stages' iterations)"),
        "levels": IntProperty(name="Levels Viewport", default=d["levels"], min=0, max=11, soft_max=6,
                              description="Subdivision steps the new object's Subdivision Surface "
                                          "modifier shows in the viewport (Loop, Doo-Sabin: steps "
                                          "of the limit surface object); the cage itself does not "
                                          "depend on it"),
        "render_levels": IntProperty(name="Render", default=d["render_levels"], min=0, max=11, soft_max=6,
                                     description="Subdivision steps the new object's Subdivision Surface "
                                                 "modifier renders with (Catmull-Clark)"),
        "quality": IntProperty(name="Quality", default=d["quality"], min=1, max=10,
                               description="Limit surface accuracy, 1 to 10, as the modifier's "
                                           "Quality (the cage is made for exactly this value)"),
        "boundary_smooth": EnumProperty(name="Boundary Smooth", items=BOUNDARY_SMOOTH_ITEMS,
                                        default=d["boundary_smooth"],
                                        description="How open boundaries and their corners are smoothed, as the "
                                                    "modifier's Boundary Smooth"),
        "use_creases": BoolProperty(name="Use Creases", default=d["use_creases"],
                                    description="Use the mesh's edge and vertex creases, as the modifier's "
                                                "Use Creases (not Doo-Sabin)"),
        # No hard range: a value outside (0, 1) is refused with a message
        # rather than silently clamped.
        "shape_parameter": FloatProperty(name="Shape Parameter", default=d["shape_parameter"],
                                         soft_min=0.01, soft_max=0.99, precision=3, step=1,
                                         description="Shape parameter of every face in the first "
                                                     "subdivision step, between 0 and 1 (no unit): "
                                                     "close to 1 hugs the mesh, lower relaxes it"),
        "shape_attribute": StringProperty(name="Shape Attribute", default=d["shape_attribute"],
                                          description="Name of a float Face attribute: where the "
                                                      "mesh has it, its per-face values win over "
                                                      "Shape Parameter (Doo-Sabin)"),
        "cleanup": BoolProperty(name="Cleanup", default=d["cleanup"],
                                description="Interpolate a cleaned copy of the mesh (the mesh itself "
                                            "is not changed): merge vertices closer than Merge "
                                            "Distance, dissolve repeated vertices in faces, remove "
                                            "zero-area faces and loose geometry, and turn the faces "
                                            "to one orientation. The cage gets the cleaned topology "
                                            "(UV maps, vertex groups and shape keys are not kept)"),
        "cleanup_distance": FloatProperty(name="Merge Distance", default=d["cleanup_distance"],
                                          min=0.0, max=0.1, precision=8, step=0.0001,
                                          description="Cleanup: vertices closer than this, relative "
                                                      "to the bounding-box diagonal, are merged "
                                                      "(faces thinner than it are removed)"),
        "method": EnumProperty(name="Method", items=METHOD_ITEMS, default=d["method"],
                               description="Iterative solver that finds the cage"),
        "tolerance": FloatProperty(name="Tolerance", default=d["tolerance"], min=1e-12, max=1.0,
                                   precision=8, step=0.0001,
                                   description="Stop when every vertex is this close to the surface, "
                                               "relative to the bounding-box diagonal"),
        "max_iterations": IntProperty(name="Max Iterations", default=d["max_iterations"],
                                      min=1, max=1000000,
                                      description="Stop after this many solver iterations at "
                                                  "the latest (the cage is still made, with a warning)"),
        # An operator cannot hold a pointer to an object: the target is named.
        "target": StringProperty(name="Target",
                                 default=d["target"],
                                 description="Mesh object to fit the cage to (a scan; its modifiers "
                                             "applied). Empty: interpolate the cage's own vertices"),
        "fit": EnumProperty(name="Fit", items=FIT_ITEMS, default=d["fit"],
                            description="What is fitted to the target"),
        "fit_cutoff": FloatProperty(name="Cut-off", default=d["fit_cutoff"], min=1e-6, max=1.0,
                                    precision=4, step=0.1,
                                    description="Parts of the surface farther than this from the "
                                                "target (relative to its bounding-box diagonal) do "
                                                "not pull: holes and areas the scan misses"),
        "fit_smoothing": FloatProperty(name="Smoothing", default=d["fit_smoothing"], min=0.0, max=1.0,
                                       precision=7, step=0.0001,
                                       description="Surface fit: fairness weight (no unit, against "
                                                   "the distance term); larger keeps the cage "
                                                   "smoother and farther from the target"),
        "fit_samples": IntProperty(name="Samples per Edge", default=d["fit_samples"], min=1, max=64,
                                   soft_max=8,
                                   description="Surface fit: samples per face edge (the square "
                                               "per quad, or per corner of another polygon)"),
        "fit_detail_levels": IntProperty(name="Detail", default=d["fit_detail_levels"], min=0, max=6,
                                         description="Surface fit: a Multires modifier with this many "
                                                     "levels on the new object, each fitted to the "
                                                     "target, the finest on it (the scan's detail to "
                                                     "sculpt on and bake from). 0: none"),
        "fit_paint_scan": BoolProperty(name="Paint Scan", default=d["fit_paint_scan"],
                                       description="Write each target vertex's distance to the fitted "
                                                   "surface onto the target: the point attribute "
                                                   "pia_scan_distance and its heat map, the colour "
                                                   "attribute pia_scan_distance_color (Catmull-Clark; "
                                                   "not through modifiers that change the target's "
                                                   "vertices)"),
    }


SETTING_NAMES = tuple(settings_annotations())


# The panel picks the target with a pointer (target_object) and passes its name.
SCENE_SETTING_NAMES = tuple(name for name in SETTING_NAMES if name != "target")

# What a preset holds: every panel setting but the target, an object of one file.
PRESET_NAMES = SCENE_SETTING_NAMES + ("use_modifier_settings", "live")


def _is_mesh(_settings, obj):
    return obj.type == 'MESH'


class SubdivPiaSettings(bpy.types.PropertyGroup):
    """Panel settings, stored on the scene."""
    __annotations__ = dict(
        {name: value for name, value in settings_annotations().items() if name != "target"},
        target_object=PointerProperty(
            name="Target", type=bpy.types.Object, poll=_is_mesh,
            description="Mesh object to fit the cage to (a scan; its modifiers applied). "
                        "Empty: interpolate the cage's own vertices"),
        live=BoolProperty(
            name="Live", default=False,
            description="Make the new cage live: it follows every later change of the source mesh"),
        use_modifier_settings=BoolProperty(
            name="Use Modifier Settings", default=True,
            description="Take levels, render levels, quality, boundary smooth and creases from the "
                        "active object's Subdivision Surface modifier (the last one) instead of the "
                        "panel's"),
    )


_register, _unregister = bpy.utils.register_classes_factory((SubdivPiaSettings,))


def register():
    _register()
    bpy.types.Scene.subdiv_pia = bpy.props.PointerProperty(type=SubdivPiaSettings)


def unregister():
    del bpy.types.Scene.subdiv_pia
    _unregister()
