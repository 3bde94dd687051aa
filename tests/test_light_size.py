"""The light's size in the fit (fit/light_size.py): `auto` finds the disc a clip was drawn with
and keeps a point light where it was drawn with one (pipeline/evaluate/exact_clips.py, the true
geometry given), its format in avatar.json, and checkpoints from before it."""
import json
import math

import pytest
import torch

from pipeline.evaluate.exact_clips import write_clip
from pipeline.fit import fitting
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.light_probe import probe_frames
from pipeline.fit.light_size import FIRST, POINT, decide_light_size
from pipeline.formats import light_size
from pipeline.init import initialise_sequence
from synth.motions import RELAXED

AMBIENT = 0.25                       # a strong light, whose shadows carry a quarter of the picture and more
LIGHT = (-0.9, -0.2, 1.0)            # from the thumb's side at the hand's depth: the fingers shadow each other


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("light_size")
    for name, degrees in (("window", FIRST), ("point", POINT)):
        write_clip(root / name, RELAXED, frames=8, size=128, turn_degrees=25, shadows=True, ambient=AMBIENT,
                   light_position=LIGHT, angular_radius=math.radians(degrees))
        initialise_sequence(root / name, "gt-noise", noise_degrees=0.0, noise_translation_m=0.0, log=lambda *a: None)
    return root


def decided(folder):
    """decide_light_size on the clip's problem with its true geometry, light and ambient (the
    albedo left to the probe's solves)."""
    problem = fitting._set_up(folder, fitting.FitJob(progress="none"), {"resolution": 128, "texture_size": 64}).problem
    with torch.no_grad():
        problem.avatar.light_position.copy_(torch.tensor(LIGHT))
        problem.avatar.ambient_logit.fill_(math.log(AMBIENT / (1 - AMBIENT)))
    decision = decide_light_size(problem, True, probe_frames(len(problem.frames)))
    assert problem.avatar.light_angle.item() == pytest.approx(math.radians(decision["degrees"]))
    return decision


def test_auto_finds_the_drawn_disc_and_keeps_a_point_light_where_there_is_one(clips):
    window = decided(clips / "window")
    assert window["degrees"] == FIRST, window                  # L1 0.0120 a point, 0.0114 11 deg, 0.0120 19 deg
    point = decided(clips / "point")
    assert point["degrees"] == POINT, point                    # 0.0105 a point, 0.0110 6 deg, 0.0118 11 deg
    assert min(point["candidates"].values()) == point["candidates"]["0.0"]


def test_without_shadows_there_is_no_size_to_decide(clips):
    problem = fitting._set_up(clips / "point", fitting.FitJob(progress="none"), {"resolution": 64}).problem
    problem.avatar.light_angle.fill_(0.3)
    assert decide_light_size(problem, False, probe_frames(len(problem.frames))) == {"degrees": 0.0, "candidates": {}}
    assert problem.avatar.light_angle.item() == 0.0


def test_a_fit_writes_its_light_size_and_a_checkpoint_from_before_it_reads_as_a_point_light(clips, tmp_path):
    report = fitting.fit(clips / "window", tmp_path / "fit", max_steps=2, progress="none", resolution=64,
                         texture_size=64, shadows="on")
    assert report["light_size"]["requested"] == "auto" and report["light_size"]["decision"] is not None
    light = json.loads((tmp_path / "fit" / "avatar.json").read_text())["light"]
    assert light_size.from_description(light) == pytest.approx(math.radians(report["light_size"]["degrees"]), abs=1e-6)
    path = tmp_path / "fit" / CHECKPOINT_FILE
    saved = torch.load(path, weights_only=True)
    del saved["avatar"]["light_angle"]
    del saved["settings"]["light_size"]
    saved["version"] = 6
    torch.save(saved, path)
    old = load_checkpoint(path)
    assert old.version == 6 and old.settings.light_size == "off" and old.avatar["light_angle"].item() == 0.0


def test_the_light_size_format():
    assert light_size.from_description({}) == 0.0                       # avatars from before it: a point light
    light = {light_size.KEY: light_size.to_description(torch.tensor(0.2))}
    assert light_size.from_description(json.loads(json.dumps(light))) == pytest.approx(0.2)
    assert light_size.sun_angle(light) == pytest.approx(0.4)
    for bad in ("wide", float("nan"), -0.1, 1.0, [0.2]):
        with pytest.raises(ValueError, match="angular_radius"):
            light_size.from_description({light_size.KEY: bad})
