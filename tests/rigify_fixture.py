"""A Rigify rig as an artist makes one for a bound avatar's hand (bpy): the human metarig, its
right arm and hand bones moved onto the avatar's rest joints (its own rolls and conventions
kept), then generated. Used by the retarget test and tools/retarget_picture.py."""
import bpy
import numpy as np

from harp_addon.rig import bone_names


def fitted_rigify_rig(bound):
    """A Rigify rig as an artist makes one for this hand: the human metarig, its arm and hand
    bones moved onto the avatar's rest joints (its own rolls and conventions kept), generated."""
    import addon_utils
    from mathutils import Vector

    addon_utils.enable("rigify", default_set=True)
    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    head = {joint: np.array(bound.armature.data.bones[ours[joint]].head_local) for joint in data.joint_names}
    keypoints = np.array(data.keypoints)
    bpy.ops.object.armature_human_metarig_add()
    metarig = bpy.context.object
    metarig.matrix_world = bound.space.matrix_world.copy()
    bpy.ops.object.mode_set(mode="EDIT")
    bones = metarig.data.edit_bones

    def place(name, start, end):
        bones[name].head, bones[name].tail = Vector(start), Vector(end)

    wrist, elbow = head["wrist"], head["forearm"]
    along = (elbow - wrist) / np.linalg.norm(elbow - wrist)
    # the elbow bent a little, as a metarig's is: Rigify takes the arm's pole from the bend, and a
    # straight arm leaves it undefined (its generation fails on some fitted shapes)
    bend = np.cross(along, [0.0, 0.0, 1.0] if abs(along[2]) < 0.9 else [1.0, 0.0, 0.0])
    place("upper_arm.R", elbow + 0.28 * along + 0.02 * bend / np.linalg.norm(bend), elbow)
    place("forearm.R", elbow, wrist)
    place("hand.R", wrist, 0.5 * (wrist + head["middle1"]))
    for finger, stem, tip in (("index", "f_index", 8), ("middle", "f_middle", 12), ("ring", "f_ring", 16),
                              ("pinky", "f_pinky", 20), ("thumb", "thumb", 4)):
        points = [head[f"{finger}1"], head[f"{finger}2"], head[f"{finger}3"], keypoints[tip]]
        for number in range(3):
            place(f"{stem}.0{number + 1}.R", points[number], points[number + 1])
    for number, finger in enumerate(("index", "middle", "ring", "pinky"), start=1):
        place(f"palm.0{number}.R", wrist + 0.3 * (head[f"{finger}1"] - wrist), head[f"{finger}1"])
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.pose.rigify_generate()
    return bpy.context.object
