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
    vee = torch.stack([matrix[..., 2, 1] - matrix[..., 1, 2], matrix[..., 0, 2] - matrix[..., 2, 0],
                       matrix[..., 1, 0] - matrix[..., 0, 1]], dim=-1)
    sin = vee.norm(dim=-1) / 2
    cos = (trace - 1) / 2
    angle = torch.atan2(sin, cos)
    # angle / sin -> 1 for small angles; vee carries the axis until the angle nears pi
    scale = torch.where(sin > 1e-12, angle / sin.clamp_min(1e-300), torch.ones_like(sin))
    result = vee / 2 * scale.unsqueeze(-1)
    near_pi = cos < -0.99
    if near_pi.any():
        # the antisymmetric part vanishes at pi: take the axis from the symmetric part instead
        m = matrix[near_pi]
        eye = torch.eye(3, dtype=matrix.dtype, device=matrix.device)
        c = cos[near_pi][:, None, None]
        sym = ((m + m.transpose(-1, -2)) / 2 - c * eye) / (1 - c)  # = axis axis^T
        column = sym.diagonal(dim1=-2, dim2=-1).argmax(-1)
        axis = sym[torch.arange(len(column)), :, column]
        axis = axis / axis.norm(dim=-1, keepdim=True)
        axis = axis * torch.where((axis * vee[near_pi]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
        result = result.clone()
        result[near_pi] = axis * angle[near_pi].unsqueeze(-1)
    return result
