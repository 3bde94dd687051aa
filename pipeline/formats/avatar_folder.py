"""The avatar folder: what a fit produces, `harp render` poses and the Blender add-on binds
(numpy and the standard library only; one home of the format).

    avatar.json    format + version, mode (hand / arm), side, shape vector, light (point light
                   position, ambient ratio, shadows, and the environment light's 8 x 3 spherical
                   harmonics or null: formats/environment_light.py; the skin's specular lobe,
                   roughness and level, or null: formats/specular_lobe.py; the colour model,
                   "display" or "linear", absent before the choice: formats/colour_model.py),
                   camera (K, width, height of the fitted images), settings used, per-stage timings
    albedo.png     albedo texture, 8-bit, in the model's UV layout (v up): sRGB-encoded where the
                   colour model is "linear"; display values shaded as they are where it is
                   "display" (the fit then treats the frames' 8-bit values as linear)
    normal.png     tangent-space normal map, 8-bit, (n + 1) / 2 per channel
    mesh.obj       the personalised rest mesh (shape and displacements applied), with UVs
    rig.npz        a hand-model file (formats/hand_model_file.py) of that rest mesh: vertices,
                   faces, UVs, skinning weights, joints, frames, limits; betas are baked in, so
                   posing it with zero betas by linear blend skinning gives the fitted surface
    poses.npz      per-frame global_orient (F, 3), transl (F, 3), pose (F, 16, 3) and the
                   sequence frame index of each (F,), with a format header

Version 2: the fitted surface is the rig's rest mesh skinned (displacements before skinning),
and poses.npz has a header. Folders of version 1 are refused with one line.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from . import hand_model_file as fmt
from .npz_file import read_npz, write_npz
from .png_file import PngError, check_png, write_png

FORMAT_NAME = "harp-avatar"
FORMAT_VERSION = 2
POSES_FORMAT = "harp-avatar-poses"
AVATAR_FILE = "avatar.json"
ALBEDO_FILE = "albedo.png"
NORMAL_FILE = "normal.png"
MESH_FILE = "mesh.obj"
RIG_FILE = "rig.npz"
POSES_FILE = "poses.npz"
POSE_ARRAYS = ("global_orient", "transl", "pose", "frames")


class AvatarFolderError(ValueError):
    """An avatar folder is missing, incomplete or inconsistent (one-line message)."""


@dataclasses.dataclass
class AvatarPoses:
    global_orient: np.ndarray   # (F, 3) axis-angle, model -> camera
    transl: np.ndarray          # (F, 3) metres, camera frame
    pose: np.ndarray            # (F, 16, 3) local axis-angle per joint
    frames: np.ndarray          # (F,) sequence frame indices

    def __len__(self):
        return len(self.frames)


@dataclasses.dataclass
class AvatarFiles:
    """An avatar folder's content (images as 8-bit arrays when written; as checked paths when
    read, for readers that load pixels their own way: Blender, OpenCV)."""

    description: dict                # avatar.json without format and version
    rig: fmt.HandModelData
    poses: AvatarPoses
    albedo: np.ndarray | Path        # (T, T, 3) uint8 RGB, or the checked albedo.png
    normal_map: np.ndarray | Path    # (T, T, 3) uint8 encoded normals, or the checked normal.png


def write_avatar_folder(folder, avatar: AvatarFiles) -> Path:
    """Write every file of the avatar folder (the rest mesh also as mesh.obj)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fmt.save_hand_model(avatar.rig, folder / RIG_FILE)
    write_obj(folder / MESH_FILE, avatar.rig.vertices, avatar.rig.faces, avatar.rig.uvs, avatar.rig.faces_uv)
    write_png(folder / ALBEDO_FILE, np.asarray(avatar.albedo, np.uint8))
    write_png(folder / NORMAL_FILE, np.asarray(avatar.normal_map, np.uint8))
    write_poses(folder, avatar.poses)
    write_avatar_json(folder, avatar.description)
    return folder


def read_avatar_folder(folder) -> AvatarFiles:
    """Every file of an avatar folder, checked: the format version, the rig, poses that fit the
    rig, intact PNGs. Any problem is one AvatarFolderError line."""
    folder = Path(folder)
    description = read_avatar_json(folder)
    try:
        rig = fmt.load_hand_model(folder / RIG_FILE)
    except fmt.HandModelFileError as error:
        raise AvatarFolderError(f"{folder}: {error}") from None
    poses = read_poses(folder)
    if rig.mode != description.get("mode"):
        raise AvatarFolderError(f"{folder}: {RIG_FILE} ({rig.mode} mode) and {AVATAR_FILE} "
                                f"({description.get('mode')} mode) disagree")
    images = []
    for name in (ALBEDO_FILE, NORMAL_FILE):
        try:
            check_png(folder / name)
        except PngError as error:
            raise AvatarFolderError(str(error)) from None
        images.append(folder / name)
    return AvatarFiles(description, rig, poses, *images)


