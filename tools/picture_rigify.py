"""Write docs/blender_rigify.png: an avatar's motion on a generated Rigify rig (harp_addon/
retarget.py), the rig's deforming hand bones drawn through the bound footage camera over the
footage at four fitted frames, beside the fit's own keypoints.

    .venv/bin/python tools/picture_rigify.py AVATAR [--out docs/blender_rigify.png]

The Rigify rig is made as tests/rigify_fixture.py makes it (the human metarig's arm and hand
moved onto the avatar's rest joints, generated); the keys go on its hand IK control and finger
FK controls. Prints the rig's fingertips against the fit's over every fitted frame (mean and
worst, mm). docs/blender_rigify.png: the demo clip's `fast` avatar (hand + forearm).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.preview_render import label  # noqa: E402

FINGERS = ("thumb", "f_index", "f_middle", "f_ring", "f_pinky")
SCALE = 2          # the footage drawn this many times larger, so the bones show


def fingertip_errors(bound, rig, frames, scene):
    """Rigify's deforming finger bones against our rig at every fitted frame: each fingertip
    keypoint carried by both (one line, mm)."""
    from harp_addon.rig import bone_names
    from harp_addon.scene import FIRST_FRAME

    data = bound.files.rig
    ours = dict(zip(data.joint_names, bone_names(data)))
    tips = {"thumb": 4, "index": 8, "middle": 12, "ring": 16, "pinky": 20}
    errors = []
    for frame in frames:
        scene.frame_set(FIRST_FRAME + frame)
        for finger, keypoint in tips.items():
            rest = np.array(data.keypoints)[keypoint]
            stem = "thumb" if finger == "thumb" else f"f_{finger}"
            points = []
            for armature, name in ((bound.armature, ours[f"{finger}3"]), (rig, f"DEF-{stem}.03.R")):
                bone = armature.pose.bones[name]
                carry = np.array(armature.matrix_world) @ np.array(bone.matrix) @ np.linalg.inv(
                    np.array(bone.bone.matrix_local))
                points.append(carry[:3, :3] @ rest + carry[:3, 3])
            errors.append(np.linalg.norm(points[0] - points[1]) * 1000)
    return (f"Rigify fingertips against the fit over {len(frames)} frames: {np.mean(errors):.3f} mm mean, "
            f"{np.max(errors):.3f} mm worst")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("avatar")
    parser.add_argument("--out", default=str(ROOT / "docs" / "blender_rigify.png"))
    args = parser.parse_args(argv)
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    from harp_addon.retarget import bone_map, retarget_motion
    from harp_addon.scene import FIRST_FRAME, bind_avatar
    from rigify_fixture import fitted_rigify_rig

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bound = bind_avatar(args.avatar)
    rig = fitted_rigify_rig(bound)
    retarget_motion(bound, rig, bone_map("rigify", bound.files.rig.side))
    scene = bpy.context.scene
    sequence = Path(bound.files.description["footage"]["sequence"])
    info = seq.read_sequence_info(sequence)
    frames = [int(f) - FIRST_FRAME for f in bound.frames]
    chosen = [frames[round(i * (len(frames) - 1) / 3)] for i in range(4)]

    def pixel(point):
        view = world_to_camera_view(scene, bound.camera, Vector(point))
        return int(round(view.x * info.width * SCALE)), int(round((1 - view.y) * info.height * SCALE))

    print(fingertip_errors(bound, rig, frames, scene))
    tiles = []
    for frame in chosen:
        scene.frame_set(FIRST_FRAME + frame)
        footage = seq.read_rgb(seq.frame_path(sequence, info, frame))
        image = cv2.resize(footage, (info.width * SCALE, info.height * SCALE), interpolation=cv2.INTER_CUBIC)
        world = np.array(rig.matrix_world)
        for stem in FINGERS + ("hand",):
            for number in ((1, 2, 3) if stem != "hand" else (None,)):
                name = f"DEF-{stem}.0{number}.R" if number else "DEF-hand.R"
                bone = rig.pose.bones[name]
                head = world[:3, :3] @ np.array(bone.head) + world[:3, 3]
                tail = world[:3, :3] @ np.array(bone.tail) + world[:3, 3]
                cv2.line(image, pixel(head), pixel(tail), (255, 170, 0), 3, cv2.LINE_AA)
                cv2.circle(image, pixel(head), 4, (255, 255, 255), -1, cv2.LINE_AA)
        tiles.append(label(image, f"frame {frame}: Rigify's DEF bones"))
    picture = np.concatenate(tiles, 1)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, picture[..., ::-1])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
