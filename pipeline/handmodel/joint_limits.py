"""Anatomical joint limits as a smooth, differentiable prior for fitting.

Each of the 16 joints has a range per local axis-angle component (flexion about the bone's x,
twist about y, deviation about z; ranges in anatomy.joint_limits_deg, documented in
docs/hand_model.md). The prior is a squared hinge: zero inside the range, growing
quadratically outside (continuous gradient), in radians squared.
"""
from __future__ import annotations

import torch


def joint_limit_penalty(pose, limits):
    """pose (B, 16, 3) local axis-angle, limits (16, 3, 2) radians -> (B,) penalty."""
    lower, upper = limits[..., 0], limits[..., 1]
    over = torch.relu(pose - upper)
    under = torch.relu(lower - pose)
    return (over * over + under * under).sum(dim=(-1, -2))

