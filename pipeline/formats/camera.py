"""The one conversion between our camera (OpenCV) and Blender's camera (numpy only).

Our convention (DESIGN.md): pinhole intrinsics K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in
pixels, with the pixel grid's origin at the top-left corner of the top-left pixel (so the image
centre is (width / 2, height / 2)); extrinsics x_cam = R @ x_world + t with the camera frame
x right, y down, z forward. Blender's camera looks down its local -Z with +Y up. `synth/`,
`harp_addon/` and the renderer's Blender cross-check all go through these functions.
"""
from __future__ import annotations

import numpy as np

SENSOR_WIDTH_MM = 36.0
OPENCV_TO_BLENDER_AXES = np.diag([1.0, -1.0, -1.0])  # camera-frame axis flip, its own inverse


def intrinsics_from_fov(width, height, horizontal_fov_deg):
    """K of a centred pinhole camera with square pixels and the given horizontal field of view."""
    fx = 0.5 * width / np.tan(0.5 * np.radians(horizontal_fov_deg))
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


def blender_camera_settings(K, width, height):
    """Blender camera data settings reproducing K at the given resolution.

    Returns a dict of `camera.data` settings: lens, sensor_width, sensor_fit, shift_x, shift_y.
    Pixels must be square (fx == fy), as they are for phone and webcam footage."""
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if fx <= 0 or fy <= 0:
        raise ValueError(f"focal lengths must be positive, got fx={fx}, fy={fy}")
    if abs(fx - fy) > 1e-6 * fx:
        raise ValueError(f"non-square pixels (fx={fx}, fy={fy}) are not supported")
    # The sensor is fitted to the image width, so the focal length in pixels is
    # lens * width / sensor_width and both shifts are fractions of the width.
    lens = fx * SENSOR_WIDTH_MM / width
    return {
        "lens": lens,
        "sensor_width": SENSOR_WIDTH_MM,
        "sensor_fit": "HORIZONTAL",
        "shift_x": (width / 2.0 - cx) / width,
        "shift_y": (cy - height / 2.0) / width,
    }


def blender_camera_matrix_world(R, t):
    """4x4 matrix_world of a Blender camera object for OpenCV extrinsics (world -> camera)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    matrix = np.eye(4)
    matrix[:3, :3] = R.T @ OPENCV_TO_BLENDER_AXES
    matrix[:3, 3] = -R.T @ t
    return matrix


def opencv_extrinsics_from_blender(matrix_world):
    """Inverse of blender_camera_matrix_world: (R, t) from a camera's matrix_world (no scale)."""
    matrix_world = np.asarray(matrix_world, dtype=np.float64)
    R = (matrix_world[:3, :3] @ OPENCV_TO_BLENDER_AXES).T
    t = -R @ matrix_world[:3, 3]
    return R, t


def project(points, K, R=None, t=None):
    """Pixel coordinates (N, 2) and depths (N,) of world points under K and [R | t]."""
    points = np.asarray(points, dtype=np.float64)
    cam = points if R is None else points @ np.asarray(R).T + np.asarray(t).reshape(1, 3)
    uvw = cam @ np.asarray(K).T
    return uvw[:, :2] / uvw[:, 2:3], cam[:, 2]
