"""Smoothing a fitted motion's keys (numpy only: the Blender add-on and `harp blend` use it at
bind time, the fit never does).

Each channel is replaced by a local quadratic fitted by least squares over the keys within
`window` frames centred on it (a Savitzky-Golay filter written for keys at any frame numbers:
a clip with held-out frames has gaps, and the windows at the clip's ends are one-sided instead
of padded). A quadratic keeps the peaks and the timing of a motion that a moving average
flattens and shifts. Rotations are smoothed as unit quaternions: signs made continuous first,
the four components filtered, then normalised (for the small changes between nearby keys this is
the rotation average); translations are filtered directly.

    smoothed = smooth_poses(files.poses, window=7)       # AvatarPoses in, AvatarPoses out
"""
from __future__ import annotations

import dataclasses

import numpy as np

from . import rotations

ORDER = 2              # the local polynomial's degree
MIN_WINDOW = 5         # a quadratic through 3 keys is the keys themselves; 0 or 1 switches it off


class SmoothingError(ValueError):
    """A smoothing window that cannot be applied (one-line message)."""


def check_window(window):
    """The window (frames) as an int: 0 or 1 (off), or an odd number >= MIN_WINDOW."""
    if isinstance(window, float) and not window.is_integer():
        raise SmoothingError(f"smoothing window {window} is not a whole number of frames")
    window = int(window)
    if window in (0, 1):
        return 0
    if window < MIN_WINDOW or window % 2 == 0:
        raise SmoothingError(f"smoothing window {window}: give 0 (off) or an odd number of frames, at least "
                             f"{MIN_WINDOW}")
    return window


def smooth_series(values, frames, window, order=ORDER):
    """(F, C) values at the frame numbers `frames` (F,), increasing: each replaced by the value at
    its frame of the degree-`order` polynomial fitted to the values whose frames lie within
    window // 2 of it (at least order + 1 of them: near the ends and across gaps the nearest keys
    are taken)."""
    values = np.asarray(values, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.float64)
    window = check_window(window)
    if window == 0 or len(frames) <= order:
        return values.copy()
    if np.any(np.diff(frames) <= 0):
        raise SmoothingError("the keys' frame numbers must increase")
    half = window // 2
    smoothed = np.empty_like(values)
    for index, frame in enumerate(frames):
        near = np.flatnonzero(np.abs(frames - frame) <= half)
        if len(near) < order + 1:
            near = np.sort(np.argsort(np.abs(frames - frame), kind="stable")[:order + 1])
        offsets = frames[near] - frame
        design = np.vander(offsets, order + 1, increasing=True)       # columns 1, t, t^2
        coefficients = np.linalg.lstsq(design, values[near], rcond=None)[0]
        smoothed[index] = coefficients[0]                              # the polynomial at t = 0
    return smoothed


def smooth_rotations(axis_angle, frames, window):
    """(F, ..., 3) axis-angle rotations over the keys at `frames`, smoothed as unit quaternions."""
    axis_angle = np.asarray(axis_angle, dtype=np.float64)
    if check_window(window) == 0:
        return axis_angle.copy()
    quaternions = continuous_quaternions(rotations.axis_angle_to_quaternion(axis_angle))
    shape = quaternions.shape
    flat = smooth_series(quaternions.reshape(shape[0], -1), frames, window).reshape(shape)
    flat /= np.maximum(np.linalg.norm(flat, axis=-1, keepdims=True), 1e-12)
    return rotations.quaternion_to_axis_angle(flat)


def continuous_quaternions(quaternions):
    """(F, ..., 4) quaternions with signs flipped where needed so each agrees with the one before
    it (q and -q are the same rotation; a filter or a linear key needs the nearer one)."""
    q = np.array(quaternions, dtype=np.float64)
    for index in range(1, len(q)):
        flip = (q[index] * q[index - 1]).sum(-1, keepdims=True) < 0
        q[index] = np.where(flip, -q[index], q[index])
    return q


def smooth_poses(poses, window):
    """An avatar_folder.AvatarPoses with every rotation and the translation smoothed over
    `window` frames (0: unchanged)."""
    frames = np.asarray(poses.frames)
    return dataclasses.replace(
        poses, global_orient=smooth_rotations(poses.global_orient, frames, window),
        pose=smooth_rotations(poses.pose, frames, window),
        transl=smooth_series(poses.transl, frames, window))
