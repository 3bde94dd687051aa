"""The anytime curve, the fit with known appearance (HARP-known), `harp plot` and `harp study`
on tiny exact clips (pipeline/evaluate/exact_clips.py, no Blender)."""
import json

import numpy as np
import pytest
import torch

from pipeline.cli import main
from pipeline.evaluate import poses
from pipeline.evaluate.curve import CurveRecorder
from pipeline.evaluate.exact_clips import write_clip
from pipeline.evaluate.study import CASES, run_study
from pipeline.fit import fit
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint, save_checkpoint
from pipeline.fit.fitting import KNOWN_APPEARANCE
from pipeline.fit.settings import settings_for
from pipeline.formats.fit_report import read_report
from pipeline.formats.fit_curve import read_curve
from pipeline.init import initialise_sequence
from synth.motions import FIST, OPEN, RELAXED

FIT = dict(progress="none", max_steps=6, texture_size=64, batch_size=2, resolution=96, shadows="off", device="cpu")

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clip") / "clip"
    write_clip(folder, RELAXED, frames=5, size=96)
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


@pytest.fixture(scope="module")
def curve_fit(clip, tmp_path_factory):
    out = tmp_path_factory.mktemp("curve") / "avatar"
    report = fit(clip, out, observers=[CurveRecorder(out, first_mark_seconds=0.05)], **FIT)
    return out, report


def test_curve_time_is_monotone_and_its_last_point_is_the_report(curve_fit, clip):
    out, report = curve_fit
    curve = read_curve(out)
    points = curve["points"]
    times = [point["fit_seconds"] for point in points]
    assert len(points) >= 4 and times[0] == 0.0 and np.all(np.diff(times) > 0)
    assert [p["stage"] for p in points][0] == "align" and points[-1]["stage"] == "done"
    # the time axis is the fit's own: measuring is left out and reported
    assert times[-1] == pytest.approx(report["total_seconds"], abs=1e-6)
    assert 0 < curve["measure_seconds"] <= report["measure_seconds"] + 1e-9
    last, scores = points[-1], report["metrics"]
    assert last["psnr_mean"] == pytest.approx(scores["psnr_mean"], abs=1e-9)
    assert last["l1_mean"] == pytest.approx(scores["l1_mean"], abs=1e-9)
    assert last["silhouette_iou_min"] == pytest.approx(scores["silhouette_iou_min"], abs=1e-9)
    assert last["silhouette_iou_mean"] == pytest.approx(np.mean(scores["silhouette_iou"]), abs=1e-9)
    errors = poses.evaluate_poses(out, clip, device="cpu")["fit"]
    assert last["joint_mm"] == pytest.approx(errors["joints"]["procrustes_mm_mean"], rel=1e-6)
    assert last["vertex_mm"] == pytest.approx(errors["vertices"]["procrustes_mm_mean"], rel=1e-6)
    # the first point is the initial estimate: its errors are init.npz's
    initial = poses.evaluate_poses(out, clip, device="cpu")["initial"]
    assert points[0]["joint_mm"] == pytest.approx(initial["joints"]["procrustes_mm_mean"], rel=1e-4)
    assert last["joint_mm"] < points[0]["joint_mm"] and last["l1_mean"] < points[0]["l1_mean"]
    assert 0 < last["albedo_mae"] < points[0]["albedo_mae"]


