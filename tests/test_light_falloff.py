"""The point light's inverse-square falloff (render/renderer.Light.falloff): the direct light at a
surface point is the falloff-free light's times (d0 / d)^2, d the point's distance to the light
and d0 the distance the falloff is 1 at (the fit's: the light's distance from the hand's mean
place), with shadows as without, and it vanishes for a light far away."""
import numpy as np
import pytest
import torch

from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from render_meshes import intrinsics

SIZE = 96


@pytest.fixture(scope="module")
def scene():
    model = HandModel.load("hand", subdivided=True)
    pose = torch.as_tensor(np.stack([NAMED_POSES["spread"], NAMED_POSES["fist"]]), dtype=torch.float32)
    orient = torch.tensor([[np.pi, 0.0, 0.0], [np.pi - 0.5, 0.4, 0.2]])
    transl = torch.tensor([[0.0, 0.09, 0.45], [0.01, 0.08, 0.5]])
    with torch.no_grad():
        points = model(pose=pose, global_orient=orient, transl=transl).vertices.double()
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    albedo = torch.full((3, 8, 8), 0.8, dtype=torch.float64)
    K = torch.stack([intrinsics(220.0, SIZE, SIZE), intrinsics(200.0, SIZE, SIZE)]).double()
    return points, mesh, albedo, K


def _shading(scene, position, falloff, shadows=False):
    points, mesh, albedo, K = scene
    light = Light(torch.as_tensor(position, dtype=torch.float64), torch.tensor(0.0, dtype=torch.float64),
                  shadows=shadows, shadow_resolution=64, falloff=float(falloff))
    return render(points, mesh, K, SIZE, SIZE, outputs=("rgb", "alpha", "position"), appearance=Appearance(albedo),
                  light=light, antialiased=False)


@pytest.mark.parametrize("shadows", [False, True])
def test_the_direct_light_falls_off_with_the_square_of_the_distance(scene, shadows):
    points = scene[0]
    lamp = np.array([0.2, -0.25, 0.15])       # about 0.4 m from the hand: the fingers nearer than the wrist
    reach = float(np.linalg.norm(lamp - points.mean((0, 1)).numpy()))     # the light's distance from the hand
    plain, fallen = _shading(scene, lamp, 0.0, shadows), _shading(scene, lamp, reach, shadows)
    lit = (plain["alpha"][..., 0] > 0.5) & (plain["rgb"].mean(-1) > 0.05)
    assert lit.sum() > 500
    distance = (torch.as_tensor(lamp) - fallen["position"]).norm(dim=-1)
    expected = (reach / distance).square()
    ratio = fallen["rgb"][lit] / plain["rgb"][lit]
    assert torch.allclose(ratio, expected[lit][:, None].expand_as(ratio), rtol=1e-9, atol=0)
    assert ratio.min() < 0.9 and ratio.max() > 1.1          # across the hand, a lamp this near matters


def test_a_light_far_away_has_no_falloff_to_speak_of(scene):
    direction = np.array([0.2, -0.25, -0.3])
    far = 200.0 * direction / np.linalg.norm(direction)
    reach = float(np.linalg.norm(far - scene[0].mean((0, 1)).numpy()))
    plain, fallen = _shading(scene, far, 0.0), _shading(scene, far, reach)
    lit = (plain["alpha"][..., 0] > 0.5) & (plain["rgb"].mean(-1) > 0.05)
    assert torch.allclose(fallen["rgb"][lit], plain["rgb"][lit], rtol=2e-3, atol=0)
