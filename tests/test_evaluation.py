"""Evaluation of a fit: held-out frames, albedo in the visible UV area, pose errors against the
ground truth, and `harp evaluate`, on a tiny synthetic clip (and analytic cases)."""
import json
import shutil

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from synth_clips import render_tiny_clip
from pipeline.evaluate import albedo, evaluation, held_out, poses
from pipeline.fit import fitting, stage_run
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint, save_checkpoint
from pipeline.fit.frames import held_out_frames, select_frames
from pipeline.init.initial_from_ground_truth import compose_axis_angle
from pipeline.formats import avatar_folder as av
from pipeline.formats import sequence_folder as seq
from pipeline.formats.initial_estimate import read_initial_estimate
from pipeline.handmodel.lbs import HandModel, load_model_data
from pipeline.handmodel.uv_atlas import uv_mask as atlas_mask
from pipeline.render.renderer import RenderMesh
from pipeline.render.texel_visibility import visible_texels

FIT_OPTIONS = dict(progress="none", max_steps=4, texture_size=64, batch_size=2, resolution=96, shadows="off",
                   device="cpu")


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    pytest.importorskip("bpy")
    folder = tmp_path_factory.mktemp("clip") / "clip"
    return render_tiny_clip(folder, frames=6)


@pytest.fixture(scope="module")
def held_out_fit(tiny_clip, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "avatar"
    report = fitting.fit(tiny_clip, out, hold_out_every=3, **FIT_OPTIONS)
    return out, report


def _procrustes_numpy(prediction, target):
    """Mean distance after the best similarity transform, computed with scipy's Kabsch."""
    p, t = prediction - prediction.mean(0), target - target.mean(0)
    rotation, _ = Rotation.align_vectors(t, p)
    rotated = rotation.apply(p)
    scale = (rotated * t).sum() / (p * p).sum()
    return np.linalg.norm(scale * rotated - t, axis=1).mean()


# ------------------------------------------------------------------ held-out frames

def test_held_out_frames_are_every_nth_and_never_fitted():
    assert held_out_frames(10, 3).tolist() == [2, 5, 8]
    assert held_out_frames(10, None).tolist() == []
    with pytest.raises(ValueError):
        held_out_frames(10, 1)
    frames = select_frames(100, 30, exclude=held_out_frames(100, 4))
    assert len(frames) == 30 and not set(frames) & set(held_out_frames(100, 4))
    assert select_frames(100, 30).tolist() == np.unique(np.round(np.linspace(0, 99, 30)).astype(int)).tolist()


def test_held_out_evaluation_fits_pose_and_light_only(held_out_fit, tiny_clip, monkeypatch):
    out, report = held_out_fit
    assert report["held_out_frames"] == [2, 5] and report["frames"] == [0, 1, 3, 4]
    assert json.loads((out / "report.json").read_text())["held_out_frames"] == [2, 5]
    saved = load_checkpoint(out / CHECKPOINT_FILE)
    result = held_out.evaluate_held_out(out, tiny_clip, steps=8, device="cpu")
    for name in held_out.FROZEN:                         # shape and appearance: bit for bit the fit's
        assert torch.equal(getattr(result.avatar, name).detach(), saved.avatar[name]), name
    initial = read_initial_estimate(tiny_clip)
    moved = np.abs(result.avatar.pose.detach().numpy() - initial.pose[[2, 5]]).max()
    assert moved > 1e-5
    assert not torch.equal(result.avatar.light_position.detach(), saved.avatar["light_position"])
    assert result.loss_after < result.loss_before and len(result.history) == 8
    assert result.history[0]["loss"] == pytest.approx(result.loss_before, rel=1e-5)
    scores = result.metrics
    assert len(scores["psnr"]) == 2 and all(np.isfinite(scores["psnr"])) and 0 < scores["silhouette_iou_mean"] <= 1
    assert result.shadows is False
    # the shadows decision of the fit is respected
    shadowed = out.parent / "shadowed"
    shutil.copytree(out, shadowed)
    saved.state.shadows.on = True
    save_checkpoint(shadowed / CHECKPOINT_FILE, saved)
    seen = []
    original = stage_run.batch_energy
    monkeypatch.setattr(stage_run, "batch_energy",
                        lambda *args, **kwargs: seen.append(args[3]) or original(*args, **kwargs))
    assert held_out.evaluate_held_out(shadowed, tiny_clip, steps=1, device="cpu").shadows is True
    assert seen and all(seen)


def test_the_occlusion_after_the_stages_shades_the_finished_avatar_but_no_stage_step(held_out_fit, tiny_clip, tmp_path,
                                                                                      monkeypatch):
    """FitSettings.occlusion "after": every gradient step of the stages shades without the room
    light's occlusion, the albedo solve with it, each fitted frame measured once (at its final
    pose); the avatar says it is drawn with it, and its held-out frames are refined and scored
    with it."""
    from pipeline.fit import avatar as avatar_module
    steps_with_occlusion, solves_with_occlusion, measured = [], [], []
    step, solve, measure = stage_run.StageRun.step, fitting.solve_avatar_albedo, avatar_module.hand_lost_light

    def recording_step(run):
        steps_with_occlusion.append(run.problem.avatar.occlusion)
        return step(run)

    def recording_solve(problem, *args, **kwargs):
        batch = torch.arange(len(problem.frames))
        solves_with_occlusion.append(problem.avatar.light(False, batch, problem.avatar.posed(batch)[0]).occlusion
                                     is not None)
        return solve(problem, *args, **kwargs)

    monkeypatch.setattr(stage_run.StageRun, "step", recording_step)
    monkeypatch.setattr(fitting, "solve_avatar_albedo", recording_solve)
    monkeypatch.setattr(avatar_module, "hand_lost_light", lambda vertices, *a: measured.append(len(vertices))
                        or measure(vertices, *a))
    out = tmp_path / "after"
    report = fitting.fit(tiny_clip, out, hold_out_every=3, occlusion="after", **FIT_OPTIONS)
    assert steps_with_occlusion and not any(steps_with_occlusion)
    assert solves_with_occlusion and all(solves_with_occlusion)
    assert sum(measured) == len(report["frames"]) == report["occlusion"]["frame_measurements"]
    assert av.read_avatar_json(out)["light"]["occlusion"] is True
    measured.clear()
    result = held_out.evaluate_held_out(out, tiny_clip, steps=2, device="cpu")
    assert result.avatar.occlusion and sum(measured) >= len(report["held_out_frames"])
    assert av.read_avatar_json(held_out_fit[0])["light"]["occlusion"] is True       # the default: after


def matrix(axis_angle):
    """The rotation matrix of an axis-angle vector (one rotation has two vectors at 180 degrees)."""
    return Rotation.from_rotvec(np.asarray(axis_angle, dtype=np.float64)).as_matrix()


def fit_whose_neighbours_are_right(out, tiny_clip, folder, turned_frames=()):
    """A copy of the fit `out` with the true shape, whose fitted frames hold true poses such that
    the held-out frames' neighbours give their true poses: fitted frames 1 and 3 hold frame 2's,
    frame 4 holds frame 5's (the tiny clip moves too far between frames for the neighbours of a
    real fit to be right). The fitted frames in `turned_frames` are turned 160 degrees about y,
    as a pose across a fast turn can be."""
    shutil.copytree(out, folder)
    saved = load_checkpoint(out / CHECKPOINT_FILE)
    gt = seq.read_ground_truth(tiny_clip / seq.GT_FILE)
    fitted_frames = json.loads((out / "report.json").read_text())["frames"]
    assert fitted_frames == [0, 1, 3, 4]
    truth_of = [0, 2, 2, 5]
    for name in ("global_orient", "transl", "pose"):
        saved.avatar[name] = torch.as_tensor(getattr(gt, name)[truth_of], dtype=saved.avatar[name].dtype)
    saved.avatar["betas"] = torch.as_tensor(gt.betas, dtype=saved.avatar["betas"].dtype)
    saved.avatar["displacement"].zero_()
    flip = Rotation.from_rotvec([0.0, np.radians(160), 0.0])
    for frame in turned_frames:
        index = fitted_frames.index(frame)
        orient = saved.avatar["global_orient"][index].double().numpy()
        saved.avatar["global_orient"][index] = torch.as_tensor((flip * Rotation.from_rotvec(orient)).as_rotvec())
    save_checkpoint(folder / CHECKPOINT_FILE, saved)
    return folder, saved


def test_the_held_out_protocols_start_from_the_neighbours_or_the_keypoints(held_out_fit, tiny_clip, tmp_path):
    """Frame 2 lies half-way between the fitted frames 1 and 3, frame 5 after the last fitted
    one (4): the neighbours protocol starts them there where their poses explain the frame
    better than the keypoints do (neighbours that give the true poses, against keypoints 5
    degrees off: their silhouettes cover the masks better); the keypoints protocol from init.npz."""
    from pipeline.formats.rotations import slerp_axis_angle

    out, _ = held_out_fit
    found, saved = fit_whose_neighbours_are_right(out, tiny_clip, tmp_path / "found")
    fitted = {name: saved.avatar[name].numpy() for name in ("global_orient", "transl", "pose")}   # frames 0 1 3 4
    result = held_out.evaluate_held_out(found, tiny_clip, steps=0, device="cpu")
    assert not result.started_from_keypoints.any()
    start = result.avatar
    np.testing.assert_allclose(start.transl.detach().numpy(), [(fitted["transl"][1] + fitted["transl"][2]) / 2,
                                                                fitted["transl"][3]], atol=1e-7)
    np.testing.assert_allclose(start.pose.detach().numpy()[0], slerp_axis_angle(fitted["pose"][1], fitted["pose"][2], 0.5),
                               atol=1e-6)
    np.testing.assert_allclose(matrix(start.global_orient.detach().numpy()[1]), matrix(fitted["global_orient"][3]),
                               atol=1e-6)
    keypoints = held_out.evaluate_held_out(found, tiny_clip, steps=0, device="cpu", protocol="keypoints")
    np.testing.assert_allclose(keypoints.avatar.pose.detach().numpy(), read_initial_estimate(tiny_clip).pose[[2, 5]])
    # the starts' silhouettes (measured: 0.94 from the neighbours, 0.77 from the keypoints); not their PSNR, which
    # after this fit's 4 steps a stage is the untrained appearance's (7-8 dB either way, in either order by machine)
    covered, from_keypoints = (np.array(r.metrics_before["silhouette_iou"]) for r in (result, keypoints))
    assert np.all(covered > from_keypoints + 0.1)
    with pytest.raises(held_out.EvaluationError, match="protocol"):
        held_out.evaluate_held_out(out, tiny_clip, steps=0, device="cpu", protocol="truth")


def test_a_frame_whose_neighbours_point_the_wrong_way_starts_from_its_keypoints(held_out_fit, tiny_clip, tmp_path):
    """Frame 2's fitted neighbours (1 and 3) turned half round: frame 2 starts from init.npz and
    scores as the keypoints protocol's start does; frame 5 (whose neighbour, 4, is right) from
    its neighbour still."""
    out, _ = held_out_fit
    turned, saved = fit_whose_neighbours_are_right(out, tiny_clip, tmp_path / "turned", turned_frames=(1, 3))
    result = held_out.evaluate_held_out(turned, tiny_clip, steps=0, device="cpu")
    assert result.started_from_keypoints.tolist() == [True, False]
    assert result.to_json()["started_from_keypoints"] == [2]
    initial = read_initial_estimate(tiny_clip)
    np.testing.assert_allclose(matrix(result.avatar.global_orient.detach().numpy()[0]), matrix(initial.global_orient[2]),
                               atol=1e-6)
    np.testing.assert_allclose(matrix(result.avatar.global_orient.detach().numpy()[1]),
                               matrix(saved.avatar["global_orient"][3].numpy()), atol=1e-6)
    keypoints = held_out.evaluate_held_out(turned, tiny_clip, steps=0, device="cpu", protocol="keypoints")
    for name in ("psnr", "silhouette_iou"):     # frame 2: the keypoints protocol's start, the same render
        assert result.metrics_before[name][0] == pytest.approx(keypoints.metrics_before[name][0], abs=1e-6)
    # frame 5: its neighbour's pose, a better silhouette (PSNR: see the test above)
    assert result.metrics_before["silhouette_iou"][1] > keypoints.metrics_before["silhouette_iou"][1] + 0.1


def test_a_rollback_in_the_held_out_refinement_returns_to_the_chosen_start(held_out_fit, tiny_clip, tmp_path,
                                                                           monkeypatch):
    """Every step rolled back (as a diverging loss is): the frames end where they started, frame 5
    at its neighbour's pose, not at the keypoints (a rollback once went back to the keypoints and
    stayed there, every later step rolled back against the better start's loss)."""
    out, _ = held_out_fit
    turned, saved = fit_whose_neighbours_are_right(out, tiny_clip, tmp_path / "turned", turned_frames=(1, 3))
    start = held_out.evaluate_held_out(turned, tiny_clip, steps=0, device="cpu")
    monkeypatch.setattr(stage_run, "DIVERGENCE_FACTOR", 0.0)
    rolled = held_out.evaluate_held_out(turned, tiny_clip, steps=3, device="cpu")
    assert len(rolled.events) == 2 and all("rolled back" in event for event in rolled.events)   # step 0 has no best
    for name in ("global_orient", "transl", "pose"):
        assert torch.equal(getattr(rolled.avatar, name).detach(), getattr(start.avatar, name).detach()), name


def test_held_out_renders_are_also_scored_in_reference_masks(held_out_fit, tiny_clip):
    """Masks a person drew for the held-out frames (benchmarks/bench_drawn_masks.py): scored inside
    the clip's own masks they give the same figures; inside masks grown by a band the silhouette
    agrees less; the poses are fitted to the clip's masks either way."""
    import cv2

    from pipeline.formats import sequence_folder as seq

    out, _ = held_out_fit
    own = np.stack([seq.read_mask(tiny_clip / seq.MASK_PATTERN.format(index=frame)) for frame in (2, 5)])
    same = held_out.evaluate_held_out(out, tiny_clip, steps=2, device="cpu", reference_masks=own)
    for name in ("psnr", "l1", "silhouette_iou"):
        np.testing.assert_allclose(same.metrics_in_reference[name], same.metrics[name], rtol=1e-6)
    grown = np.stack([cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0 for mask in own])
    wider = held_out.evaluate_held_out(out, tiny_clip, steps=2, device="cpu", reference_masks=grown)
    np.testing.assert_allclose(wider.metrics["psnr"], same.metrics["psnr"], rtol=1e-9)      # the same fit
    assert wider.metrics_in_reference["silhouette_iou_mean"] < same.metrics["silhouette_iou_mean"] - 0.05
    assert "metrics_in_reference" in wider.to_json() and "metrics_in_reference" not in \
        held_out.evaluate_held_out(out, tiny_clip, steps=0, device="cpu").to_json()
    with pytest.raises(held_out.EvaluationError, match="reference masks"):
        held_out.evaluate_held_out(out, tiny_clip, steps=0, device="cpu", reference_masks=own[:1])


def test_the_refinement_stops_when_the_loss_stops_falling():
    falling = list(np.linspace(1.0, 0.5, 40))
    assert not held_out.loss_converged(falling) and not held_out.loss_converged([1.0] * 19)
    assert held_out.loss_converged(falling + [0.5] * 20) is True and held_out.loss_converged([1.0] * 20)


# ------------------------------------------------------------------ albedo

def test_albedo_error_of_known_differences():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.2, 0.8, (32, 32, 3))
    visible = rng.uniform(size=(32, 32)) < 0.5
    same = albedo.albedo_error(truth, truth, visible)
    assert same["mae"] == 0 and same["mae_scaled"] == 0 and same["texels"] == visible.sum()
    shifted = albedo.albedo_error(truth + 0.05, truth, visible)
    assert shifted["mae"] == pytest.approx(0.05) and shifted["psnr"] == pytest.approx(20 * np.log10(1 / 0.05))
    scales = np.array([0.8, 1.0, 1.25])
    darker = truth * scales
    darker[~visible] = 0.0                               # what is not seen does not count
    scaled = albedo.albedo_error(darker, truth, visible)
    assert scaled["mae"] == pytest.approx(np.abs(truth * scales - truth)[visible].mean())
    assert scaled["mae_scaled"] < 1e-12 and np.allclose(scaled["scale"], 1 / scales)


