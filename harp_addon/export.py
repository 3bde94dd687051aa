"""Exports of a bound avatar (bpy): glTF binary with Blender's own exporter (the skinned mesh,
its armature and the fitted motion) and the .blend file."""
from __future__ import annotations

from pathlib import Path

import bpy


class ExportError(ValueError):
    """An export failed (one-line message)."""


def export_gltf(bound, path) -> Path:
    """Write the hand of `bound` (a scene.BoundAvatar) as a .glb: mesh, skin and animation."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    view_layer = bpy.context.view_layer
    previous = [obj for obj in view_layer.objects if obj.select_get()], view_layer.objects.active
    for obj in view_layer.objects:
        obj.select_set(False)
    for obj in (bound.armature, bound.mesh):
        obj.select_set(True)
    view_layer.objects.active = bound.armature
    try:
        result = bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", use_selection=True,
                                           export_animations=True, export_skins=True, export_yup=True,
                                           export_animation_mode="ACTIONS", export_force_sampling=True)
    except RuntimeError as error:
        raise ExportError(f"glTF export failed: {str(error).strip().splitlines()[-1]}") from None
    finally:
        for obj in view_layer.objects:
            obj.select_set(obj in previous[0])
        view_layer.objects.active = previous[1]
    if "FINISHED" not in result or not path.is_file():
        raise ExportError(f"glTF export to {path} did not finish")
    return path


def save_blend(path) -> Path:
    """Save the current file as `path` (a copy: the open file keeps its own name)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path.resolve()), copy=True)
    return path
