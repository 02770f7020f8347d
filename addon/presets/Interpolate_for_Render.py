# Built-in preset: a cage to render.  The levels and quality a new
# Subdivision Surface modifier has (Viewport 1, Render 2, Quality 3),
# solved to a millionth of the mesh's size.
# Every setting not named here is at its default (the preset menu resets them).
import bpy
settings = bpy.context.scene.subdiv_pia
settings.use_modifier_settings = False
settings.levels = 1
settings.render_levels = 2
settings.quality = 3
settings.tolerance = 1e-6