def test_visible_texels_are_part_of_the_uv_area(tiny_clip):
    gt = seq.read_ground_truth(tiny_clip / seq.GT_FILE)
    info = seq.read_sequence_info(tiny_clip)
    data = load_model_data(gt.mode, gt.side)
    mesh = RenderMesh.from_model_data(data)
    in_atlas = atlas_mask(data.uvs, data.faces_uv, 128)
    vertices = torch.as_tensor(gt.vertices)
    visible = visible_texels(vertices, mesh, info.K, info.height, info.width, 128)
    assert visible.any() and visible.sum() < in_atlas.sum()
    assert in_atlas[visible].mean() > 0.97               # the nearest texel of a UV inside a chart
    first = visible_texels(vertices[:1], mesh, info.K, info.height, info.width, 128)
    assert (visible | first).sum() == visible.sum() and first.sum() < visible.sum()
    # the hand turned half around about its centre shows mostly other texels
    centre = vertices[0].mean(0)
    turned = (vertices[0] - centre) @ torch.as_tensor(Rotation.from_euler("y", 180, degrees=True).as_matrix().T,
                                                      dtype=vertices.dtype) + centre
    back = visible_texels(turned[None], mesh, info.K, info.height, info.width, 128)
    assert (first & back).sum() < 0.1 * min(first.sum(), back.sum())


