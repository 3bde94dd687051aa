"""The fit end to end on a tiny synthetic clip: outputs, checkpoint and resume, rollback."""
import dataclasses
import json

import cv2
import numpy as np
import pytest
import torch

from synth_clips import ROOT, render_tiny_clip
from pipeline.fit import albedo_solve, estimate, fitting, stage_run
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.settings import FitSettings
from pipeline.formats import avatar_folder as av
from pipeline.formats import hand_model_file as fmt

pytest.importorskip("bpy")


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clip") / "clip"
    return render_tiny_clip(folder, frames=4)


def test_fit_writes_a_complete_avatar(tiny_clip, tmp_path):
    out = tmp_path / "avatar"
    report = fitting.fit(tiny_clip, out, progress="none", max_steps=4, texture_size=64, batch_size=2, resolution=96)
    description = av.read_avatar_json(out)
    assert description["mode"] == "hand" and len(description["betas"]) == 12
    rig = fmt.load_hand_model(out / av.RIG_FILE)
    vertices, faces, uvs, faces_uv = av.read_obj(out / av.MESH_FILE)
    np.testing.assert_allclose(vertices, rig.vertices, atol=1e-6)
    assert np.array_equal(faces, rig.faces) and np.array_equal(faces_uv, rig.faces_uv)
    poses = av.read_poses(out)
    assert poses.pose.shape == (4, 16, 3) and np.all(poses.pose[:, 0] == 0)  # hand mode: no wrist joint
    for name in (av.ALBEDO_FILE, av.NORMAL_FILE, "fit_grid.png", "overlay.mp4", "report.json"):
        assert (out / name).is_file(), name
    assert report["albedo_solve"]["solved_fraction"] > 0.1       # the albedo solve runs by default
    low, high = albedo_solve.PULL_RANGE                             # with the pull its frames' noise gave it
    assert low <= report["albedo_solve"]["neighbour_pull"] <= high
    scores = report["metrics"]
    assert all(np.isfinite(scores["psnr"])) and 0 < scores["silhouette_iou_min"] <= 1
    written = json.loads((out / "report.json").read_text())
    assert written["stage_seconds"]["geometry"] > 0
    # the whole run's time holds the stages' and what came after them (the albedo solve, the outputs)
    after = written["after_stages_seconds"]     # by part, each inside the whole run's time
    assert {"albedo_solve", "light_decisions", "texture_fill"} <= set(after) and min(after.values()) >= 0
    assert written["wall_seconds"] > written["total_seconds"] + written["output_seconds"] + after["albedo_solve"]
    # every texel outside the charts carries its nearest chart texel's value (filtering at the
    # seams mixes in only the hand's), in the albedo and the normal map alike
    from pipeline.fit.texture_fill import extend_outside
    from pipeline.handmodel.uv_raster import rasterize_uv
    inside = rasterize_uv(rig.uvs, rig.faces_uv, 64)[0] >= 0
    for name in (av.ALBEDO_FILE, av.NORMAL_FILE):
        image = cv2.imread(str(out / name))
        assert np.array_equal(extend_outside(image, inside), image), name

    # a checkpoint of the previous version (no exposure gains) still reads as a finished fit,
    # with its gains off, and refuses to be resumed in one line
    saved = torch.load(out / CHECKPOINT_FILE, weights_only=True)
    del saved["avatar"]["exposure"], saved["settings"]["exposure"]
    torch.save({**saved, "version": 2}, out / CHECKPOINT_FILE)
    older = load_checkpoint(out / CHECKPOINT_FILE)
    assert older.settings.exposure == "off" and older.avatar["exposure"].abs().max() == 0
    assert older.avatar["exposure"].shape == (4, 3)
    with pytest.raises(fitting.FitError, match="older harp version .*fit again without --resume"):
        fitting.fit(tiny_clip, out, resume=True, progress="none", max_steps=4, texture_size=64, batch_size=2,
                    resolution=96)