def test_a_resumed_fit_continues_its_curve(clip, tmp_path, monkeypatch):
    from pipeline.fit import stage_run

    out = tmp_path / "avatar"
    original, calls = stage_run.batch_energy, {"count": 0}

    def interrupting(*args, **kwargs):
        calls["count"] += 1
        if calls["count"] == 9:
            import os
            import signal
            os.kill(os.getpid(), signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(stage_run, "batch_energy", interrupting)
    with pytest.raises(KeyboardInterrupt):
        fit(clip, out, observers=[CurveRecorder(out, first_mark_seconds=0.05)], **FIT)
    before = read_curve(out)["points"]
    monkeypatch.setattr(stage_run, "batch_energy", original)
    report = fit(clip, out, resume=True, observers=[CurveRecorder(out, first_mark_seconds=0.05)], **FIT)
    points = read_curve(out)["points"]
    times = [point["fit_seconds"] for point in points]
    assert points[0] == before[0] and np.all(np.diff(times) > 0)
    assert times[-1] == pytest.approx(report["total_seconds"], abs=1e-6)


def test_known_appearance_moves_only_the_poses(curve_fit, clip, tmp_path):
    known, _ = curve_fit
    out = tmp_path / "known"
    report = fit(clip, out, known_appearance=known, **FIT)
    source, fitted = load_checkpoint(known / CHECKPOINT_FILE), load_checkpoint(out / CHECKPOINT_FILE)
    for name in KNOWN_APPEARANCE:                         # bit for bit the known fit's
        assert torch.equal(fitted.avatar[name], source.avatar[name]), name
    start = load_checkpoint(known / CHECKPOINT_FILE)       # per-frame parameters did move (from init.npz)
    initial = np.load(clip / "init.npz")
    assert np.abs(fitted.avatar["pose"].numpy() - initial["pose"]).max() > 1e-5
    assert report["appearance"] == "known (frozen)" and start.state.shadows.on == fitted.state.shadows.on
    assert set(report["final_losses"]) == {"align", "geometry", "geometry+appearance"}   # nothing left to fit after
    with pytest.raises(ValueError, match="not a fit folder"):
        fit(clip, tmp_path / "again", known_appearance=tmp_path / "nothing", **FIT)
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    start.state.stage = 1
    save_checkpoint(unfinished / CHECKPOINT_FILE, start)
    with pytest.raises(ValueError, match="has not finished"):
        fit(clip, tmp_path / "again", known_appearance=unfinished, **FIT)
    assert not (tmp_path / "again").exists()


def test_harp_plot_draws_the_curves(curve_fit, tmp_path):
    import cv2

    out, _ = curve_fit
    picture = tmp_path / "curves.png"
    assert main(["plot", str(out), str(out), "--out", str(picture)]) == 0
    image = cv2.imread(str(picture))
    assert image is not None and image.shape[0] > 200 and image.std() > 10
    assert main(["plot", str(tmp_path / "missing"), "--out", str(picture)]) == 1


def test_a_fit_known_only_by_its_end_is_drawn_as_one_star(curve_fit, tmp_path):
    import cv2

    from pipeline.evaluate.plot import plot_curves

    out, _ = curve_fit
    last = read_curve(out)["points"][-1]
    plain = cv2.imread(str(plot_curves([out], tmp_path / "plain.png", figures=("l1_mean",))))
    starred = cv2.imread(str(plot_curves([out], tmp_path / "starred.png", figures=("l1_mean",),
                                         finals=[("a long fit", 4 * last["fit_seconds"], {"l1_mean": last["l1_mean"]})])))
    assert plain.shape == starred.shape and (np.abs(plain.astype(int) - starred).sum(-1) > 60).sum() > 50


def test_the_paper_preset_counts_its_epochs_over_the_frames_it_fits():
    assert settings_for("paper", 150).steps == (900, 450, 450)                  # 9 batches of 18 per epoch
    assert settings_for("paper", 150, max_frames=30).steps == (200, 100, 100)   # 2 batches per epoch
    assert settings_for("paper", 150, max_frames=30, steps=(1, 2, 3)).steps == (1, 2, 3)
    assert settings_for("full", 150).steps == settings_for("full", 30).steps == (400, 600, 400)   # steps, not epochs
    assert settings_for("fast", 150, max_frames=30).steps == settings_for("fast", 150).steps


def test_study_on_two_tiny_clips_fills_every_cell(tmp_path):
    dataset = tmp_path / "dataset"
    write_clip(dataset / "tiny_flip_front_ambient", OPEN, size=96, frames=5, turn_degrees=30)
    fingers = np.stack([OPEN + (FIST - OPEN) * t for t in np.linspace(0, 0.5, 5)])
    write_clip(dataset / "tiny_fingers_front_ambient", fingers, size=96, frames=5, turn_degrees=5)
    options = dict(max_steps=2, resolution=96, texture_size=64, batch_size=2, device="cpu")
    study = run_study(dataset, tmp_path / "study", quick=True, log=lambda message: None, runtime_frames=4, **options)
    refinement = study["sections"]["refinement"]
    assert [row["case"] for row in refinement["rows"] if row["clip"].startswith("tiny_fingers")] == list(CASES)
    for row in refinement["rows"]:
        assert all(row[name] is not None and np.isfinite(row[name])
                   for name in ("joint_mm", "vertex_mm", "joint_camera_mm", "vertex_camera_mm")), row
    assert set(refinement["means"]["all"]) == set(CASES)
    runtime = study["sections"]["runtime"]
    assert [row["preset"] for row in runtime["table"]] == ["preview", "fast", "full", "paper"]
    assert all(row["final_l1"] is not None and row["final_joint_mm"] is not None for row in runtime["table"])
    assert runtime["table"][-1]["seconds_to_both"] is not None      # the reference reaches its own level
    assert runtime["frames"] == 4
    assert all(len(read_report(folder)["frames"]) == 4 for folder in runtime["fits"].values())
    stability = study["sections"]["stability"]
    assert stability["all_finite"] and {row["kind"] for row in stability["rows"]} == {
        "baseline", "weights", "rates", "poses", "shapes", "framing", "inputs"}
    text = (tmp_path / "study" / "study.md").read_text()
    assert "## 1. Pose refinement" in text and "## 2. Error against run time" in text and "## 3. Stability" in text
    per_clip = [line.split("|")[1:-1] for line in text.split("### Per clip")[1].split("## 2.")[0].splitlines()
                if line.startswith("| tiny_")]
    assert len(per_clip) == 9 and all("–" not in cell for row in per_clip for cell in row[2:6])
    for plot in ("refinement.png", "runtime_tiny_flip_front_ambient.png", "refinement_tiny_fingers_front_ambient.png"):
        assert (tmp_path / "study" / "plots" / plot).is_file(), plot
    # a rerun finds every result and fits nothing
    again = run_study(dataset, tmp_path / "study", quick=True, log=lambda message: None, **options)
    assert again["sections"]["refinement"]["rows"] == refinement["rows"]
    saved = json.loads((tmp_path / "study" / "study.json").read_text())
    assert saved["sections"]["stability"]["rows"] == stability["rows"]


def test_study_seeds_in_worker_processes_match_the_study_run_here(tmp_path):
    dataset = tmp_path / "dataset"
    write_clip(dataset / "tiny_flip_front_ambient", OPEN, size=96, frames=5, turn_degrees=30)
    fingers = np.stack([OPEN + (FIST - OPEN) * t for t in np.linspace(0, 0.5, 5)])
    write_clip(dataset / "tiny_fingers_front_ambient", fingers, size=96, frames=5, turn_degrees=5)
    options = dict(max_steps=2, resolution=96, texture_size=64, batch_size=2, device="cpu", quick=True,
                   sections=("refinement",), log=lambda message: None)
    pooled = run_study(dataset, tmp_path / "pooled", seeds=(0, 1), jobs=2, threads=1, **options)
    here = run_study(dataset, tmp_path / "here", seeds=(0,), **options)

    def figures(rows, seed):
        return [{k: v for k, v in row.items() if k != "fit_seconds"} for row in rows if row["seed"] == seed]

    rows = pooled["sections"]["refinement"]["rows"]
    assert figures(rows, 0) == figures(here["sections"]["refinement"]["rows"], 0)     # bit for bit
    assert [row["case"] for row in rows if row["seed"] == 1 and row["clip"].startswith("tiny_fingers")] == list(CASES)
    assert (tmp_path / "pooled" / "fits" / "tiny_fingers_front_ambient" / "seed1" / "known" / "report.json").is_file()
    full = {row["seed"]: row["joint_mm"] for row in rows if row["case"] == "HARP-full" and row["clip"].startswith("tiny_f")}
    assert full[0] != full[1]                                   # the seed changes the fit
    means = pooled["sections"]["refinement"]["means"]["all"]["HARP-full"]
    lowest, highest = means["joint_mm_spread"]
    assert lowest < highest and lowest <= means["joint_mm"] <= highest
    assert here["sections"]["refinement"]["means"]["all"]["HARP-full"]["joint_mm_spread"] is None
    text = (tmp_path / "pooled" / "study.md").read_text()
    assert "fit seeds 0, 1" in text and f"{means['joint_mm']:.2f} ({lowest:.2f}-{highest:.2f})" in text


def test_a_target_counts_as_reached_only_once_the_curve_stays_there():
    from pipeline.evaluate.study import _at_most, _settled_time

    def curve(values):
        return [{"fit_seconds": float(t), "joint_mm": v} for t, v in enumerate(values)]

    below = lambda point: _at_most(point, "joint_mm", 4.0)  # noqa: E731
    assert _settled_time(curve([6, 3.5, 4.5, 4.7]), below) is None            # dipped, rose again
    assert _settled_time(curve([6, 3.5, 4.5, 3.9, 3.8]), below) == 3.0
    assert _settled_time(curve([3, 3, 3]), below) == 0.0
    assert _settled_time(curve([6, float("nan"), 3]), below) == 2.0
