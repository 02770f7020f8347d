# Built-in preset: a cage to look at in the viewport.  Solved to a
# ten-thousandth of the mesh's size (a tenth of a pixel where the mesh
# fills a 1000-pixel view), one level in the viewport and in renders.
# Every setting not named here is at its default (the preset menu resets them).
import bpy
settings = bpy.context.scene.subdiv_pia
settings.use_modifier_settings = False
settings.levels = 1
settings.render_levels = 1
settings.tolerance = 1e-4