def test_a_finer_solve_reads_the_clips_own_frames_with_the_light_held(tiny_clip, tmp_path, monkeypatch):
    """solve_resolution above the working size: the albedo is solved with the light from the working
    frames, then again from the clip's own frames with the light held (the environment bit for bit);
    a finished fit resumed with another solve_resolution is accepted and left as it was."""
    calls = []
    original = fitting.solve_avatar_albedo

    def recording(problem, shadows, solve_environment=True, frames=None):
        before = problem.avatar.environment.detach().clone()
        figures = original(problem, shadows, solve_environment, frames)
        held = torch.equal(before, problem.avatar.environment)
        calls.append((tuple(problem.clip.images.shape[1:3]), solve_environment, held))
        return figures

    monkeypatch.setattr(fitting, "solve_avatar_albedo", recording)
    options = dict(progress="none", max_steps=2, texture_size=64, batch_size=2, resolution=64, environment="on")
    report = fitting.fit(tiny_clip, tmp_path / "finer", solve_resolution=96, **options)
    assert calls[0] == ((64, 64), True, False) and calls[-1] == ((96, 96), False, True)
    assert report["albedo_solve"][fitting.FINER_SOLVE]["solved_fraction"] > 0.1
    assert report["albedo_solve"]["solved_fraction"] > 0.1
    albedo = cv2.imread(str(tmp_path / "finer" / av.ALBEDO_FILE))
    calls.clear()
    fitting.fit(tiny_clip, tmp_path / "finer", resume=True, solve_resolution=0, **options)
    assert not calls and np.array_equal(cv2.imread(str(tmp_path / "finer" / av.ALBEDO_FILE)), albedo)


def test_each_later_albedo_pass_starts_from_the_last_ones_albedo_and_a_resumed_fit_runs_none_again(
        tiny_clip, tmp_path, monkeypatch, capsys):
    """FitSettings.albedo_passes 3 with a finer solve: after the first pass's solves and fill come two
    more, each solving the working frames (the room light with the albedo) then the finer ones (the
    light held) and filling, each from the albedo the pass before it left; the report and the log
    hold their figures, the estimate counts them, and the finished fit resumed runs none again."""
    calls, filled = [], []
    solve, fill = fitting.solve_avatar_albedo, fitting.fill_avatar_albedo

    def recording_solve(problem, shadows, solve_environment=True, frames=None):
        calls.append((tuple(problem.clip.images.shape[1:3]), solve_environment,
                      problem.avatar.albedo.detach().clone()))
        return solve(problem, shadows, solve_environment, frames)

    def recording_fill(avatar, decided, **options):
        figures = fill(avatar, decided, **options)
        filled.append(avatar.albedo.detach().clone())
        return figures

    monkeypatch.setattr(fitting, "solve_avatar_albedo", recording_solve)
    monkeypatch.setattr(fitting, "fill_avatar_albedo", recording_fill)
    options = dict(progress="none", max_steps=2, texture_size=64, batch_size=2, resolution=64, environment="on",
                   specular="off", light_size="off", solve_resolution=96, albedo_passes=3)
    report = fitting.fit(tiny_clip, tmp_path / "passes", **options)
    assert [(size, environment) for size, environment, _ in calls] == [((64, 64), True), ((96, 96), False)] * 3
    assert len(filled) == 3
    for later in (1, 2):     # each later pass starts where the fill before it left the albedo
        assert torch.equal(calls[2 * later][2], filled[later - 1])
    assert not torch.equal(filled[1], filled[0])
    passes = report["albedo_passes"]
    assert len(passes) == 2 and all(p["working"]["solved_fraction"] > 0.1 and p[fitting.FINER_SOLVE]["solved_fraction"]
                                    > 0.1 and "unseen_fraction" in p["fill"] for p in passes)
    assert capsys.readouterr().err.count("albedo solved again (pass") == 2
    settings = FitSettings(**{k: v for k, v in options.items() if k in FitSettings.__dataclass_fields__})
    costs = {kind: 0.1 for kind in estimate.FALLBACK_COSTS}
    once = estimate.after_stages_seconds(costs, dataclasses.replace(settings, albedo_passes=1), 4)
    assert estimate.after_stages_seconds(costs, settings, 4) > once
    calls.clear()
    fitting.fit(tiny_clip, tmp_path / "passes", resume=True, **options)
    assert not calls


