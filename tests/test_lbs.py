"""The torch model against independent references: template, linearity, finite differences,
an exact mirror, and finite results everywhere."""
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pipeline.handmodel import joint_limits, mirror
from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from pipeline.handmodel.subdivision import midpoint_edges

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def test_zero_pose_reproduces_template(model64, mode):
    model = model64[mode]
    out = model()
    np.testing.assert_allclose(out.vertices[0].numpy(), model.data.vertices, atol=1e-15)
    np.testing.assert_allclose(out.joints[0].numpy(), model.data.joints, atol=1e-15)
    np.testing.assert_allclose(out.keypoints[0].numpy(), model.data.keypoints, atol=1e-15)
    betas = torch.linspace(-2, 2, model.num_betas, dtype=torch.float64)
    expected = model.data.vertices + model.data.shapedirs @ betas.numpy()
    np.testing.assert_allclose(model(betas=betas).vertices[0].numpy(), expected, atol=1e-14)


def test_translation_and_global_rotation_are_rigid(model64):
    model = model64["hand"]
    rotvec = np.array([0.3, -1.1, 0.4])
    out = model(global_orient=torch.tensor(rotvec[None]), transl=torch.tensor([[0.1, -0.2, 0.5]], dtype=torch.float64))
    expected = Rotation.from_rotvec(rotvec).apply(model.data.vertices) + [0.1, -0.2, 0.5]
    np.testing.assert_allclose(out.vertices[0].numpy(), expected, atol=1e-14)


def test_joint_rotation_matches_rotation_about_the_pivot(model64):
    """A vertex carried by a single bone moves by the frame-conjugated rotation about its pivot."""
    model = model64["hand"]
    dense = model.data.dense_weights()
    joint = 3  # index DIP
    rigid = np.where(dense[:, joint] == 1.0)[0]
    assert len(rigid) > 10
    local = np.array([0.5, 0.1, -0.2])
    pose = torch.zeros(1, 16, 3, dtype=torch.float64)
    pose[0, joint] = torch.tensor(local)
    frame = model.data.joint_frames[joint]
    rotation = frame @ Rotation.from_rotvec(local).as_matrix() @ frame.T
    pivot = model.data.joints[joint]
    expected = (model.data.vertices[rigid] - pivot) @ rotation.T + pivot
    np.testing.assert_allclose(model(pose=pose).vertices[0, rigid].numpy(), expected, atol=1e-14)


def test_joints_are_exactly_linear_in_beta(model64, mode):
    model = model64[mode]
    generator = torch.Generator().manual_seed(2)
    a, b = (torch.randn(model.num_betas, generator=generator, dtype=torch.float64) for _ in range(2))
    pose = 0.3 * torch.randn(1, 16, 3, generator=generator, dtype=torch.float64)
    for p in (None, pose):
        j = lambda beta: model(betas=beta, pose=p).joints[0]
        zero = j(torch.zeros_like(a))
        np.testing.assert_allclose((j(a + 2 * b) - zero).numpy(),
                                   ((j(a) - zero) + 2 * (j(b) - zero)).numpy(), atol=1e-14)


def test_rotation_matches_scipy():
    generator = torch.Generator().manual_seed(3)
    vectors = torch.cat([torch.randn(200, 3, generator=generator, dtype=torch.float64) * 2,
                         torch.randn(50, 3, generator=generator, dtype=torch.float64) * 1e-5,
                         torch.zeros(1, 3, dtype=torch.float64),
                         torch.tensor([[np.pi, 0, 0], [0, np.pi - 1e-7, 0]], dtype=torch.float64)])
    expected = Rotation.from_rotvec(vectors.numpy()).as_matrix()
    np.testing.assert_allclose(axis_angle_to_matrix(vectors).numpy(), expected, atol=1e-13)
    inside = vectors[vectors.norm(dim=1) < np.pi - 1e-3]
    back = matrix_to_axis_angle(axis_angle_to_matrix(inside))
    np.testing.assert_allclose(back.numpy(), inside.numpy(), atol=1e-9)
    near_pi = torch.tensor([[np.pi - 1e-9, 0.0, 0.0]], dtype=torch.float64)
    np.testing.assert_allclose(axis_angle_to_matrix(matrix_to_axis_angle(axis_angle_to_matrix(near_pi))).numpy(),
                               axis_angle_to_matrix(near_pi).numpy(), atol=1e-7)


def _pose_cases():
    generator = torch.Generator().manual_seed(4)
    rest = torch.zeros(16, 3, dtype=torch.float64)
    near_zero = 1e-9 * torch.randn(16, 3, generator=generator, dtype=torch.float64)
    directions = torch.nn.functional.normalize(torch.randn(16, 3, generator=generator, dtype=torch.float64), dim=1)
    near_pi = (np.pi - 1e-4) * directions
    beyond = 2.5 * directions  # far outside every joint limit
    return {"rest": rest, "near_zero": near_zero, "near_pi": near_pi, "beyond_limits": beyond}