def write_avatar_json(folder, description: dict) -> Path:
    """avatar.json with format and version added; `description` must be JSON-serialisable."""
    path = Path(folder) / AVATAR_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format": FORMAT_NAME, "version": FORMAT_VERSION, **description}, indent=2))
    return path


def read_avatar_json(folder) -> dict:
    path = Path(folder) / AVATAR_FILE
    if not Path(folder).is_dir():
        raise AvatarFolderError(f"avatar folder not found: {Path(folder)}")
    if not path.is_file():
        raise AvatarFolderError(f"not an avatar folder (no {AVATAR_FILE}): {Path(folder)}")
    try:
        description = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise AvatarFolderError(f"cannot read {path}: {error}") from None
    if description.get("format") != FORMAT_NAME:
        raise AvatarFolderError(f"{path} is not a {FORMAT_NAME} file")
    if description.get("version") != FORMAT_VERSION:
        raise AvatarFolderError(f"{path} is an avatar folder of version {description.get('version')}; this program "
                                f"reads version {FORMAT_VERSION}: fit the clip again")
    return {key: value for key, value in description.items() if key not in ("format", "version")}


def write_poses(folder, poses: AvatarPoses) -> Path:
    arrays = {name: np.asarray(getattr(poses, name), np.int64 if name == "frames" else np.float64)
              for name in POSE_ARRAYS}
    return write_npz(Path(folder) / POSES_FILE, {"format": POSES_FORMAT, "version": FORMAT_VERSION}, arrays)


def read_poses(folder) -> AvatarPoses:
    path = Path(folder) / POSES_FILE
    if not path.is_file():
        raise AvatarFolderError(f"missing {path}")
    _, arrays = read_npz(path, POSES_FORMAT, FORMAT_VERSION, AvatarFolderError, required=POSE_ARRAYS,
                         what="pose file")
    poses = AvatarPoses(**arrays)
    count = len(poses.frames)
    if poses.pose.shape != (count, 16, 3) or poses.transl.shape != (count, 3) or \
            poses.global_orient.shape != (count, 3):
        raise AvatarFolderError(f"{path}: inconsistent pose arrays")
    if not all(np.isfinite(getattr(poses, name)).all() for name in ("global_orient", "transl", "pose")):
        raise AvatarFolderError(f"{path}: NaN or Inf in the poses")
    return poses


def write_obj(path, vertices, faces, uvs, faces_uv) -> Path:
    """Wavefront OBJ with positions, UVs and faces (1-based v/vt indices)."""
    lines = ["# harp avatar rest mesh"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in np.asarray(vertices)]
    lines += [f"vt {u:.7f} {v:.7f}" for u, v in np.asarray(uvs)]
    lines += [f"f {a + 1}/{ta + 1} {b + 1}/{tb + 1} {c + 1}/{tc + 1}"
              for (a, b, c), (ta, tb, tc) in zip(np.asarray(faces), np.asarray(faces_uv))]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def read_obj(path):
    """(vertices (V, 3), faces (F, 3), uvs (U, 2), faces_uv (F, 3)) of a triangle OBJ."""
    vertices, uvs, faces, faces_uv = [], [], [], []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            uvs.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            corners = [p.split("/") for p in parts[1:4]]
            faces.append([int(c[0]) - 1 for c in corners])
            faces_uv.append([int(c[1]) - 1 if len(c) > 1 and c[1] else -1 for c in corners])
    return np.array(vertices), np.array(faces, dtype=np.int64), np.array(uvs), np.array(faces_uv, dtype=np.int64)


def encode_normal_map(normal_map) -> np.ndarray:
    """(H, W, 3) tangent-space vectors in [-1, 1] -> uint8 image."""
    return np.clip(np.round((np.asarray(normal_map) + 1) * 127.5), 0, 255).astype(np.uint8)


def decode_normal_map(image) -> np.ndarray:
    """uint8 (H, W, 3) -> unit tangent-space vectors."""
    vectors = np.asarray(image, dtype=np.float64) / 127.5 - 1
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)