def test_the_finer_solve_writes_the_texture_it_grew_and_a_resumed_fit_keeps_it(tmp_path):
    """Stages at 64 px with a 64 texture, a 256 px clip: the finer solve grows the texture to 128
    (texel_footprint.py), albedo.png and normal.png are written at that size, the report says so, and
    the finished fit resumed (its checkpoint's textures larger than the stages') writes the same files."""
    from synth_clips import exact_clip

    clip = exact_clip(tmp_path / "clip", 4, size=256)
    options = dict(progress="none", max_steps=2, texture_size=64, grow_texture=True, batch_size=2, resolution=64,
                   solve_resolution=256, shadows="off")
    report = fitting.fit(clip, tmp_path / "fit", **options)
    texture = report["albedo_solve"][fitting.FINER_SOLVE]["texture"]
    assert texture["grown_from"] == 64 and texture["texture_size"] == 128 and texture["pixel_footprint"] > 0
    written = {name: cv2.imread(str(tmp_path / "fit" / name)) for name in (av.ALBEDO_FILE, av.NORMAL_FILE)}
    assert all(image.shape == (128, 128, 3) for image in written.values())
    fitting.fit(clip, tmp_path / "fit", resume=True, **options)
    for name, image in written.items():
        assert np.array_equal(cv2.imread(str(tmp_path / "fit" / name)), image), name


def test_the_texture_is_no_finer_than_the_clips_pixels(tiny_clip):
    """A preset's texture shrinks to what the clip's working images can fill (the 96 px clip:
    128 texels, not `paper`'s 512); a texture size the user gives is kept."""
    problem = fitting._set_up(tiny_clip, fitting.FitJob("paper", device="cpu", max_steps=1), {"shadows": "off"}).problem
    assert problem.settings.texture_size == 128 and problem.avatar.albedo.shape[-1] == 128
    problem = fitting._set_up(tiny_clip, fitting.FitJob("paper", device="cpu", max_steps=1),
                              {"shadows": "off", "texture_size": 512}).problem
    assert problem.settings.texture_size == 512 and problem.avatar.albedo.shape[-1] == 512


