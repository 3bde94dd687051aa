"""`harp init`: write SEQUENCE/init.npz from MediaPipe, a keypoint file or ground truth + noise.

    mediapipe        detect 2D keypoints (saved as SEQUENCE/keypoints.json, a keypoint file
                     that `--init keypoints` reads back) and fit the model to them
    keypoints FILE   fit the model to the keypoints of a file (formats/keypoint_file.py)
    gt-noise         synthetic clips: the ground truth with controlled noise

The template mode (hand, or hand + forearm) is given or chosen from the masks (`auto`): arm
when, in the median of up to 10 frames, more than ARM_FRACTION of the mask lies beyond the
wrist, more than ARM_DISTANCE palm lengths (wrist to middle knuckle) away from the fingers.
Measured on synthetic clips (256 px, exact keypoints): hand-only 0.0 in every frame; hand +
forearm framed tightly on the hand 0.04 - 0.08.
"""
from __future__ import annotations

import dataclasses

from pathlib import Path

import numpy as np

from ..formats import sequence_folder as seq
from ..formats.initial_estimate import write_initial_estimate
from ..formats.keypoint_file import read_keypoint_file, write_keypoint_file

METHODS = ("mediapipe", "keypoints", "gt-noise")
ARM_FRACTION = 0.02
ARM_DISTANCE = 0.25
KEYPOINTS_FILE = "keypoints.json"


def forearm_fraction(mask, keypoints):
    """Fraction of the mask (H, W) bool lying beyond the wrist, more than ARM_DISTANCE palm
    lengths from it on the side away from the fingers; keypoints (21, 2) pixels."""
    wrist, knuckle = keypoints[0], keypoints[9]
    axis = knuckle - wrist
    length = float(np.linalg.norm(axis))
    rows, cols = np.nonzero(mask)
    if length < 1e-6 or len(rows) == 0:
        return 0.0
    along = ((np.stack([cols + 0.5, rows + 0.5], 1) - wrist) @ (axis / length))
    return float((along < -ARM_DISTANCE * length).mean())


def choose_mode(folder, info, keypoints):
    """"hand" or "arm" from the masks and 2D keypoints (see the module docstring)."""
    if info.masks is None:
        return "hand", "no masks: hand"
    frames = np.unique(np.linspace(0, info.frame_count - 1, min(info.frame_count, 10)).round().astype(int))
    fractions = [forearm_fraction(seq.read_mask(seq.mask_path(folder, info, i)), keypoints.points[i]) for i in frames]
    fraction = float(np.median(fractions))
    mode = "arm" if fraction > ARM_FRACTION else "hand"
    return mode, f"{mode} ({100 * fraction:.0f}% of the mask lies beyond the wrist)"


