"""A light with a size (render/area_light.py): its points cover the disc evenly, a point light is
what it was, and the penumbra of a straight edge is the analytic share of the disc the edge leaves
in view."""
import math

import torch

from edge_scene import edge_scene
from pipeline.render import area_light, shadow_map
from pipeline.render.renderer import Appearance, Light, render

TARGET = torch.tensor([0.0, 0.0, 0.475], dtype=torch.float64)
SLANT = math.pi / 4           # the light's direction from the hand: 45 degrees off the view axis, from the left
HEIGHT = 0.05                 # the occluder's height above the receiver


def test_the_disc_points_are_spread_evenly_over_the_unit_disc():
    offsets = area_light.disc_offsets(64, torch.float64)
    radius = offsets.norm(dim=-1)
    assert radius.max() < 1 and radius.min() > 0
    assert offsets.mean(0).abs().max() < 0.02                          # centred
    assert abs(radius.square().mean().item() - 0.5) < 1e-3            # a uniform disc's second moment
    for wedge in range(4):                                             # as many in each quarter
        angle = torch.atan2(offsets[:, 1], offsets[:, 0]) % (2 * math.pi)
        assert abs(int(((angle >= wedge * math.pi / 2) & (angle < (wedge + 1) * math.pi / 2)).sum()) - 16) <= 1


def test_the_points_lie_on_a_disc_of_the_angular_radius_facing_the_centre():
    position = torch.tensor([0.3, -0.4, 0.0], dtype=torch.float64)
    centre = torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)
    points = torch.stack(area_light.light_points(position, centre, 0.2, 32))
    towards = (position - centre) / (position - centre).norm()
    assert ((points - position) @ towards).abs().max() < 1e-12        # in the plane facing the centre
    angles = torch.acos(((points - centre) / (points - centre).norm(dim=-1, keepdim=True)) @ towards)
    assert angles.max() < 0.2 and angles.max() > 0.18
    assert area_light.light_points(position, centre, 0.0, 32) == [position]


def _visibility_along_a_row(angular_radius, samples=64):
    """(x of the receiver's points along the image row through y = 0, their light visibility)."""
    points, mesh = edge_scene(HEIGHT)
    position = TARGET + 1.0 * torch.tensor([-math.sin(SLANT), 0.0, -math.cos(SLANT)], dtype=torch.float64)
    light = Light(position, torch.tensor(0.2, dtype=torch.float64), shadows=True, shadow_resolution=512,
                  shadow_target=TARGET, shadow_radius=0.15, angular_radius=angular_radius, samples=samples)
    K = torch.tensor([[500.0, 0, 128], [0, 500.0, 128], [0, 0, 1]], dtype=torch.float64)
    images = render(points, mesh, K, 256, 256, outputs=("rgb", "position", "light_visibility"),
                    appearance=Appearance(torch.ones(3, 4, 4, dtype=torch.float64)), light=light, antialiased=False)
    row = images["position"][0, 128]
    on_receiver = (row[:, 2] - 0.5).abs() < 1e-9
    return row[on_receiver, 0], images["light_visibility"][0, 128, on_receiver, 0]


def _light_angle(x):
    """The angle off the view axis (towards -x) under which a receiver point at x sees the
    light's centre as the shadow map casts it: from the shadow camera's eye, LIGHT_DISTANCE from
    the target along the light's direction (its shadows are a point light's there)."""
    eye = TARGET + shadow_map.LIGHT_DISTANCE * torch.tensor([-math.sin(SLANT), 0.0, -math.cos(SLANT)],
                                                            dtype=torch.float64)
    return torch.atan((x - eye[0]) / (0.5 - eye[2]))


def _disc_share_in_view(x, angular_radius):
    """The share of a disc of light of `angular_radius` around _light_angle(x) that a receiver
    point at x sees past the occluder's edge: the directions nearer the view axis than the edge's,
    atan(x / HEIGHT) (the disc flat in angle, its segment's area)."""
    t = ((torch.atan(x / HEIGHT) - _light_angle(x)) / angular_radius).clamp(-1, 1)
    return 1 - (torch.acos(t) - t * torch.sqrt(1 - t * t)) / math.pi


def test_a_point_light_casts_a_hard_edge():
    x, visibility = _visibility_along_a_row(0.0)
    edge = x[(torch.atan(x / HEIGHT) - _light_angle(x)).abs().argmin()]
    assert (visibility[x < edge - 0.002] < 0.01).all()
    assert (visibility[x > edge + 0.002] > 0.99).all()


def test_an_area_light_casts_the_analytic_penumbra():
    radius = 0.15
    x, visibility = _visibility_along_a_row(radius)
    expected = _disc_share_in_view(x, radius) * torch.sigmoid(torch.tensor(8.0, dtype=torch.float64))
    inside = (x > HEIGHT * math.tan(SLANT - radius)) & (x < HEIGHT * math.tan(SLANT + radius))
    assert inside.sum() > 20                              # the penumbra spans many pixels
    assert (visibility - expected).abs().max() < 0.04
    assert (visibility - expected).abs()[inside].mean() < 0.015
    assert (visibility.diff() >= -0.02).all()             # it brightens across the edge, step by step


def test_an_unshadowed_area_light_shades_as_the_mean_of_its_points():
    points, mesh = edge_scene(HEIGHT)
    position = TARGET + torch.tensor([-0.7, 0.0, -0.7], dtype=torch.float64)
    K = torch.tensor([[500.0, 0, 128], [0, 500.0, 128], [0, 0, 1]], dtype=torch.float64)
    ambient = torch.tensor(0.3, dtype=torch.float64)
    albedo = Appearance(torch.full((3, 4, 4), 0.5, dtype=torch.float64))
    area = render(points, mesh, K, 256, 256, outputs=("rgb",), appearance=albedo,
                  light=Light(position, ambient, shadow_target=TARGET, angular_radius=0.2, samples=8),
                  antialiased=False)["rgb"]
    places = area_light.light_points(position, TARGET, 0.2, 8)
    each = [render(points, mesh, K, 256, 256, outputs=("rgb",), appearance=albedo, light=Light(place, ambient),
                   antialiased=False)["rgb"] for place in places]
    assert torch.allclose(area, torch.stack(each).mean(0), atol=1e-12)
