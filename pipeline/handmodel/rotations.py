"""Axis-angle rotations in torch, with finite values and gradients everywhere (0 and pi too)."""
from __future__ import annotations

import torch

SMALL_ANGLE_SQUARED = 1e-6


def skew(v):
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(v.shape + (3,))


def axis_angle_to_matrix(axis_angle):
    """Rodrigues' formula R = I + a K + b K^2 with K = skew(w), a = sin t / t, b = (1 - cos t) / t^2.

    Near t = 0 the coefficients use their Taylor series, so both branches and their gradients
    stay finite (torch.where differentiates both branches)."""
    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True).unsqueeze(-1)
    small = theta2 < SMALL_ANGLE_SQUARED
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(safe2)
    a = torch.where(small, 1 - theta2 / 6 + theta2 * theta2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2 * theta2 / 720, (1 - torch.cos(theta)) / safe2)
    k = skew(axis_angle)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + a * k + b * (k @ k)


def matrix_to_axis_angle(matrix):
    """Inverse of axis_angle_to_matrix (angle in [0, pi]); for data conversion, not for losses."""
    trace = matrix[..., 0, 0] + matrix[..., 1, 1] + matrix[..., 2, 2]
    cos = ((trace - 1) / 2).clamp(-1.0, 1.0)
    angle = torch.acos(cos)
    vee = torch.stack([matrix[..., 2, 1] - matrix[..., 1, 2], matrix[..., 0, 2] - matrix[..., 2, 0],
                       matrix[..., 1, 0] - matrix[..., 0, 1]], dim=-1)
    sin = torch.sin(angle)
    axis = vee / (2 * sin.clamp_min(1e-12)).unsqueeze(-1)
    # near pi the antisymmetric part vanishes: take the axis from the symmetric part instead
    near_pi = cos < -0.999
    if near_pi.any():
        sym = (matrix[near_pi] + torch.eye(3, dtype=matrix.dtype, device=matrix.device)) / 2
        column = sym.diagonal(dim1=-2, dim2=-1).argmax(-1)
        candidate = sym[torch.arange(len(column)), :, column]
        candidate = candidate / candidate.norm(dim=-1, keepdim=True)
        candidate = candidate * torch.where((candidate * vee[near_pi]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
        axis = axis.clone()
        axis[near_pi] = candidate
    small = angle < 1e-6
    return torch.where(small.unsqueeze(-1), vee / 2, axis * angle.unsqueeze(-1))
