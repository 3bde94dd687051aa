"""`harp init`: keypoint files, MediaPipe on synthetic renders, the initial fit against ground
truth, and one-line errors."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.cli import main
from pipeline.detection import mediapipe_hands
from pipeline.formats import keypoint_file as kf
from pipeline.init import initial_fit as fit
from pipeline.init.initialisation import forearm_fraction
from pipeline.formats import initial_estimate as ie
from pipeline.formats import sequence_folder as seq
from pipeline.formats.camera import project
from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.rotations import axis_angle_to_matrix
from pipeline.metrics import procrustes_error

ROOT = Path(__file__).resolve().parents[1]
K = np.array([[1000.0, 0, 128], [0, 1000.0, 128], [0, 0, 1]])


def render(out, *args):
    command = [sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(out), "--width", "256",
               "--height", "256", "--samples", "1", "--texture-size", "256", "--lighting", "ambient", *args]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="module")
def right_clip(tmp_path_factory):
    """A rendered right hand + forearm, 6 frames of `flip` (1 s: back, palm, back)."""
    return render(tmp_path_factory.mktemp("right") / "clip", "--motion", "flip", "--frames", "6", "--seconds", "1")


@pytest.fixture(scope="module")
def left_clip(tmp_path_factory):
    return render(tmp_path_factory.mktemp("left") / "clip", "--side", "left", "--frames", "4", "--seconds", "1")


@pytest.fixture(scope="module")
def model():
    return HandModel.load("hand", dtype=torch.float64)


def synthetic_hands(model, frames=6, seed=0):
    """A smooth motion between two random poses inside the joint limits, in front of the camera:
    parameters, 3D keypoints (F, 21, 3) and their projections (F, 21, 2) through K."""
    generator = torch.Generator().manual_seed(seed)
    dtype = torch.float64
    limits = model.joint_limits
    ends = limits[..., 0] + (limits[..., 1] - limits[..., 0]) * torch.rand(2, 16, 3, generator=generator, dtype=dtype)
    t = torch.linspace(0, 1, frames, dtype=dtype)[:, None, None]
    pose = 0.5 * ((1 - t) * ends[0] + t * ends[1])
    pose[:, 0] = 0
    orient = torch.tensor([np.pi, 0.0, 0.0], dtype=dtype) + 0.5 * t[:, :, 0] * torch.tensor([0.3, 1.0, 0.2], dtype=dtype)
    transl = torch.tensor([[0.0, 0.08, 0.6]], dtype=dtype) + 0.05 * t[:, :, 0] * torch.tensor([1.0, 0.0, 0.5], dtype=dtype)
    betas = 0.5 * torch.randn(model.num_betas, generator=generator, dtype=dtype)
    keypoints = model(betas, pose, orient, transl).keypoints[:, :21]
    pixels = np.stack([project(frame, K)[0] for frame in keypoints.numpy()])
    return betas, pose, orient, transl, keypoints.numpy(), pixels


# --- pieces, on analytic cases ----------------------------------------------------------------
def test_model_keypoints_equal_the_posed_model(model):
    betas, pose, orient, transl, keypoints, _ = synthetic_hands(model)
    local = fit.model_keypoints(model, betas, pose)
    moved = local @ axis_angle_to_matrix(orient).transpose(1, 2) + transl[:, None]
    np.testing.assert_allclose(moved.numpy(), keypoints, atol=1e-12)


def test_translation_and_rotation_solvers_are_exact():
    generator = torch.Generator().manual_seed(1)
    points = 0.05 * torch.randn(4, 8, 3, generator=generator, dtype=torch.float64)
    transl = torch.tensor([[0.02, -0.01, 0.5], [0.0, 0.0, 0.3], [-0.05, 0.03, 0.8], [0.1, 0.1, 1.0]], dtype=torch.float64)
    pixels = torch.stack([torch.as_tensor(project((p + t).numpy(), K)[0]) for p, t in zip(points, transl)])
    solved = fit.solve_translation(points, pixels, torch.as_tensor(K))
    torch.testing.assert_close(solved, transl, atol=1e-10, rtol=0)
    rotation = fit.random_rotations(4, generator)
    torch.testing.assert_close(fit.kabsch(points, points @ rotation.transpose(1, 2)), rotation, atol=1e-10, rtol=0)
    assert torch.allclose(rotation @ rotation.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(4, 3, 3))
    flipped = fit.palm_flip(rotation)  # 180 degrees about the hand's long axis (model y)
    torch.testing.assert_close(flipped @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), rotation[..., 1])


def test_fit_to_exact_keypoints_recovers_the_hand(model):
    betas, pose, orient, transl, keypoints, pixels = synthetic_hands(model)
    frames = len(pixels)
    exact = kf.Keypoints2D(points=pixels, detected=np.ones(frames, bool), score=np.ones(frames), source="keypoints")
    estimate = fit.fit_initial_estimate(exact, K, mode="hand", model=model)
    estimate.validate()
    hand_px = np.linalg.norm(pixels.max(1) - pixels.min(1), axis=-1).mean()
    assert np.median(estimate.residual_px) < 0.01 * hand_px   # measured 2.6 px of 390 px
    error_mm = 1000 * procrustes_error(torch.as_tensor(estimate.keypoints3d), torch.as_tensor(keypoints)).numpy()
    assert error_mm.mean() < 10, error_mm  # measured 7.7 mm: 2D alone leaves finger depth ambiguous
    # depth from the hand's size, and the size (shape) is not known: a relative error like a
    # hand size's (measured 7%)
    depth_error = np.abs(estimate.transl[:, 2] / transl[:, 2].numpy() - 1)
    assert depth_error.mean() < 0.1
    assert np.all(estimate.pose[:, 0] == 0)


def test_interpolation_over_missing_frames():
    values = np.array([[0.0], [0.0], [2.0], [0.0], [6.0], [0.0]])
    detected = np.array([False, True, False, True, True, False])
    np.testing.assert_allclose(kf.interpolate_missing(values, detected)[:, 0], [0, 0, 0, 0, 6, 6])
    values[3] = 4.0
    np.testing.assert_allclose(kf.interpolate_missing(values, detected)[:, 0], [0, 0, 2, 4, 6, 6])
    with pytest.raises(kf.KeypointError, match="no frame"):
        kf.interpolate_missing(values, np.zeros(6, bool))


def test_keypoint_files(tmp_path):
    points = np.random.default_rng(0).uniform(20, 200, (5, 21, 2))
    np.save(tmp_path / "k.npy", points)
    np.savez(tmp_path / "k.npz", keypoints=points, score=np.full(5, 0.7))
    frames = points.tolist()
    frames[2] = None
    (tmp_path / "k.json").write_text(json.dumps({"format": "harp-keypoints", "version": 1, "keypoints": frames}))
    for name in ("k.npy", "k.npz"):
        read = kf.read_keypoint_file(tmp_path / name, 5, 256, 256)
        np.testing.assert_array_equal(read.points, points)
        assert read.detected.all()
    assert np.all(kf.read_keypoint_file(tmp_path / "k.npz", 5, 256, 256).score == 0.7)
    read = kf.read_keypoint_file(tmp_path / "k.json", 5, 256, 256)
    assert read.detected.tolist() == [True, True, False, True, True]
    np.testing.assert_allclose(read.points[2], (points[1] + points[3]) / 2)
    again = kf.read_keypoint_file(kf.write_keypoint_file(tmp_path / "again.json", read), 5, 256, 256)
    np.testing.assert_allclose(again.points[read.detected], points[read.detected], atol=1e-3)

    with pytest.raises(kf.KeypointError, match="for 5 frames, the sequence has 6"):
        kf.read_keypoint_file(tmp_path / "k.npy", 6, 256, 256)
    np.save(tmp_path / "normalised.npy", points / 256)
    with pytest.raises(kf.KeypointError, match="look normalised"):
        kf.read_keypoint_file(tmp_path / "normalised.npy", 5, 256, 256)
    np.save(tmp_path / "shape.npy", points[:, :20])
    with pytest.raises(kf.KeypointError, match=r"expected \(5, 21, 2\)"):
        kf.read_keypoint_file(tmp_path / "shape.npy", 5, 256, 256)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(kf.KeypointError, match="cannot read"):
        kf.read_keypoint_file(tmp_path / "bad.json", 5, 256, 256)
    with pytest.raises(kf.KeypointError, match="not found"):
        kf.read_keypoint_file(tmp_path / "missing.npy", 5, 256, 256)


# --- MediaPipe on synthetic renders -----------------------------------------------------------
def test_mediapipe_on_a_rendered_right_hand(right_clip):
    info = seq.read_sequence_info(right_clip)
    gt = seq.read_ground_truth(right_clip / seq.GT_FILE)
    keypoints = mediapipe_hands.detect_sequence_keypoints(right_clip, info)
    assert keypoints.detected.mean() >= 0.5
    error = np.linalg.norm(keypoints.points - gt.keypoints2d, axis=-1).mean(-1)[keypoints.detected]
    assert np.median(error) < 0.05 * info.width, error   # measured about 6 px at 256 (docs)
    # an unmirrored right hand is what MediaPipe's selfie-trained label calls "Left"
    assert keypoints.handedness_ok[keypoints.detected].mean() >= 0.5
    world_error = procrustes_error(torch.as_tensor(keypoints.world), torch.as_tensor(gt.keypoints3d))
    assert 1000 * world_error[torch.as_tensor(keypoints.detected)].mean() < 25


def test_mediapipe_reads_a_large_sequence_shrunk_and_answers_in_its_pixels(right_clip):
    """harp init detects a sequence's frames shrunk to SEQUENCE_DETECTION_SIZE where they are larger
    (the import keeps windows up to 1024 px): the 256 px clip detected at 128 px gives keypoints in
    its own 256 px frame, near the true projections and near its detection at full size."""
    info = seq.read_sequence_info(right_clip)
    gt = seq.read_ground_truth(right_clip / seq.GT_FILE)
    full = mediapipe_hands.detect_sequence_keypoints(right_clip, info)       # 256 px: under the size, as it is
    half = mediapipe_hands.detect_sequence_keypoints(right_clip, info, size=128)
    both = full.detected & half.detected
    assert both.mean() >= 0.5
    error = np.linalg.norm(half.points - gt.keypoints2d, axis=-1).mean(-1)[half.detected]
    assert np.median(error) < 0.06 * info.width, error
    apart = np.linalg.norm(half.points - full.points, axis=-1).mean(-1)[both]
    assert np.median(apart) < 0.03 * info.width, apart      # unscaled, they would be a hand's size apart


def test_mediapipe_calls_a_left_hand_right(left_clip):
    side, votes = mediapipe_hands.guess_hand_side(seq.read_rgb(p) for p in sorted((left_clip / "rgb").glob("*.png")))
    assert side == "left" and votes["left"] > votes["right"], votes


def test_forearm_fraction_tells_arm_from_hand(right_clip):
    info = seq.read_sequence_info(right_clip)
    gt = seq.read_ground_truth(right_clip / seq.GT_FILE)
    mask = seq.read_mask(seq.mask_path(right_clip, info, 0))
    keypoints = gt.keypoints2d[0]
    assert forearm_fraction(mask, keypoints) > 0.02
    # cut the mask at the wrist, across the hand's axis: a hand-only mask
    rows, cols = np.mgrid[0:info.height, 0:info.width] + 0.5
    axis = keypoints[9] - keypoints[0]
    along = (cols - keypoints[0][0]) * axis[0] + (rows - keypoints[0][1]) * axis[1]
    assert forearm_fraction(mask & (along > 0), keypoints) == 0


# --- the command ------------------------------------------------------------------------------
def run(capsys, *args):
    code = main(["init", *[str(a) for a in args]])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip().splitlines()


def test_init_command_end_to_end(right_clip, capsys):
    gt = seq.read_ground_truth(right_clip / seq.GT_FILE)
    code, out, _ = run(capsys, right_clip)
    assert code == 0 and "template mode: arm" in out
    estimate = ie.read_initial_estimate(right_clip)
    assert estimate.source == "mediapipe" and estimate.mode == "arm" and estimate.side == "right"
    error_mm = 1000 * procrustes_error(torch.as_tensor(estimate.keypoints3d), torch.as_tensor(gt.keypoints3d))
    assert error_mm.mean() < 20, error_mm     # measured 7 - 12 mm on 30-frame clips (docs)
    assert np.median(estimate.residual_px) < 0.08 * 256
    assert (right_clip / "keypoints.json").is_file()

    code, _, _ = run(capsys, right_clip, "--init", "keypoints", right_clip / "keypoints.json", "--mode", "hand")
    estimate = ie.read_initial_estimate(right_clip)
    assert code == 0 and estimate.source == "keypoints" and estimate.mode == "hand"

    code, _, _ = run(capsys, right_clip, "--init", "gt-noise", "--seed", "3")
    estimate = ie.read_initial_estimate(right_clip)
    assert code == 0 and estimate.source == "gt-noise" and estimate.metadata["joint_degrees"] == 10


def one_line_error(capsys, *args):
    code, _, err = run(capsys, *args)
    assert code == 1 and len(err) == 1 and err[0].startswith("harp: error: "), err
    return err[0]


def test_init_errors_are_one_line(right_clip, tmp_path, capsys):
    assert "sequence folder not found" in one_line_error(capsys, tmp_path / "missing")
    assert "needs a FILE" in one_line_error(capsys, right_clip, "--init", "keypoints")
    assert "takes no file" in one_line_error(capsys, right_clip, "--init", "mediapipe", "extra.json")
    assert "unknown --init" in one_line_error(capsys, right_clip, "--init", "metro")
    assert "does not match" in one_line_error(capsys, right_clip, "--init", "gt-noise", "--mode", "hand")
    assert "keypoint file not found" in one_line_error(capsys, right_clip, "--init", "keypoints", tmp_path / "k.npy")

    # a clip without a hand: MediaPipe finds nothing
    info = seq.read_sequence_info(right_clip)
    blank = tmp_path / "blank"
    for index in range(3):
        seq.write_png(seq.frame_path(blank, info, index), np.full((64, 64, 3), 120, np.uint8))
        mask = np.zeros((64, 64), np.uint8)
        mask[20:40, 20:40] = 255
        seq.write_png(seq.mask_path(blank, info, index), mask)
    seq.write_sequence_info(blank, seq.SequenceInfo(fps=30, width=64, height=64, frame_count=3, hand_side="right",
                                                    K=K))
    assert "MediaPipe found no hand in any of the 3 frames" in one_line_error(capsys, blank, "--progress", "none")
    assert "needs ground truth" in one_line_error(capsys, blank, "--init", "gt-noise")
