"""Camera intrinsics and where the hand sits in front of the camera (numpy).

The camera is the world: it sits at the origin looking down +z (OpenCV frame, R = I, t = 0),
and the hand is placed in camera coordinates. A viewpoint is given hand-centred: the camera
looks at the hand's pivot from azimuth/elevation at a distance. Azimuth 0 and elevation 0 see
the back of the hand with the fingers pointing up in the image; azimuth turns the camera
about the hand's long axis (+90: from the thumb side of a right hand), elevation raises it
towards the fingertips.
"""
from __future__ import annotations

import numpy as np

from pipeline.formats.camera import intrinsics_from_fov
from pipeline.formats.rotations import axis_angle_to_matrix, matrix_to_axis_angle

HARP_FOCAL_AT_448 = 2000.0  # pixels (method facts); scaled with the image width by default


def camera_intrinsics(width, height, focal=None, fov=None):
    """K (3, 3) from a focal length in pixels or a horizontal field of view in degrees
    (default: HARP's 2000 px at 448 px width, scaled with the width); principal point centred."""
    if focal is not None and fov is not None:
        raise ValueError("give either a focal length or a field of view, not both")
    if fov is None:
        focal = HARP_FOCAL_AT_448 * width / 448 if focal is None else focal
        fov = 2 * np.degrees(np.arctan(0.5 * width / focal))
    return intrinsics_from_fov(width, height, fov)


def view_rotation(azimuth_deg, elevation_deg):
    """Model-to-camera rotation (3, 3) of the hand seen from azimuth/elevation (degrees)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    to_camera = np.array([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)])  # model space
    forward = -to_camera
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


def fit_distance(K, width, height, radius, fill=0.85):
    """Distance (metres) at which a sphere of `radius` metres around the pivot fills `fill` of
    the smaller half-extent of the image."""
    half = 0.5 * min(width, height) * fill
    return float(K[0, 0] * radius / half)


def place_hand(view, rotations, pivot, distance):
    """Per-frame global_orient (F, 3) and transl (F, 3) putting the model-space `pivot` (3,) at
    depth `distance` on the optical axis, the hand turned by `rotations` (F, 3) (model space,
    about the pivot) and then seen through `view` (3, 3)."""
    R = view @ axis_angle_to_matrix(rotations)                         # (F, 3, 3)
    transl = np.array([0.0, 0.0, distance]) - R @ np.asarray(pivot)
    return matrix_to_axis_angle(R), transl