def test_albedo_error_of_a_fit_folder(held_out_fit, tiny_clip, tmp_path):
    out, _ = held_out_fit
    folder = tmp_path / "avatar"
    shutil.copytree(out, folder)
    truth = seq.read_rgb(tiny_clip / seq.GT_ALBEDO_FILE)
    seq.write_png(folder / av.ALBEDO_FILE, truth)
    same = albedo.evaluate_albedo(folder, tiny_clip, device="cpu")
    assert same["mae"] == 0 and same["mae_scaled"] < 1e-12 and same["texture_size"] == 128
    assert (folder / albedo.ALBEDO_PICTURE).is_file()
    assert 0.1 < same["visible_fraction_of_uv_area"] < 1 and same["visibility_from"] == "gt.npz vertices"
    darker = truth.astype(int) - 10
    assert darker.min() >= 0                           # no clipping: the error is ten levels everywhere
    seq.write_png(folder / av.ALBEDO_FILE, darker.astype(np.uint8))
    shifted = albedo.evaluate_albedo(folder, tiny_clip, device="cpu", picture=False)
    assert shifted["mae"] == pytest.approx(10 / 255) and shifted["psnr"] == pytest.approx(20 * np.log10(25.5))
    assert shifted["texels"] == same["texels"]
    # the fit's own albedo (64 texels) is compared against the truth resized to 64
    fitted = albedo.evaluate_albedo(out, tiny_clip, device="cpu", picture=False)
    assert fitted["texture_size"] == 64 and np.isfinite(fitted["psnr"]) and fitted["mae"] < 0.5


