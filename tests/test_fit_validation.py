"""Validation inside the fit (pipeline/fit/validation.py): frames kept out and scored as the fit
runs; the written avatar is the best check's, and a stage whose checks stop gaining ends."""
import numpy as np
import pytest
import torch

from synth_clips import exact_clip
from pipeline.fit import fitting, validation
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.frames import neighbours, validation_frames
from pipeline.formats.rotations import axis_angle_to_matrix, slerp_axis_angle

FIT = dict(progress="none", texture_size=64, batch_size=2, resolution=96, shadows="off", device="cpu",
           solve_albedo=False, validation_frames=2)
GEOMETRY = ("betas", "displacement", "global_orient", "transl", "pose", "light_position", "ambient_logit")


def test_validation_frames_are_few_spread_and_between_fitted_frames():
    assert validation_frames(150, 6).tolist() == [12, 37, 62, 87, 112, 137]
    assert len(validation_frames(30, 6)) == 3 and len(validation_frames(9, 6)) == 0     # one in ten at most
    held_out = np.arange(9, 150, 10)
    assert not set(validation_frames(150, 6, exclude=held_out)) & set(held_out)


def test_neighbours_and_the_interpolated_rotation():
    left, right, fraction = neighbours(np.array([0, 4, 10]), np.array([2, 7, 10, 12, -1]))
    assert left.tolist() == [0, 1, 2, 2, 0] and right.tolist() == [1, 2, 2, 2, 0]
    np.testing.assert_allclose(fraction, [0.5, 0.5, 0.0, 0.0, 0.0])
    axis = np.array([0.0, 0.6, 0.8])
    np.testing.assert_allclose(slerp_axis_angle(0.2 * axis, 1.0 * axis, 0.25), 0.4 * axis, atol=1e-12)
    # between two rotations about different axes: equally far (in angle) from both at t = 0.5
    a, b = np.array([0.9, 0.0, 0.0]), np.array([0.0, 0.0, -0.7])
    middle = axis_angle_to_matrix(slerp_axis_angle(a, b, 0.5))

    def angle(m, n):
        return np.arccos(np.clip((np.trace(m.T @ n) - 1) / 2, -1, 1))

    assert angle(middle, axis_angle_to_matrix(a)) == pytest.approx(angle(middle, axis_angle_to_matrix(b)), abs=1e-9)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return exact_clip(tmp_path_factory.mktemp("validation") / "clip", frames=20, turn_degrees=40)


def test_a_fit_scores_its_validation_frames_and_never_fits_them(clip, tmp_path):
    report = fitting.fit(clip, tmp_path / "avatar", max_steps=12, **FIT)
    kept_out = report["validation"]["frames"]
    assert len(kept_out) == 2 and not set(kept_out) & set(report["frames"])
    checks = report["validation"]["checks"]
    assert {check["stage"] for check in checks} == {"geometry+appearance", "appearance"}
    assert all(np.isfinite(check["psnr_mean"]) and 0.3 < check["silhouette_iou_mean"] <= 1 for check in checks)
    assert all(check["refine_steps"] == validation.REFINE_STEPS for check in checks)


def test_the_written_avatar_is_the_best_checks(clip, tmp_path, monkeypatch):
    """Scores that peak at the third check: the avatar written is the one of that check (its
    geometry and light bit for bit), not the last."""
    scores = iter([20.0, 21.0, 23.0, 22.0, 21.5, 21.0, 20.5, 20.0, 19.5, 19.0, 18.5, 18.0, 17.5, 17.0])
    seen = []

    def score(self, shadows):
        seen.append({name: getattr(self.fit.avatar, name).detach().clone() for name in GEOMETRY})
        return {"psnr_mean": next(scores), "l1_mean": 0.1, "silhouette_iou_mean": 0.9, "refine_steps": 0}

    monkeypatch.setattr(validation.Validator, "score", score)
    monkeypatch.setattr(validation, "PATIENCE", 100)      # no stage ends early here
    report = fitting.fit(clip, tmp_path / "avatar", max_steps=12, **FIT)
    assert len(seen) >= 5 and report["validation"]["best"] == {"psnr": 23.0, "stage": "geometry+appearance",
                                                               "step": report["validation"]["checks"][2]["step"],
                                                               "restored": True}
    written = load_checkpoint(tmp_path / "avatar" / CHECKPOINT_FILE, "cpu").avatar
    for name in GEOMETRY:
        assert torch.equal(written[name], seen[2][name]), name
    assert not torch.equal(written["pose"], seen[-1]["pose"])


def test_a_stage_whose_checks_stop_gaining_ends_early(clip, tmp_path, monkeypatch):
    def score(self, shadows):
        return {"psnr_mean": 25.0, "l1_mean": 0.1, "silhouette_iou_mean": 0.9, "refine_steps": 0}

    monkeypatch.setattr(validation.Validator, "score", score)
    report = fitting.fit(clip, tmp_path / "avatar", max_steps=24, **FIT)
    every = 24 // validation.CHECKS_PER_STAGE
    stopped_at = every * (validation.PATIENCE + 1)        # the first check sets the bar, PATIENCE more fail it
    assert report["schedule"]["geometry+appearance"] == stopped_at
    assert report["schedule"]["appearance"] == stopped_at
    assert report["schedule"]["geometry"] == 24           # no checks before appearance is fitted


def test_the_validation_curve_goes_beside_the_training_curve(clip, tmp_path):
    from pipeline.evaluate.curve import CurveRecorder
    from pipeline.evaluate.plot import plot_curves
    from pipeline.formats.fit_curve import read_curve

    out = tmp_path / "avatar"
    report = fitting.fit(clip, out, max_steps=12, observers=[CurveRecorder(out)], **FIT)
    curve = read_curve(out)
    assert curve["validation"] == report["validation"]["checks"] and len(curve["validation"]) >= 4
    assert [p["fit_seconds"] for p in curve["validation"]] == sorted(p["fit_seconds"] for p in curve["validation"])
    picture = plot_curves([out], tmp_path / "curves.png", figures=("psnr_mean", "joint_mm"))
    assert picture.stat().st_size > 10_000
