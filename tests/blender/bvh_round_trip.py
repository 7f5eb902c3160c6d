"""Run inside Blender (``blender -b --factory-startup --python bvh_round_trip.py -- IN.bvh OUT.json OUT.bvh``):
import a BVH with Blender's own importer, write every bone's world head position per frame
(JSON) and export the armature again with Blender's own BVH exporter."""

import builtins
import json
import sys

import bpy

# Debian's Blender 3.4 runs on the system Python 3.11, where open(..., "rU") is gone, and its
# BVH importer still asks for it: drop the "U" (universal newlines are the default anyway)
_open = builtins.open
builtins.open = lambda file, mode="r", *a, **k: _open(file, mode.replace("U", ""), *a, **k)

args = sys.argv[sys.argv.index("--") + 1:]
src, out_json, out_bvh = args[:3]
# optional: a scale on import (a file authored in other units) and the Euler order of the export
scale, rotate = (float(args[3]), args[4]) if len(args) > 3 else (1.0, "NATIVE")
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=src, global_scale=scale, rotate_mode=rotate, update_scene_fps=True,
                        update_scene_duration=True, axis_forward="-Z", axis_up="Y")
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
first, last = (int(round(v)) for v in arm.animation_data.action.frame_range)  # the scene's end is never shortened
scene.frame_start, scene.frame_end = first, last
frames = {}
for f in range(scene.frame_start, scene.frame_end + 1):
    scene.frame_set(f)
    frames[f] = {b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones}
with open(out_json, "w") as fh:
    json.dump({"fps": scene.render.fps / scene.render.fps_base, "frames": frames}, fh)
bpy.ops.object.select_all(action="DESELECT")
arm.select_set(True)
bpy.context.view_layer.objects.active = arm
bpy.ops.export_anim.bvh(filepath=out_bvh, frame_start=scene.frame_start, frame_end=scene.frame_end, global_scale=1.0,
                        rotate_mode=rotate)
