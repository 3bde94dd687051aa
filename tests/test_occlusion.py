"""The room light's self-occlusion (render/occlusion.py) against exact ray casting, the
quadrature against the harmonics' own irradiance, the renderer's use of it, and the fit's
per-frame measurements."""
import dataclasses

import numpy as np
import pytest
import torch

from pipeline.formats.environment_light import COEFFICIENTS
from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.mesh_checks import _segment_hits_triangles
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.render import occlusion
from pipeline.render.renderer import Appearance, Light, RenderMesh, render
from pipeline.render.shading import environment_basis_values, vertex_normals


def posed_hand(name, frames=1, mode="hand"):
    model = HandModel.load(mode, dtype=torch.float64)
    pose = torch.as_tensor(NAMED_POSES[name], dtype=torch.float64)[None].repeat(frames, 1, 1)
    out = model(None, pose, torch.zeros(frames, 3, dtype=torch.float64),
                torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64).repeat(frames, 1))
    return model, out.vertices


def ray_cast_blocked(points, faces, normals, vertices, directions):
    """(len(vertices), D) bool by exact segment-triangle tests (Moller-Trumbore), from each vertex
    (a tenth of a millimetre out of its surface) half a metre along each direction that faces
    out of the surface; the faces at the vertex itself never block it."""
    a, b, c = (points[faces[:, k]] for k in range(3))
    blocked = np.zeros((len(vertices), len(directions)), dtype=bool)
    for row, vertex in enumerate(vertices):
        start = np.broadcast_to(points[vertex] + 1e-4 * normals[vertex], a.shape)
        own = (faces == vertex).any(1)
        for column, direction in enumerate(directions):
            if normals[vertex] @ direction > 0:
                end = np.broadcast_to(points[vertex] + 1e-4 * normals[vertex] + 0.5 * direction, a.shape)
                blocked[row, column] = (_segment_hits_triangles(start, end, a, b, c) & ~own).any()
    return blocked


@pytest.mark.parametrize("pose,mode", [("fist", "hand"), ("pinch", "hand"), ("fist", "arm")])
def test_blocked_directions_agree_with_exact_ray_casting(pose, mode):
    """On the hand; with a forearm, the depth maps frame the hand alone (hand_focus)."""
    model, points = posed_hand(pose, mode=mode)
    faces = torch.as_tensor(model.data.faces, dtype=torch.long)
    directions, _ = occlusion._quadrature(torch.float64, points.device, occlusion.DIRECTIONS)
    focus = occlusion.hand_focus(model.data.vertex_parts)
    assert (focus is None) == (mode == "hand")
    ours = occlusion.blocked_directions(points, faces, directions, focus=focus)[0].numpy()
    normals = vertex_normals(points, faces)[0].numpy()
    on_hand = np.arange(points.shape[1]) if focus is None else np.flatnonzero(focus.numpy())
    chosen = np.random.default_rng(1).choice(on_hand, 60, replace=False)
    exact = ray_cast_blocked(points[0].numpy(), model.data.faces, normals, chosen, directions.numpy())
    cosine = np.clip(normals[chosen] @ directions.numpy().T, 0, None)
    agreement = ((ours[chosen] == exact) * cosine).sum() / cosine.sum()
    assert agreement > 0.96                               # measured 0.977 (fist), 0.986 (pinch) at 128 texels
    blocked_share = lambda blocked: (blocked * cosine).sum(1) * 4 / len(directions)   # noqa: E731
    assert exact.any(1).mean() > 0.3                      # the pose does hide part of the room from its surface
    assert np.abs(blocked_share(ours[chosen]) - blocked_share(exact)).mean() < 0.03


