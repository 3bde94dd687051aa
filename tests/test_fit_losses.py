"""The fit's energy terms on analytic cases."""
import types

import numpy as np
import scipy.ndimage
import pytest
import torch

from pipeline.fit import losses
from pipeline.fit.problem import FitProblem
from pipeline.fit.surface_regularisers import SurfaceRegularisers
from pipeline.render.antialias import edge_topology
from scipy.spatial.transform import Rotation


def grid_mesh(n=6, z=None):
    """A flat regular n x n vertex grid in the xy plane (optionally with heights z (n, n))."""
    ys, xs = np.mgrid[0:n, 0:n].astype(float)
    zs = np.zeros_like(xs) if z is None else z
    vertices = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], 1) * 0.01
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            faces += [(a, b, d), (a, d, c)]
    return torch.tensor(vertices)[None], torch.tensor(faces)


def surface_of(faces, vertex_count):
    """SurfaceRegularisers of a mesh, in float64."""
    topology = edge_topology(faces)
    return SurfaceRegularisers(faces, topology.edges, topology.faces[topology.faces[:, 1] >= 0], vertex_count,
                               dtype=torch.float64)


def test_laplacian_vanishes_on_flat_interior_and_sees_a_bump():
    vertices, faces = grid_mesh()
    surface = surface_of(faces, 36)
    lap = surface.uniform_laplacian(vertices)[0].numpy()
    interior = [j * 6 + i for j in range(1, 5) for i in range(1, 5)]
    assert np.abs(lap[interior]).max() < 1e-15
    bumped = vertices.clone()
    bumped[0, 14, 2] = 0.005        # an interior vertex raised by 5 mm
    lap = surface.uniform_laplacian(bumped)[0]
    assert lap[14, 2].item() == pytest.approx(-0.005)   # its neighbours are all flat
    assert lap[13, 2].item() == pytest.approx(0.005 / 6)   # a neighbour of it (six neighbours each)


def test_normal_consistency_of_a_fold():
    vertices = torch.tensor([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 3], [0, 3, 2]])
    surface = surface_of(faces, 4)
    assert torch.equal(surface.face_pairs.sort(1).values, torch.tensor([[0, 1]]))
    assert surface.normal_consistency_loss(vertices).item() == pytest.approx(0.0, abs=1e-15)
    folded = vertices.clone()
    folded[0, 2, 2] = 1.0             # lift one corner: the second face tilts by 45 degrees about the diagonal
    n1 = np.array([0, 0, 1.0])
    v0, v3, v2 = folded[0, 0].numpy(), folded[0, 3].numpy(), folded[0, 2].numpy()
    n2 = np.cross(v3 - v0, v2 - v0)
    n2 /= np.linalg.norm(n2)
    expected = 1 - n1 @ n2
    assert surface.normal_consistency_loss(folded).item() == pytest.approx(expected)


def test_edge_length_term_is_blind_to_rigid_motion():
    vertices, faces = grid_mesh()
    surface = surface_of(faces, 36)
    edges = surface.edges
    reference = surface.edge_lengths(vertices)
    moved = torch.tensor(Rotation.from_rotvec([0.3, -0.8, 0.2]).apply(vertices[0].numpy()) + [0.1, 0.2, -0.3])[None]
    assert surface.edge_length_loss(moved, reference).item() < 1e-30
    stretched = vertices * 1.1
    lengths = (vertices[0, edges[:, 0]] - vertices[0, edges[:, 1]]).norm(dim=-1)
    assert surface.edge_length_loss(stretched, reference).item() == pytest.approx((0.1 * lengths).square().mean().item())


