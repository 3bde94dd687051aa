"""Bad input to `harp import-video`, `init`, `fit` and `render`: one clear line `harp: error:
...` on stderr and exit status 1 (no traceback, and nothing from native libraries either:
stderr is captured at the file descriptor), or a documented recovery (docs/initialisation.md,
"Bad input").

Covered next door and not repeated here: import-video's frame/mask count mismatch, mask of
another size, all-foreground mask, all masks empty, missing video or masks, a file that is no
video, and empty-mask frames left out (tests/test_import_video.py); init on a missing folder
and MediaPipe finding no hand in any frame (tests/test_initialisation.py).
"""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluate.exact_clips import write_clip
from pipeline.cli import main
from pipeline.init import initialise_sequence
from pipeline.formats import initial_estimate as ie
from pipeline.formats import sequence_folder as seq
from pipeline.formats.camera import project
from synth.motions import RELAXED
from test_import_video import draw_clip

ROOT = Path(__file__).resolve().parents[1]
FIT = ["--progress", "none", "--shadows", "off", "--device", "cpu"]


def one_line_error(capfd, *argv):
    """Run `harp ARGV`; check it failed with exactly one `harp: error:` line; return the line."""
    code = main([str(a) for a in argv])
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and err[0].startswith("harp: error: "), (code, err)
    return err[0]


@pytest.fixture(scope="module")
def good_clip(tmp_path_factory):
    """A valid 3-frame, 48 px sequence folder with ground truth and an init.npz."""
    folder = tmp_path_factory.mktemp("good") / "clip"
    write_clip(folder, RELAXED, frames=3, size=48)
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


@pytest.fixture
def clip(good_clip, tmp_path):
    """A copy of good_clip to damage."""
    return Path(shutil.copytree(good_clip, tmp_path / "clip"))


# --- import-video: damaged video files ----------------------------------------------------------
def test_damaged_videos_give_one_line_and_no_decoder_noise(tmp_path, capfd):
    frames, masks, _ = draw_clip(tmp_path / "src", frames=6, video=True, masks_as_video=True)
    common = ["--out", tmp_path / "seq", "--side", "right", "--size", 64]
    noise = tmp_path / "noise.mp4"   # FFmpeg prints "moov atom not found" for this on fd 2
    noise.write_bytes(np.random.default_rng(1).integers(0, 255, 5000).astype(np.uint8).tobytes())
    assert "cannot read masks" in one_line_error(capfd, "import-video", frames, "--masks", noise, *common)
    truncated = tmp_path / "truncated.avi"   # cut in the middle: 6 frames in the header, 4 decodable
    truncated.write_bytes(frames.read_bytes()[:frames.stat().st_size // 2])
    line = one_line_error(capfd, "import-video", truncated, "--masks", masks, *common)
    assert "frame/mask count mismatch: 4 frames, 6 masks; the video truncated.avi states 6 frames but only 4 " \
           "could be decoded (damaged or truncated file?)" in line
    assert not (tmp_path / "seq").exists()


# --- fit and render: missing folders and files -----------------------------------------------
def test_missing_folders(tmp_path, capfd):
    missing = tmp_path / "missing"
    assert f"sequence folder not found: {missing}" in one_line_error(capfd, "fit", missing, "--out",
                                                                     tmp_path / "avatar", *FIT)
    assert not (tmp_path / "avatar").exists()   # nothing written on an error
    assert f"avatar folder not found: {missing}" in one_line_error(capfd, "render", missing, "--out",
                                                                   tmp_path / "a.png")


def test_fit_without_init(clip, tmp_path, capfd):
    (clip / ie.FILE_NAME).unlink()
    line = one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)
    assert f"no initial estimate at {clip / ie.FILE_NAME}; run `harp init` first" in line
    assert not (tmp_path / "avatar").exists()


# --- sequence folders written by hand ------------------------------------------------------------
def test_mask_of_another_size_than_its_frame(clip, tmp_path, capfd):
    seq.write_png(clip / "mask" / "000001.png", np.zeros((24, 48), np.uint8))
    expected = f"{clip / 'mask' / '000001.png'} is 48x24, sequence.json says 48x48"
    assert expected in one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)
    assert expected in one_line_error(capfd, "init", clip, "--init", "gt-noise")


