# Built-in preset: fit a retopologized Catmull-Clark cage (the active
# object) to a scan (the Target, chosen in the panel): the whole limit
# surface onto the scan, the scan painted by its distance to the result.
# Every setting not named here is at its default (the preset menu resets them).
import bpy
settings = bpy.context.scene.subdiv_pia
settings.scheme = 'CATMULL_CLARK'
settings.fit = 'SURFACE'
settings.fit_paint_scan = True