@pytest.mark.parametrize("case", list(_pose_cases()))
def test_gradients_match_finite_differences(model64, mode, case):
    model = model64[mode]
    pose = _pose_cases()[case].clone()[None].requires_grad_(True)
    orient = (pose[0, 0].detach().clone()[None] * 0.5).requires_grad_(True)
    transl = torch.tensor([[0.01, 0.02, 0.5]], dtype=torch.float64, requires_grad=True)
    betas = torch.linspace(-1, 1, model.num_betas, dtype=torch.float64).requires_grad_(True)
    vertex_subset = torch.arange(0, model.data.num_vertices, 37)

    def f(pose, orient, transl, betas):
        out = model(betas=betas, pose=pose, global_orient=orient, transl=transl)
        return torch.cat([out.vertices[:, vertex_subset].reshape(-1), out.keypoints.reshape(-1)])

    assert torch.autograd.gradcheck(f, (pose, orient, transl, betas), eps=1e-6, atol=1e-6, rtol=1e-5)


def test_gradients_of_given_rest_vertices_and_per_frame_shapes_match_finite_differences(model64, mode):
    """The skinning's hand-written blend (lbs._Blend) in the fit's use: two frames of one rest
    surface given as `rest_vertices`, and two frames of their own shapes."""
    model = model64[mode]
    generator = torch.Generator().manual_seed(4)
    pose = (0.3 * torch.randn(2, 16, 3, generator=generator, dtype=torch.float64)).requires_grad_(True)
    orient = torch.tensor([[0.2, -0.1, 0.3], [np.pi - 0.4, 0.2, 0.1]], dtype=torch.float64, requires_grad=True)
    transl = torch.tensor([[0.01, 0.02, 0.5], [0.0, -0.03, 0.4]], dtype=torch.float64, requires_grad=True)
    subset = torch.arange(0, model.data.num_vertices, 53)
    rest = model.shaped(torch.zeros(model.num_betas, dtype=torch.float64))[0]
    rest = (rest + 0.001 * torch.randn(rest.shape, generator=generator, dtype=torch.float64)).requires_grad_(True)

    def given_rest(pose, orient, transl, rest):
        return model(pose=pose, global_orient=orient, transl=transl, rest_vertices=rest).vertices[:, subset].reshape(-1)

    assert torch.autograd.gradcheck(given_rest, (pose, orient, transl, rest), eps=1e-6, atol=1e-6, rtol=1e-5)
    betas = torch.linspace(-1, 1, 2 * model.num_betas, dtype=torch.float64).reshape(2, -1).requires_grad_(True)

    def per_frame(betas, pose):
        return model(betas=betas, pose=pose, global_orient=orient.detach(), transl=transl.detach()).vertices[:, subset].reshape(-1)

    assert torch.autograd.gradcheck(per_frame, (betas, pose), eps=1e-6, atol=1e-6, rtol=1e-5)


def test_joint_limit_prior(model64):
    limits = model64["hand"].joint_limits
    inside = torch.zeros(2, 16, 3, dtype=torch.float64)
    for name in NAMED_POSES:
        inside[0] = torch.as_tensor(NAMED_POSES[name])
        assert joint_limits.joint_limit_penalty(inside[:1], limits).item() == 0.0, name
    outside = (limits[..., 1] + 0.2).expand(1, 16, 3).clone().requires_grad_(True)
    penalty = joint_limits.joint_limit_penalty(outside, limits)
    assert penalty.item() == pytest.approx(16 * 3 * 0.04)
    assert torch.autograd.gradcheck(lambda p: joint_limits.joint_limit_penalty(p, limits),
                                    (outside,), eps=1e-6, atol=1e-7)


