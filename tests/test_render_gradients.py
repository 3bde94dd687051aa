"""Renderer gradients against finite differences and analytic derivatives (float64)."""
import numpy as np
import pytest
import torch

from pipeline.render import fused, shadow_map
from pipeline.render.antialias import edge_topology
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from render_meshes import icosphere, intrinsics, sphere_uvs

SIZE = 48
K = intrinsics(60.0, SIZE, SIZE)


def sphere_scene(subdivisions=2, radius=0.1, centre=(0.01, -0.005, 0.5)):
    vertices, faces = icosphere(subdivisions)
    points = torch.tensor(vertices * radius + np.array(centre))[None]
    faces_t = torch.tensor(faces)
    mesh = RenderMesh(faces_t, torch.tensor(sphere_uvs(vertices)), faces_t, edge_topology(faces_t))
    return points, mesh


def smooth_texture(channels=3, size=8, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return 0.3 + 0.4 * torch.rand(channels, size, size, generator=generator, dtype=torch.float64)


def weights_like(image, seed=1):
    return torch.rand(image.shape, generator=torch.Generator().manual_seed(seed), dtype=image.dtype)


def test_interpolated_attributes_match_finite_differences():
    points, mesh = sphere_scene()
    chosen = torch.tensor([0, 5, 17, 40])
    weights = None

    def loss(moved):
        nonlocal weights
        p = points.clone()
        p[0, chosen] = moved
        normal = render(p, mesh, K, SIZE, SIZE, outputs=("normal",))["normal"]
        weights = weights_like(normal) if weights is None else weights
        return (normal * weights).sum()

    start = points[0, chosen].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(loss, (start,), eps=1e-7, atol=1e-5, rtol=1e-4)


def test_silhouette_gradient_matches_the_analytic_area_derivative():
    """For a fronto-parallel triangle, sum(alpha) is its area in pixels; its derivative with
    respect to a vertex is half the opposite edge turned outwards (times f / z), and with
    respect to a uniform scale about the centroid it is twice the area."""
    z, focal, size = 1.0, 150.0, 128
    K_big = intrinsics(focal, size, size)
    triangle = torch.tensor([[[-0.2, -0.15, z], [0.25, -0.1, z], [-0.05, 0.22, z]]], dtype=torch.float64)
    faces = torch.tensor([[0, 2, 1]])  # counter-clockwise as seen from the camera (y down)
    mesh = RenderMesh(faces, topology=edge_topology(faces))
    points = triangle.clone().requires_grad_(True)
    alpha = render(points, mesh, K_big, size, size, outputs=("alpha",))["alpha"]
    alpha.sum().backward()
    pixels = triangle[0, :, :2].numpy() * focal / z
    (ax, ay), (bx, by) = pixels[1] - pixels[0], pixels[2] - pixels[0]
    area = 0.5 * abs(ax * by - ay * bx)
    assert alpha.sum().item() == pytest.approx(area, rel=0.01)
    centroid = pixels.mean(0)
    grad = points.grad[0, :, :2].numpy()
    scale_derivative = (grad * (triangle[0, :, :2].numpy() - triangle[0, :, :2].numpy().mean(0))).sum()
    assert scale_derivative == pytest.approx(2 * area, rel=0.06)  # pixels at corners are missed
    for vertex in range(3):
        a, b = pixels[(vertex + 1) % 3], pixels[(vertex + 2) % 3]
        edge = b - a
        outward = np.array([edge[1], -edge[0]])
        if np.dot(outward, pixels[vertex] - centroid) < 0:
            outward = -outward
        analytic = 0.5 * outward * focal / z  # d(area px^2)/d(vertex metres)
        assert np.linalg.norm(grad[vertex] - analytic) < 0.15 * np.linalg.norm(analytic), (grad[vertex], analytic)


@pytest.mark.parametrize("output", ["alpha", "rgb"])
def test_silhouette_gradient_matches_finite_differences(output):
    """Moving the sphere's silhouette (scaling it about its centre, shifting it sideways) changes
    the antialiased image continuously; autograd agrees with central differences of 1/500 of a
    pixel (small enough that hardly any pixel centre changes sides)."""
    points, mesh = sphere_scene(subdivisions=3)
    centre = points.mean(1, keepdim=True)
    appearance = Appearance(smooth_texture())
    light = Light(torch.tensor([0.3, -0.4, 0.0], dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64))
    background = torch.tensor([0.1, 0.8, 0.2], dtype=torch.float64)
    weights = weights_like(torch.zeros(1, SIZE, SIZE, 1 if output == "alpha" else 3))

    def loss(scale, shift):
        p = centre + (points - centre) * scale + shift
        image = render(p, mesh, K, SIZE, SIZE, outputs=(output,), appearance=appearance, light=light,
                       background=background)[output]
        return (image * weights).sum()

    scale = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    shift = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    loss(scale, shift).backward()
    pixel = 0.5 / 60                                  # metres per pixel at the sphere
    step = 0.002 * pixel / 0.1                        # radius change of 1/500 pixel
    numeric = (loss(torch.tensor(1 + step), torch.zeros(3)) - loss(torch.tensor(1 - step), torch.zeros(3))) / (2 * step)
    assert scale.grad.item() == pytest.approx(numeric.item(), rel=0.1)
    assert abs(scale.grad.item()) > 10
    for axis in (0, 1):
        offset = torch.zeros(3, dtype=torch.float64)
        offset[axis] = 0.002 * pixel
        numeric = (loss(torch.tensor(1.0), offset) - loss(torch.tensor(1.0), -offset)) / (2 * offset[axis])
        assert shift.grad[axis].item() == pytest.approx(numeric.item(), rel=0.2, abs=0.05 * abs(scale.grad.item()))


def test_silhouette_moves_both_ways():
    """Growing the sphere adds coverage outside the silhouette, shrinking removes it inside:
    d sum(alpha) / d radius > 0 at every silhouette vertex, and the pixels that change are on
    both sides of the hard silhouette."""
    from pipeline.render.rasterize import front_facing

    points, mesh = sphere_scene(subdivisions=3)
    p = points.clone().requires_grad_(True)
    out = render(p, mesh, K, SIZE, SIZE, outputs=("alpha",))["alpha"]
    out.sum().backward()
    centre = points.mean(1)
    radial = torch.nn.functional.normalize(points - centre, dim=-1)[0]
    front = front_facing(points, mesh.faces)[0]
    topology = mesh.edges()
    f0, f1 = topology.faces[:, 0], topology.faces[:, 1]
    rim_edges = topology.edges[front[f0] != front[f1]]
    rim = torch.unique(rim_edges)
    along = (p.grad[0, rim] * radial[rim]).sum(-1)
    assert len(rim) > 30
    assert (along >= -1e-9).all() and (along > 0).float().mean() > 0.8
    hard = render(points, mesh, K, SIZE, SIZE, outputs=("alpha",), antialiased=False)["alpha"]
    soft = out.detach()
    assert ((soft > 0) & (hard == 0)).any()      # coverage spilled outward
    assert ((soft < 1) & (hard == 1)).any()      # and withdrawn inward


def test_texture_normal_map_light_and_ambient_gradients():
    points, mesh = sphere_scene()
    albedo = smooth_texture(seed=3).requires_grad_(True)
    normal_map = torch.nn.functional.normalize(
        torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).view(3, 1, 1) + 0.3 * (smooth_texture(seed=4) - 0.5), dim=0)
    normal_map.requires_grad_(True)
    light_position = torch.tensor([0.25, -0.3, 0.1], dtype=torch.float64, requires_grad=True)
    ambient = torch.tensor(0.4, dtype=torch.float64, requires_grad=True)
    weights = weights_like(torch.zeros(1, SIZE, SIZE, 3))

    def loss(albedo, normal_map, light_position, ambient):
        image = render(points, mesh, K, SIZE, SIZE, outputs=("rgb",), appearance=Appearance(albedo, normal_map),
                       light=Light(light_position, ambient))["rgb"]
        return (image * weights).sum()

    assert torch.autograd.gradcheck(loss, (albedo, normal_map, light_position, ambient), eps=1e-6, atol=1e-5, rtol=1e-4)


