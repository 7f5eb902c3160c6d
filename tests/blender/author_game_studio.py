"""Run inside Blender (``blender -b --factory-startup --python author_game_studio.py -- IN.bvh OUT.bvh``):
author a BVH in a game studio's conventions from a clip, with Blender doing the authoring.

Blender imports ``IN.bvh``, then the armature is rebuilt the way a game studio's skeleton is:
a static root bone at the floor above the hips, every bone's rest pose along the X axis of
its parent (the way to its largest child on +X, the other children turned with it: the
hips' own frame turns its trunk along X), no bone
connected (so Blender's exporter writes 6 channels on every joint, its positions replacing
the offset), and the animation re-expressed so that every bone's head stays where it was in
every frame. Exported in centimetres (``global_scale=100``) with Blender's Z up."""

import builtins
import sys

import bpy
from mathutils import Matrix, Vector

# Debian's Blender 3.4 on Python 3.11: its BVH importer still opens with "rU"
_open = builtins.open
builtins.open = lambda file, mode="r", *a, **k: _open(file, mode.replace("U", ""), *a, **k)

src, out = sys.argv[sys.argv.index("--") + 1:][:2]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=src, rotate_mode="XYZ", update_scene_fps=True, update_scene_duration=True,
                        axis_forward="-Z", axis_up="Y")
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
first, last = (int(round(v)) for v in arm.animation_data.action.frame_range)
scene.frame_start, scene.frame_end = first, last
bones = [b.name for b in arm.data.bones]  # parents first
parent = {b.name: (b.parent.name if b.parent else None) for b in arm.data.bones}
kids = {n: [k for k in bones if parent[k] == n] for n in bones}

# every bone's rest head and its rotation relative to rest, per frame (armature space)
rest_head = {b.name: b.head_local.copy() for b in arm.data.bones}
rest_rot = {b.name: b.matrix_local.to_3x3() for b in arm.data.bones}
frames = {}
for f in range(first, last + 1):
    scene.frame_set(f)
    frames[f] = {n: (arm.pose.bones[n].head.copy(), arm.pose.bones[n].matrix.to_3x3() @ rest_rot[n].inverted())
                 for n in bones}


def along_x(v: Vector) -> Matrix:
    """A rotation taking v onto +X."""
    return v.normalized().rotation_difference(Vector((1.0, 0.0, 0.0))).to_matrix() if v.length > 1e-9 else Matrix.Identity(3)


def size(n: str) -> int:
    return 1 + sum(size(k) for k in kids[n])


def first_away(n: str) -> Vector:
    """From bone n's head to the first head elsewhere down its largest children (the trunk
    from the hips, as a game studio's Hips -> Spine lies along X; a skeleton may start several
    bones at one point, as HDM05's pelvis does)."""
    k = n
    while kids[k]:
        k = max(kids[k], key=size)
        if (rest_head[k] - rest_head[n]).length > 1e-6:
            return rest_head[k] - rest_head[n]
    return Vector((0.0, 0.0, 0.0))


# Q[n]: the turn of bone n's rest frame that puts the way to its largest child on +X; new offsets Q_parent o
Q = {n: (along_x(first_away(n)) if kids[n] else Matrix.Identity(3)) for n in bones}


def to_axes(m: Matrix) -> Matrix:
    """The axis rotation (a signed permutation) nearest m: a studio's root frame differs from
    another's by a turn of its axes (Y up against X up), not by any angle."""
    out = Matrix(((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    used = set()
    for col in range(3):
        row = max((r for r in range(3) if r not in used), key=lambda r: abs(m[r][col]))
        used.add(row)
        out[row][col] = 1.0 if m[row][col] > 0 else -1.0
    return out


Q[bones[0]] = to_axes(Q[bones[0]])
new_head = {}
for n in bones:
    p = parent[n]
    new_head[n] = Vector((0.0, 0.0, 0.0)) if p is None else new_head[p] + Q[p] @ (rest_head[n] - rest_head[p])
hips = bones[0]
floor = min(min(fr[n][0].z for n in bones) for fr in frames.values())

bpy.context.view_layer.objects.active = arm
bpy.ops.object.mode_set(mode="EDIT")
eb = arm.data.edit_bones
for n in bones:
    b = eb[n]
    b.use_connect = False
    b.head = new_head[n]
    b.tail = new_head[n] + Vector((0.05, 0.0, 0.0))
    b.roll = 0.0
root = eb.new("joint_Root")  # the studio's static node at the floor, above the hips in the tree
root.head, root.tail, root.roll = Vector((0.0, 0.0, floor)), Vector((0.05, 0.0, floor)), 0.0
eb[hips].parent = root
eb[hips].use_connect = False
bpy.ops.object.mode_set(mode="POSE")

arm.animation_data.action = bpy.data.actions.new("authored")
new_rot = {b.name: b.matrix_local.to_3x3() for b in arm.data.bones}
for f in range(first, last + 1):
    scene.frame_set(f)
    for n in bones:  # parents first: a child's matrix is set after its parent's
        head, g = frames[f][n]
        pb = arm.pose.bones[n]
        pb.rotation_mode = "XYZ"
        pb.matrix = Matrix.Translation(head) @ (g @ Q[n].inverted() @ new_rot[n]).to_4x4()
        bpy.context.view_layer.update()
        pb.keyframe_insert("location", frame=f)
        pb.keyframe_insert("rotation_euler", frame=f)
bpy.ops.object.mode_set(mode="OBJECT")
bpy.ops.object.select_all(action="DESELECT")
arm.select_set(True)
bpy.ops.export_anim.bvh(filepath=out, frame_start=first, frame_end=last, global_scale=100.0, rotate_mode="XYZ")