def test_the_surface_terms_over_a_batch_are_each_meshs_own_terms_averaged():
    """The batched sparse terms against a plain computation, one mesh at a time, by loops over the
    faces, edges and neighbours: values and gradients of three different bumpy meshes."""
    generator = torch.Generator().manual_seed(3)
    flat, faces = grid_mesh()
    batch = flat.repeat(3, 1, 1) + 0.002 * torch.randn(3, 36, 3, generator=generator, dtype=torch.float64)
    reference = flat.repeat(3, 1, 1) + 0.002 * torch.randn(3, 36, 3, generator=generator, dtype=torch.float64)
    surface = surface_of(faces, 36)
    edges = [tuple(edge) for edge in surface.edges.tolist()]
    neighbours = {v: [b if a == v else a for a, b in edges if v in (a, b)] for v in range(36)}
    pairs = surface.face_pairs.tolist()

    def plain(mesh, reference_mesh):
        laplacian = torch.stack([(mesh[neighbours[v]].mean(0) - mesh[v]).norm() for v in range(36)]).mean()
        normals = [torch.cross(mesh[b] - mesh[a], mesh[c] - mesh[a], dim=0) for a, b, c in faces.tolist()]
        normals = [n / n.norm() for n in normals]
        consistency = torch.stack([1 - normals[f] @ normals[g] for f, g in pairs]).mean()
        stretch = torch.stack([((mesh[a] - mesh[b]).norm() - (reference_mesh[a] - reference_mesh[b]).norm()) ** 2
                               for a, b in edges]).mean()
        return laplacian, consistency, stretch

    ours_input = batch.clone().requires_grad_()
    ours = (surface.laplacian_loss(ours_input), surface.normal_consistency_loss(ours_input),
            surface.edge_length_loss(ours_input, surface.edge_lengths(reference)))
    plain_input = batch.clone().requires_grad_()
    theirs = [torch.stack(values).mean() for values in zip(*(plain(plain_input[i], reference[i]) for i in range(3)))]
    for mine, other in zip(ours, theirs):
        assert mine.item() == pytest.approx(other.item(), rel=1e-12)
    assert ours[1].item() > 1e-4 and ours[2].item() > 1e-8        # the meshes are bumpy, the terms not zero
    sum(weight * value for weight, value in zip((1.0, 10.0, 1e4), ours)).backward()
    sum(weight * value for weight, value in zip((1.0, 10.0, 1e4), theirs)).backward()
    assert torch.allclose(ours_input.grad, plain_input.grad, rtol=1e-10, atol=1e-14)


def test_keypoint_anchor_in_units_of_ten_centimetres():
    initial = torch.zeros(2, 21, 3, dtype=torch.float64)
    moved = initial.clone()
    moved[:, 5, 0] = 0.01            # one keypoint 1 cm off in both frames
    assert losses.keypoint_anchor_loss(moved, initial).item() == pytest.approx(0.01 / 21)
    shifted = initial + torch.tensor([0.3, 0.1, 0.2], dtype=torch.float64)  # a global shift is free
    assert losses.keypoint_anchor_loss(shifted, initial).item() == pytest.approx(0.0)


def test_photometric_loss_ignores_the_mask_border():
    mask = torch.zeros(1, 20, 20, 1, dtype=torch.float64)
    mask[:, 5:15, 5:15] = 1
    eroded = losses.eroded_mask(mask, 2)
    assert eroded.sum().item() == 36    # 10 x 10 square shrunk by 2 px on each side
    image = torch.rand(1, 20, 20, 3, dtype=torch.float64)
    rendered = image.clone()
    rendered[:, 5:7] += 1.0            # error only in the border band
    assert losses.photometric_loss(rendered, image, mask).item() == 0.0
    rendered[:, 9, 9] += 0.36
    assert losses.photometric_loss(rendered, image, mask).item() == pytest.approx(0.36 / 36)


def test_eroded_mask_is_scipys_binary_erosion_by_a_square():
    """Against scipy.ndimage: random masks touching every border, radii 0-3; beyond the image
    counts as inside (border_value=1)."""
    generator = torch.Generator().manual_seed(4)
    masks = (torch.rand(3, 17, 23, 1, generator=generator) > 0.2).double()
    for pixels in range(4):
        eroded = losses.eroded_mask(masks, pixels)
        assert eroded.shape == masks.shape and eroded.dtype == masks.dtype
        for mask, result in zip(masks.numpy()[..., 0] > 0.5, eroded.numpy()[..., 0]):
            expected = scipy.ndimage.binary_erosion(mask, structure=np.ones((2 * pixels + 1,) * 2), border_value=1)
            assert np.array_equal(result > 0.5, expected), pixels