def test_shadow_gradients_with_respect_to_light_and_geometry(monkeypatch):
    """With self-shadowing on, the image still differentiates smoothly in the light position and in
    the occluder's geometry (a small sphere hovering in front of a large one). The shadow camera's
    framing is held fixed, as the gradients assume."""
    big, faces = icosphere(2)
    small = big * 0.03 + np.array([0.0, 0.0, 0.4])
    points = torch.tensor(np.concatenate([big * 0.1 + np.array([0.0, 0.0, 0.5]), small]))[None]
    faces_t = torch.tensor(np.concatenate([faces, faces + len(big)]))
    uvs = torch.tensor(np.concatenate([sphere_uvs(big), sphere_uvs(big)]))
    mesh = RenderMesh(faces_t, uvs, faces_t, edge_topology(faces_t))
    appearance = Appearance(smooth_texture())
    weights = weights_like(torch.zeros(1, SIZE, SIZE, 3))

    def loss(light_position, occluder_shift):
        p = points.clone()
        p[0, len(big):] = p[0, len(big):] + occluder_shift
        light = Light(light_position, torch.tensor(0.3, dtype=torch.float64), shadows=True, shadow_resolution=64,
                      shadow_target=torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64), shadow_radius=0.11)
        return (render(p, mesh, K, SIZE, SIZE, outputs=("rgb",), appearance=appearance, light=light)["rgb"] * weights).sum()

    # the shadow test's filter weights carry no gradient (shadow_map.filter_taps): the finite
    # differences hold them where the unperturbed render put each receiver
    taken = []

    def filter_taps_kept(texel):
        taken.append(shadow_map.filter_taps(texel))
        return taken[-1]

    monkeypatch.setattr(fused, "filter_taps", filter_taps_kept)
    light_position = torch.tensor([0.05, -0.04, -0.2], dtype=torch.float64, requires_grad=True)
    shift = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    value = loss(light_position, shift)
    value.backward()
    monkeypatch.setattr(fused, "filter_taps", lambda texel: taken[0])
    assert torch.isfinite(light_position.grad).all() and light_position.grad.abs().sum() > 0
    for parameter, gradient in ((0, light_position.grad), (1, shift.grad)):
        for axis in range(3):
            step = torch.zeros(3, dtype=torch.float64)
            step[axis] = 1e-7
            args_plus = [light_position.detach(), shift.detach()]
            args_minus = [light_position.detach(), shift.detach()]
            args_plus[parameter] = args_plus[parameter] + step
            args_minus[parameter] = args_minus[parameter] - step
            numeric = (loss(*args_plus) - loss(*args_minus)) / 2e-7
            assert gradient[axis].item() == pytest.approx(numeric.item(), rel=2e-3, abs=1e-3)
