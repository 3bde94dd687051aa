"""`harp model preview`: one picture of the hand model in both modes and several poses."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from .handmodel.lbs import HandModel
from .handmodel.poses import NAMED_POSES
from .handmodel.uv_atlas import uv_mask
from .preview_render import checker_colours, label, look_at_rotation, paint_mesh

VIEWS = {  # name: (pose, view direction (camera looks along it), up)
    "front (palm)": ("rest", (0, 0, -1), (0, 1, 0)),
    "side (thumb)": ("rest", (-1, 0, 0), (0, 1, 0)),
    "back": ("rest", (0, 0, 1), (0, 1, 0)),
    "fist": ("fist", (-0.5, 0, -1), (0, 1, 0)),
    "spread": ("spread", (0, 0, -1), (0, 1, 0)),
    "thumbs-up": ("thumbs_up", (-1, 0, 0.3), (0, 1, 0)),
    "pinch": ("pinch", (-0.6, -0.2, -1), (0, 1, 0)),
}


def preview_image(size=300, side="right", folder=None):
    """(H, W, 3) uint8 RGB: rows hand-only and hand+forearm, columns the VIEWS and a UV checker."""
    rows = []
    for mode in ("hand", "arm"):
        model = HandModel.load(mode, side=side, subdivided=True, dtype=torch.float64, folder=folder)
        pose_names = sorted({pose for pose, _, _ in VIEWS.values()})
        poses = torch.as_tensor(np.stack([NAMED_POSES[p] for p in pose_names]))
        if side == "left":
            from .handmodel.mirror import mirror_axis_angle
            poses = mirror_axis_angle(poses)
        with torch.no_grad():
            vertices = model(pose=poses).vertices.numpy()
        faces = model.data.faces
        extent = 0.24 if mode == "hand" else 0.52
        tiles = []
        for title, (pose, direction, up) in VIEWS.items():
            v = vertices[pose_names.index(pose)]
            tile = paint_mesh(v, faces, look_at_rotation(direction, up), size=size, extent=extent,
                              centre=0.5 * (v.min(0) + v.max(0)), face_colours=_skin(len(faces)))
            tiles.append(label(tile, f"{mode}: {title}"))
        v = vertices[pose_names.index("rest")]
        checker = checker_colours(model.data.uvs, model.data.faces_uv)
        tiles.append(label(paint_mesh(v, faces, look_at_rotation((-0.4, 0, 1), (0, 1, 0)), size=size,
                                      extent=extent, centre=0.5 * (v.min(0) + v.max(0)),
                                      face_colours=checker), f"{mode}: UV checker"))
        tiles.append(label(_atlas_tile(model, size), f"{mode}: UV atlas"))
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)


def _skin(count):
    return np.tile(np.array([[0.93, 0.78, 0.70]]), (count, 1))


def _atlas_tile(model, size):
    """The UV layout: the used area (the UV mask) with chart borders drawn."""
    mask = uv_mask(model.data.uvs, model.data.faces_uv, resolution=size, dilation_px=0)
    tile = np.full((size, size, 3), 255, np.uint8)
    tile[mask] = (150, 170, 210)
    edge = mask & ~cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    tile[edge] = (60, 70, 110)
    return tile


def write_preview(path, size=300, side="right", folder=None):
    """Write the preview PNG of the model in `folder` (default: the shipped model)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image = preview_image(size=size, side=side, folder=folder)
    if not cv2.imwrite(str(path), image[:, :, ::-1]):
        raise OSError(f"could not write {path}")
    return path
