"""Filling the texels a clip never showed (pipeline/fit/texture_fill.py) on the hand model's
own atlas: seen texels are kept, a constant is filled exactly, and the fill crosses UV seams
through the surface instead of stopping at chart borders."""
import numpy as np
import pytest

from pipeline.fit import texture_fill as tf
from pipeline.handmodel.lbs import load_model_data
from pipeline.handmodel.uv_raster import interpolate, rasterize_uv

SIZE = 96


@pytest.fixture(scope="module")
def hand():
    data = load_model_data("hand")
    graph = tf.texel_graph(data.vertices, data.faces, data.uvs, data.faces_uv, SIZE)
    face, bary = rasterize_uv(data.uvs, data.faces_uv, SIZE)
    points = interpolate(face, bary, data.faces, data.vertices)     # (T, T, 3) surface point of each texel
    return data, graph, points


def test_the_graph_joins_charts_across_their_seams(hand):
    data, graph, points = hand
    assert graph.inside.sum() > 0.3 * SIZE * SIZE and len(graph.seams) > 100
    inside_points = points[graph.inside]
    gaps = np.linalg.norm(inside_points[graph.seams[:, 0]] - inside_points[graph.seams[:, 1]], axis=1)
    rows, cols = np.nonzero(graph.inside)
    atlas_gaps = np.abs(rows[graph.seams[:, 0]] - rows[graph.seams[:, 1]]) + \
        np.abs(cols[graph.seams[:, 0]] - cols[graph.seams[:, 1]])
    assert gaps.max() < 0.01 and np.median(atlas_gaps) > 10      # close on the hand, far apart in the atlas


def test_fill_keeps_what_was_seen_and_fills_a_constant_exactly(hand):
    _, graph, points = hand
    rng = np.random.default_rng(0)
    texture = rng.uniform(size=(SIZE, SIZE, 3))
    seen = graph.inside & (points[..., 1] > np.median(points[graph.inside][:, 1]))   # the fingers' half
    filled = tf.fill_unseen(texture, seen, graph)
    np.testing.assert_array_equal(filled[seen], texture[seen])
    constant = np.where(seen[..., None], 0.4, texture)
    filled = tf.fill_unseen(constant, seen, graph)
    np.testing.assert_allclose(filled, 0.4, atol=1e-9)                 # outside the charts too


def test_fill_continues_a_smooth_colour_across_seams(hand):
    """Skin whose colour varies smoothly over the hand, seen on one side (the back, say):
    filled from it, the seams lose the jumps the initial colour made."""
    _, graph, points = hand
    inside = points[graph.inside]
    centre, spread = inside.mean(0), inside.std(0)
    colour = 0.5 + 0.3 * np.tanh((points - centre) / spread)             # smooth over the surface
    seen = graph.inside & (points[..., 2] > np.percentile(inside[:, 2], 40))
    start = np.where(seen[..., None], colour, [[[232 / 255, 190 / 255, 172 / 255]]])
    filled = tf.fill_unseen(start, seen, graph)
    before, after = tf.seam_contrast(start, graph), tf.seam_contrast(filled, graph)
    truth = tf.seam_contrast(colour, graph)
    assert after < 0.5 * before and after < 2 * truth + 0.01
    unseen = graph.inside & ~seen
    assert np.abs(filled[unseen] - colour[unseen]).mean() < np.abs(start[unseen] - colour[unseen]).mean()
