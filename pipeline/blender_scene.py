"""`harp blend AVATAR --out scene.blend [--gltf hand.glb] [--fbx hand.fbx] [--pack] [--smooth N]`: the Blender add-on's binding
without its interface, through the bpy module (for pipelines and tests): a new empty scene, the
avatar bound into it (harp_addon/scene.py), saved, and optionally exported as glTF binary and FBX. The
.blend finds its images relative to its own folder, or, with `pack`, carries them inside."""
from __future__ import annotations

from pathlib import Path


class BlendError(ValueError):
    """The scene cannot be made (one-line message)."""


def blend_avatar(avatar, out, gltf=None, sequence=None, pack=False, smooth=0, fbx=None):
    """Write `out` (.blend), `gltf` (.glb) and `fbx` (.fbx) of the avatar folder (its keys smoothed over
    `smooth` frames, 0: as fitted); returns the paths written."""
    try:
        import bpy
    except ImportError:
        raise BlendError("harp blend needs the bpy module (bash tools/setup.sh installs it)") from None
    from harp_addon import actions

    bpy.ops.wm.read_factory_settings(use_empty=True)
    try:
        bound = actions.bind(avatar, sequence, pack=pack, smooth=smooth)
    except actions.ActionError as error:
        raise BlendError(str(error)) from None
    return actions.export(bound, gltf=gltf, blend=Path(out), fbx=fbx)
