"""Frames the alignment left off their silhouettes, started again from their neighbours
(fit/lost_frames.py): a frame turned over about the hand's long axis, as a detector flips an
edge-on hand, is found, put back near its true pose, and its keypoint anchor follows it."""
import numpy as np
import pytest
import torch

from pipeline.evaluate.exact_clips import write_clip
from pipeline.fit.checkpoint import FitState
from pipeline.fit.lost_frames import alignment_ious, anchor_restarted, restart_lost_frames
from pipeline.fit.problem import build_problem
from pipeline.fit.settings import settings_for
from pipeline.formats import sequence_folder as seq
from pipeline.handmodel.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from pipeline.init import initialise_sequence
from synth.motions import OPEN

FRAMES, SIZE, FLIPPED = 7, 96, 3


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lost") / "clip"
    write_clip(folder, OPEN, frames=FRAMES, size=SIZE, turn_degrees=8, occlusion=False)
    initialise_sequence(folder, "gt-noise", noise_degrees=0.0, noise_translation_m=0.0, log=lambda *a: None)
    settings = settings_for("fast", FRAMES, resolution=SIZE, texture_size=32)
    return build_problem(folder, settings, np.arange(FRAMES), "cpu"), folder


def turned_over(problem, frame, degrees=150.0):
    """The hand of `frame` turned by `degrees` about its own long axis (the line through the wrist
    and the middle finger's knuckle): the flip an edge-on view invites."""
    avatar = problem.avatar
    with torch.no_grad():
        _, keypoints = avatar.posed(torch.tensor([frame]))
        wrist, knuckle = keypoints[0, 0].clone(), keypoints[0, 9]
        turn = axis_angle_to_matrix((torch.nn.functional.normalize(knuckle - wrist, dim=0) * np.radians(degrees))[None])
        orient = axis_angle_to_matrix(avatar.global_orient[frame][None])
        avatar.global_orient[frame] = matrix_to_axis_angle(turn @ orient)[0]
        _, moved = avatar.posed(torch.tensor([frame]))
        avatar.transl[frame] += wrist - moved[0, 0]      # turned about the wrist


def test_a_frame_turned_over_is_found_and_started_again_near_its_true_pose(problem):
    problem, folder = problem
    avatar = problem.avatar
    truth = seq.read_ground_truth(folder / seq.GT_FILE)
    start = alignment_ious(problem).numpy()
    assert start.min() > 0.9                                         # the gt-noise start covers every mask
    turned_over(problem, FLIPPED)
    anchor_before = problem.anchor_keypoints.clone()
    ious = alignment_ious(problem).numpy()
    assert ious[FLIPPED] < 0.75 and np.delete(ious, FLIPPED).min() > 0.9
    untouched = {name: getattr(avatar, name).detach().clone() for name in ("global_orient", "transl", "pose")}
    found = restart_lost_frames(problem)
    assert found["tried"] == [FLIPPED] and found["frames"] == [FLIPPED]
    assert found["iou_after"][0] > 0.9 > ious[FLIPPED] + 0.1
    # near the true pose: its orientation within a few degrees of the truth's
    orient = axis_angle_to_matrix(avatar.global_orient[FLIPPED].detach().double()[None])[0]
    true_orient = axis_angle_to_matrix(torch.as_tensor(truth.global_orient[FLIPPED])[None])[0]
    angle = torch.rad2deg(torch.arccos(((orient.T @ true_orient).trace() - 1).clamp(-2, 2) / 2))
    assert angle < 5.0
    # every other frame as it was; the turned frame's anchor follows it, the others' stay
    others = [i for i in range(FRAMES) if i != FLIPPED]
    for name, value in untouched.items():
        assert torch.equal(getattr(avatar, name)[others], value[others])
    assert torch.equal(problem.anchor_keypoints[others], anchor_before[others])
    _, keypoints = avatar.posed(torch.tensor([FLIPPED]))
    torch.testing.assert_close(problem.anchor_keypoints[FLIPPED], keypoints[0, :21].detach())
    problem.anchor_keypoints[FLIPPED] = anchor_before[FLIPPED]       # a resumed fit's problem, built again
    anchor_restarted(problem, found)
    torch.testing.assert_close(problem.anchor_keypoints[FLIPPED], keypoints[0, :21].detach())
    assert torch.equal(problem.anchor_keypoints[others], anchor_before[others])


def test_frames_that_cover_their_masks_are_left_alone(problem):
    problem, _ = problem
    found = restart_lost_frames(problem)     # after the test above every frame covers its mask
    assert found["tried"] == [] and found["frames"] == []


def test_a_state_from_before_the_restart_reads():
    state = FitState.fresh(settings_for("fast", 4).schedule())
    values = state.to_dict()
    del values["restarted"]
    assert FitState.from_dict(values).restarted is None


def test_the_restart_is_asked_for():
    """Off by default (docs/fit.md: the frames gain, the hand's size moves), and off in settings
    saved before it."""
    from pipeline.fit.settings import FitSettings

    settings = settings_for("fast", 4)
    assert settings.restart_lost_frames == "off"
    values = {k: v for k, v in vars(settings).items() if k != "restart_lost_frames"}
    assert FitSettings.from_dict(values).restart_lost_frames == "off"
    with pytest.raises(ValueError, match="restart_lost_frames"):
        FitSettings(restart_lost_frames="yes")


def test_the_albedo_solve_leaves_out_a_frame_the_fit_left_off_its_silhouette(tmp_path_factory):
    """Frames drawn by the avatar itself with a known albedo, one of them then turned over in the
    fit (its pose wrong, its picture right): the rule finds it on the final surface, and the albedo
    solved without it is the albedo the frames were drawn with, where with it that frame's colours
    land on the wrong texels."""
    from test_albedo_solve import problem_rendered_with, sharp_albedo
    from pipeline.fit.albedo_solve import solved_albedo
    from pipeline.fit.lost_frames import frames_kept, frames_off_their_silhouettes

    problem, truth = problem_rendered_with(tmp_path_factory, sharp_albedo())
    assert frames_kept(frames_off_their_silhouettes(problem), len(problem.frames)) is None   # none lost: every frame
    turned_over(problem, 1)
    found = frames_off_their_silhouettes(problem)
    assert found["indices"] == [1] and found["frames"] == [int(problem.frames[1])] and found["ious"][0] < 0.75
    assert frames_kept(found, len(problem.frames)) == [i for i in range(len(problem.frames)) if i != 1]

    def error(frames):
        albedo, read = solved_albedo(problem, shadows=False, frames=frames)
        read = read.numpy() & (problem.uv_mask.numpy() > 0)
        return np.abs(albedo.numpy() - truth).mean(0)[read].mean()

    without = error(frames_kept(found, len(problem.frames)))
    with_it = error(None)
    assert without < 0.02 and with_it > 4 * without      # measured: 0.011 without it, 0.098 with it