def test_interrupt_then_resume_reaches_the_same_result(tiny_clip, tmp_path, monkeypatch):
    """Ctrl-C in the middle of stage two saves a checkpoint; --resume finishes the fit with the
    same final loss as an uninterrupted run (within 1%)."""
    import os
    import signal

    options = dict(progress="none", max_steps=6, texture_size=64, batch_size=2, resolution=96)
    reference = fitting.fit(tiny_clip, tmp_path / "reference", **options)
    original = stage_run.batch_energy
    calls = {"count": 0}

    def interrupting(*args, **kwargs):
        calls["count"] += 1
        if calls["count"] == 9:            # the geometry stage (after 6 alignment steps), step three
            os.kill(os.getpid(), signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(stage_run, "batch_energy", interrupting)
    out = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        fitting.fit(tiny_clip, out, **options)
    saved = load_checkpoint(out / CHECKPOINT_FILE)
    assert saved.state.stage == 1 and 0 < saved.state.step < 6
    monkeypatch.setattr(stage_run, "batch_energy", original)
    resumed = fitting.fit(tiny_clip, out, resume=True, **options)
    final = lambda report: report["final_losses"]["appearance"]["loss"]  # noqa: E731
    assert final(resumed) == pytest.approx(final(reference), rel=0.01)
    with pytest.raises(fitting.FitError, match="nothing to resume"):
        fitting.fit(tiny_clip, tmp_path / "fresh", resume=True, progress="none")


def test_a_resumed_fit_may_switch_the_albedo_solve_but_no_stage_setting(tiny_clip, tmp_path):
    options = dict(progress="none", max_steps=2, texture_size=64, batch_size=2, resolution=96)
    out = tmp_path / "avatar"
    assert fitting.fit(tiny_clip, out, solve_albedo=False, **options)["albedo_solve"] is None
    assert fitting.fit(tiny_clip, out, resume=True, **options)["albedo_solve"]["solved_fraction"] > 0
    with pytest.raises(fitting.FitError, match=r"other settings \(texture_size\)"):
        fitting.fit(tiny_clip, out, resume=True, **{**options, "texture_size": 32})


def test_a_fit_started_under_a_renamed_preset_resumes_under_its_new_name(tiny_clip, tmp_path):
    """HARP's schedule was the `full` preset before it became `paper`: a fit it started resumes
    with --preset paper, and --preset full (now other settings) says which name to use."""
    from pipeline.fit.checkpoint import save_checkpoint

    options = dict(progress="none", max_steps=2, texture_size=64, resolution=96)
    out = tmp_path / "avatar"
    fitting.fit(tiny_clip, out, preset="paper", **options)
    saved = load_checkpoint(out / CHECKPOINT_FILE)
    saved.settings = dataclasses.replace(saved.settings, preset="full")     # as written before the rename
    save_checkpoint(out / CHECKPOINT_FILE, saved)
    assert fitting.fit(tiny_clip, out, resume=True, preset="paper", **options)["preset"] == "paper"
    save_checkpoint(out / CHECKPOINT_FILE, saved)
    with pytest.raises(fitting.FitError, match="now called paper: resume with --preset paper"):
        fitting.fit(tiny_clip, out, resume=True, preset="full", **options)


def test_a_pixel_the_camera_clipped_says_only_at_least_white(tiny_clip):
    """Where a frame is saturated, a render above it matches it and one below it is pulled up; the
    albedo solve and the light search take no equation from a clipped pixel."""
    from pipeline.fit.albedo_solve import SOLVE_BATCH, _observations
    from pipeline.fit.energy import BatchData
    from pipeline.fit.schedule import StageKind

    problem = fitting._set_up(tiny_clip, fitting.FitJob(device="cpu", max_steps=1),
                              {"shadows": "off", "resolution": 96, "texture_size": 64}).problem
    joint = next(stage for stage in problem.settings.schedule() if stage.kind is StageKind.JOINT)
    frames = torch.arange(2)
    from pipeline.fit.light_search import _pixels
    before = _observations(problem, False, SOLVE_BATCH, 64).colour.shape[0]
    searched_before = _pixels(problem)[0].shape[0]
    with torch.no_grad():
        problem.avatar.albedo.mul_(2.5)        # skin bright enough to render above white in places
    clipped = problem.clip.masks[frames, ..., 0] > 0
    clipped[:, ::2] = False                    # every other row of the hand saturated in the frames
    problem.clip.images[frames] = torch.where(clipped[..., None], torch.ones(()), problem.clip.images[frames])
    problem.__dict__.pop("saturated", None)     # the frames changed: their clipped channels are found again
    batch = BatchData(problem, joint, frames, False, torch.Generator(), True)
    raw, rendered, target = batch.images["rgb"].detach(), batch.rendered.detach(), batch.target
    above = (target >= 254 / 255) & (raw > target)          # the frame saturated (8-bit 254 or 255), the render above
    assert (clipped[..., None] & (raw > 1)).sum() > 20 and (clipped[..., None] & (raw < 1)).sum() > 20
    assert torch.equal(rendered[above], target[above])      # as good as the white it was clipped to
    assert torch.equal(rendered[~above], raw[~above])       # the rest as rendered: below white it is pulled up
    after = _observations(problem, False, SOLVE_BATCH, 64).colour.shape[0]
    assert after < before - 0.3 * int(clipped.sum())         # the clipped pixels left the solve
    assert _pixels(problem)[0].shape[0] < searched_before - 0.3 * int(clipped.sum())   # and the light search


def test_a_rollback_compares_what_follows_with_the_snapshot_it_returned_to(tiny_clip):
    """A full-batch loss that rises past DIVERGENCE_FACTOR times its best is rolled back to the
    last snapshot; the steps after it are compared with that snapshot's loss, not with the best
    the undone steps had reached (else the snapshot itself counts as divergence at every step:
    a 3-frame clip's alignment rolled back 87 times in a row and never moved again)."""
    from pipeline.fit import stage_run
    from pipeline.fit.checkpoint import FitState
    from pipeline.fit.schedule import StageKind

    problem = fitting._set_up(tiny_clip, fitting.FitJob(device="cpu", max_steps=1),
                              {"shadows": "off", "resolution": 64, "texture_size": 64}).problem
    schedule = problem.settings.schedule()
    align = next(stage for stage in schedule if stage.kind is StageKind.ALIGN)
    align = dataclasses.replace(align, steps=40)
    # the snapshot taken after step ROLLBACK_EVERY measures 3.0 at the next step; the loss falls to 1.5, jumps
    # (40: rolled back), and the state restored to that snapshot measures 3.0 again and goes on falling
    losses = [100.0 / (index + 1) for index in range(stage_run.ROLLBACK_EVERY - 1)] + [5.0, 3.0, 1.5, 40.0]
    losses += [3.0, 2.5, 2.2]
    scripted = iter(losses)
    run = stage_run.StageRun(problem, align, FitState.fresh(schedule, "off"), torch.Generator().manual_seed(0))
    run.energy = lambda batch, backward=True: (next(scripted), {})
    events = [run.step().event for _ in losses]
    assert [event is not None for event in events] == [loss == 40.0 for loss in losses]
    assert "loss rose to 40 from 1.5" in events[losses.index(40.0)]
    assert run.best_loss == 2.2


def test_a_batch_loss_far_above_the_stages_recent_ones_is_rolled_back(tiny_clip):
    """In a stage of batches (no single best to compare with) a loss above BATCH_DIVERGENCE_FACTOR
    times the median of the stage's recent batch losses is divergence: rolled back, rates halved.
    The batches' ordinary spread (here up to 5x, as a stage's second step reaches) is not."""
    from pipeline.fit import stage_run
    from pipeline.fit.checkpoint import FitState
    from pipeline.fit.schedule import StageKind

    problem = fitting._set_up(tiny_clip, fitting.FitJob(device="cpu", max_steps=1),
                              {"shadows": "off", "resolution": 64, "texture_size": 64}).problem
    schedule = problem.settings.schedule()
    geometry = dataclasses.replace(next(stage for stage in schedule if stage.kind is StageKind.GEOMETRY), steps=40)
    losses = [0.2, 1.0, 0.6, 0.3, 0.25, 0.3, 0.22, 0.9, 0.25, 0.24, 3.1, 0.2, 0.21]
    scripted = iter(losses)
    state = FitState.fresh(schedule, "off")
    state.history.append({"stage": StageKind.ALIGN.value, "step": 100, "loss": 0.001})   # another stage's: not compared
    run = stage_run.StageRun(problem, geometry, state, torch.Generator().manual_seed(0))
    run.energy = lambda batch, backward=True: (next(scripted), {})
    rates = [group["lr"] for group in run.optimiser.param_groups]
    events = [run.step().event for _ in losses]
    assert [event is not None for event in events] == [loss == 3.1 for loss in losses]
    assert "loss rose to 3.1 from 0.275" in events[losses.index(3.1)]
    assert [group["lr"] for group in run.optimiser.param_groups] == [rate / 2 for rate in rates]


def test_a_checkpoint_with_a_setting_this_version_does_not_know_is_one_line(tiny_clip, tmp_path):
    """A fit written by a newer harp (a setting this one lacks) is refused in one FitError line
    naming the setting, not a TypeError from deep inside."""
    out = tmp_path / "avatar"
    fitting.fit(tiny_clip, out, progress="none", max_steps=1, texture_size=64, batch_size=2, resolution=96)
    saved = torch.load(out / CHECKPOINT_FILE, weights_only=True)
    saved["settings"]["a_setting_from_the_future"] = 1
    torch.save(saved, out / CHECKPOINT_FILE)
    with pytest.raises(fitting.FitError, match="a_setting_from_the_future.*newer version"):
        load_checkpoint(out / CHECKPOINT_FILE)
    with pytest.raises(fitting.FitError, match="a_setting_from_the_future"):
        fitting.fit(tiny_clip, out, resume=True, progress="none")


def test_killed_fit_resumes_from_its_last_checkpoint(tiny_clip, tmp_path):
    """A fit process killed outright (SIGKILL, no chance to save) right after a stage-end
    checkpoint: --resume finishes it with the final loss of an uninterrupted run (within 1%)."""
    import subprocess
    import sys
    import time

    options = dict(progress="none", max_steps=6, texture_size=64, batch_size=2, resolution=96, device="cpu")
    reference = fitting.fit(tiny_clip, tmp_path / "reference", **options)
    out = tmp_path / "killed"
    # the child is slowed down per step so that it is surely still fitting when it is killed
    child = subprocess.Popen([sys.executable, "-c", f"""
import sys, time
sys.path.insert(0, {str(ROOT)!r})
from pipeline.fit import fitting, stage_run
original = stage_run.batch_energy
def slowed(*args, **kwargs):
    time.sleep(0.1)
    return original(*args, **kwargs)
stage_run.batch_energy = slowed
fitting.fit({str(tiny_clip)!r}, {str(out)!r}, **{options!r})
"""], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    checkpoint = out / CHECKPOINT_FILE
    deadline = time.time() + 240
    while not checkpoint.is_file() and child.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    assert child.poll() is None, child.stderr.read().decode()    # still fitting: the kill is real
    child.kill()
    child.wait()
    saved = load_checkpoint(checkpoint)
    assert saved.state.stage == 1 and saved.state.step == 0   # the alignment's end
    resumed = fitting.fit(tiny_clip, out, resume=True, **options)
    final = lambda report: report["final_losses"]["appearance"]["loss"]  # noqa: E731
    assert final(resumed) == pytest.approx(final(reference), rel=0.01)


def test_non_finite_loss_rolls_back(tiny_clip, tmp_path, monkeypatch):
    from pipeline.fit import energy

    original = energy.batch_energy
    calls = {"count": 0}

    def sometimes_nan(*args, **kwargs):
        loss, terms = original(*args, **kwargs)
        calls["count"] += 1
        return (loss * float("nan"), terms) if calls["count"] == 2 else (loss, terms)

    monkeypatch.setattr(stage_run, "batch_energy", sometimes_nan)
    report = fitting.fit(tiny_clip, tmp_path / "avatar", progress="none", max_steps=3, texture_size=64,
                         batch_size=2, resolution=96)
    assert any("rolled back" in event for event in report["events"])
    assert np.isfinite(report["metrics"]["psnr_mean"])


def test_progress_as_json_lines(tiny_clip, tmp_path, capsys):
    fitting.fit(tiny_clip, tmp_path / "avatar", progress="jsonl", max_steps=10, texture_size=64, batch_size=2,
                resolution=96)
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    progress = [e for e in events if e["event"] == "progress"]
    assert progress and progress[-1]["done"] == progress[-1]["total"] and "seconds_left" in progress[-1]
    assert any(e["event"] == "log" and "expected time" in e["message"] for e in events)


def test_measuring_the_step_costs_changes_nothing_in_the_fit(tiny_clip, tmp_path, monkeypatch):
    """The calibration's throwaway steps leave the avatar and the random draws as they were: a
    fit that measures its step costs ends bit-for-bit where one that does not ends."""
    options = dict(progress="none", max_steps=3, texture_size=64, batch_size=2, resolution=96)
    plain = fitting.fit(tiny_clip, tmp_path / "plain", **options)
    monkeypatch.setattr(estimate, "CALIBRATE_MIN_STEPS", 0)
    measured = fitting.fit(tiny_clip, tmp_path / "measured", **options)
    assert not plain["estimate"]["calibrated"] and measured["estimate"]["calibrated"]
    assert measured["estimate"]["calibration_seconds"] > 0 and measured["estimate"]["expected_seconds"] > 0
    first, second = (load_checkpoint(tmp_path / name / CHECKPOINT_FILE, "cpu").avatar
                     for name in ("plain", "measured"))
    for name, value in first.items():
        assert torch.equal(value, second[name]), name


def test_render_the_avatar_in_new_poses_views_and_lights(tiny_clip, tmp_path):
    import cv2

    from pipeline.cli import main

    out = tmp_path / "avatar"
    fitting.fit(tiny_clip, out, progress="none", max_steps=2, texture_size=64, batch_size=2, resolution=96)
    pictures = {}
    for name, arguments in {"rest": [], "fist": ["--pose", "fist"], "turned": ["--azimuth", "90"],
                            "frame": ["--frame", "1"], "lit": ["--light", "0,-0.5,0", "--shadows", "on"]}.items():
        path = tmp_path / f"{name}.png"
        assert main(["render", str(out), "--out", str(path), "--size", "96", *arguments]) == 0
        pictures[name] = cv2.imread(str(path)).astype(float)
        covered = (np.abs(pictures[name] - pictures[name][0, 0]).sum(-1) > 10).mean()
        assert 0.05 < covered < 0.9, name          # the hand is in the picture, framed
    assert np.abs(pictures["rest"] - pictures["fist"]).mean() > 2
    assert np.abs(pictures["rest"] - pictures["turned"]).mean() > 2
    assert main(["render", str(out), "--frame", "99", "--out", str(tmp_path / "x.png")]) == 1
    assert main(["render", str(tmp_path / "nothing"), "--out", str(tmp_path / "x.png")]) == 1


def test_alignment_in_chunks_equals_one_batch(tiny_clip, tmp_path, monkeypatch):
    """A long clip's alignment step renders its frames in chunks: the same step as one batch."""
    options = dict(progress="none", max_steps=3, texture_size=64, resolution=96, steps=(0, 0, 0))
    whole = fitting.fit(tiny_clip, tmp_path / "whole", **options)
    monkeypatch.setattr(stage_run, "ALIGN_CHUNK_FRAMES", 1)
    chunked = fitting.fit(tiny_clip, tmp_path / "chunked", **options)
    assert whole["final_losses"]["align"]["loss"] == pytest.approx(chunked["final_losses"]["align"]["loss"], rel=1e-4)
    first, second = (av.read_poses(tmp_path / name) for name in ("whole", "chunked"))
    assert np.allclose(first.pose, second.pose, atol=1e-5)


def test_learning_rate_factor_is_a_half_cosine_to_its_final_fraction():
    assert stage_run.learning_rate_factor(0.0, 0.1) == pytest.approx(1.0)
    assert stage_run.learning_rate_factor(0.5, 0.1) == pytest.approx(0.55)
    assert stage_run.learning_rate_factor(1.0, 0.1) == pytest.approx(0.1)
    assert stage_run.learning_rate_factor(1.7, 0.1) == pytest.approx(0.1)    # a budget cut a stage short
    assert stage_run.learning_rate_factor(0.3, 1.0) == pytest.approx(1.0)    # constant rates
    for wrong in (0.0, 1.5):
        with pytest.raises(ValueError, match="final_rate_fraction must be in"):
            FitSettings(final_rate_fraction=wrong)


def test_plateau_factor_halves_after_each_window_that_stopped_falling():
    falling = [1.0] * 4 + [0.5] * 4 + [0.25] * 4           # windows of 4: each half the one before
    assert stage_run.plateau_factor(falling, 0.1, window=4) == 1.0
    level = [1.0] * 4 + [0.99] * 4 + [0.98] * 4 + [0.5] * 4 + [0.5] * 2    # -1%, -1%, -49%, then 2 steps
    assert stage_run.plateau_factor(level, 0.02, window=4) == 0.25      # the last, unfinished window waits
    assert stage_run.plateau_factor(level, 0.005, window=4) == 1.0      # -1% counts as falling here
    assert stage_run.plateau_factor([1.0] * 40, 0.01, window=4, floor=0.125) == 0.125
    assert stage_run.plateau_factor([1.0] * 40, 0.0, window=4) == 1.0   # off
    assert stage_run.plateau_factor([1.0] * 3, 0.5, window=4) == 1.0    # no full window yet
    for wrong in (-0.1, 1.0):
        with pytest.raises(ValueError, match="plateau_tolerance must be in"):
            FitSettings(plateau_tolerance=wrong)


def test_the_stages_rates_decay_and_a_rollback_halves_them(tiny_clip, tmp_path, monkeypatch):
    """The alignment and geometry stages keep their rates; the joint and appearance stages, the
    last to move their parameters, take them from the settings' down the half cosine to
    final_rate_fraction of them; a rolled-back step halves what follows, in the stages after it
    too."""
    from pipeline.fit import energy

    used, original_step = [], stage_run.StageRun._lazy_step

    def recording(self, batch):
        used.append((self.stage.kind.value, self.state.step, [group["lr"] for group in self.optimiser.param_groups]))
        return original_step(self, batch)

    original_energy, calls = energy.batch_energy, {"count": 0}

    def nan_in_the_joint_stage(problem, stage, *args, **kwargs):
        loss, terms = original_energy(problem, stage, *args, **kwargs)
        calls["count"] += stage.kind.value == "geometry+appearance"
        return (loss * float("nan"), terms) if calls["count"] == 3 else (loss, terms)

    monkeypatch.setattr(stage_run.StageRun, "_lazy_step", recording)
    monkeypatch.setattr(stage_run, "batch_energy", nan_in_the_joint_stage)
    steps, final = 6, 0.1
    report = fitting.fit(tiny_clip, tmp_path / "avatar", progress="none", max_steps=steps, texture_size=64,
                         batch_size=2, resolution=96, final_rate_fraction=final)
    assert sum("rolled back" in event for event in report["events"]) == 1
    by_stage = {}
    for kind, step, rates in used:
        by_stage.setdefault(kind, []).append((step, rates))
    for kind in ("align", "geometry"):
        assert all(rates == by_stage[kind][0][1] for _, rates in by_stage[kind]), kind
    appearance = by_stage["appearance"]
    for step, rates in appearance:
        assert rates == pytest.approx([rate * stage_run.learning_rate_factor(step / steps, final)
                                       for rate in appearance[0][1]])
    joint = by_stage["geometry+appearance"]
    joint_start = joint[0][1]
    defaults = FitSettings()
    assert sorted(set(joint_start)) == sorted({defaults.lr_geometry, defaults.lr_betas, defaults.lr_displacement,
                                               defaults.lr_appearance})
    for step, rates in joint:            # the third step's loss was not finite: no Adam step, halved after
        scale = 0.5 if step >= 3 else 1.0
        assert rates == pytest.approx([scale * rate * stage_run.learning_rate_factor(step / steps, final)
                                       for rate in joint_start])
    assert [step for step, _ in joint] == [0, 1, 3, 4, 5]
    assert appearance[0][1] == pytest.approx([0.5 * defaults.lr_appearance])   # the joint stage's halving carried on
