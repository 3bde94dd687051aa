"""Inverse problems the fit relies on converge through our renderer."""
import numpy as np
import pytest
import torch

from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.handmodel.uv_atlas import uv_mask
from pipeline.render.antialias import edge_topology
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from render_meshes import icosphere, intrinsics, rotation_y


def test_sphere_recovered_from_masks():
    """Centre offset by 10% of the radius and radius scaled by 10%: three masks bring both back
    to within 1% of the radius."""
    unit, faces = icosphere(3)
    unit = torch.tensor(unit)
    faces = torch.tensor(faces)
    mesh = RenderMesh(faces, topology=edge_topology(faces))
    size, K = 96, intrinsics(160.0, 96, 96)
    rotations = torch.tensor(np.stack([np.eye(3), rotation_y(np.pi / 2),
                                       np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])]))
    distance = torch.tensor([0.0, 0.0, 0.35], dtype=torch.float64)
    radius_true, centre_true = 0.05, torch.tensor([0.004, -0.002, 0.003], dtype=torch.float64)

    def masks(centre, radius):
        world = unit * radius + centre
        points = torch.einsum("bij,vj->bvi", rotations, world) + distance
        return render(points, mesh, K, size, size, outputs=("alpha",))["alpha"]

    target = masks(centre_true, torch.tensor(radius_true, dtype=torch.float64)).detach()
    offset = torch.tensor([0.6, -0.5, 0.62], dtype=torch.float64)
    centre = (centre_true + 0.1 * radius_true * offset / offset.norm()).clone().requires_grad_(True)
    log_radius = torch.tensor(np.log(1.1 * radius_true), dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([centre, log_radius], lr=5e-4)
    for step in range(300):
        loss = (masks(centre, log_radius.exp()) - target).square().mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert (centre.detach() - centre_true).norm().item() < 0.01 * radius_true
    assert abs(log_radius.exp().item() - radius_true) < 0.01 * radius_true


@pytest.fixture(scope="module")
def hand_views():
    """The base hand mesh in 12 views (rotations about two axes), camera frame, float64."""
    model = HandModel.load("hand", dtype=torch.float64)
    angles = torch.linspace(0, 2 * np.pi, 13, dtype=torch.float64)[:-1]
    orient = torch.stack([torch.full_like(angles, np.pi), angles, 0.35 * torch.sin(2 * angles)], dim=1)
    pose = torch.as_tensor(NAMED_POSES["spread"])[None].expand(12, -1, -1)
    centre = torch.tensor([0.0, 0.09, 0.0], dtype=torch.float64)
    from pipeline.handmodel.rotations import axis_angle_to_matrix
    points = model(pose=pose).vertices
    rotation = axis_angle_to_matrix(orient)
    points = torch.einsum("bij,bvj->bvi", rotation, points - centre) + torch.tensor([0.0, 0.0, 0.45], dtype=torch.float64)
    return model, points.detach()


def test_texture_recovered_from_renders(hand_views):
    model, points = hand_views
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    size, K = 128, intrinsics(260.0, 128, 128)
    resolution = 64
    generator = torch.Generator().manual_seed(0)
    coarse = torch.rand(3, 8, 8, generator=generator, dtype=torch.float64)
    target_texture = 0.2 + 0.6 * torch.nn.functional.interpolate(coarse[None], size=resolution, mode="bicubic",
                                                                 align_corners=False)[0].clamp(0, 1)
    flat = Light(torch.zeros(3, dtype=torch.float64), torch.tensor(1.0, dtype=torch.float64))  # colour = albedo
    background = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64)

    def images(texture):
        return render(points, mesh, K, size, size, outputs=("rgb",), appearance=Appearance(texture),
                      light=flat, background=background)["rgb"]

    target = images(target_texture).detach()
    texture = torch.full_like(target_texture, 0.5).requires_grad_(True)
    optimiser = torch.optim.Adam([texture], lr=0.03)
    for step in range(250):
        loss = (images(texture) - target).square().sum()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    # visible UV area: texels that the renders sample with a total bilinear weight of at least one
    # pixel, inside the atlas's UV mask
    probe = torch.zeros_like(texture, requires_grad=True)
    images(probe).sum().backward()
    seen = (probe.grad[0] >= 1.0) & torch.as_tensor(uv_mask(model.data.uvs, model.data.faces_uv, resolution, 0))
    assert seen.float().mean() > 0.25
    error = (texture.detach() - target_texture)[:, seen]
    psnr = 10 * np.log10(1.0 / error.square().mean().item())
    assert psnr >= 35.0, psnr


def test_light_position_recovered(hand_views):
    model, points = hand_views
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    size, K = 96, intrinsics(200.0, 96, 96)
    albedo = torch.full((3, 16, 16), 0.7, dtype=torch.float64)
    centre = torch.tensor([0.0, 0.0, 0.45], dtype=torch.float64)
    true_light = centre + torch.tensor([0.3, -0.4, -0.2], dtype=torch.float64)

    def images(light_position):
        return render(points[:6], mesh, K, size, size, outputs=("rgb",), appearance=Appearance(albedo),
                      light=Light(light_position, torch.tensor(0.3, dtype=torch.float64)))["rgb"]

    target = images(true_light).detach()
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    from pipeline.handmodel.rotations import axis_angle_to_matrix
    start = centre + axis_angle_to_matrix(axis * np.radians(40)) @ (true_light - centre)
    light = start.clone().requires_grad_(True)
    optimiser = torch.optim.Adam([light], lr=0.01)
    for step in range(200):
        loss = (images(light) - target).square().mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    direction = lambda p: torch.nn.functional.normalize(p - centre, dim=0)  # noqa: E731
    angle = torch.rad2deg(torch.acos((direction(light.detach()) * direction(true_light)).sum().clamp(-1, 1)))
    start_angle = torch.rad2deg(torch.acos((direction(start) * direction(true_light)).sum()))
    assert start_angle > 30 and angle < 5.0, (start_angle, angle)