def test_ten_thousand_random_poses_stay_finite(model64, mode):
    model = HandModel(model64[mode].data, dtype=torch.float32)
    generator = torch.Generator().manual_seed(5)
    limits = model.joint_limits
    for chunk in range(5):
        n = 2000
        inside = limits[..., 0] + (limits[..., 1] - limits[..., 0]) * torch.rand(n // 2, 16, 3, generator=generator)
        wild = 12 * torch.randn(n // 2, 16, 3, generator=generator)  # far outside, several turns
        pose = torch.cat([inside, wild]).requires_grad_(True)
        betas = (6 * torch.rand(n, model.num_betas, generator=generator) - 3).requires_grad_(True)
        orient = (4 * torch.randn(n, 3, generator=generator)).requires_grad_(True)
        transl = torch.randn(n, 3, generator=generator).requires_grad_(True)
        out = model(betas=betas, pose=pose, global_orient=orient, transl=transl)
        assert torch.isfinite(out.vertices).all() and torch.isfinite(out.keypoints).all()
        loss = out.vertices.square().mean() + joint_limits.joint_limit_penalty(pose, limits).mean()
        loss.backward()
        for tensor in (pose, betas, orient, transl):
            assert torch.isfinite(tensor.grad).all()


def test_left_hand_is_an_exact_mirror(model64, mode):
    right = model64[mode]
    left = HandModel.load(mode, side="left", dtype=torch.float64)
    generator = torch.Generator().manual_seed(6)
    pose = 0.4 * torch.randn(3, 16, 3, generator=generator, dtype=torch.float64)
    orient = torch.randn(3, 3, generator=generator, dtype=torch.float64)
    transl = torch.randn(3, 3, generator=generator, dtype=torch.float64)
    betas = torch.randn(right.num_betas, generator=generator, dtype=torch.float64)
    r = right(betas=betas, pose=pose, global_orient=orient, transl=transl)
    l = left(betas=betas, pose=mirror.mirror_axis_angle(pose), global_orient=mirror.mirror_axis_angle(orient),
             transl=mirror.mirror_points(transl))
    np.testing.assert_allclose(l.vertices.numpy(), mirror.mirror_points(r.vertices).numpy(), atol=1e-14)
    np.testing.assert_allclose(l.keypoints.numpy(), mirror.mirror_points(r.keypoints).numpy(), atol=1e-14)
    from pipeline.handmodel import mesh_checks
    assert mesh_checks.signed_volume(left.data.vertices, left.data.faces) > 0
    limit_penalty = joint_limits.joint_limit_penalty
    assert torch.allclose(limit_penalty(pose, right.joint_limits),
                          limit_penalty(mirror.mirror_axis_angle(pose), left.joint_limits))
    twice = mirror.mirror_model_data(left.data)
    assert np.array_equal(twice.vertices, right.data.vertices) and np.array_equal(twice.faces, right.data.faces)


def test_subdivided_model_is_the_midpoint_subdivision(model64, mode):
    base = model64[mode]
    fine = HandModel.load(mode, subdivided=True, dtype=torch.float64)
    edges, _ = midpoint_edges(base.data.faces)
    assert fine.data.num_vertices == base.data.num_vertices + len(edges)
    assert len(fine.data.faces) == 4 * len(base.data.faces)
    betas = torch.linspace(-3, 3, base.num_betas, dtype=torch.float64)
    coarse = base.shaped(betas)[0].numpy()
    shaped = fine.shaped(betas)[0].numpy()
    # every base vertex is kept; every other vertex is the midpoint of a base edge
    kept = np.array([np.where((shaped == v).all(1))[0][0] for v in coarse[:50]])
    assert len(kept) == 50
    midpoints = 0.5 * (coarse[edges[:, 0]] + coarse[edges[:, 1]])
    from scipy.spatial import cKDTree
    distance, _ = cKDTree(shaped).query(midpoints)
    assert distance.max() < 1e-12
    # the UV of a split edge is the mean of its ends' UVs: areas sum up
    def area(uv, f):
        a, b = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
        return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()   # np.cross of 2-vectors is gone in numpy 2
    assert area(fine.data.uvs, fine.data.faces_uv) == pytest.approx(area(base.data.uvs, base.data.faces_uv))
    # posing the fine model agrees with posing the coarse one at the kept vertices
    pose = torch.as_tensor(NAMED_POSES["fist"])[None]
    kept_all = fine.data.num_vertices - len(edges)
    order = np.concatenate([np.arange(base.data.shared_vertex_count)])
    np.testing.assert_allclose(fine(pose=pose).vertices[0, order].numpy(),
                               base(pose=pose).vertices[0, order].numpy(), atol=1e-12)
    assert kept_all == base.data.num_vertices


def test_subdivided_modes_still_share_a_leading_block():
    hand = HandModel.load("hand", subdivided=True, dtype=torch.float64).data
    arm = HandModel.load("arm", subdivided=True, dtype=torch.float64).data
    n = hand.shared_vertex_count
    assert n == arm.shared_vertex_count
    assert np.array_equal(hand.vertices[:n], arm.vertices[:n])


@pytest.mark.parametrize("device", DEVICES)
def test_float32_and_device_agree_with_float64(model64, device):
    data = model64["arm"].data
    model32 = HandModel(data, dtype=torch.float32, device=device)
    pose = torch.as_tensor(NAMED_POSES["fist"])[None]
    orient = torch.tensor([[0.2, 0.3, -0.1]], dtype=torch.float64)
    v64 = model64["arm"](pose=pose, global_orient=orient).vertices
    v32 = model32(pose=pose.float().to(device), global_orient=orient.float().to(device)).vertices
    assert v32.device.type == device and v32.dtype == torch.float32
    np.testing.assert_allclose(v32.cpu().numpy(), v64.numpy(), atol=2e-6)