def test_the_problem_erodes_every_mask_once_as_the_photometric_term_would():
    """FitProblem.photometric_inside (in chunks of frames) is the term's own erosion of every
    frame, and the term given it is the term."""
    generator = torch.Generator().manual_seed(1)
    masks = (torch.rand(21, 24, 30, 1, generator=generator) > 0.3).double()
    stand_in = types.SimpleNamespace(clip=types.SimpleNamespace(masks=masks, valid=None))
    stand_in._eroded_masks = lambda pixels: FitProblem._eroded_masks(stand_in, pixels)
    inside = FitProblem.photometric_inside.func(stand_in)
    assert inside.dtype == torch.bool and torch.equal(inside, losses.eroded_mask(masks, 2) > 0.5)
    # the albedo solve reads one pixel nearer the edge: the mask eroded by 1, more pixels than the term's
    stand_in.photometric_inside, stand_in.albedo_solve_inside = inside, FitProblem.albedo_solve_inside.func(stand_in)
    assert torch.equal(stand_in.albedo_solve_inside, losses.eroded_mask(masks, 1) > 0.5)
    solved = FitProblem.compared_pixels(stand_in, torch.tensor([3, 17]), albedo_solve=True)
    compared = FitProblem.compared_pixels(stand_in, torch.tensor([3, 17]))
    assert torch.equal(compared, inside[[3, 17], ..., 0]) and bool((solved | ~compared).all())
    assert int(solved.sum()) > int(compared.sum())
    rendered, image = torch.rand(2, 21, 24, 30, 3, generator=generator, dtype=torch.float64)
    batch = torch.tensor([3, 17, 20])
    assert losses.photometric_loss(rendered[batch], image[batch], masks[batch], inside=inside[batch]).item() == \
        losses.photometric_loss(rendered[batch], image[batch], masks[batch]).item()


def test_texture_regularisers():
    mask = torch.ones(32, 32, dtype=torch.bool)
    flat = torch.full((3, 32, 32), 0.5, dtype=torch.float64)
    assert losses.texture_smoothness_loss(flat, mask, torch.Generator().manual_seed(0)).item() == pytest.approx(0.0)
    noisy = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    assert losses.texture_smoothness_loss(noisy, mask, torch.Generator().manual_seed(0)).item() > 0.1
    up = torch.zeros(3, 32, 32, dtype=torch.float64)
    up[2] = 1
    assert losses.normal_map_loss(up, mask, torch.Generator().manual_seed(0)).item() == pytest.approx(0.0)
    tilted = up.clone()
    tilted[0] = 0.3
    assert losses.normal_map_loss(tilted, mask, torch.Generator().manual_seed(0)).item() == pytest.approx(0.09 / 3)


def test_silhouette_and_displacement_terms():
    mask = torch.zeros(1, 4, 4, 1)
    alpha = torch.full((1, 4, 4, 1), 0.25)
    assert losses.silhouette_loss(alpha, mask).item() == pytest.approx(0.25)
    assert losses.displacement_loss(torch.tensor([0.001, -0.002])).item() == pytest.approx(5e-6)


def test_pose_smoothness_by_acceleration_lets_a_steady_motion_be_and_holds_jitter_harder():
    """The acceleration of a finger bending at a steady speed is 0 (its velocity is not); one
    frame's jolt of 0.1 rad gives velocities (0.1, -0.1) and accelerations (-0.1, 0.2, -0.1) per
    frame^2; independent jitter costs three times its velocity's cost (6 s^2 against 2 s^2)."""
    times = torch.tensor([0, 1, 2, 4, 5])
    pose = torch.zeros(5, 16, 3)
    pose[:, 3, 0] = 0.1 * times
    assert losses.temporal_pose_loss(pose, times, "acceleration").item() == pytest.approx(0, abs=1e-10)
    times = torch.arange(5)
    jolted = torch.zeros(5, 16, 3)
    jolted[2, 3, 0] = 0.1
    assert losses.temporal_pose_loss(jolted, times, "velocity").item() == pytest.approx(2 * 0.01 / 4, rel=1e-5)
    assert losses.temporal_pose_loss(jolted, times, "acceleration").item() == pytest.approx(
        (0.01 + 0.04 + 0.01) / 3, rel=1e-5)
    jitter = torch.randn(4000, 16, 3, generator=torch.Generator().manual_seed(0)) * 0.01
    times = torch.arange(4000)
    ratio = losses.temporal_pose_loss(jitter, times, "acceleration") / losses.temporal_pose_loss(jitter, times)
    assert ratio.item() == pytest.approx(3.0, rel=0.02)
    assert losses.temporal_pose_loss(jitter[:2], times[:2], "acceleration") == 0     # too few frames to tell
    with pytest.raises(ValueError, match="velocity, acceleration, adaptive"):
        losses.temporal_pose_loss(jitter, times, "jerk")


