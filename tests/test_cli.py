"""The `harp` command: the quick-start demo and the model subcommands, end to end."""
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

import pytest

from pipeline.cli import build_parser, main
from pipeline.demo import run_demo
from pipeline.fit.settings import settings_for
from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel.measurements import joint_limits_markdown

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_demo_renders_initialises_fits_and_evaluates(tmp_path):
    """The README's main job, shrunk (6 frames, 160 px, a few steps): every output appears."""
    pytest.importorskip("bpy")
    lines = []
    result = run_demo(tmp_path, progress="none", log=lines.append, max_steps=3, frames=6, width=160, height=160,
                      samples=2)
    for path in ("clip/gt.npz", "clip/init.npz", "avatar/albedo.png", "avatar/rig.npz", "avatar/fit_grid.png",
                 "avatar/overlay.mp4", "avatar/report.json", "avatar/evaluation.json"):
        assert (tmp_path / path).is_file(), path
    assert len(result["metrics"]["silhouette_iou"]) == 6 and result["metrics"]["silhouette_iou_min"] > 0.5
    assert np.isfinite(result["evaluation"]["poses"]["fit"]["joints"]["procrustes_mm_mean"])
    fidelity = result["evaluation"]["fidelity"]               # the avatar against the true hand, in new poses
    assert 0 < fidelity["geometry"]["surface_mm_mean"] < 10 and 0 < fidelity["new_poses"]["iou_mean"] <= 1
    assert (tmp_path / "avatar" / "fidelity.png").is_file()
    assert any(line.startswith("fidelity to the true hand") for line in lines)
    for picture in result["pictures"]:
        image = cv2.imread(str(picture))
        assert image is not None and image.std() > 5  # the hand is drawn on the grey background
    assert any(line.startswith("demo finished") for line in lines)
    assert any("initialised from MediaPipe" in line for line in lines)


def test_demo_is_the_default_job():
    args = build_parser().parse_args(["demo"])
    assert args.run.__name__ == "_demo" and args.out == "harp_demo"


def test_the_albedo_solve_is_on_unless_switched_off():
    parser = build_parser()
    assert parser.parse_args(["fit", "seq", "--out", "a"]).solve_albedo is None      # the settings' default: on
    assert parser.parse_args(["fit", "seq", "--out", "a", "--no-solve-albedo"]).solve_albedo is False
    assert settings_for("fast", 10).solve_albedo
    assert not settings_for("fast", 10, solve_albedo=False).solve_albedo


def _fit_options(monkeypatch, *argvs):
    """[the options `harp fit` passes to fit()] for each command line, fit() itself stubbed."""
    import pipeline.fit

    seen = []
    monkeypatch.setattr(pipeline.fit, "fit", lambda *args, **options: seen.append(options) or
                        {"total_seconds": 0.0, "metrics": {}})
    monkeypatch.setattr("pipeline.fit.outputs.metrics_line", lambda metrics: "")
    parser = build_parser()
    for argv in argvs:
        args = parser.parse_args(argv)
        args.run(args)
    return seen


def test_harp_fit_passes_its_seed_to_the_fit_and_leaves_the_default_otherwise(monkeypatch):
    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--seed", "3"], ["fit", "seq", "--out", "a"])
    assert seen[0]["seed"] == 3 and "seed" not in seen[1]


def test_harp_fit_offers_the_occlusions_settings_and_passes_the_one_chosen(monkeypatch):
    """--occlusion's choices are FitSettings' (written out in the command, which does not import torch)."""
    from pipeline.fit.settings import OCCLUSION_CHOICES

    fit_parser = build_parser()._subparsers._group_actions[0].choices["fit"]
    assert tuple(next(a for a in fit_parser._actions if a.dest == "occlusion").choices) == OCCLUSION_CHOICES
    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--occlusion", "after"], ["fit", "seq", "--out", "a"])
    assert seen[0]["occlusion"] == "after" and seen[1]["occlusion"] is None     # None: the preset's


def test_harp_fit_offers_every_albedo_fill_and_passes_the_one_chosen(monkeypatch):
    """--albedo-fill's choices are FitSettings' (written out in the command, which does not import torch)."""
    from pipeline.fit.settings import ALBEDO_FILL_CHOICES

    fit_parser = build_parser()._subparsers._group_actions[0].choices["fit"]
    assert tuple(next(a for a in fit_parser._actions if a.dest == "albedo_fill").choices) == ALBEDO_FILL_CHOICES
    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--albedo-fill", "edge"], ["fit", "seq", "--out", "a"])
    assert seen[0]["albedo_fill"] == "edge" and seen[1]["albedo_fill"] is None


def test_harp_fit_sets_term_weights_by_name_over_the_defaults(monkeypatch, capsys):
    from pipeline.fit.energy_terms import default_weights

    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--weight", "size_prior=1", "--weight",
                                      "texture=0.5"], ["fit", "seq", "--out", "a"])
    parser = build_parser()
    assert seen[0]["weights"] == {**default_weights(), "size_prior": 1.0, "texture": 0.5}
    assert "weights" not in seen[1]
    for bad, said in (("no_such_term=1", "no energy term named 'no_such_term'"), ("size_prior=big", "a number"),
                      ("size_prior=-1", "0 or more"), ("size_prior=nan", "0 or more")):
        args = parser.parse_args(["fit", "seq", "--out", "a", "--weight", bad])
        with pytest.raises(SystemExit, match=said):
            args.run(args)


