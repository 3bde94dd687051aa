"""The avatar folder: what a fit produces and the Blender add-on binds (numpy only; one home).

    avatar.json    format + version, mode (hand / arm), side, shape vector, light, settings used,
                   per-stage timings and final losses
    albedo.png     albedo texture, 8-bit sRGB-less linear values, in the model's UV layout (v up)
    normal.png     tangent-space normal map, 8-bit, (n + 1) / 2 per channel
    mesh.obj       the personalised rest mesh (shape and displacements applied), with UVs
    rig.npz        a hand-model file (pipeline/formats/hand_model_file.py) of that rest mesh:
                   vertices, faces, UVs, skinning weights, joints, frames, limits; betas are baked
                   in, so posing it with zero betas gives the person
    poses.npz      per-frame global_orient (F, 3), transl (F, 3), pose (F, 16, 3), frame indices
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FORMAT_NAME = "harp-avatar"
FORMAT_VERSION = 1
AVATAR_FILE = "avatar.json"
ALBEDO_FILE = "albedo.png"
NORMAL_FILE = "normal.png"
MESH_FILE = "mesh.obj"
RIG_FILE = "rig.npz"
POSES_FILE = "poses.npz"


class AvatarFolderError(ValueError):
    """An avatar folder is missing, incomplete or inconsistent (one-line message)."""


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
    if description.get("format") != FORMAT_NAME or description.get("version") != FORMAT_VERSION:
        raise AvatarFolderError(f"{path} is not a {FORMAT_NAME} file of version {FORMAT_VERSION}")
    return description


def write_poses(folder, global_orient, transl, pose, frames) -> Path:
    path = Path(folder) / POSES_FILE
    with open(path, "wb") as handle:
        np.savez_compressed(handle, global_orient=np.asarray(global_orient, np.float64),
                            transl=np.asarray(transl, np.float64), pose=np.asarray(pose, np.float64),
                            frames=np.asarray(frames, np.int64))
    return path


def read_poses(folder) -> dict:
    path = Path(folder) / POSES_FILE
    if not path.is_file():
        raise AvatarFolderError(f"missing {path}")
    with np.load(path, allow_pickle=False) as archive:
        poses = {name: archive[name] for name in ("global_orient", "transl", "pose", "frames")}
    count = len(poses["frames"])
    if poses["pose"].shape != (count, 16, 3) or poses["transl"].shape != (count, 3):
        raise AvatarFolderError(f"{path}: inconsistent pose arrays")
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
