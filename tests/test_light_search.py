"""The light searched over the sphere before it is fitted (fit/light_search.py): from a start
behind the hand, an exact clip's light is found (its direction from the hand and its ambient
ratio); a light already right is kept; the fit runs it once, reports it, and skips it when off; a
light that needs an albedo above 1 scores what the avatar can draw under it."""
import json

import numpy as np
import pytest
import torch

from pipeline.evaluate.exact_clips import AMBIENT, LIGHT_POSITION, write_clip
from pipeline.fit.fitting import fit
from pipeline.fit.light_search import _residual, _texel_colours, search_light
from pipeline.fit.problem import build_problem
from pipeline.fit.settings import settings_for
from pipeline.init import initialise_sequence
from pipeline.render.renderer import render
from synth.motions import OPEN

FRAMES, SIZE = 8, 96


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("light") / "clip"
    write_clip(folder, OPEN, frames=FRAMES, size=SIZE, turn_degrees=25)
    initialise_sequence(folder, "gt-noise", noise_degrees=0.0, noise_translation_m=0.0, log=lambda *a: None)
    return folder


def exact_problem(folder):
    """The clip's problem at its true poses and shape (a gt-noise start without noise) and the true albedo
    left unknown, as the search finds it."""
    settings = settings_for("fast", FRAMES, resolution=SIZE, texture_size=32)
    return build_problem(folder, settings, np.arange(FRAMES), "cpu")


def hand_centre(problem):
    with torch.no_grad():
        vertices, _ = problem.avatar.posed(torch.arange(FRAMES))
    return vertices.reshape(-1, 3).mean(0).double()


def angle_degrees(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_a_light_started_behind_the_hand_is_found(clip):
    problem = exact_problem(clip)
    avatar = problem.avatar
    centre = hand_centre(problem)
    truth = np.asarray(LIGHT_POSITION) - centre.numpy()
    with torch.no_grad():
        avatar.light_position.copy_((centre + torch.tensor([0.0, 0.1, 0.3], dtype=torch.float64)).to(
            avatar.light_position.dtype))
    flat_error = frame_error(problem)
    found = search_light(problem)
    assert found["moved"] and found["after"]["residual"] < 0.5 * found["before"]["residual"], found
    assert angle_degrees(np.array([0.0, 0.1, 0.3]), truth) > 120                 # where it started
    direction = avatar.light_position.detach().double() - centre
    # the candidates are 64 directions, about 25 degrees apart, at the start's distance (0.3 m; the
    # light is 1.1 m away), and this clip turns about the vertical: measured 26 degrees, most of it
    # up and down
    assert angle_degrees(direction.numpy(), truth) < 30, (direction, truth)
    assert abs(avatar.ambient.item() - AMBIENT) <= 0.1 + 1e-6
    # and the texels' colours it solved are the starting albedo: the frames drawn by the avatar come nearer
    # (measured: 0.019 against 0.064 with the flat start)
    assert frame_error(problem) < 0.4 * flat_error, (frame_error(problem), flat_error)


def frame_error(problem):
    """The mean absolute difference between the frames and the avatar's render of them, in the masks."""
    avatar, clip = problem.avatar, problem.clip
    with torch.no_grad():
        vertices, _ = avatar.posed(torch.arange(FRAMES))
        rgb = render(vertices, avatar.mesh, clip.K, clip.height, clip.width, outputs=("rgb",),
                     appearance=avatar.appearance(), light=avatar.light(False))["rgb"]
    masks = (clip.masks > 0.5).expand_as(rgb)
    return float((rgb - clip.images).abs()[masks].mean())


def test_a_light_already_right_is_kept(clip):
    problem = exact_problem(clip)
    avatar = problem.avatar
    with torch.no_grad():
        avatar.light_position.copy_(torch.as_tensor(LIGHT_POSITION, dtype=avatar.light_position.dtype))
        avatar.ambient_logit.copy_(torch.logit(torch.tensor(AMBIENT, dtype=avatar.ambient_logit.dtype)))
    found = search_light(problem)
    assert not found["moved"]
    assert torch.allclose(avatar.light_position.detach().double(), torch.tensor(LIGHT_POSITION, dtype=torch.float64))


@pytest.mark.parametrize("light_search", ["on", "off"])
def test_the_fit_searches_once_before_the_light_moves_and_reports_it(clip, tmp_path, light_search):
    report = fit(clip, tmp_path / "fit", max_steps=2, progress="none", resolution=SIZE, texture_size=32,
                 light_search=light_search)
    written = json.loads((tmp_path / "fit" / "report.json").read_text())
    if light_search == "off":
        assert written["light_search"] is None
        return
    assert written["light_search"]["candidates"] == 257 and "residual" in written["light_search"]["before"]
    assert report["light_search"] == written["light_search"]


def test_a_light_that_needs_albedo_above_one_scores_what_the_avatar_can_draw():
    """One texel seen in two pixels (facing the camera; sideways) at albedo 0.9 under the light in
    front (ambient 0.6): shading 1 and 0.6. A dim light from above and the side with ambient 0.15
    shades them 0.5 and 0.3, in the same ratio, so in least squares it explains them exactly too, but
    only with an albedo of 1.8. The avatar's albedo stops at 1: the search must score that light by
    what the avatar can draw under it, worse than the true one."""
    positions = torch.zeros(2, 3, dtype=torch.float64)
    normals = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    texels = torch.zeros(2, dtype=torch.long)
    colours = 0.9 * torch.tensor([[1.0], [0.6]], dtype=torch.float64).expand(2, 3)
    far = 1e6
    truth = torch.tensor([0.0, 0.0, -far], dtype=torch.float64)
    up, side = (0.5 - 0.15) / 0.85, (0.3 - 0.15) / 0.85          # the dim light's cosines: shading 0.5, 0.3
    dim = far * torch.tensor([side, (1 - side ** 2 - up ** 2) ** 0.5, -up], dtype=torch.float64)
    _, shading, _ = _texel_colours(positions, normals, colours, texels, dim, 0.15)
    assert torch.allclose(shading[:, 0], torch.tensor([0.5, 0.3], dtype=torch.float64), atol=1e-6)
    assert float(_residual(positions, normals, colours, texels, truth, 0.6)) < 1e-12
    colour, _, _ = _texel_colours(positions, normals, colours, texels, dim, 0.15)
    assert torch.allclose(colour[0], torch.ones(3, dtype=torch.float64))    # 1.8, held at 1
    # drawn at albedo 1 under the dim light: 0.5 and 0.3 against 0.9 and 0.54
    expected = ((0.9 - 0.5) ** 2 + (0.54 - 0.3) ** 2) / (0.9 ** 2 + 0.54 ** 2)
    assert float(_residual(positions, normals, colours, texels, dim, 0.15)) == pytest.approx(expected, rel=1e-6)
