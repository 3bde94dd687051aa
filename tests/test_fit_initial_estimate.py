"""init.npz round trip and the ground-truth-plus-noise initialiser."""
import numpy as np
import pytest
import torch

from pipeline.init.initial_from_ground_truth import compose_axis_angle, ground_truth_with_noise
from pipeline.formats import initial_estimate as ie
from pipeline.formats.sequence_folder import GroundTruth
from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.rotations import axis_angle_to_matrix


@pytest.fixture
def ground_truth():
    model = HandModel.load("arm", dtype=torch.float64)
    frames = 5
    generator = torch.Generator().manual_seed(0)
    pose = 0.3 * torch.randn(frames, 16, 3, generator=generator, dtype=torch.float64)
    orient = torch.randn(frames, 3, generator=generator, dtype=torch.float64)
    transl = torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64).expand(frames, 3)
    betas = torch.linspace(-1, 1, model.num_betas, dtype=torch.float64)
    keypoints = model(betas, pose, orient, transl).keypoints[:, :21]
    return GroundTruth(mode="arm", side="right", betas=betas.numpy(), global_orient=orient.numpy(),
                       transl=transl.numpy(), pose=pose.numpy(), keypoints3d=keypoints.numpy(),
                       keypoints2d=np.zeros((frames, 21, 2)))


def test_noise_has_the_requested_size(ground_truth):
    estimate = ground_truth_with_noise(ground_truth, joint_degrees=10, translation_m=0.01, seed=3)
    relative = axis_angle_to_matrix(torch.as_tensor(ground_truth.pose)).transpose(-1, -2) @ \
        axis_angle_to_matrix(torch.as_tensor(estimate.pose))
    angle = torch.rad2deg(torch.acos(((relative.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)))
    np.testing.assert_allclose(angle.numpy(), 10.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(estimate.transl - ground_truth.transl, axis=1), 0.01)
    assert np.array_equal(estimate.betas, ground_truth.betas)
    assert np.all(ground_truth_with_noise(ground_truth, keep_shape=False).betas == 0)
    np.testing.assert_allclose(compose_axis_angle(ground_truth.pose[0], np.zeros((16, 3))), ground_truth.pose[0], atol=1e-9)


def test_round_trip_and_errors(ground_truth, tmp_path):
    estimate = ground_truth_with_noise(ground_truth, seed=1)
    ie.write_initial_estimate(tmp_path, estimate)
    again = ie.read_initial_estimate(tmp_path)
    for name in ("betas", "pose", "global_orient", "transl", "keypoints3d", "residual_px", "detected"):
        assert np.array_equal(getattr(again, name), getattr(estimate, name)), name
    assert again.metadata == estimate.metadata and again.source == "gt-noise"
    with pytest.raises(ie.InitialEstimateError, match="harp init"):
        ie.read_initial_estimate(tmp_path / "elsewhere")
    estimate.pose[0, 0, 0] = np.nan
    with pytest.raises(ie.InitialEstimateError, match="NaN"):
        ie.write_initial_estimate(tmp_path, estimate)
