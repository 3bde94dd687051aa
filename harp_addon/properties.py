"""The scene's HARP settings (scene.harp): the panel's fields and the mirror of the running job."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

# as pipeline/cli.PRESET_NOTES gives the measured figures (the add-on cannot import the fitting engine)
PRESETS = [("preview", "Preview", "A first look in under 2 min for a 150-frame clip on 2 CPU cores: joint error "
                                  "5% and L1 9% above Fast's"),
           ("fast", "Fast", "About 7 min for a 150-frame 448 px clip on 2 CPU cores, 8 on one"),
           ("full", "Full", "Fast's fit carried to convergence, about 8-9 min for a 150-frame clip on 2 CPU "
                            "cores: the held-out frames 0.3-0.4 dB closer than Fast's, the joints closer on a "
                            "phone-like clip"),
           ("paper", "Paper", "HARP's own schedule at 448 px, about 50 min for 150 frames, to compare with the "
                              "paper; no better than Fast")]
SHADOWS = [("auto", "Auto", "Decided by measuring: fitted frames rendered with and without shadows, "
                               "the better kept"),
           ("on", "On", "Self-shadowing always"), ("off", "Off", "No self-shadowing (soft, even light)")]
# "preset": whatever the chosen preset does (Auto in Fast, Full and Paper; Off in Preview: HARP's light alone)
ENVIRONMENTS = [("preset", "As the preset", "Auto in Fast, Full and Paper, Off in Preview"),
                ("auto", "Auto", "A room's light from every side, kept where its colour changes with direction "
                                 "(a white point light cannot explain that)"),
                ("on", "On", "Always fit a room's light beside the point light"),
                ("off", "Off", "One point light and an even ambient light (HARP's light)")]
SPECULARS = [("preset", "As the preset", "Auto in Fast, Full and Paper, Off in Preview"),
             ("auto", "Auto", "The skin's sheen (a roughness and a level), kept where it carries a visible share "
                              "of the light"),
             ("on", "On", "Always fit the skin's sheen"),
             ("off", "Off", "A matte skin (HARP's)")]
LIGHT_SIZES = [("preset", "As the preset", "Auto in Fast, Full and Paper, a point light in Preview"),
               ("auto", "Auto", "A point light or a disc 6-19 degrees across (a lamp's shade, a window), whichever "
                                "casts the footage's shadows: soft shadows in renders and in the bound sun"),
               ("off", "Point", "A point light's hard shadows (HARP's)")]
SIDES = [("auto", "Auto", "Tell from the footage (MediaPipe)"), ("right", "Right", ""), ("left", "Left", "")]
RIG_KINDS = [("mixamo", "Mixamo", "Bones named mixamorig:RightHandIndex1 ..."),
             ("rigify", "Rigify", "A generated Rigify rig: the hand's IK control hand_ik.R, the fingers' FK controls "
                                  "f_index.01.R ..."),
             ("file", "Bone map file", "A JSON file: {our joint name: your bone name}")]
PLACES = [("follow", "Follow the footage", "The hand goes where the capture puts it, every frame"),
          ("keep", "Keep the rig's place", "Only the hand's own rotations; your rig keeps its placement")]
INITS = [("mediapipe", "MediaPipe", "Detect the hand's keypoints in every frame (offline)"),
         ("gt-noise", "Ground truth + noise", "Synthetic clips only: the true pose with noise")]


class HarpSettings(bpy.types.PropertyGroup):
    video: StringProperty(name="Footage", subtype="FILE_PATH", description="Video file or folder of frames")
    masks: StringProperty(name="Masks", subtype="FILE_PATH",
                          description="Mask video or folder (white = hand); empty: made from the footage")
    side: EnumProperty(name="Hand", items=SIDES, default="auto")
    fov: FloatProperty(name="Field of view", default=0.0, min=0.0, max=170.0, subtype="ANGLE",
                       description="Horizontal field of view of the footage; 0: a phone's main camera")
    sequence: StringProperty(name="Sequence", subtype="DIR_PATH", description="Sequence folder (written by Import)")
    preset: EnumProperty(name="Preset", items=PRESETS, default="fast")
    shadows: EnumProperty(name="Shadows", items=SHADOWS, default="auto")
    environment: EnumProperty(name="Room light", items=ENVIRONMENTS, default="preset")
    specular: EnumProperty(name="Skin sheen", items=SPECULARS, default="preset")
    light_size: EnumProperty(name="Light size", items=LIGHT_SIZES, default="preset")
    init: EnumProperty(name="Start from", items=INITS, default="mediapipe")
    avatar: StringProperty(name="Avatar", subtype="DIR_PATH", description="Avatar folder (written by Fit)")
    pack_on_bind: BoolProperty(name="Pack images", default=False,
                               description="Keep the albedo, normal map and footage frame inside the .blend")
    smooth_frames: IntProperty(name="Smooth keys", default=0, min=0, max=31, step=2,
                               description="Smooth the motion over this many frames (odd, at least 5; 0: the fit's "
                                           "keys as they are). 7-9 frames took out 70-77% of the jitter on "
                                           "synthetic clips and brought the joints closer to the truth")
    retarget_rig: PointerProperty(name="Rig", type=bpy.types.Object, poll=lambda self, obj: obj.type == "ARMATURE",
                                  description="Your armature: the fitted motion goes onto its hand bones as keys")
    rig_kind: EnumProperty(name="Bones", items=RIG_KINDS, default="mixamo")
    bone_map_file: StringProperty(name="Bone map", subtype="FILE_PATH",
                                  description="JSON: {\"wrist\": \"hand.R\", \"index1\": ...}; joints left out stay as "
                                              "they are")
    retarget_place: EnumProperty(name="Placement", items=PLACES, default="follow")
    mesh_onto_rig: BoolProperty(name="Mesh onto the rig", default=False,
                                description="Also skin a copy of the personalised mesh to your rig (carried into its "
                                            "rest hand); off: the mesh stays on the avatar's own armature")
    gltf: StringProperty(name="glTF", subtype="FILE_PATH", default="//hand.glb")
    fbx: StringProperty(name="FBX", subtype="FILE_PATH", default="",
                        description="Also export the hand as FBX (skin, embedded textures, motion); empty: no FBX")
    blend: StringProperty(name=".blend", subtype="FILE_PATH", default="//hand.blend")
    pack_on_export: BoolProperty(name="Pack images", default=True,
                                 description="The exported .blend carries every image inside it (the open file "
                                             "is left as it is)")
    # the running job, mirrored by actions.poll
    job_label: StringProperty()
    job_state: StringProperty()
    job_fraction: FloatProperty(min=0.0, max=1.0, subtype="FACTOR")
    job_status: StringProperty()
    job_log: StringProperty()
    job_errors: StringProperty()


def register():
    bpy.utils.register_class(HarpSettings)
    bpy.types.Scene.harp = PointerProperty(type=HarpSettings)


def unregister():
    del bpy.types.Scene.harp
    bpy.utils.unregister_class(HarpSettings)