def initialise_sequence(folder, method="mediapipe", keypoint_file=None, mode="auto", noise_degrees=10.0,
                        noise_translation_m=0.01, seed=0, log=print, warn=None, progress="none",
                        landmark_offsets=False):
    """Write folder/init.npz; returns the InitialEstimate. `progress` ("bar", "jsonl" or "none",
    fit/progress.py) shows the MediaPipe detection and the initial fit step by step.
    `landmark_offsets`: compare MediaPipe's landmarks where they sit on the model
    (InitialFitSettings.landmark_offsets)."""
    from ..fit.progress import Progress

    warn = warn or log
    folder = Path(folder)
    info = seq.validate_sequence_folder(folder)
    if method not in METHODS:
        raise ValueError(f"unknown --init {method!r}; choose one of {', '.join(METHODS)}")
    if mode not in ("hand", "arm", "auto"):
        raise ValueError(f"unknown --mode {mode!r}; choose hand, arm or auto")
    if (method == "keypoints") != (keypoint_file is not None):
        raise ValueError("--init keypoints needs a FILE" if method == "keypoints"
                         else f"--init {method} takes no file")
    if method == "gt-noise":
        estimate = _ground_truth_with_noise(folder, info, mode, noise_degrees, noise_translation_m, seed)
    else:
        if info.frames["kind"] != "images":
            raise ValueError("harp init reads image frames; this sequence's frames are a video")
        if method == "mediapipe":
            log(f"detecting keypoints in {info.frame_count} frames with MediaPipe Hands")
            from ..detection.mediapipe_hands import detect_sequence_keypoints

            with Progress(progress, info.frame_count) as bar:
                keypoints = detect_sequence_keypoints(
                    folder, info, on_frame=lambda: bar.update("MediaPipe", bar.done, float("nan")))
            write_keypoint_file(folder / KEYPOINTS_FILE, keypoints)
        else:
            keypoints = read_keypoint_file(keypoint_file, info.frame_count, info.width, info.height)
        _report_keypoints(keypoints, info, log, warn)
        if mode == "auto":
            mode, reason = choose_mode(folder, info, keypoints)
            log(f"template mode: {reason}" + (" - the fit will model the forearm as far as the masks show "
                                               "it; harp init --mode hand fits the hand alone" if mode == "arm" else ""))
        from .initial_fit import InitialFitSettings, fit_initial_estimate, planned_steps

        settings = InitialFitSettings(landmark_offsets=landmark_offsets)
        log(f"initial fit of pose and shape to the keypoints ({planned_steps(settings)} steps)")
        # each frame's pixels as the first frame's camera would see them: with a crop that follows
        # the hand the frames differ in their principal point alone (sequence.json)
        frame_K = info.frame_K()
        in_first_camera = dataclasses.replace(keypoints, points=keypoints.points
                                              + (frame_K[0, :2, 2] - frame_K[:, :2, 2])[:, None])
        with Progress(progress, planned_steps(settings)) as bar:
            estimate = fit_initial_estimate(in_first_camera, info.K, mode=mode, side=info.hand_side, settings=settings,
                                            log=bar.log if progress != "none" else log, progress=bar)
        if mode == "arm" and info.masks is not None:
            from .forearm_alignment import align_forearms

            masks = np.stack([seq.read_mask(seq.mask_path(folder, info, i)) for i in range(info.frame_count)])
            estimate, turned = align_forearms(estimate, masks, frame_K)
            if turned["frames"]:
                log(f"forearm turned to the masks in {turned['frames']} frames (median "
                    f"{turned['median_degrees']:.0f} degrees)")
    path = write_initial_estimate(folder, estimate)
    log(f"wrote {path}")
    return estimate


def _report_keypoints(keypoints, info, log, warn):
    summary = keypoints.summary()
    missing = np.flatnonzero(~keypoints.detected)
    log(f"keypoints ({summary['source']}): {summary['detected']} of {summary['frames']} frames"
        + (f"; interpolated frames {seq.frame_ranges(missing.tolist())}" if len(missing) else ""))
    agreement = summary.get("handedness_agreement")
    if agreement is not None and agreement < 0.5:
        warn(f"warning: MediaPipe takes the hand for a {'left' if info.hand_side == 'right' else 'right'} hand in "
             f"{100 * (1 - agreement):.0f}% of the frames, but the sequence says {info.hand_side}; "
             "check the hand side (sequence.json hand_side, or import-video --side)")


def _ground_truth_with_noise(folder, info, mode, degrees, translation_m, seed):
    from .initial_from_ground_truth import ground_truth_with_noise

    if not info.ground_truth:
        raise ValueError(f"--init gt-noise needs ground truth (gt.npz), and the sequence in {folder} has none")
    gt = seq.read_ground_truth(folder / info.ground_truth)
    if mode not in ("auto", gt.mode):
        raise ValueError(f"the ground truth is in {gt.mode} mode; --mode {mode} does not match it")
    return ground_truth_with_noise(gt, joint_degrees=degrees, translation_m=translation_m, seed=seed)