def test_a_joint_turning_steadily_is_as_still_as_its_speed_says_and_jitter_does_not_count():
    """joint_stillness: a joint turning at a steady w rad/s is 1 / (1 + (w / still speed)^2) still away
    from the clip's ends (smoothing leaves a steady turn as it is), under independent jitter of 10
    degrees (gt-noise's) too; one held still under that jitter reads still, on a long clip and on
    short ones (where smoothing leaves much of the jitter: what it leaves is taken off the speed)."""
    fps, speed = 30.0, 1.2
    pose = np.zeros((240, 16, 3))
    pose[:, 2, 1] = speed / fps * np.arange(240)
    stillness = losses.joint_stillness(pose, fps)
    expected = 1 / (1 + (speed / losses.STILL_SPEED) ** 2)
    np.testing.assert_allclose(stillness[70:170, 2], expected, rtol=1e-6)     # the smoothing reaches 60 frames
    np.testing.assert_allclose(stillness[:, 5], 1.0)
    rng = np.random.default_rng(0)
    jittered = pose + rng.normal(size=pose.shape) * np.radians(10) / np.sqrt(3)
    assert losses.joint_stillness(jittered, fps)[70:170, 2].mean() == pytest.approx(expected, abs=0.01)
    assert losses.joint_stillness(jittered, fps)[:, 5].mean() > 0.95
    assert losses.joint_stillness(rng.normal(size=(3000, 16, 3)) * np.radians(10) / np.sqrt(3), fps).mean() > 0.98
    short = [losses.joint_stillness(rng.normal(size=(30, 16, 3)) * np.radians(10) / np.sqrt(3), fps).mean()
             for _ in range(50)]
    assert np.mean(short) > 0.93          # without taking the jitter off: 0.79
    assert losses.joint_stillness(pose[:1], fps).shape == (1, 16)


def test_the_jitter_left_after_smoothing_is_that_of_the_smoothed_steps():
    """The variance that joint_stillness's smoothed centred step keeps of unit independent noise, per
    frame, against the variance of that step over many draws of such noise; long clips take their
    middle's value from a short one, which equals the whole computation."""
    sigma = losses.MOTION_SMOOTHING_S * 30.0
    noise = np.random.default_rng(1).normal(size=(12, 40000))
    drawn = np.gradient(scipy.ndimage.gaussian_filter1d(noise, sigma, axis=0, mode="nearest"), axis=0).var(1)
    np.testing.assert_allclose(losses._smoothed_step_noise_gain(12, sigma), drawn, rtol=0.03)
    whole = np.gradient(scipy.ndimage.gaussian_filter1d(np.eye(300), sigma, axis=0, mode="nearest"), axis=0)
    np.testing.assert_allclose(losses._smoothed_step_noise_gain(300, sigma), (whole ** 2).sum(1), rtol=1e-12)


