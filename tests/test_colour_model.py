"""The colour model (pipeline/formats/colour_model.py): the sRGB formulas against their defining
values and finite differences, the renderer's linear light against the display model fed the
decoded albedo, and a fit in linear light on a clip drawn so against the same fit in display
values."""
import dataclasses
import json
import shutil

import cv2

import numpy as np
import pytest
import torch

from pipeline.avatar_render import load_avatar, render_avatar
from pipeline.evaluate.albedo import albedo_error, albedo_truth
from pipeline.evaluate.exact_clips import AMBIENT, write_clip
from pipeline.fit.settings import FitSettings
from pipeline.formats import colour_model
from pipeline.formats.colour_model import linear_to_srgb, srgb_to_linear
from pipeline.render.renderer import Appearance, Light, render
from synth.motions import OPEN
from synth_clips import known_scene, quick_fits


def test_the_srgb_curve_at_its_defining_values():
    encoded = np.array([0.0, 0.04045, 0.5, 1.0, 1.2])
    linear = srgb_to_linear(encoded)
    # IEC 61966-2-1: the straight part's slope 1/12.92, the curve through (1, 1); 0.5 -> 0.2140
    np.testing.assert_allclose(linear[:4], [0.0, 0.04045 / 12.92, 0.21404114, 1.0], atol=1e-7)
    assert linear[4] > 1.0                                    # above 1 the curve goes on
    # the standard's two knees miss each other by 3e-8: the round trip holds to that
    np.testing.assert_allclose(linear_to_srgb(linear), encoded, atol=1e-7, rtol=0)
    values = torch.linspace(0, 1, 101, dtype=torch.float64)
    torch.testing.assert_close(srgb_to_linear(values), torch.as_tensor(srgb_to_linear(values.numpy())))
    torch.testing.assert_close(linear_to_srgb(srgb_to_linear(values)), values, atol=1e-7, rtol=0)


def test_the_gradients_are_finite_at_black_and_match_finite_differences():
    for formula in (srgb_to_linear, linear_to_srgb):
        at = torch.tensor([0.0, 1e-4, 0.2, 0.7, 1.0], dtype=torch.float64, requires_grad=True)
        gradient, = torch.autograd.grad(formula(at).sum(), at)
        assert torch.isfinite(gradient).all()
        step = 1e-7
        with torch.no_grad():
            numeric = (formula(at + step) - formula(at - step)) / (2 * step)
        # at 0 the central difference straddles the straight part's end of the line: one side
        torch.testing.assert_close(gradient[1:], numeric[1:], rtol=1e-5, atol=1e-7)
        assert gradient[0] == pytest.approx(12.92 if formula is linear_to_srgb else 1 / 12.92)


def test_names_settings_and_folders_from_before_the_choice():
    assert colour_model.from_description({}) == colour_model.DISPLAY
    assert colour_model.is_linear({"colour_model": "linear"})
    with pytest.raises(ValueError, match="colour model"):
        colour_model.from_description({"colour_model": "gamma"})
    with pytest.raises(ValueError, match="colour model"):
        FitSettings(colour_model="srgb")
    saved = {k: v for k, v in vars(FitSettings()).items() if k != "colour_model"}
    assert FitSettings.from_dict(saved).colour_model == "display"


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("colour")
    write_clip(root / "linear", OPEN, frames=8, size=96, turn_degrees=20, colour_model="linear",
               specular=(0.5, 0.5), environment=np.array([[0.0] * 3, [0.05, 0.0, -0.05]] + [[0.0] * 3] * 6))
    return root


def test_the_renderer_shades_the_decoded_albedo_and_encodes_the_colour(clips):
    """Linear light, drawn: every covered pixel is the display model's colour of the decoded albedo
    (point light, ambient, environment and sheen, all in linear light), encoded."""
    scene = known_scene(clips / "linear")
    light = Light(torch.tensor([0.1, -0.2, 0.0], dtype=torch.float64), torch.tensor(AMBIENT, dtype=torch.float64),
                  environment=torch.zeros(8, 3, dtype=torch.float64).index_fill_(0, torch.tensor([1]), 0.05),
                  specular=(torch.tensor(0.5, dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64)))
    arguments = (scene["vertices"], scene["mesh"], scene["K"], scene["height"], scene["width"])
    shaded = render(*arguments, outputs=("rgb", "alpha"), appearance=scene["appearance"],
                    light=dataclasses.replace(light, linear=True), antialiased=False)
    decoded = Appearance(srgb_to_linear(scene["appearance"].albedo))
    reference = render(*arguments, outputs=("rgb",), appearance=decoded, light=light, antialiased=False)["rgb"]
    inside = shaded["alpha"][..., 0] > 0.5
    assert inside.sum() > 1000
    torch.testing.assert_close(shaded["rgb"][inside], linear_to_srgb(reference)[inside], atol=1e-12, rtol=0)
    # the same light in display values is darker where the shading is below 1 (the encoding lifts it)
    display = render(*arguments, outputs=("rgb",), appearance=scene["appearance"], light=light, antialiased=False)
    assert (shaded["rgb"][inside].mean() - display["rgb"][inside].mean()) > 0.02   # measured 0.041


@pytest.fixture(scope="module")
def fits(clips, tmp_path_factory):
    """Quick fits (synth_clips.quick_fits) of the clip drawn in linear light, in either model, the
    light started where the fit starts it (the search, tests/test_light_search.py, left out: with it
    both models found this clip's albedo, the display one to 0.021 and the linear to 0.035)."""
    out = tmp_path_factory.mktemp("colour_fits")
    return {model: quick_fits(clips, ("linear",), out / model, colour_model=model, light_search="off")["linear"]
            for model in colour_model.MODELS}


def test_a_fit_in_linear_light_finds_the_albedo_the_clip_was_drawn_with(clips, fits):
    errors = {}
    for model, report in fits.items():
        folder = report["out"]
        assert json.loads((folder / "avatar.json").read_text())["light"]["colour_model"] == model
        _, appearance, _ = load_avatar(folder)
        known = albedo_truth(clips / "linear", appearance.albedo.shape[-1], fit_folder=folder)
        errors[model] = albedo_error(appearance.albedo.permute(1, 2, 0).double().numpy(), known.image,
                                     known.visible)["mae"]
    # measured in a run of 100 steps a stage: 0.052 against 0.076 (the linear fit's albedo 7% too light, the
    # display fit's 10%), fitted PSNR 31.2 against 30.9 dB
    assert errors["linear"] < 0.8 * errors["display"], errors
    assert fits["linear"]["metrics"]["psnr_mean"] > fits["display"]["metrics"]["psnr_mean"]


def test_harp_render_shades_a_folder_in_its_own_colour_model(fits, tmp_path):
    """The linear fit's folder rendered as written, and again with its colour model taken away (a
    folder from before the choice): the same avatar, lighter where it is shaded in linear light."""
    folder = tmp_path / "avatar"
    shutil.copytree(fits["linear"]["out"], folder)
    linear = cv2.imread(str(render_avatar(folder, tmp_path / "linear.png", size=128, background=(0, 0, 0)))) / 255
    description = json.loads((folder / "avatar.json").read_text())
    del description["light"]["colour_model"]
    (folder / "avatar.json").write_text(json.dumps(description))
    display = cv2.imread(str(render_avatar(folder, tmp_path / "display.png", size=128, background=(0, 0, 0)))) / 255
    hand = (linear.max(-1) > 0) & (display.max(-1) > 0)
    assert hand.sum() > 1000
    assert (linear - display)[hand].mean() > 0.02
