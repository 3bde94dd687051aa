"""Masks made from the footage by several processes at once (detection/mask_workers.py), and the
disc growth they use (detection/mask_growth.py), against direct computations."""
import os

import cv2
import numpy as np
import pytest

from pipeline import sequence_import as si
from pipeline.detection.hand_masks import screened_masks
from pipeline.detection.mask_growth import grown
from pipeline.detection.mask_workers import MIN_JOBS_PER_WORKER, each_frame
from pipeline.detection.mediapipe_hands import detect_keypoints
from pipeline.evaluate.exact_clips import write_clip
from pipeline.formats import sequence_folder as seq
from synth.motions import OPEN


def _distance_to(mask):
    """(H, W) each pixel's Euclidean distance to the nearest pixel of `mask`, by brute force."""
    ys, xs = np.nonzero(mask)
    rows, cols = np.mgrid[:mask.shape[0], :mask.shape[1]]
    return np.sqrt(((rows[..., None] - ys) ** 2 + (cols[..., None] - xs) ** 2).min(-1))


@pytest.mark.parametrize("radius", [1.0, 4.4, 11.6])
def test_a_grown_mask_holds_the_pixels_within_the_radius_and_no_farther(radius):
    rng = np.random.default_rng(int(radius * 10))
    mask = np.zeros((70, 60), np.uint8)
    for _ in range(3):
        cv2.fillConvexPoly(mask, rng.uniform(10, 50, (4, 2)).astype(np.int32), 1)
    mask[5, 55] = 1                                   # a lone pixel near the edge
    distance = _distance_to(mask)
    result = grown(mask, radius).astype(bool)
    reach = max(1, round(radius))
    assert result[distance <= reach].all()            # everything within the (whole-pixel) radius
    assert not result[distance > reach + 0.5].any()   # nothing beyond it
    # the elliptical kernel's dilation it replaces differs only along the outline
    dilated = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1,) * 2)).astype(bool)
    assert (dilated != result).sum() <= 0.03 * result.sum()
    assert not grown(np.zeros((8, 8), np.uint8), radius).any()


def _pid_and_double(value):
    return os.getpid(), 2 * value


def _dies_in_a_worker(job):
    parent, value = job
    if os.getpid() != parent:
        os._exit(3)
    return 2 * value


def test_worker_processes_give_the_results_in_order():
    jobs = list(range(4 * MIN_JOBS_PER_WORKER))
    results = list(each_frame(_pid_and_double, jobs, workers=2))
    assert [value for _, value in results] == [2 * job for job in jobs]
    pids = {pid for pid, _ in results}
    assert os.getpid() not in pids and len(pids) == 2
    # too few frames to be worth a worker's start: made here
    few = list(each_frame(_pid_and_double, jobs[:MIN_JOBS_PER_WORKER + 1], workers=2))
    assert {pid for pid, _ in few} == {os.getpid()}


def test_workers_that_die_leave_their_frames_to_this_process():
    jobs = [(os.getpid(), value) for value in range(3 * MIN_JOBS_PER_WORKER)]
    assert list(each_frame(_dies_in_a_worker, jobs, workers=2)) == [2 * value for _, value in jobs]


def test_the_masks_made_by_two_workers_are_the_masks_made_by_one(tmp_path):
    info = write_clip(tmp_path / "clip", OPEN, frames=2 * MIN_JOBS_PER_WORKER, size=160, turn_degrees=20)
    frames = [seq.read_rgb(seq.frame_path(tmp_path / "clip", info, index)) for index in range(info.frame_count)]
    keypoints = detect_keypoints(frames, "right")
    alone, screen_alone = screened_masks(frames, keypoints, 30.0, workers=1)
    seen = []
    shared, screen_shared = screened_masks(frames, keypoints, 30.0, on_frame=seen.append, workers=2)
    assert seen == list(range(len(frames)))
    assert all(np.array_equal(a, b) for a, b in zip(alone, shared))
    assert screen_alone == screen_shared and sum(mask.sum() for mask in shared) > 0


def test_the_import_says_what_is_wrong_with_its_worker_count(tmp_path):
    with pytest.raises(si.ImportVideoError, match="mask workers must be at least 1"):
        si.import_video(tmp_path / "video.mp4", None, tmp_path / "out", workers=0)
