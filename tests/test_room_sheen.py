"""The skin's specular lobe as Principled BSDF makes it (render/shading.py): its Fresnel term
against the Fresnel equations, its reflectance of a uniform room (the tabulated
room_sheen_reflectance) against direct quadrature of the lobe over the hemisphere, and the room's
sheen in a render (render/renderer.py: added to the colour, zero at level 0, held back where the
hand keeps the room from a point). Blender's own rendering of the same lobe:
tests/test_blender_specular.py."""
import math

import pytest
import torch

from pipeline.render.shading import (principled_fresnel, room_sheen_reflectance, room_specular,
                                     specular_shading)

DOUBLE = torch.float64


def scalar(value):
    return torch.tensor(value, dtype=DOUBLE)


def fresnel_equations(cosine, eta):
    """The unpolarised reflectance of a dielectric of relative index `eta` for light arriving at
    `cosine` to its normal, from Snell's law and the s and p amplitudes."""
    sine_t = math.sqrt(1 - cosine * cosine) / eta
    cosine_t = math.sqrt(1 - sine_t * sine_t)
    s = (cosine - eta * cosine_t) / (cosine + eta * cosine_t)
    p = (eta * cosine - cosine_t) / (eta * cosine + cosine_t)
    return (s * s + p * p) / 2


@pytest.mark.parametrize("degrees", [0.0, 30.0, 56.31, 60.0, 75.0, 85.0])
def test_fresnel_at_level_one_half_is_that_of_ior_1_5(degrees):
    cosine = math.cos(math.radians(degrees))
    assert principled_fresnel(scalar(cosine), scalar(0.5)).item() == pytest.approx(fresnel_equations(cosine, 1.5),
                                                                                   rel=1e-9)


def test_the_level_scales_the_reflectance_at_normal_incidence_and_grazing_light_still_reflects():
    head_on = scalar(1.0)
    assert principled_fresnel(head_on, scalar(0.5)).item() == pytest.approx(0.04)
    assert principled_fresnel(head_on, scalar(1.0)).item() == pytest.approx(0.08)
    assert principled_fresnel(head_on, scalar(0.25)).item() == pytest.approx(0.02)
    # the index that reflects 2% head on, IOR (1 + sqrt 0.02) / (1 - sqrt 0.02)
    eta = (1 + math.sqrt(0.02)) / (1 - math.sqrt(0.02))
    assert principled_fresnel(scalar(0.3), scalar(0.25)).item() == pytest.approx(fresnel_equations(0.3, eta), rel=1e-9)
    assert principled_fresnel(scalar(0.01), scalar(0.25)).item() > 0.8
    assert principled_fresnel(scalar(0.5), scalar(0.0)).item() < 1e-9


def quadrature(n_v, roughness, level, steps=1500):
    """(1 / pi) * the integral of specular_shading over the hemisphere of light directions (the
    midpoint rule in cos(theta) and phi), for a viewer at n . v = n_v."""
    cosines = (torch.arange(steps, dtype=DOUBLE) + 0.5) / steps
    angles = (torch.arange(2 * steps, dtype=DOUBLE) + 0.5) / (2 * steps) * 2 * math.pi
    c, phi = torch.meshgrid(cosines, angles, indexing="ij")
    s = torch.sqrt(1 - c * c)
    to_light = torch.stack([s * torch.cos(phi), s * torch.sin(phi), c], -1).reshape(-1, 3)
    to_camera = torch.tensor([math.sqrt(1 - n_v * n_v), 0.0, n_v], dtype=DOUBLE).expand_as(to_light)
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=DOUBLE).expand_as(to_light)
    lobe = specular_shading(normal, to_light, to_camera, scalar(roughness), scalar(level))
    return float(lobe.sum() / steps * (math.pi / steps) / math.pi)


@pytest.mark.parametrize("n_v, roughness, level", [(1.0, 0.5, 0.5), (0.6, 0.35, 0.5), (0.4, 0.2, 0.3),
                                                   (0.4, 0.7, 0.9), (0.15, 0.6, 0.2), (0.8, 1.0, 0.35)])
def test_the_tabulated_reflectance_of_a_uniform_room_is_the_lobes_integral(n_v, roughness, level):
    # measured: within 0.3% of the quadrature (importance sampling on a 64 x 64 grid, binned Fresnel)
    tabulated = room_sheen_reflectance(torch.tensor([[n_v]], dtype=DOUBLE), scalar(roughness), scalar(level)).item()
    assert tabulated == pytest.approx(quadrature(n_v, roughness, level), rel=0.01)


def test_the_reflectance_is_differentiable_in_roughness_and_level():
    roughness, level = scalar(0.47).requires_grad_(), scalar(0.3).requires_grad_()   # between two table rows
    n_v = torch.tensor([[0.3], [0.7]], dtype=DOUBLE)
    torch.autograd.gradcheck(lambda r, s: room_sheen_reflectance(n_v, r, s), (roughness, level))


def test_the_room_sheen_follows_the_rooms_radiance_along_the_mirror_direction():
    normal = torch.tensor([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8]], dtype=DOUBLE)
    to_camera = torch.tensor([[0.0, 0.0, -1.0]], dtype=DOUBLE).expand_as(normal)
    roughness, level = scalar(0.5), scalar(0.4)
    uniform = room_specular(normal, to_camera, roughness, level, 0.3)
    n_v = (normal * to_camera).sum(-1, keepdim=True)
    assert torch.allclose(uniform, 0.3 * room_sheen_reflectance(n_v, roughness, level))
    # an environment light brighter towards +x (its x harmonic, the third: formats/environment_light.py)
    # leaves the point that mirrors straight back to the camera as the ambient alone, and brightens
    # the one tilted to +x, whose mirror direction is (0.96, 0, -0.28), by c Y_x = 0.1 sqrt(3 / 4 pi) 0.96
    environment = torch.zeros(8, 3, dtype=DOUBLE)
    environment[2] = 0.1
    lit = room_specular(normal, to_camera, roughness, level, 0.3, environment)
    assert lit.shape == (2, 3)
    assert torch.allclose(lit[0], uniform[0].expand(3))
    expected = (0.3 + 0.1 * math.sqrt(3 / (4 * math.pi)) * 0.96) / 0.3 * uniform[1]
    assert torch.allclose(lit[1], expected.expand(3))
