"""Exports of a bound avatar (bpy): glTF binary with Blender's own exporter (the skinned mesh,
its armature and the fitted motion) and the .blend file, its images packed or not."""
from __future__ import annotations

import contextlib
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


def save_blend(path, pack=False) -> Path:
    """Save the current file as `path` (a copy: the open file keeps its own name). Image paths
    are written relative to the new file's folder; with `pack`, every image read from a file
    travels inside it (packed for the copy only: the open file is left as it was)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _packed_images() if pack else contextlib.nullcontext():
        try:
            bpy.ops.wm.save_as_mainfile(filepath=str(path.resolve()), copy=True, relative_remap=True)
        except RuntimeError as error:
            raise ExportError(f"saving {path} failed: {str(error).strip().splitlines()[-1]}") from None
    return path


@contextlib.contextmanager
def _packed_images():
    """Packs every unpacked image whose file exists for the duration of the block, then unpacks
    it again. A SEQUENCE image is packed as a still of the frame its path names (Blender reads
    the frames of a sequence from their files only): the footage's first frame."""
    packed = []      # (image, its source)
    try:
        for image in bpy.data.images:
            if image.packed_file is None and image.source in ("FILE", "SEQUENCE") and \
                    Path(bpy.path.abspath(image.filepath)).is_file():
                packed.append((image, image.source))
                image.source = "FILE"
                try:
                    image.pack()
                except RuntimeError as error:
                    raise ExportError(f"cannot pack {image.filepath}: {str(error).strip()}") from None
        yield
    finally:
        for image, source in packed:
            if image.packed_file is not None:
                image.unpack(method="REMOVE")
            image.source = source