# ------------------------------------------------------------------ poses

def test_pose_error_of_the_truth_and_of_known_offsets(tiny_clip):
    gt = seq.read_ground_truth(tiny_clip / seq.GT_FILE)
    model = HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    joints, _ = poses._hand(model, gt.betas, gt.pose, gt.global_orient, gt.transl)
    same = poses.point_errors(joints, gt.keypoints3d)
    assert same["procrustes_mm_mean"] < 1e-3 and same["camera_mm_mean"] < 1e-3
    # the whole hand turned by 20 degrees about its wrist: nothing left after alignment
    offset = Rotation.from_rotvec([0.0, np.radians(20), 0.0])
    turned = compose_axis_angle(np.repeat(offset.as_rotvec()[None], gt.frame_count, 0), gt.global_orient)
    joints, _ = poses._hand(model, gt.betas, gt.pose, turned, gt.transl)
    errors = poses.point_errors(joints, gt.keypoints3d)
    relative = gt.keypoints3d - gt.transl[:, None]
    expected = np.linalg.norm(offset.apply(relative.reshape(-1, 3)).reshape(relative.shape) - relative, axis=-1)
    assert errors["procrustes_mm_mean"] < 1e-3
    assert errors["camera_mm_mean"] == pytest.approx(expected.mean() * 1000, rel=1e-6)
    # the index finger bent 30 degrees more at its PIP joint
    pose = gt.pose.copy()
    pose[:, 2] = compose_axis_angle(pose[:, 2], np.repeat([[np.radians(30), 0, 0]], gt.frame_count, 0))
    joints, _ = poses._hand(model, gt.betas, pose, gt.global_orient, gt.transl)
    errors = poses.point_errors(joints, gt.keypoints3d)
    expected = [_procrustes_numpy(p, t) * 1000 for p, t in zip(joints.numpy(), gt.keypoints3d)]
    assert errors["procrustes_mm"] == pytest.approx(expected, rel=1e-6) and min(expected) > 1


