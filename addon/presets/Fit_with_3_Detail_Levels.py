# Built-in preset: as "Fit Cage to Scan", and three Multires levels on the
# result, each fitted to the scan: the scan's detail to sculpt on and bake.
# Every setting not named here is at its default (the preset menu resets them).
import bpy
settings = bpy.context.scene.subdiv_pia
settings.scheme = 'CATMULL_CLARK'
settings.fit = 'SURFACE'
settings.fit_detail_levels = 3
settings.fit_paint_scan = True
