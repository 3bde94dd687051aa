"""A small numpy/OpenCV mesh painter for pictures of meshes (no gradients, no torch).

Faces are sorted back to front and filled with OpenCV at 2x resolution, then downsampled:
simple, dependable and fast enough for previews of a few ten-thousand faces. The
differentiable renderer used for fitting is a different module.
"""
from __future__ import annotations

import cv2
import numpy as np


def look_at_rotation(view_direction, up=(0.0, 1.0, 0.0)):
    """World-to-camera rotation (OpenCV camera: x right, y down, z forward) looking along
    `view_direction` with `up` pointing up in the image."""
    forward = np.asarray(view_direction, dtype=np.float64)
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-8:
        right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


def paint_mesh(vertices, faces, rotation, size=320, face_colours=None, light=(0.3, -0.5, -1.0),
               background=(255, 255, 255), margin=0.08, extent=None, centre=None):
    """Orthographic picture of a mesh seen through `rotation` (3x3, world -> camera).

    face_colours: (F, 3) RGB in [0, 1] (default light grey). Returns an (size, size, 3) uint8
    RGB image. `extent`/`centre` fix the framing (metres across, world point in the middle)."""
    scale_up = 2
    cam = vertices @ rotation.T
    if centre is None:
        centre_cam = 0.5 * (cam.min(0) + cam.max(0))
    else:
        centre_cam = np.asarray(centre) @ rotation.T
    if extent is None:
        extent = (cam[:, :2].max(0) - cam[:, :2].min(0)).max() * (1 + 2 * margin)
    pixels_per_metre = size * scale_up / extent
    xy = (cam[:, :2] - centre_cam[:2]) * pixels_per_metre + size * scale_up / 2
    tri = cam[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    light = np.asarray(light, dtype=np.float64)
    light /= np.linalg.norm(light)
    # faces facing away are drawn with their flipped normal (open or thin parts stay visible)
    shade = 0.35 + 0.65 * np.abs(np.clip(normals @ light, -1, 1)) * (normals[:, 2] < 0) \
        + 0.35 * (normals[:, 2] >= 0)
    if face_colours is None:
        face_colours = np.full((len(faces), 3), 0.85)
    colours = np.clip(face_colours * shade[:, None], 0, 1)
    order = np.argsort(-tri[:, :, 2].mean(1))
    canvas = np.empty((size * scale_up, size * scale_up, 3), np.uint8)
    canvas[:] = background
    polygons = np.round(xy[faces] * 16).astype(np.int32)
    bgr = (colours[:, ::-1] * 255).astype(np.uint8)
    for f in order:
        if normals[f, 2] < 0:
            cv2.fillConvexPoly(canvas, polygons[f], bgr[f].tolist(), lineType=cv2.LINE_8, shift=4)
    canvas = cv2.resize(canvas, (size, size), interpolation=cv2.INTER_AREA)
    return canvas[:, :, ::-1].copy()


def checker_colours(uvs, faces_uv, squares=8):
    """Per-face colours of a UV checker (sampled at each face's UV centroid)."""
    centre = uvs[faces_uv].mean(1)
    cells = np.floor(centre * squares).astype(int)
    odd = (cells[:, 0] + cells[:, 1]) % 2 == 1
    hue = (cells[:, 0] * 0.13 + cells[:, 1] * 0.07) % 1.0
    base = np.stack([0.55 + 0.4 * np.cos(2 * np.pi * hue), 0.55 + 0.4 * np.cos(2 * np.pi * (hue + 1 / 3)),
                     0.55 + 0.4 * np.cos(2 * np.pi * (hue + 2 / 3))], axis=1)
    return np.where(odd[:, None], base, 0.25 + 0.2 * base)


def label(image, text, scale=0.45):
    """Write a caption in the top-left corner (in place) and return the image: dark text on a
    light corner, light text on a dark one."""
    corner = image[4:22, 4:4 + 8 * len(text)]
    colour = (30, 30, 30) if corner.size == 0 or corner.mean() > 110 else (235, 235, 235)
    cv2.putText(image, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)
    return image
