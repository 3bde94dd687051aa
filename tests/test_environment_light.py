"""The environment light's formulas (formats/environment_light.py, render/shading.py) against
numerical integration over the sphere, and its path through the renderer."""
import math

import numpy as np
import torch

from pipeline.formats import environment_light as el
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from pipeline.render.shading import environment_shading


def sphere_quadrature(count=400):
    """(directions (N, 3), solid angles (N,)) of a latitude-longitude grid over the unit sphere."""
    theta = (np.arange(count) + 0.5) / count * math.pi
    phi = (np.arange(2 * count) + 0.5) / (2 * count) * 2 * math.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    directions = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    weights = (np.sin(t) * (math.pi / count) * (2 * math.pi / (2 * count))).reshape(-1)
    return directions, weights


def test_the_basis_is_orthonormal_over_the_sphere():
    directions, weights = sphere_quadrature()
    values = np.stack(el.basis(*directions.T), axis=1)
    gram = values.T @ (values * weights[:, None])
    assert np.abs(gram - np.eye(el.COEFFICIENTS)).max() < 1e-4


def test_the_worlds_radiance_gives_the_shading_factor_on_a_lambertian_surface():
    """(1 / pi) * integral of radiance(w) max(0, n . w) dw = a + sum_k c_k Y_k(n): the band weights
    A_l that turn the fit's factor into the radiance Blender's world needs."""
    rng = np.random.default_rng(0)
    coefficients = rng.normal(0, 0.05, (el.COEFFICIENTS, 3))
    ambient = 0.6                     # the radiance stays positive: no clipping
    directions, weights = sphere_quadrature()
    radiance = el.radiance(directions, coefficients, ambient)
    assert radiance.min() > 0
    normals = rng.normal(size=(20, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cosine = np.clip(normals @ directions.T, 0, None)                    # (20, N)
    integrated = (cosine * weights) @ radiance / math.pi
    assert np.abs(integrated - (ambient + el.shading_factor(normals, coefficients))).max() < 2e-4


def test_the_relative_strength_is_zero_for_a_uniform_room_and_scales_with_the_light():
    assert el.relative_strength(np.zeros((8, 3)), 0.5) == 0.0
    coefficients = np.zeros((8, 3))
    coefficients[2] = 0.1
    directions, weights = sphere_quadrature(200)
    rms = math.sqrt((el.shading_factor(directions, coefficients)[:, 0] ** 2 * weights).sum() / (4 * math.pi))
    assert abs(el.relative_strength(coefficients, 0.5) - rms / 0.5) < 1e-4


def test_the_description_round_trips_and_refuses_bad_values():
    coefficients = np.arange(24.0).reshape(8, 3) / 100
    assert np.array_equal(el.from_description({"environment": el.to_description(coefficients)}), coefficients)
    assert el.from_description({}) is None and el.to_description(None) is None
    for bad in ([[0.0] * 3] * 7, [[float("nan")] * 3] * 8):
        try:
            el.from_description({"environment": bad})
        except ValueError as error:
            assert "8 x 3" in str(error)
        else:
            raise AssertionError("a malformed environment was accepted")


def test_the_torch_shading_matches_the_formula_and_the_renderer_adds_it():
    rng = np.random.default_rng(1)
    coefficients = rng.normal(0, 0.1, (8, 3))
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    torch_values = environment_shading(torch.as_tensor(normals), torch.as_tensor(coefficients))
    assert np.allclose(torch_values.numpy(), el.shading_factor(normals, coefficients), atol=1e-12)
    # a square facing the camera (normal -z), lit by the ambient and the environment only (the
    # point light behind it): every pixel is albedo * (a + E(-z))
    points = torch.tensor([[[-1.0, -1.0, 3.0], [1.0, -1.0, 3.0], [1.0, 1.0, 3.0], [-1.0, 1.0, 3.0]]],
                          dtype=torch.float64)
    faces = torch.tensor([[0, 2, 1], [0, 3, 2]])
    mesh = RenderMesh(faces, torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], dtype=torch.float64), faces)
    K = torch.tensor([[20.0, 0, 16], [0, 20.0, 16], [0, 0, 1]], dtype=torch.float64)
    albedo = torch.tensor([0.8, 0.6, 0.5], dtype=torch.float64)[:, None, None].expand(3, 8, 8).clone()
    env = torch.as_tensor(coefficients)
    for fused in (True, False):
        image = render(points, mesh, K, 32, 32, outputs=("rgb",), appearance=Appearance(albedo), fused=fused,
                       light=Light(torch.tensor([0.0, 0.0, 10.0], dtype=torch.float64),
                                   torch.tensor(0.5, dtype=torch.float64), environment=env),
                       antialiased=False)["rgb"][0, 16, 16]
        facing = el.shading_factor(np.array([[0.0, 0.0, -1.0]]), coefficients)[0]
        assert np.allclose(image.numpy(), albedo[:, 0, 0].numpy() * (0.5 + facing), atol=1e-9)


def test_the_sphere_directions_are_unit_and_evenly_spread():
    directions = el.sphere_directions(256)
    assert np.abs(np.linalg.norm(directions, axis=1) - 1).max() < 1e-12
    assert np.abs(directions.mean(0)).max() < 0.01                              # no side favoured
    assert np.abs(directions.T @ directions / len(directions) - np.eye(3) / 3).max() < 0.01
    # no direction farther than a few degrees from its nearest neighbour
    cosine = directions @ directions.T
    np.fill_diagonal(cosine, -1)
    assert np.degrees(np.arccos(cosine.max(1))).max() < 15


def test_the_unclipped_radiance_is_the_radiance_where_it_is_positive_and_the_basis_its_columns():
    rng = np.random.default_rng(1)
    coefficients = rng.normal(0, 0.3, (el.COEFFICIENTS, 3))
    directions = el.sphere_directions(500)
    unclipped = el.unclipped_radiance(directions, coefficients, 0.2)
    assert unclipped.min() < 0 < unclipped.max()                               # the case worth testing
    assert np.array_equal(el.radiance(directions, coefficients, 0.2), np.clip(unclipped, 0, None))
    columns = np.stack(el.radiance_basis(*directions.T), axis=1)
    assert np.abs(0.2 + columns @ coefficients - unclipped).max() < 1e-12
    # torch takes the same functions
    as_torch = torch.stack(el.radiance_basis(*torch.as_tensor(directions).T), dim=1).numpy()
    assert np.abs(as_torch - columns).max() < 1e-12
