"""The UV atlas: few charts, no overlaps, even texel density, a mask at any resolution."""
import numpy as np
import pytest

from pipeline.handmodel.uv_atlas import texel_density_spread, uv_mask


def uv_areas(data):
    t = data.uvs[data.faces_uv]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def test_few_charts_even_density(model_data, mode):
    data = model_data[mode]
    assert data.metadata["uv_charts"] <= 30
    assert texel_density_spread(data.vertices, data.faces, data.uvs, data.faces_uv) < 0.25
    assert data.uvs.min() >= 0 and data.uvs.max() <= 1
    assert (uv_areas(data) > 0).all()  # no degenerate UV triangles


def test_charts_do_not_overlap(model_data, mode):
    """Covered area equals the summed triangle area (overlaps would make it smaller); the small
    excess is the rasterised chart borders and shrinks as the resolution grows."""
    data = model_data[mode]
    total = uv_areas(data).sum()
    ratios = [uv_mask(data.uvs, data.faces_uv, r, dilation_px=0).sum() / (total * r * r) for r in (1024, 2048)]
    assert 1.0 <= ratios[1] < ratios[0] < 1.04


@pytest.mark.parametrize("resolution", [128, 512, 1000])
def test_mask_follows_the_requested_resolution(model_data, resolution):
    data = model_data["hand"]
    mask = uv_mask(data.uvs, data.faces_uv, resolution)
    assert mask.shape == (resolution, resolution) and mask.dtype == bool
    assert 0.3 < mask.mean() < 0.8


def test_mask_orientation_matches_uv_convention(model_data):
    """v = 1 is the top row: a UV at the top of the atlas lands in row 0's neighbourhood."""
    data = model_data["hand"]
    mask = uv_mask(data.uvs, data.faces_uv, 256, dilation_px=0)
    top_face = np.argmax(data.uvs[data.faces_uv].mean(1)[:, 1])
    u, v = data.uvs[data.faces_uv[top_face]].mean(0)
    assert mask[int((1 - v) * 256), int(u * 256)]