def test_adaptive_pose_smoothness_is_the_velocity_where_still_and_the_acceleration_where_moving():
    times = torch.tensor([0, 1, 2, 4, 5, 6])
    pose = torch.randn(6, 16, 3, generator=torch.Generator().manual_seed(1)) * 0.1
    still, moving = torch.ones(6, 16), torch.zeros(6, 16)
    assert losses.temporal_pose_loss(pose, times, "adaptive", still).item() == pytest.approx(
        losses.temporal_pose_loss(pose, times, "velocity").item(), rel=1e-6)
    assert losses.temporal_pose_loss(pose, times, "adaptive", moving).item() == pytest.approx(
        losses.temporal_pose_loss(pose, times, "acceleration").item(), rel=1e-6)
    # joint 3 still (its velocity), the others moving (their acceleration): the sum of the two parts
    mixed = moving.clone()
    mixed[:, 3] = 1
    only_joint_3, the_others = torch.zeros_like(pose), pose.clone()
    only_joint_3[:, 3], the_others[:, 3] = pose[:, 3], 0
    expected = (losses.temporal_pose_loss(only_joint_3, times, "velocity")
                + losses.temporal_pose_loss(the_others, times, "acceleration"))
    assert losses.temporal_pose_loss(pose, times, "adaptive", mixed).item() == pytest.approx(expected.item(), rel=1e-6)
    with pytest.raises(ValueError, match="stillness"):
        losses.temporal_pose_loss(pose, times, "adaptive")


def test_the_fits_stillness_is_measured_on_the_whole_clip_and_read_at_its_frames():
    """The adaptive term's prepared stillness: the initial estimate's every frame at the clip's fps
    (held-out frames and subsampling do not make the motion look faster), read at the fitted frames;
    none for the other measures."""
    from pipeline.fit.energy_terms import ENERGY_TERMS

    pose = np.zeros((90, 16, 3))
    pose[:, 4, 0] = np.sin(np.arange(90) / 9)
    frames = np.arange(0, 90, 3)
    problem = types.SimpleNamespace(settings=types.SimpleNamespace(pose_smoothness="adaptive"),
                                    initial=types.SimpleNamespace(pose=pose), frames=frames, device=torch.device("cpu"),
                                    clip=types.SimpleNamespace(info=types.SimpleNamespace(fps=30.0)),
                                    avatar=types.SimpleNamespace(pose=torch.zeros(30, 16, 3, dtype=torch.float64)))
    prepared = ENERGY_TERMS["temporal_pose"].prepare(problem)
    assert prepared.shape == (30, 16) and prepared.dtype == torch.float64
    np.testing.assert_allclose(prepared.numpy(), losses.joint_stillness(pose, 30.0)[frames])
    assert prepared[:, 4].min() < 0.9 and bool((prepared[:, 5] == 1).all())
    problem.settings.pose_smoothness = "velocity"
    assert ENERGY_TERMS["temporal_pose"].prepare(problem) is None


def test_temporal_terms_vanish_on_steady_motion_and_count_time_gaps():
    times = torch.tensor([0, 1, 2, 4, 5])
    pose = torch.zeros(5, 16, 3)
    assert losses.temporal_pose_loss(pose, times) == 0
    pose[:, 3, 0] = 0.1 * times          # a finger bending at 0.1 rad per frame, gaps included
    assert losses.temporal_pose_loss(pose, times).item() == pytest.approx(0.01, rel=1e-5)
    # steady translation (2 mm per frame) and a fixed rotation: no acceleration
    rotations = torch.as_tensor(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix(), dtype=torch.float32).expand(5, 3, 3)
    translations = torch.stack([0.002 * times, 0 * times, 0.5 + 0 * times], 1).float()
    assert losses.temporal_global_loss(rotations, translations, times).item() == pytest.approx(0, abs=1e-8)
    # frame 1 shifted by 1 cm: velocities (1, -1, 0, 0) cm per frame (the gap of two frames
    # halves the third), changes (-2, 1, 0) over half spans (1, 1.5, 1.5) frames
    jolted = translations.clone()
    jolted[1, 1] += 0.01
    expected = np.mean([(-2 / 1) ** 2, (1 / 1.5) ** 2, 0.0])
    assert losses.temporal_global_loss(rotations, jolted, times).item() == pytest.approx(expected, rel=1e-4)



