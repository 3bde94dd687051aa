"""The sequence-folder format module: round trips and one-line errors (numpy only)."""
import json

import numpy as np
import pytest

from pipeline.formats import sequence_folder as seq


def make_info(frames=3):
    K = np.array([[500.0, 0, 32], [0, 500.0, 32], [0, 0, 1]])
    return seq.SequenceInfo(fps=30, width=64, height=64, frame_count=frames, hand_side="right", K=K,
                            ground_truth=seq.GT_FILE, albedo=seq.GT_ALBEDO_FILE)


def make_gt(frames=3):
    rng = np.random.default_rng(0)
    return seq.GroundTruth(mode="arm", side="right", betas=rng.normal(size=12),
                           global_orient=rng.normal(size=(frames, 3)), transl=rng.normal(size=(frames, 3)),
                           pose=rng.normal(size=(frames, 16, 3)), keypoints3d=rng.normal(size=(frames, 21, 3)),
                           keypoints2d=rng.normal(size=(frames, 21, 2)), vertices=rng.normal(size=(frames, 10, 3)),
                           personal_offsets=rng.normal(size=(10, 3)), light={"preset": "sun"})


def write_folder(folder, frames=3):
    info = make_info(frames)
    image = np.zeros((64, 64, 3), np.uint8)
    for i in range(frames):
        seq.write_png(seq.frame_path(folder, info, i), image)
        seq.write_png(seq.mask_path(folder, info, i), image[..., 0])
    seq.write_png(folder / seq.GT_ALBEDO_FILE, image)
    seq.write_ground_truth(folder / seq.GT_FILE, make_gt(frames))
    seq.write_sequence_info(folder, info)
    return info


def test_round_trip(tmp_path):
    info = write_folder(tmp_path)
    back = seq.validate_sequence_folder(tmp_path)
    np.testing.assert_array_equal(back.K, info.K)
    assert (back.fps, back.width, back.height, back.frame_count, back.hand_side) == (30, 64, 64, 3, "right")
    assert seq.frame_path(tmp_path, back, 2) == tmp_path / "rgb" / "000002.png"
    gt, ref = seq.read_ground_truth(tmp_path / seq.GT_FILE), make_gt()
    for name in ("betas", "global_orient", "transl", "pose", "keypoints3d", "keypoints2d"):
        np.testing.assert_array_equal(getattr(gt, name), getattr(ref, name))
    np.testing.assert_allclose(gt.vertices, ref.vertices, atol=1e-6)
    assert gt.mode == "arm" and gt.light == {"preset": "sun"}


def test_png_writer_matches_opencv(tmp_path):
    cv2 = pytest.importorskip("cv2")
    image = (np.random.default_rng(1).random((17, 23, 3)) * 255).astype(np.uint8)
    seq.write_png(tmp_path / "a.png", image)
    np.testing.assert_array_equal(seq.read_rgb(tmp_path / "a.png"), image)
    seq.write_png(tmp_path / "g.png", image[..., 1])
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "g.png"), cv2.IMREAD_UNCHANGED), image[..., 1])
    assert seq.png_size(tmp_path / "a.png") == (23, 17)


def test_fov_instead_of_K(tmp_path):
    entry = make_info().to_json()
    del entry["K"]
    entry["horizontal_fov_deg"] = 90.0
    (tmp_path / seq.SEQUENCE_FILE).write_text(json.dumps(entry))
    np.testing.assert_allclose(seq.read_sequence_info(tmp_path).K, [[32, 0, 32], [0, 32, 32], [0, 0, 1]])


@pytest.mark.parametrize("damage, message", [
    (lambda f: (f / "rgb" / "000001.png").unlink(), "frame 1 of 3 is missing"),
    (lambda f: (f / "mask" / "000002.png").unlink(), "mask 2 of 3 is missing"),
    (lambda f: seq.write_png(f / "rgb" / "000003.png", np.zeros((64, 64, 3), np.uint8)), "more frames than"),
    (lambda f: seq.write_png(f / "rgb" / "000000.png", np.zeros((32, 64, 3), np.uint8)), "is 64x32"),
    (lambda f: seq.write_ground_truth(f / seq.GT_FILE, make_gt(2)), "ground truth has 2 frames"),
    (lambda f: (f / seq.GT_ALBEDO_FILE).unlink(), "albedo not found"),
    (lambda f: (f / seq.SEQUENCE_FILE).unlink(), "no sequence.json"),
    (lambda f: _edit_json(f, version=7), "format version 7"),
    (lambda f: _edit_json(f, format="other"), "is not a harp-sequence file"),
    (lambda f: _edit_json(f, fps=-1), "fps must be positive"),
    (lambda f: _edit_json(f, hand_side="middle"), "hand_side"),
])
def test_errors_are_one_line(tmp_path, damage, message):
    write_folder(tmp_path)
    damage(tmp_path)
    with pytest.raises(seq.SequenceFolderError, match=message) as error:
        seq.validate_sequence_folder(tmp_path)
    assert "\n" not in str(error.value)


def test_ground_truth_shape_errors(tmp_path):
    gt = make_gt()
    gt.keypoints2d = gt.keypoints2d[:, :20]
    with pytest.raises(seq.SequenceFolderError, match=r"keypoints2d has shape \(3, 20, 2\)"):
        seq.write_ground_truth(tmp_path / "gt.npz", gt)


def _edit_json(folder, **changes):
    path = folder / seq.SEQUENCE_FILE
    entry = json.loads(path.read_text())
    entry.update(changes)
    path.write_text(json.dumps(entry))
