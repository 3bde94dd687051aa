"""Exports of a bound avatar (bpy): glTF binary and FBX with Blender's own exporters (the
skinned mesh, its armature, its textures and the fitted motion) and the .blend file, its images
packed or not."""
from __future__ import annotations

import contextlib
from pathlib import Path

import bpy


class ExportError(ValueError):
    """An export failed (one-line message)."""


def export_gltf(bound, path) -> Path:
    """Write the hand of `bound` (a scene.BoundAvatar) as a .glb: mesh, skin and animation."""
    path = Path(path)
    with _selected(bound):
        _run_exporter("glTF", bpy.ops.export_scene.gltf, path, export_format="GLB", use_selection=True,
                      export_animations=True, export_skins=True, export_yup=True, export_animation_mode="ACTIONS",
                      export_force_sampling=True)
    return path


def export_fbx(bound, path) -> Path:
    """Write the hand of `bound` as an .fbx (for game engines and other 3D tools): mesh, skin,
    the textures embedded, and the motion baked at every scene frame, unsimplified, on the
    armature's own bones (no leaf bones added)."""
    path = Path(path)
    with _selected(bound):
        _run_exporter("FBX", bpy.ops.export_scene.fbx, path, use_selection=True, object_types={"ARMATURE", "MESH"},
                      add_leaf_bones=False, bake_anim=True, bake_anim_use_all_actions=False,
                      bake_anim_use_nla_strips=False, bake_anim_simplify_factor=0.0, bake_anim_step=1.0,
                      bake_anim_force_startend_keying=True, path_mode="COPY", embed_textures=True,
                      armature_nodetype="NULL", use_armature_deform_only=True)
    return path


def _run_exporter(kind, operator, path, **options):
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        result = operator(filepath=str(path), **options)
    except RuntimeError as error:
        raise ExportError(f"{kind} export failed: {str(error).strip().splitlines()[-1]}") from None
    if "FINISHED" not in result or not path.is_file():
        raise ExportError(f"{kind} export to {path} did not finish")


@contextlib.contextmanager
def _selected(bound):
    """The armature and the mesh of `bound` selected (the armature active) for the block; the
    selection as it was afterwards."""
    view_layer = bpy.context.view_layer
    previous = [obj for obj in view_layer.objects if obj.select_get()], view_layer.objects.active
    for obj in view_layer.objects:
        obj.select_set(False)
    for obj in (bound.armature, bound.mesh):
        obj.select_set(True)
    view_layer.objects.active = bound.armature
    try:
        yield
    finally:
        for obj in view_layer.objects:
            obj.select_set(obj in previous[0])
        view_layer.objects.active = previous[1]


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