def test_the_translations_as_the_camera_sees_them_are_blind_to_the_scenes_scale():
    """With a reference depth the temporal term measures image position and log depth: the same
    jolted path scaled by 1.1 about the camera (a larger hand farther away) costs what it did,
    where in metres it costs 1.1^2 times more; at the reference depth a 1 mm sideways or
    forward jolt costs as much as in metres (to first order)."""
    times = torch.tensor([0, 1, 2, 3, 4])
    rotations = torch.eye(3).expand(5, 3, 3)
    path = torch.stack([0.002 * times, 0 * times, 0.5 + 0 * times], 1).double()
    path[2, 0] += 0.004
    path[3, 2] -= 0.006
    camera = losses.temporal_global_loss(rotations, path, times, reference_depth=0.5)
    assert losses.temporal_global_loss(rotations, path * 1.1, times, reference_depth=0.5).item() \
        == pytest.approx(camera.item(), rel=1e-9)
    metres = losses.temporal_global_loss(rotations, path, times)
    assert losses.temporal_global_loss(rotations, path * 1.1, times).item() == pytest.approx(1.21 * metres.item(), rel=1e-9)
    for axis in (0, 2):
        still = torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64).repeat(5, 1)
        still[2, axis] += 1e-3
        assert losses.temporal_global_loss(rotations, still, times, reference_depth=0.5).item() == pytest.approx(
            losses.temporal_global_loss(rotations, still, times).item(), rel=5e-3)

def test_coarse_displacements_are_carried_to_every_subdivided_point():
    """displacement_grid "coarse": one displacement per unsubdivided vertex; each subdivided
    point moves along its rest normal by the mean of its parents', so a constant field is the
    fine grid's constant field and a midpoint takes the mean of its edge's ends."""
    from pipeline.fit.problem import build_avatar
    from pipeline.formats.initial_estimate import InitialEstimate

    frames = 2
    initial = InitialEstimate(source="test", mode="hand", side="right", betas=np.zeros(12),
                              pose=np.zeros((frames, 16, 3)), global_orient=np.zeros((frames, 3)),
                              transl=np.tile([0.0, 0.0, 0.5], (frames, 1)), keypoints3d=np.zeros((frames, 21, 3)),
                              residual_px=np.zeros(frames), detected=np.ones(frames, dtype=bool))
    coarse = build_avatar(initial, np.arange(frames), 16, "cpu", "coarse")
    fine = build_avatar(initial, np.arange(frames), 16, "cpu", "fine")
    assert coarse.displacement.shape[0] == coarse.coarse_model.data.num_vertices
    assert fine.displacement.shape[0] == fine.model.data.num_vertices
    with torch.no_grad():
        coarse.displacement.fill_(0.001)
        fine.displacement.fill_(0.001)
    torch.testing.assert_close(coarse.displaced_rest(), fine.displaced_rest())
    with torch.no_grad():
        coarse.displacement.copy_(torch.rand(coarse.displacement.shape[0], generator=torch.Generator().manual_seed(0)))
    parents = coarse.displacement_parents
    field = coarse.displacement_field()
    torch.testing.assert_close(field, 0.5 * (coarse.displacement[parents[:, 0]] + coarse.displacement[parents[:, 1]]))
    field.sum().backward()   # the parameters get gradients through the grid
    assert coarse.displacement.grad.abs().sum() > 0
    from pipeline.fit.problem import FitError
    with pytest.raises(FitError, match="displacement_grid must be 'coarse' or 'fine'"):
        build_avatar(initial, np.arange(frames), 16, "cpu", "medium")


def test_settings_saved_before_the_coarse_grid_keep_the_fine_one():
    """A checkpoint's settings from before displacement_grid existed load as the fine grid its
    displacements were saved on; new fits default to the coarse grid, `full` to the fine one, and
    an explicit choice wins over the preset's."""
    from pipeline.fit.settings import FitSettings, settings_for

    saved = {k: v for k, v in vars(FitSettings()).items() if k != "displacement_grid"}
    assert FitSettings.from_dict(saved).displacement_grid == "fine"
    assert FitSettings().displacement_grid == "coarse"
    assert FitSettings.from_dict(vars(FitSettings())).displacement_grid == "coarse"
    assert [settings_for(preset, 150).displacement_grid for preset in ("preview", "fast", "full", "paper")] == \
        ["coarse", "coarse", "coarse", "fine"]
    assert settings_for("paper", 150, displacement_grid="coarse").displacement_grid == "coarse"
    paper = settings_for("paper", 150)
    assert FitSettings.from_dict(vars(paper)).displacement_grid == "fine"