def test_pose_errors_of_a_fit(held_out_fit, tiny_clip, tmp_path):
    out, report = held_out_fit
    gt = seq.read_ground_truth(tiny_clip / seq.GT_FILE)
    initial = read_initial_estimate(tiny_clip)
    frames = report["frames"]
    result = poses.evaluate_poses(out, tiny_clip, device="cpu")
    assert result["frames"] == frames and result["gt_keypoint_check_mm"] < 1e-3
    expected = [_procrustes_numpy(p, t) * 1000 for p, t in zip(initial.keypoints3d[frames], gt.keypoints3d[frames])]
    assert result["initial"]["joints"]["procrustes_mm"] == pytest.approx(expected, rel=1e-5)
    for kind in ("joints", "vertices", "surface"):
        assert 0 < result["fit"][kind]["procrustes_mm_mean"] < 20, kind
    # a "fit" that found the truth (true shape and poses, no displacement) scores zero but for
    # the person's own surface offsets, which the plain model lacks
    truth_fit = tmp_path / "truth"
    shutil.copytree(out, truth_fit)
    saved = load_checkpoint(out / CHECKPOINT_FILE)
    for name in ("betas", "global_orient", "transl", "pose"):
        value = getattr(gt, name)[frames] if name != "betas" else gt.betas
        saved.avatar[name] = torch.as_tensor(value, dtype=torch.float32)
    saved.avatar["displacement"].zero_()
    save_checkpoint(truth_fit / CHECKPOINT_FILE, saved)
    perfect = poses.evaluate_poses(truth_fit, tiny_clip, device="cpu")["fit"]
    assert perfect["joints"]["procrustes_mm_mean"] < 0.01 and perfect["joints"]["camera_mm_mean"] < 0.01
    assert perfect["vertices"]["procrustes_mm_mean"] < 0.01
    offsets = np.linalg.norm(gt.personal_offsets, axis=1).mean() * 1000
    assert 0.8 * offsets < perfect["surface"]["camera_mm_mean"] < 1.2 * offsets