def test_harp_fit_sets_the_size_priors_anchor_and_band(monkeypatch):
    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--size-anchor", "initial", "--size-tolerance",
                                      "0.01", "--size-measure", "palm", "--anchor-size", "free"],
                        ["fit", "seq", "--out", "a"])
    assert seen[0]["size_anchor"] == "initial" and seen[0]["size_tolerance"] == 0.01
    assert seen[0]["size_measure"] == "palm" and seen[0]["anchor_size"] == "free"
    assert seen[1]["anchor_size"] is None and settings_for("fast", 30).anchor_size == "held"
    assert seen[1]["size_anchor"] is None and seen[1]["size_tolerance"] is None     # the settings' defaults
    assert seen[1]["size_measure"] is None and settings_for("fast", 30).size_measure == "scale"
    with pytest.raises(ValueError, match="size_measure must be"):
        settings_for("fast", 30, size_measure="fingers")
    with pytest.raises(ValueError, match="size_anchor must be"):
        settings_for("fast", 30, size_anchor="middle")
    with pytest.raises(ValueError, match="size_tolerance must be"):
        settings_for("fast", 30, size_tolerance=-0.01)


def test_harp_fit_sets_what_the_temporal_pose_term_measures(monkeypatch):
    from pipeline.fit.losses import POSE_SMOOTHNESS

    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--pose-smoothness", "velocity"],
                        ["fit", "seq", "--out", "a"])
    assert seen[0]["pose_smoothness"] == "velocity" and seen[1]["pose_smoothness"] is None
    fit_parser = build_parser()._subparsers._group_actions[0].choices["fit"]
    choices = next(action.choices for action in fit_parser._actions if action.dest == "pose_smoothness")
    assert sorted(choices) == sorted(POSE_SMOOTHNESS)       # written out in the CLI (no torch import there)
    with pytest.raises(ValueError, match="pose_smoothness must be"):
        settings_for("fast", 30, pose_smoothness="jerk")


def test_harp_fit_sets_a_terms_factor_in_a_stage(monkeypatch):
    seen = _fit_options(monkeypatch, ["fit", "seq", "--out", "a", "--stage-factor", "size_prior@align=0",
                                      "--stage-factor", "keypoint_anchor@geometry=0.5", "--stage-factor",
                                      "size_prior@geometry+appearance=2"], ["fit", "seq", "--out", "a"])
    parser = build_parser()
    assert seen[0]["stage_factors"] == {"size_prior": {"align": 0.0, "geometry+appearance": 2.0},
                                        "keypoint_anchor": {"geometry": 0.5}}
    assert "stage_factors" not in seen[1]
    for bad, said in (("no_such_term@align=1", "no energy term named 'no_such_term'"),
                      ("size_prior@nowhere=1", "no stage named 'nowhere'"), ("size_prior=1", "no stage named ''"),
                      ("size_prior@align=big", "a number"), ("size_prior@align=-1", "0 or more")):
        args = parser.parse_args(["fit", "seq", "--out", "a", "--stage-factor", bad])
        with pytest.raises(SystemExit, match=said):
            args.run(args)
    # as the fit's settings take them: the term's weight in that stage only
    from pipeline.fit.energy_terms import ENERGY_TERMS
    from pipeline.fit.schedule import StageKind
    settings = settings_for("fast", 30, weights={"size_prior": 1.0}, stage_factors=seen[0]["stage_factors"])
    size_prior = ENERGY_TERMS["size_prior"]
    assert size_prior.weight_in(settings, StageKind.ALIGN) == 0.0
    assert size_prior.weight_in(settings, StageKind.GEOMETRY) == 1.0


def test_preview_of_the_left_hand(tmp_path):
    assert main(["model", "preview", "--side", "left", "--size", "120", "--out", str(tmp_path / "left.png")]) == 0
    right = tmp_path / "right.png"
    assert main(["model", "preview", "--size", "120", "--out", str(right)]) == 0
    left_image, right_image = cv2.imread(str(tmp_path / "left.png")), cv2.imread(str(right))
    # the first tile (palm view) of the left hand is the mirror image of the right's
    tile = lambda image: image[20:120, :120].astype(float)
    assert np.abs(tile(left_image) - tile(right_image)[:, ::-1]).mean() < 12


def test_bad_model_folder_gives_one_clear_line(tmp_path, capsys):
    assert main(["model", "info", "--model", str(tmp_path / "missing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hand model file not found" in err[0]


def test_console_script_is_installed():
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "--help"], capture_output=True, text=True)
    assert result.returncode == 0 and "demo" in result.stdout


def test_docs_joint_limit_table_matches_the_code():
    assert joint_limits_markdown() in (ROOT / "docs" / "hand_model.md").read_text()


def test_the_presets_are_named_alike_in_the_settings_the_command_and_the_blender_panel():
    """harp fit --preset, its help's measured notes and the add-on's preset menu offer exactly the
    presets fit/settings.PRESETS defines (the add-on's list is read as text: it imports bpy)."""
    import ast

    from pipeline.cli import PRESET_NOTES
    from pipeline.fit.settings import PRESETS

    assert list(PRESET_NOTES) == list(PRESETS)
    fit_parser = build_parser()._subparsers._group_actions[0].choices["fit"]
    assert tuple(next(a for a in fit_parser._actions if a.dest == "preset").choices) == tuple(PRESETS)
    source = Path(__file__).resolve().parents[1] / "harp_addon" / "properties.py"
    panel = next(node.value for node in ast.parse(source.read_text()).body
                 if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "PRESETS")
    assert [item[0] for item in ast.literal_eval(panel)] == list(PRESETS)
