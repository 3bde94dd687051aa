"""The fit's image scores: background plates and PSNR / L1 of a render over the plate, on
analytic images (a disc of one colour over a flat or linearly shaded background, with exact
antialiased coverage from supersampling)."""
import numpy as np
import pytest
import torch

from pipeline.fit.clip_data import ClipData, background_plates, harmonic_fill
from pipeline.fit.outputs import image_scores

SIZE, RADIUS = 48, 13.0
HAND = np.array([0.85, 0.62, 0.55])


def _coverage(size=SIZE, radius=RADIUS, samples=8):
    """Share of each pixel inside the disc centred in the image (supersampled)."""
    offsets = (np.arange(samples) + 0.5) / samples
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    inside = np.zeros((size, size))
    for dy in offsets:
        for dx in offsets:
            inside += (x + dx - size / 2) ** 2 + (y + dy - size / 2) ** 2 <= radius ** 2
    return inside / samples ** 2


def _background(kind):
    if kind == "flat":
        return np.broadcast_to(np.array([0.4, 0.45, 0.5]), (SIZE, SIZE, 3)).copy()
    ramp = np.linspace(0.2, 0.7, SIZE)  # linear shading left to right
    return np.stack([ramp[None, :].repeat(SIZE, 0), 0.5 + 0 * ramp[None, :].repeat(SIZE, 0),
                     ramp[::-1][None, :].repeat(SIZE, 0)], -1)


def _clip(background):
    """One photographed frame: the disc over `background`, edges blended by coverage, and its
    binary mask (coverage >= 0.5)."""
    coverage = _coverage()[..., None]
    image = HAND * coverage + background * (1 - coverage)
    mask = (coverage >= 0.5).astype(np.float64)
    clip = ClipData(torch.tensor(image[None]), torch.tensor(mask[None]), torch.eye(3, dtype=torch.float64),
                    info=None, frames=np.array([0]))
    return clip, coverage


@pytest.mark.parametrize("kind", ["flat", "ramp"])
def test_background_plate_recovers_the_background_behind_the_hand(kind):
    """Laplace's equation reproduces flat and linear shading exactly."""
    background = _background(kind)
    clip, coverage = _clip(background)
    plate = background_plates(clip.images, clip.masks)[0].numpy()
    behind = coverage[..., 0] > 0
    assert np.abs(plate - background)[behind].max() < 1e-9
    outside = _coverage(radius=RADIUS + 4) == 0     # beyond the grown mask: unchanged
    assert np.array_equal(plate[outside], background[outside])


def test_harmonic_fill_at_the_image_border_and_without_any_background():
    """A hole on the image's left edge under shading that varies down the image only: the
    free border condition keeps the fill exact. No known pixel at all: grey."""
    shading = np.linspace(0.1, 0.9, 20)[:, None, None] * np.ones((20, 30, 3))
    hole = np.zeros((20, 30), bool)
    hole[4:15, :9] = True
    noisy = shading.copy()
    noisy[hole] = np.random.default_rng(0).random((hole.sum(), 3))
    assert np.abs(harmonic_fill(noisy, hole) - shading).max() < 1e-9
    assert np.array_equal(harmonic_fill(noisy, np.ones_like(hole)), np.full_like(noisy, 0.5))


def test_a_render_that_matches_the_photograph_scores_near_perfect():
    clip, coverage = _clip(_background("ramp"))
    plate = clip.backgrounds[0].numpy()
    rgb = HAND * coverage + plate * (1 - coverage)    # the renderer's composite over the plate
    scores = image_scores(torch.tensor(rgb[None]), torch.tensor(coverage[None]), clip)
    assert scores["silhouette_iou"][0] == pytest.approx(1.0)
    assert scores["psnr"][0] > 40 and scores["l1"][0] < 0.01


def test_hand_pixels_the_render_misses_count_in_full():
    """The left half of the disc is missed: there the render shows the plate, and the error
    inside the mask is the hand-background difference on those pixels."""
    background = _background("flat")
    clip, coverage = _clip(background)
    missed = np.zeros_like(coverage)
    missed[:, : SIZE // 2 - 2] = 1
    alpha = coverage * (1 - missed)
    rgb = HAND * alpha + clip.backgrounds[0].numpy() * (1 - alpha)
    scores = image_scores(torch.tensor(rgb[None]), torch.tensor(alpha[None]), clip)
    mask = clip.masks[0, ..., 0].numpy() > 0
    # a missed pixel shows the background where the photograph shows coverage * (hand - background) more
    per_pixel = ((coverage * missed * (HAND - background)) ** 2).mean(-1)
    expected_mse = per_pixel[mask].sum() / mask.sum()
    assert expected_mse > 0.005          # the miss is large: at least ~half the disc's area
    assert scores["psnr"][0] == pytest.approx(10 * np.log10(1 / expected_mse), abs=0.05)
    assert scores["psnr"][0] < 20
    assert scores["silhouette_iou"][0] == pytest.approx((alpha[..., 0] >= 0.5)[mask].sum() / mask.sum(), abs=1e-9)