# ------------------------------------------------------------------ harp evaluate

def test_harp_evaluate_writes_evaluation_json(held_out_fit, tiny_clip, capsys):
    from pipeline.cli import main

    out, _ = held_out_fit
    assert main(["evaluate", str(out), str(tiny_clip), "--held-out-steps", "2", "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "held-out frames (2, from the fitted neighbours' poses, 2 pose+light steps)" in printed
    assert "held-out frames (2, from the keypoints, 100 pose+light steps)" in printed
    assert "albedo in the visible UV area" in printed
    assert "pose error, fitted frames" in printed and "pose error, held-out frames" in printed
    result = json.loads((out / evaluation.EVALUATION_FILE).read_text())
    assert set(result) >= {"held_out", "albedo", "poses", "fit_frames"}
    assert result["held_out"]["frames"] == [2, 5] and result["poses"]["held_out"]["frames"] == [2, 5]
    assert (out / albedo.ALBEDO_PICTURE).is_file()
    assert main(["evaluate", str(out.parent / "missing"), str(tiny_clip)]) == 1
    assert "not a finished fit" in capsys.readouterr().err


def test_tone_contrast_of_a_fit_that_lifts_the_dark_skin():
    """A palm-and-back albedo: the fitted dark skin 1.5 times too bright and the light skin 1.2
    times (a common factor the light could take) gives contrast 1.25; scaled per tone it is exact."""
    rng = np.random.default_rng(1)
    truth = np.where(rng.uniform(size=(40, 40, 1)) < 0.6, [0.36, 0.23, 0.17], [0.8, 0.6, 0.47])
    truth = truth * rng.uniform(0.9, 1.1, (40, 40, 1))
    dark = truth.mean(-1) < 0.4
    fitted = truth * np.where(dark, 1.5, 1.2)[..., None]
    visible = np.ones((40, 40), bool)
    tones = albedo.albedo_error(fitted, truth, visible)["tones"]
    assert tones["dark"] == pytest.approx(1.5) and tones["light"] == pytest.approx(1.2)
    assert tones["contrast"] == pytest.approx(1.25) and tones["dark_share"] == pytest.approx(dark.mean())
    assert tones["psnr_scaled_per_tone"] > 100
    assert albedo.albedo_error(fitted, truth, visible)["psnr_scaled"] < 40
    # skin of one tone: nothing to compare
    assert albedo.albedo_error(truth[dark][:, None], truth[dark][:, None], np.ones((dark.sum(), 1), bool))["tones"] is None
