"""The shadow test's filter: a shadow's edge is a ramp three shadow-map texels wide, not a
staircase of texels, checked against the analytic ramp of a straight edge."""
import math

import pytest
import torch

from pipeline.render import shadow_map

RESOLUTION = 32
RADIUS = 0.11
TARGET = torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)


def _edge_scene():
    """A receiving square at z = 0.5 and, 5 cm nearer the light (on the axis, behind the
    camera's side at z = -1), an occluding square over x < 0: the shadow's edge on the receiver is
    the line x = 0, which the light's camera sees on the boundary between two texel columns."""
    def square(x0, x1, z):
        return [[x0, -0.1, z], [x1, -0.1, z], [x1, 0.1, z], [x0, 0.1, z]]

    points = torch.tensor([square(-0.1, 0.1, 0.5) + square(-0.1, 0.0, 0.45)], dtype=torch.float64)
    faces = torch.tensor([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]])   # facing the light
    return points, faces, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)


def _texels_from_edge(x, depth_from_light):
    """Where a receiver at x (m) projects in the shadow map, in texels from the edge's column."""
    half_angle = math.asin(RADIUS * 1.05 / shadow_map.LIGHT_DISTANCE)
    focal = (RESOLUTION / 2) / math.tan(half_angle)
    return focal * x / depth_from_light


def test_a_straight_shadow_edge_is_a_ramp_three_texels_wide():
    points, faces, light = _edge_scene()
    x = torch.linspace(-0.018, 0.018, 361, dtype=torch.float64)
    receivers = torch.stack([x, torch.full_like(x, 0.013), torch.full_like(x, 0.5)], dim=1)
    visibility = shadow_map.shadow_visibility(points, faces, receivers, torch.zeros(len(x), dtype=torch.long),
                                              light, RESOLUTION, TARGET, RADIUS)[:, 0]
    offset = _texels_from_edge(x, 1.5)
    lit = torch.sigmoid(torch.tensor(shadow_map.SHARPNESS * shadow_map.BIAS, dtype=torch.float64))
    expected = (0.5 + offset / 3).clamp(0, 1) * lit
    assert offset.min() < -2 and offset.max() > 2
    assert torch.allclose(visibility, expected, atol=1e-4)
    steps = visibility.diff()
    assert (steps >= -1e-12).all() and steps.max() < 0.02   # no jump of a third, as a texel's box gave


def test_the_filter_is_the_texel_box_at_a_texel_centre_and_blends_towards_the_next_texels():
    centre = torch.tensor([[5.5, 7.5]], dtype=torch.float64)
    first, weights = shadow_map.filter_taps(centre)
    assert first.tolist() == [[4, 6]]
    box = torch.zeros(4, 4, dtype=torch.float64)
    box[:3, :3] = 1 / 9
    assert torch.allclose(weights.view(4, 4), box)
    place = torch.tensor([[5.8, 7.6]], dtype=torch.float64, requires_grad=True)
    first, weights = shadow_map.filter_taps(place)
    columns = torch.tensor([0.7, 1, 1, 0.3], dtype=torch.float64) / 3      # 0.3 of a texel past column 5's centre
    rows = torch.tensor([0.9, 1, 1, 0.1], dtype=torch.float64) / 3         # 0.1 past row 7's
    assert first.tolist() == [[4, 6]]
    assert torch.allclose(weights.view(4, 4), rows[:, None] * columns[None, :])
    assert not weights.requires_grad        # the occluders' edges in the map do not move either
