"""Smoothing the keys at bind time (pipeline/formats/pose_smoothing.py) against analytic cases:
a quadratic passes unchanged, a noisy smooth motion comes closer to its truth with most of the
jitter gone, and rotations are treated as rotations (signs, the long way round)."""
import numpy as np
import pytest

from pipeline.formats import rotations
from pipeline.formats.avatar_folder import AvatarPoses
from pipeline.formats.pose_smoothing import (SmoothingError, check_window, smooth_poses, smooth_rotations,
                                             smooth_series)


def test_a_quadratic_passes_unchanged_at_the_ends_and_across_gaps():
    frames = np.array([0, 1, 2, 4, 5, 6, 7, 9, 10, 11, 14, 15])
    values = np.stack([3 - 0.5 * frames + 0.02 * frames ** 2, np.full(len(frames), 2.0)], 1)
    assert smooth_series(values, frames, 7) == pytest.approx(values, abs=1e-10)


def test_noise_on_a_smooth_motion_is_mostly_removed_and_the_truth_comes_closer():
    rng = np.random.default_rng(0)
    frames = np.arange(120)
    truth = np.stack([np.sin(frames / 15), np.cos(frames / 20), 0.3 * np.sin(frames / 9)], 1)
    noisy = truth + rng.normal(0, 0.05, truth.shape)
    smoothed = smooth_series(noisy, frames, 9)

    def acceleration(x):
        return np.abs(np.diff(x, 2, axis=0)).mean()

    assert acceleration(smoothed) < 0.25 * acceleration(noisy)
    assert np.abs(smoothed - truth).mean() < 0.6 * np.abs(noisy - truth).mean()


def test_rotations_are_smoothed_as_rotations_through_the_half_turn():
    # a steady turn about z through 180 degrees: axis-angle jumps from +pi to -pi there, the rotation does not
    frames = np.arange(30)
    angles = np.radians(150 + 2.0 * frames)
    axis_angle = rotations.quaternion_to_axis_angle(np.stack([np.cos(angles / 2), 0 * angles, 0 * angles,
                                                              np.sin(angles / 2)], 1))
    assert np.abs(np.diff(axis_angle[:, 2])).max() > 6          # the jump is in the input
    smoothed = smooth_rotations(axis_angle, frames, 7)
    # a steady turn is linear in angle: smoothing returns it (up to the quaternion average's tiny bias)
    q, expected = rotations.axis_angle_to_quaternion(smoothed), rotations.axis_angle_to_quaternion(axis_angle)
    assert np.abs(np.abs((q * expected).sum(-1)) - 1).max() < 1e-6


def test_smoothed_poses_keep_their_frames_and_shapes():
    rng = np.random.default_rng(1)
    frames = np.array([0, 1, 2, 3, 5, 6, 7, 8])
    poses = AvatarPoses(global_orient=rng.normal(0, 0.1, (8, 3)), transl=rng.normal(0, 0.01, (8, 3)),
                        pose=rng.normal(0, 0.2, (8, 16, 3)), frames=frames)
    smoothed = smooth_poses(poses, 5)
    assert smoothed.pose.shape == (8, 16, 3) and (smoothed.frames == frames).all()
    assert np.isfinite(smoothed.pose).all() and not np.allclose(smoothed.pose, poses.pose)
    unchanged = smooth_poses(poses, 0)
    assert (unchanged.pose == poses.pose).all() and (unchanged.transl == poses.transl).all()


@pytest.mark.parametrize("window, message", [(4, "odd number"), (3, "at least 5"), (2.5, "whole number"),
                                             (-3, "odd number")])
def test_a_window_that_cannot_be_applied_is_named(window, message):
    with pytest.raises(SmoothingError, match=message):
        check_window(window)


def test_frames_out_of_order_are_refused():
    with pytest.raises(SmoothingError, match="increase"):
        smooth_series(np.zeros((4, 1)), np.array([0, 2, 1, 3]), 5)