def test_frame_and_mask_counts_disagree(clip, tmp_path, capfd):
    shutil.copy(clip / "mask" / "000002.png", clip / "mask" / "000003.png")
    assert "more masks than frame_count = 3" in one_line_error(capfd, "init", clip, "--init", "gt-noise")
    (clip / "mask" / "000003.png").unlink()
    (clip / "mask" / "000002.png").unlink()
    assert "mask 2 of 3 is missing" in one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)


def test_empty_and_all_foreground_masks_stop_the_fit(clip, tmp_path, capfd):
    """harp import-video leaves empty-mask frames out; in a sequence folder written otherwise
    such a frame (or an inverted mask) stops the fit before it starts."""
    seq.write_png(clip / "mask" / "000001.png", np.zeros((48, 48), np.uint8))
    line = one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)
    assert "mask 1 is empty (fewer than 16 hand pixels): leave the frame out" in line
    assert not (tmp_path / "avatar").exists()
    seq.write_png(clip / "mask" / "000001.png", np.full((48, 48), 255, np.uint8))
    line = one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)
    assert "mask 1 is all foreground (every pixel is hand)" in line and "inverted?" in line


def test_damaged_images_in_a_sequence_folder(clip, tmp_path, capfd):
    frame = clip / "rgb" / "000001.png"
    good = frame.read_bytes()
    frame.write_bytes(good[:8] + bytes(range(64)))            # PNG signature, then garbage
    expected = f"{frame} is not a PNG file (or its header is damaged)"
    assert expected in one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)
    assert expected in one_line_error(capfd, "init", clip, "--init", "gt-noise")
    frame.write_bytes(good[:40] + bytes(len(good) - 40))      # a good header, the pixels zeroed
    assert f"cannot read image {frame}" in one_line_error(capfd, "fit", clip, "--out", tmp_path / "avatar", *FIT)


# --- init: a frame without a detected hand ------------------------------------------------------
@pytest.mark.slow
@pytest.mark.blender
def test_frame_without_a_detected_hand_is_interpolated(tmp_path, capfd, one_torch_thread):
    """MediaPipe finds no hand in a blanked frame: its keypoints are interpolated from the
    neighbouring frames, it is flagged, and its initial pose follows the neighbours (the hand
    stays in place in `fingers`, so the interpolation lands on the true hand)."""
    pytest.importorskip("bpy")
    pytest.importorskip("mediapipe")
    folder = tmp_path / "clip"
    command = [sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(folder), "--frames", "5",
               "--seconds", "1", "--width", "160", "--height", "160", "--samples", "1", "--texture-size", "128",
               "--motion", "fingers", "--mode", "hand"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    info = seq.read_sequence_info(folder)
    seq.write_png(seq.frame_path(folder, info, 2), np.full((160, 160, 3), 120, np.uint8))

    assert main(["init", str(folder), "--mode", "hand"]) == 0
    out = capfd.readouterr().out
    assert "keypoints (mediapipe): 4 of 5 frames; interpolated frames 2" in out
    estimate = ie.read_initial_estimate(folder)
    assert estimate.detected.tolist() == [True, True, False, True, True]
    assert np.isfinite(estimate.pose).all() and np.isfinite(estimate.transl).all()
    saved = json.loads((folder / "keypoints.json").read_text())["keypoints"]
    assert saved[2] is None and all(saved[i] is not None for i in (0, 1, 3, 4))
    # frame 2's initial hand, projected, sits on the neighbours' mean keypoints and on the truth
    projected = project(estimate.keypoints3d[2], info.K)[0]
    neighbours = (np.array(saved[1]) + np.array(saved[3])) / 2
    truth = seq.read_ground_truth(folder / seq.GT_FILE).keypoints2d[2]
    assert np.linalg.norm(projected - neighbours, axis=-1).mean() < 0.05 * 160   # measured 3.4 px
    assert np.linalg.norm(projected - truth, axis=-1).mean() < 0.06 * 160        # measured 4.1 px