def test_the_fits_subdivided_mesh_drawn_coarse_agrees_with_ray_casting_as_drawn_whole():
    """hand_lost_light draws the unsubdivided surface into the depth maps of a subdivided mesh (a
    quarter of the faces): against exact ray casting on the subdivided mesh it agrees as closely
    as drawing every face does, and its losses are those of drawing every face."""
    from pipeline.handmodel.subdivision import unsubdivided_faces

    model = HandModel.load("hand", subdivided=True, dtype=torch.float64)
    pose = torch.as_tensor(NAMED_POSES["fist"], dtype=torch.float64)[None]
    points = model(None, pose, torch.zeros(1, 3, dtype=torch.float64),
                   torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64)).vertices
    faces = torch.as_tensor(model.data.faces, dtype=torch.long)
    coarse = unsubdivided_faces(faces)
    unsubdivided = HandModel.load("hand", dtype=torch.float64).data
    np.testing.assert_array_equal(model.data.vertices[coarse.numpy()], unsubdivided.vertices[unsubdivided.faces])
    directions, _ = occlusion._quadrature(torch.float64, points.device, occlusion.DIRECTIONS)
    normals = vertex_normals(points, faces)[0].numpy()
    chosen = np.random.default_rng(1).choice(points.shape[1], 60, replace=False)
    exact = ray_cast_blocked(points[0].numpy(), model.data.faces, normals, chosen, directions.numpy())
    cosine = np.clip(normals[chosen] @ directions.numpy().T, 0, None)

    def agreement(occluders):
        ours = occlusion.blocked_directions(points, faces, directions, occluders=occluders)[0].numpy()[chosen]
        return ((ours == exact) * cosine).sum() / cosine.sum()

    whole, drawn_coarse = agreement(None), agreement(coarse)
    assert drawn_coarse > 0.94 and drawn_coarse > whole - 0.005     # measured 0.952 and 0.951
    lost_whole = occlusion.lost_light(points, faces)
    lost_coarse = occlusion.hand_lost_light(points, model.data)
    assert (lost_coarse[..., 0] - lost_whole[..., 0]).abs().mean() < 0.01


