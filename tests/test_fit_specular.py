"""The skin's specular lobe in the fit: a known roughness and level recovered from clips drawn
exactly with them (pipeline/evaluate/exact_clips.py), `auto` switching the lobe off on a clip
without one, its format, and checkpoints from before it."""
import json

import pytest
import torch

from pipeline.evaluate.exact_clips import AMBIENT, BACKGROUND, write_clip
from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
from pipeline.fit.fitting import fit
from pipeline.formats import specular_lobe
from pipeline.init import initialise_sequence
from pipeline.render.renderer import Light, render
from synth.motions import OPEN
from synth_clips import known_scene, quick_fits

SHINY = (0.4, 0.6)      # roughness, level: an oily sheen


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("specular")
    for name, lobe in (("shiny", SHINY), ("plain", None)):
        write_clip(root / name, OPEN, frames=8, size=96, turn_degrees=25, specular=lobe)
    return root


def recovered_lobe(folder, steps=150):
    """(roughness, level) fitted to a clip with everything else known (its true surface, albedo,
    point light and ambient): Adam on the squared difference inside the masks, rendered as the
    clip was (antialiased over its background: the room's sheen is brightest at the outline)."""
    scene = known_scene(folder)
    roughness_logit = torch.zeros((), dtype=torch.float64, requires_grad=True)     # roughness 0.6
    level_logit = torch.tensor(-1.4, dtype=torch.float64, requires_grad=True)      # level 0.2
    optimiser = torch.optim.Adam([roughness_logit, level_logit], lr=0.05)
    low, high = specular_lobe.ROUGHNESS_RANGE
    for _ in range(steps):
        optimiser.zero_grad()
        lobe = low + (high - low) * torch.sigmoid(roughness_logit), torch.sigmoid(level_logit)
        light = Light(torch.tensor([0.1, -0.2, 0.0], dtype=torch.float64), torch.tensor(AMBIENT, dtype=torch.float64),
                      specular=lobe, linear=scene["linear"], occlusion=scene["occlusion"], bounce=scene["bounce"])
        rgb = render(scene["vertices"], scene["mesh"], scene["K"], scene["height"], scene["width"], outputs=("rgb",),
                     appearance=scene["appearance"], light=light,
                     background=torch.tensor(BACKGROUND, dtype=torch.float64))["rgb"]     # drawn as the clip was
        loss = ((rgb - scene["frames"]).pow(2) * scene["masks"]).sum() / scene["masks"].sum()
        loss.backward()
        optimiser.step()
    return tuple(value.item() for value in lobe)


def test_a_known_lobe_is_recovered_and_none_where_there_is_none(clips):
    roughness, level = recovered_lobe(clips / "shiny")
    assert abs(roughness - SHINY[0]) < 0.03 and abs(level - SHINY[1]) < 0.05, (roughness, level)
    _, level = recovered_lobe(clips / "plain")
    assert level < 0.03, level


@pytest.fixture(scope="module")
def auto_fits(clips, tmp_path_factory):
    """{clip name: report} of quick `fast` fits (synth_clips.quick_fits) with the lobe auto."""
    return quick_fits(clips, ("shiny", "plain"), tmp_path_factory.mktemp("fits"), specular="auto")


def test_auto_keeps_a_sheen_and_switches_it_off_without_one(auto_fits):
    shiny = auto_fits["shiny"]["specular"]
    assert shiny["decision"]["on"] is True, shiny
    lobe = json.loads((auto_fits["shiny"]["out"] / "avatar.json").read_text())["light"][specular_lobe.KEY]
    # the roughness as drawn; the level low (an L1 photometric term lets the albedo take part of the highlight)
    assert abs(lobe["roughness"] - SHINY[0]) < 0.1 and 0.4 * SHINY[1] < lobe["level"] < 1.2 * SHINY[1], lobe
    plain = auto_fits["plain"]
    assert plain["specular"]["decision"]["on"] is False and plain["specular"]["lobe"] is None, plain["specular"]
    assert json.loads((plain["out"] / "avatar.json").read_text())["light"][specular_lobe.KEY] is None
    saved = load_checkpoint(plain["out"] / CHECKPOINT_FILE)
    assert not bool(saved.avatar["specular_on"])


def test_a_checkpoint_from_before_the_lobe_reads_without_one(clips, tmp_path):
    initialise_sequence(clips / "plain", "gt-noise", log=lambda *a: None)
    fit(clips / "plain", tmp_path / "fit", max_steps=2, progress="none", resolution=96, texture_size=64)
    path = tmp_path / "fit" / CHECKPOINT_FILE
    saved = torch.load(path, weights_only=True)
    for name in ("roughness_logit", "specular_logit", "specular_on"):
        del saved["avatar"][name]
    del saved["settings"]["specular"]
    saved["version"] = 5
    torch.save(saved, path)
    old = load_checkpoint(path)
    assert old.version == 5 and old.settings.specular == "off" and not bool(old.avatar["specular_on"])
    assert old.avatar["roughness_logit"].shape == () and old.avatar["specular_logit"].shape == ()


def test_the_lobe_format():
    light = {specular_lobe.KEY: specular_lobe.to_description(torch.tensor(0.4), 0.3)}
    assert specular_lobe.from_description(json.loads(json.dumps(light))) == pytest.approx((0.4, 0.3))
    assert specular_lobe.from_description({}) is None and specular_lobe.from_description({"specular": None}) is None
    for bad in ({"roughness": 0.4}, {"roughness": float("nan"), "level": 0.3}, {"roughness": 0.0, "level": 0.3}, [1]):
        with pytest.raises(ValueError, match="specular lobe"):
            specular_lobe.from_description({specular_lobe.KEY: bad})
    assert specular_lobe.principled_inputs({"specular": None})["Specular IOR Level"] == 0.0
    assert specular_lobe.principled_inputs({}) == {"Roughness": 0.5, "Specular IOR Level": 0.5, "IOR": 1.5}