def test_a_retired_preset_says_why_and_what_to_choose():
    from pipeline.fit.settings import settings_for

    with pytest.raises(ValueError, match="preset 'balanced' was retired: fast scored .*'preview', 'fast', 'full', 'paper'"):
        settings_for("balanced", 30)
    with pytest.raises(ValueError, match="unknown preset 'best'"):
        settings_for("best", 30)


def test_the_presets_texture_follows_the_working_image_size():
    """The texture is at most the power of two at or above the working images' long side (the
    preset's resolution, or the clip's own size when smaller: clips are never enlarged)."""
    from pipeline.fit.settings import settings_for, texture_size_for

    assert [texture_size_for(n) for n in (40, 96, 256, 257, 320, 448, 1080)] == [64, 128, 256, 512, 512, 512, 2048]
    assert settings_for("paper", 150).texture_size == 512                       # size unknown: the preset's
    assert settings_for("paper", 150, image_size=1920).texture_size == 512      # worked at 448 px
    assert settings_for("paper", 150, image_size=448).texture_size == 512
    assert settings_for("paper", 30, image_size=256).texture_size == 256        # the demo clip
    assert settings_for("full", 30, image_size=1920).texture_size == 256        # full works at fast's 256 px
    assert settings_for("preview", 30, image_size=256).texture_size == 256
    assert settings_for("fast", 30, image_size=256).texture_size == 256
    assert settings_for("fast", 30, image_size=96).texture_size == 128
    assert settings_for("paper", 30, image_size=256, texture_size=1024).texture_size == 1024  # the user's choice


def test_the_albedo_solves_finer_frames_are_the_clips_own_at_most():
    """solve_resolution is cut to the clip's own size, and dropped (no second pass) where that is
    no finer than the working images."""
    from pipeline.fit.settings import settings_for

    assert settings_for("fast", 30, image_size=448, solve_resolution=1024).solve_resolution == 448
    assert settings_for("fast", 30, image_size=1920, solve_resolution=448).solve_resolution == 448
    assert settings_for("fast", 30, image_size=256, solve_resolution=448).solve_resolution is None   # the demo
    assert settings_for("fast", 30, image_size=200, solve_resolution=448).solve_resolution is None
    assert settings_for("fast", 30, solve_resolution=448).solve_resolution == 448     # size unknown: as asked
    assert settings_for("preview", 30, image_size=256, solve_resolution=200).solve_resolution == 200  # 160 px work
    # the presets: fast and full read the clip's own frames a second time (up to the import's 1024 px), preview and
    # paper do not
    assert settings_for("fast", 30, image_size=448).solve_resolution == 448
    assert settings_for("fast", 30, image_size=873).solve_resolution == 873
    assert settings_for("full", 30, image_size=1080).solve_resolution == 1024
    assert settings_for("fast", 30, image_size=256).solve_resolution is None
    assert settings_for("fast", 30, image_size=448, solve_resolution=0).solve_resolution == 0    # the user's "off"
    assert settings_for("preview", 30, image_size=448).solve_resolution is None
    assert settings_for("paper", 30, image_size=448).solve_resolution is None


def test_the_finer_solve_grows_the_texture_unless_a_size_is_given():
    """grow_texture: on in the presets, off where the user gave a texture size (kept as given), and
    off in checkpoints saved before it (their fits wrote the stages' texture)."""
    from pipeline.fit.settings import FitSettings, settings_for

    assert settings_for("fast", 30, image_size=873).grow_texture
    assert not settings_for("fast", 30, image_size=873, texture_size=256).grow_texture
    assert settings_for("fast", 30, image_size=873, texture_size=256, grow_texture=True).grow_texture
    old = {k: v for k, v in vars(settings_for("fast", 30)).items() if k != "grow_texture"}
    assert not FitSettings.from_dict(old).grow_texture