def test_a_convex_surface_loses_no_light():
    """An icosphere-like convex mesh (the hand's rest surface scaled flat would not be): a box."""
    corners = torch.tensor([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    points = (0.05 * corners + torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64))[None]
    # outward winding, as the rasteriser's culling needs: flip the faces whose normals point in
    v0, v1, v2 = (points[0, faces[:, k]] for k in range(3))
    inward = (torch.cross(v1 - v0, v2 - v0, dim=-1) * (v0 - points[0].mean(0))).sum(-1) < 0
    faces = torch.where(inward[:, None], faces[:, [0, 2, 1]], faces)
    assert occlusion.lost_light(points, faces).abs().max() < 1e-12


def test_the_quadrature_of_the_whole_sphere_is_the_unoccluded_shading():
    """Every direction blocked, a point loses its whole ambient (O_0 = 1) and each harmonic's
    whole irradiance (O_k = Y_k(n), the renderer's unoccluded environment shading): the weights
    and the radiance basis are those of formats/environment_light.py."""
    directions, rows = occlusion._quadrature(torch.float64, torch.device("cpu"), 4096)
    normals = torch.nn.functional.normalize(torch.randn(20, 3, dtype=torch.float64,
                                                        generator=torch.Generator().manual_seed(0)), dim=-1)
    lost = (normals @ directions.T).clamp(min=0) @ rows
    np.testing.assert_allclose(lost[:, 0], 1.0, atol=2e-3)
    np.testing.assert_allclose(lost[:, 1:], environment_basis_values(normals), atol=3e-3)


def test_the_renderer_takes_the_lost_light_off_the_ambient_and_environment():
    model, points = posed_hand("fist")
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    K = torch.tensor([[400.0, 0, 48], [0, 400.0, 48], [0, 0, 1]], dtype=torch.float64)
    albedo = torch.rand(3, 32, 32, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    environment = 0.05 * torch.randn(COEFFICIENTS, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    light = Light(torch.tensor([0.1, -0.2, 0.2], dtype=torch.float64), torch.tensor(0.6, dtype=torch.float64),
                  environment=environment)
    lost = occlusion.lost_light(points, mesh.faces)

    def draw(with_light):
        return render(points, mesh, K, 96, 96, outputs=("rgb", "albedo", "normal") +
                      (("lost_light",) if with_light.occlusion is not None else ()),
                      appearance=Appearance(albedo), light=with_light, antialiased=False)

    plain = draw(light)
    occluded = draw(dataclasses.replace(light, occlusion=lost))
    none_lost = draw(dataclasses.replace(light, occlusion=torch.zeros_like(lost)))
    np.testing.assert_allclose(none_lost["rgb"], plain["rgb"], atol=1e-12)
    seen = occluded["lost_light"]
    assert seen[..., 0].max() > 0.1                       # the fist hides part of the room from the side seen
    expected = plain["rgb"] - plain["albedo"] * (0.6 * seen[..., :1] + seen[..., 1:] @ environment)
    np.testing.assert_allclose(occluded["rgb"], expected, atol=1e-12)


def test_the_fit_measures_a_frames_occlusion_again_only_once_its_pose_has_moved(monkeypatch):
    from pipeline.fit import avatar as avatar_module
    from pipeline.fit.problem import build_avatar
    from pipeline.formats.initial_estimate import InitialEstimate

    frames = 3
    initial = InitialEstimate(source="test", mode="hand", side="right", betas=np.zeros(12),
                              pose=np.tile(np.asarray(NAMED_POSES["fist"]), (frames, 1, 1)),
                              global_orient=np.zeros((frames, 3)), transl=np.tile([0.0, 0.0, 0.5], (frames, 1)),
                              keypoints3d=np.zeros((frames, 21, 3)), residual_px=np.zeros(frames),
                              detected=np.ones(frames, dtype=bool))
    avatar = build_avatar(initial, np.arange(frames), 16, "cpu")
    avatar.occlusion = True
    measured = []
    real = avatar_module.hand_lost_light
    monkeypatch.setattr(avatar_module, "hand_lost_light", lambda points, data, faces: measured.append(len(points))
                        or real(points, data, faces))
    batch = torch.tensor([0, 2])
    first = avatar.light(False, batch, avatar.posed(batch)[0]).occlusion
    assert measured == [2] and first.shape == (2, avatar.model.data.num_vertices, occlusion.TERMS)
    with torch.no_grad():
        avatar.pose[0, 3] += 0.5 * avatar_module.OCCLUSION_POSE_TOLERANCE     # within the tolerance: kept
    again = avatar.light(False, batch, avatar.posed(batch)[0]).occlusion
    assert measured == [2] and torch.equal(again, first)
    with torch.no_grad():
        avatar.pose[2, 3] += 0.3                                               # frame 2's finger bends: measured
    avatar.light(False, batch, avatar.posed(batch)[0])
    assert measured == [2, 1]
    assert avatar.light().occlusion is None                                    # no frames given: none
    avatar.occlusion = False
    assert avatar.light(False, batch, avatar.posed(batch)[0]).occlusion is None


def test_the_skin_sends_back_what_it_blocks_by_its_mean_albedo_under_its_mean_shading():
    """bounce_radiance: a uniform albedo rho under an ambient a gives rho (a + (1 - a) / 4) (the
    mean of max(0, n . l) over a sphere is 1/4: checked by quadrature), decoded in linear light;
    the renderer takes b O_0 back off the loss."""
    directions = occlusion._quadrature(torch.float64, torch.device("cpu"), 4096)[0]
    assert directions[:, 2].clamp(min=0).mean().item() == pytest.approx(0.25, abs=1e-3)
    albedo = torch.full((3, 4, 4), 0.5, dtype=torch.float64)
    np.testing.assert_allclose(occlusion.bounce_radiance(albedo, 0.6, linear=False), 0.5 * (0.6 + 0.4 / 4))
    decoded = ((0.5 + 0.055) / 1.055) ** 2.4   # sRGB 0.5 in linear light (IEC 61966-2-1)
    np.testing.assert_allclose(occlusion.bounce_radiance(albedo, 0.6, linear=True), decoded * 0.7, rtol=1e-9)
    lost = torch.tensor([[0.5] + [0.0] * 8], dtype=torch.float64)
    bounce = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    np.testing.assert_allclose(occlusion.lost_shading(lost, 0.6, None, bounce), [[0.25, 0.2, 0.15]])
