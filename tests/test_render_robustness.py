"""Bad geometry never produces NaN or Inf, in images or in gradients; the camera's pixel rays invert its projection."""
import numpy as np
import pytest
import torch

from pipeline.render.antialias import edge_topology
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from render_meshes import icosphere, intrinsics, sphere_uvs

SIZE = 40
K = intrinsics(50.0, SIZE, SIZE)


def sphere(centre, radius=0.1, extra_faces=None):
    vertices, faces = icosphere(2)
    if extra_faces is not None:
        faces = np.concatenate([faces, extra_faces])
    faces = torch.tensor(faces)
    points = torch.tensor(vertices * radius + np.array(centre))[None]
    mesh = RenderMesh(faces, torch.tensor(sphere_uvs(vertices)), faces, edge_topology(faces))
    return points, mesh


CASES = {
    "in view": ((0.0, 0.0, 0.5), None, 0.1),
    "behind the camera": ((0.0, 0.0, -0.5), None, 0.1),
    "off screen": ((3.0, -2.0, 0.5), None, 0.1),
    "crossing the near plane": ((0.0, 0.0, 0.02), None, 0.1),
    "around the camera": ((0.0, 0.0, 0.0), None, 0.1),
    "degenerate faces": ((0.0, 0.0, 0.5), np.array([[0, 0, 1], [3, 3, 3], [0, 1, 1]]), 0.1),
    "sub-pixel triangles": ((0.0, 0.0, 3.0), None, 0.002),
    "filling the view": ((0.0, 0.0, 0.12), None, 0.1),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("shadows", [False, True])
@pytest.mark.parametrize("fused", [True, False])
def test_finite_images_and_gradients(case, shadows, fused):
    centre, extra, radius = CASES[case]
    points, mesh = sphere(centre, radius, extra)
    points = points.clone().requires_grad_(True)
    albedo = torch.full((3, 8, 8), 0.6, dtype=torch.float64, requires_grad=True)
    normal_map = torch.zeros(3, 8, 8, dtype=torch.float64)
    normal_map[2] = 1.0
    normal_map[:, 0, 0] = 0.0            # a zero vector in the normal map
    normal_map.requires_grad_(True)
    light_position = torch.tensor(centre, dtype=torch.float64) + torch.tensor([0.0, 0.0, -radius])  # on the surface
    light_position.requires_grad_(True)
    ambient = torch.tensor(0.4, dtype=torch.float64, requires_grad=True)
    images = render(points, mesh, K, SIZE, SIZE, outputs=("alpha", "rgb", "depth", "normal", "albedo"),
                    appearance=Appearance(albedo, normal_map), light=Light(light_position, ambient, shadows=shadows, shadow_resolution=32),
                    background=torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64), fused=fused)
    for name, image in images.items():
        finite = torch.isfinite(image) | (name == "depth")
        assert finite.all(), name
    loss = sum(images[name].sum() for name in ("alpha", "rgb", "normal", "albedo"))
    loss.backward()
    for tensor in (points, albedo, normal_map, light_position, ambient):
        assert tensor.grad is None or torch.isfinite(tensor.grad).all()
    if case in ("behind the camera", "off screen"):
        assert images["alpha"].abs().max() == 0
        assert torch.allclose(images["rgb"], torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64))
    if case == "in view":
        assert images["alpha"].sum() > 50


def test_empty_batch_of_frames():
    points, mesh = sphere((0.0, 0.0, -1.0))
    images = render(points.expand(3, -1, -1), mesh, K, SIZE, SIZE, outputs=("alpha",))
    assert images["alpha"].shape == (3, SIZE, SIZE, 1) and images["alpha"].sum() == 0


@pytest.mark.parametrize("fused", [True, False])
def test_only_requested_work_is_done(monkeypatch, fused):
    """A silhouette-only call samples no texture and shades nothing; shadows off never builds a
    shadow map."""
    import dataclasses

    import pipeline.render.renderer as renderer

    def forbidden(*args, **kwargs):
        raise AssertionError("work that was not requested")

    points, mesh = sphere((0.0, 0.0, 0.5))
    appearance = Appearance(torch.full((3, 8, 8), 0.6, dtype=torch.float64))
    light = Light(torch.tensor([0.2, 0.0, 0.0], dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64))
    path = "FUSED" if fused else "REFERENCE"
    primitives = getattr(renderer, path)
    monkeypatch.setattr(renderer, path, dataclasses.replace(
        primitives, vertex_normals=forbidden, shadow_visibility=forbidden, uv_tangents=forbidden,
        perturbed_normal=forbidden, lit_colour=forbidden))
    monkeypatch.setattr(renderer, "sample_texture", forbidden)
    render(points, mesh, K, SIZE, SIZE, outputs=("alpha",), appearance=appearance, light=light, fused=fused)
    monkeypatch.undo()
    monkeypatch.setattr(renderer, path, dataclasses.replace(    # no normal map: no tangents
        primitives, shadow_visibility=forbidden, uv_tangents=forbidden, perturbed_normal=forbidden))
    render(points, mesh, K, SIZE, SIZE, outputs=("rgb",), appearance=appearance, light=light, fused=fused)


def test_unknown_output_is_refused():
    points, mesh = sphere((0.0, 0.0, 0.5))
    with pytest.raises(ValueError, match="unknown render outputs"):
        render(points, mesh, K, SIZE, SIZE, outputs=("alpha", "specular"))


def test_pixel_rays_are_the_projections_inverse():
    """A point at depth z along a pixel's ray projects onto that pixel's centre, per frame's K."""
    from pipeline.render.rasterize import pixel_rays, project
    K = torch.tensor([[[100.0, 0, 31.5], [0, 120.0, 20.0], [0, 0, 1]],
                      [[80.0, 0, 10.0], [0, 80.0, 12.5], [0, 0, 1]]], dtype=torch.float64)
    rays = pixel_rays(K, 2, 24, 40, torch.float64, "cpu")
    assert rays.shape == (2, 24, 40, 3) and torch.all(rays[..., 2] == 1)
    points = rays * torch.linspace(0.2, 3.0, 24, dtype=torch.float64)[None, :, None, None]
    pixels = project(points.reshape(2, -1, 3), K).reshape(2, 24, 40, 2)
    rows, columns = torch.meshgrid(torch.arange(24.0) + 0.5, torch.arange(40.0) + 0.5, indexing="ij")
    assert torch.allclose(pixels, torch.stack([columns, rows], -1).double().expand_as(pixels), atol=1e-9)
