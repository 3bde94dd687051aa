"""The environment light in the fit: a known room's light recovered from clips drawn exactly with
it (pipeline/evaluate/exact_clips.py), `auto` switching itself off on a clip without one, and
checkpoints from before it."""
import json

import numpy as np
import pytest
import torch

from pipeline.evaluate.exact_clips import AMBIENT, coloured_room, write_clip
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.fitting import ENVIRONMENT_THRESHOLD, fit
from pipeline.formats import environment_light as el
from pipeline.init import initialise_sequence
from pipeline.render.renderer import Light, render
from synth.motions import OPEN
from synth_clips import known_scene, quick_fits


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("environment")
    for name, environment in (("room", coloured_room()), ("plain", None)):
        write_clip(root / name, OPEN, frames=8, size=96, turn_degrees=25, environment=environment)
    return root


def recovered_environment(folder, steps=150):
    """The environment light fitted to a clip with everything else known (its true surface,
    albedo, point light and ambient): Adam on the L1 difference inside the masks."""
    scene = known_scene(folder)
    environment = torch.zeros(el.COEFFICIENTS, 3, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([environment], lr=0.02)
    for _ in range(steps):
        optimiser.zero_grad()
        light = Light(torch.tensor([0.1, -0.2, 0.0], dtype=torch.float64), torch.tensor(AMBIENT, dtype=torch.float64),
                      environment=environment, linear=scene["linear"], occlusion=scene["occlusion"],
                      bounce=scene["bounce"])
        rgb = render(scene["vertices"], scene["mesh"], scene["K"], scene["height"], scene["width"], outputs=("rgb",),
                     appearance=scene["appearance"], light=light, antialiased=False)["rgb"]
        loss = ((rgb - scene["frames"]).abs() * scene["masks"]).sum() / scene["masks"].sum()
        loss.backward()
        optimiser.step()
    return environment.detach().numpy(), scene["vertices"], scene["mesh"]


def test_a_known_room_light_is_recovered_and_none_where_there_is_none(clips):
    truth = coloured_room()
    found, vertices, mesh = recovered_environment(clips / "room")
    # compared where it acts: on the normals the clip shows (the coefficients of directions no
    # frame faces are not determined)
    from pipeline.render.shading import vertex_normals
    normals = vertex_normals(vertices, mesh.faces).reshape(-1, 3).numpy()
    facing = normals[normals[:, 2] < -0.2]
    error = np.abs(el.shading_factor(facing, found) - el.shading_factor(facing, truth))
    assert error.mean() < 0.01, error.mean()
    assert np.abs(el.shading_factor(facing, truth)).mean() > 5 * error.mean()
    assert el.relative_strength(found, AMBIENT) > ENVIRONMENT_THRESHOLD
    plain, _, _ = recovered_environment(clips / "plain")
    # what the known scene does not reproduce (the clip's antialiased outline, its 8-bit values) leaves a faint
    # room: measured 0.0065 in linear light, 0.0026 in display values, against the threshold's 0.015
    assert el.relative_strength(plain, AMBIENT) < 0.5 * ENVIRONMENT_THRESHOLD


@pytest.fixture(scope="module")
def auto_fits(clips, tmp_path_factory):
    """{clip name: report} of quick `fast` fits (synth_clips.quick_fits) with the environment auto."""
    return quick_fits(clips, ("room", "plain"), tmp_path_factory.mktemp("fits"), environment="auto")


def test_auto_keeps_a_coloured_room_light_and_switches_it_off_without_one(auto_fits):
    """The colour the room adds is recovered (strength and direction); a clip without one gets none."""
    truth = coloured_room()
    truth_strength = el.colour_strength(truth, AMBIENT)
    decided = auto_fits["room"]["environment"]["decision"]
    assert decided["on"] is True and 0.5 * truth_strength < decided["colour_strength"] < 1.5 * truth_strength, decided
    found = np.array(json.loads((auto_fits["room"]["out"] / "avatar.json").read_text())["light"]["environment"])
    # its colour points the way the room's does: blue from the left, warm from below
    colour, true_colour = (c - c.mean(1, keepdims=True) for c in (found, truth))
    assert (colour * true_colour).sum() / np.linalg.norm(colour) / np.linalg.norm(true_colour) > 0.8
    light = json.loads((auto_fits["room"]["out"] / "avatar.json").read_text())["light"]
    # and the world it stands for is one Blender can show: nowhere darker than no light
    world = el.unclipped_radiance(el.sphere_directions(2000), found, light["ambient"])
    assert world.min() > -0.01, world.min()
    plain = auto_fits["plain"]
    decided = plain["environment"]["decision"]
    assert decided["on"] is False and decided["colour_strength"] < ENVIRONMENT_THRESHOLD
    assert plain["environment"]["coefficients"] is None
    assert json.loads((plain["out"] / "avatar.json").read_text())["light"]["environment"] is None
    saved = load_checkpoint(plain["out"] / CHECKPOINT_FILE)
    assert not bool(saved.avatar["environment_on"]) and not saved.avatar["environment"].any()


def test_auto_leaves_it_off_on_too_few_frames(clips, tmp_path):
    """Four frames of the room: too few views to tell its light from the albedo."""
    initialise_sequence(clips / "room", "gt-noise", log=lambda *a: None)
    report = fit(clips / "room", tmp_path / "fit", max_steps=20, progress="none", resolution=96, texture_size=64,
                 environment="auto", max_frames=4)
    assert len(report["frames"]) == 4 and report["environment"]["decision"]["on"] is False
    assert report["environment"]["coefficients"] is None


def test_a_checkpoint_from_before_the_environment_light_reads_without_one(clips, tmp_path):
    initialise_sequence(clips / "plain", "gt-noise", log=lambda *a: None)
    fit(clips / "plain", tmp_path / "fit", max_steps=2, progress="none", resolution=96, texture_size=64)
    path = tmp_path / "fit" / CHECKPOINT_FILE
    saved = torch.load(path, weights_only=True)
    for name in ("environment", "environment_on"):
        del saved["avatar"][name]
    del saved["settings"]["environment"]
    saved["version"] = 4
    torch.save(saved, path)
    old = load_checkpoint(path)
    assert old.version == 4 and old.settings.environment == "off"
    assert not bool(old.avatar["environment_on"]) and old.avatar["environment"].shape == (el.COEFFICIENTS, 3)
