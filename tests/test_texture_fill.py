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


def test_texels_shown_only_at_the_silhouette_are_filled_not_left_at_the_start(tmp_path):
    """An exact clip, the avatar at its truth and its albedo at the starting colour except on the
    texels the frames decide (set to the true albedo, as a perfect fit leaves them). Texels the
    frames show only at the silhouette, outside the pixels the fit compares, are filled like
    unseen ones: afterwards no texel inside the charts holds the starting colour, which a new
    pose would show as pale streaks along the fingers' sides."""
    import torch

    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.fit import fitting
    from pipeline.fit.albedo_solve import decided_texels
    from pipeline.fit.avatar import SKIN_RGB
    from pipeline.formats import sequence_folder as seq
    from pipeline.formats.initial_estimate import write_initial_estimate
    from pipeline.init.initial_from_ground_truth import ground_truth_with_noise
    from pipeline.render.texel_visibility import visible_texels
    from synth.motions import RELAXED

    folder = tmp_path / "clip"
    write_clip(folder, RELAXED, frames=3, size=96, turn_degrees=20)
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    write_initial_estimate(folder, ground_truth_with_noise(gt, joint_degrees=0.0, translation_m=0.0, seed=0))
    problem = fitting._set_up(folder, fitting.FitJob("fast", device="cpu"), {"exposure": "off"}).problem
    avatar, clip = problem.avatar, problem.clip
    size = avatar.albedo.shape[-1]
    truth = torch.as_tensor(seq.read_rgb(folder / seq.GT_ALBEDO_FILE) / 255.0, dtype=torch.float32).permute(2, 0, 1)
    truth = torch.nn.functional.interpolate(truth[None], size=(size, size), mode="area")[0]
    start = torch.tensor(SKIN_RGB, dtype=torch.float32)[:, None, None]

    decided = decided_texels(problem)
    with torch.no_grad():
        vertices = avatar.posed(problem.all_frames())[0]
    shown = torch.as_tensor(visible_texels(vertices, avatar.mesh, clip.K, clip.height, clip.width, size))
    data = avatar.model.data
    inside = torch.as_tensor(tf.texel_graph(avatar.rest_mesh().numpy(), data.faces, data.uvs, data.faces_uv, size).inside)
    rim = shown & ~decided & inside
    assert decided.any() and not (decided & ~shown).sum() > 0.02 * decided.sum()
    assert rim.sum() > 0.1 * decided.sum(), (int(rim.sum()), int(decided.sum()))   # the silhouette's texels

    with torch.no_grad():
        avatar.albedo.copy_(torch.where(decided, truth, start.expand_as(truth)))
    figures = tf.fill_avatar_albedo(avatar, decided)
    albedo = avatar.albedo.detach()
    at_start = ((albedo - start).abs().amax(0) < 1e-4) & inside
    assert not at_start.any(), int(at_start.sum())
    torch.testing.assert_close(albedo[:, decided & inside], truth[:, decided & inside], rtol=0, atol=1e-6)
    # and the filled rim is nearer the truth than the starting colour was
    assert (albedo - truth).abs().mean(0)[rim].mean() < 0.7 * (start - truth).abs().mean(0)[rim].mean()
    assert figures["unseen_fraction"] > 1 - float(decided.sum() / inside.sum()) - 1e-6


def test_a_partly_trusted_texel_is_pulled_to_its_own_value_as_far_as_it_is_trusted():
    """Three texels in a row, the ends kept at 0 and 1, the middle one solved at v with trust t:
    it minimises (x - 0)^2 + (x - 1)^2 + w (x - v)^2 + SKIN_PRIOR (x - m)^2, w = t / (1 - t), m the
    median of the trusted-at-all texels (0.5 here): x = (1 + w v + SKIN_PRIOR m) / (2 + w + SKIN_PRIOR)."""
    inside = np.zeros((1, 3), bool)
    inside[:] = True
    graph = tf.TexelGraph(inside, np.arange(3).reshape(1, 3), np.array([[0, 1], [1, 2]]), np.zeros((0, 2), np.int64), 1.0)
    texture = np.array([[[0.0], [0.9], [1.0]]])
    for t in (0.0, 0.25, 0.5, 0.9):
        trust = np.array([[1.0, t, 1.0]])
        w, v = t / (1 - t), 0.9
        median = np.median([0.0, 0.9, 1.0] if t > 0 else [0.0, 1.0])
        expected = (1 + w * v + tf.SKIN_PRIOR * median) / (2 + w + tf.SKIN_PRIOR)
        np.testing.assert_allclose(tf.fill_unseen(texture, trust, graph)[0, 1, 0], expected, rtol=1e-9)
    np.testing.assert_array_equal(tf.fill_unseen(texture, np.ones((1, 3)), graph), texture)     # fully trusted


def test_texels_seen_only_edge_on_are_trusted_less_than_those_seen_squarely(tmp_path, monkeypatch):
    """On an exact clip: texel_trust is 0 where the frames do not decide a texel, 1 on the skin the
    camera faces, below 1 on decided texels no pixel sees at more than a grazing angle, and the
    squarely seen share of each texel's weight as the test measures it from the frames' own normals."""
    import torch

    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.fit import fitting
    from pipeline.fit.albedo_solve import (FACING_GRAZING, FACING_SQUARE, SQUARE_SHARE, _facing, decided_texels,
                                           texel_trust)
    from pipeline.formats import sequence_folder as seq
    from pipeline.formats.initial_estimate import write_initial_estimate
    from pipeline.init.initial_from_ground_truth import ground_truth_with_noise
    from pipeline.render.renderer import render
    from pipeline.render.texture import bilinear_texels
    from synth.motions import RELAXED

    folder = tmp_path / "clip"
    write_clip(folder, RELAXED, frames=3, size=256, turn_degrees=20)
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    write_initial_estimate(folder, ground_truth_with_noise(gt, joint_degrees=0.0, translation_m=0.0, seed=0))
    problem = fitting._set_up(folder, fitting.FitJob("fast", device="cpu"),
                              {"exposure": "off", "albedo_openness": "off"}).problem
    avatar, clip = problem.avatar, problem.clip
    size = avatar.albedo.shape[-1]
    trust, decided = texel_trust(problem), decided_texels(problem)
    assert ((trust >= 0) & (trust <= 1)).all() and not trust[~decided].any()
    best = torch.zeros(size * size)                       # each texel's most head-on view
    weight, square = torch.zeros(size * size), torch.zeros(size * size)
    with torch.no_grad():
        vertices = avatar.posed(problem.all_frames())[0]
        images = render(vertices, avatar.mesh, clip.K, clip.height, clip.width, outputs=("uv", "alpha", "normal"),
                        antialiased=False)
    usable = problem.compared_pixels(problem.all_frames(), albedo_solve=True) & (images["alpha"][..., 0] > 0.5)
    rows, columns, weights = bilinear_texels(images["uv"][usable], size)
    facing = _facing(images["normal"], clip.K)[usable][:, None].expand_as(weights)
    texels = (rows * size + columns).flatten()
    best.scatter_reduce_(0, texels, torch.where(weights > 0.05, facing, 0).flatten(), reduce="amax")
    best = best.view(size, size)
    weight.index_add_(0, texels, weights.flatten())
    ramp = ((facing - FACING_GRAZING) / (FACING_SQUARE - FACING_GRAZING)).clamp(0, 1)
    square.index_add_(0, texels, (weights * ramp * ramp * (3 - 2 * ramp)).flatten())
    share = (square / weight.clamp(min=1e-12)).view(size, size)
    edge_on = decided & (best < 2 * FACING_GRAZING)
    squarely = decided & (best > 0.8)
    assert edge_on.any() and squarely.sum() > 1000, (int(edge_on.sum()), int(squarely.sum()))
    assert (trust[edge_on] < 1).all() and (trust[squarely] == 1).all()
    ramp = (share / SQUARE_SHARE).clamp(0, 1)
    torch.testing.assert_close(trust[decided], (ramp * ramp * (3 - 2 * ramp))[decided], rtol=0, atol=1e-4)
    # the fit's fill reads the trust its settings name: the decided texels by default, texel_trust when feathered
    assert torch.equal(fitting.fill_trust(problem), decided)
    problem.settings.albedo_fill = "feathered"
    torch.testing.assert_close(fitting.fill_trust(problem), trust)
    # and "edge" fills with that trust kept to the fill's edge
    filled = {}
    monkeypatch.setattr(fitting, "fill_avatar_albedo",
                        lambda avatar, trust, blend_reach=None: filled.update(trust=trust, reach=blend_reach))
    fitting.fill_albedo(problem, problem)
    assert filled["reach"] is None
    problem.settings.albedo_fill = "edge"
    fitting.fill_albedo(problem, problem)
    assert filled["reach"] == fitting.EDGE_BLEND_REACH
    # at its own, lower squarely-seen share: trusting every texel at least as far as "feathered" does
    edge_ramp = (share / fitting.EDGE_SQUARE_SHARE).clamp(0, 1)
    torch.testing.assert_close(filled["trust"][decided], (edge_ramp * edge_ramp * (3 - 2 * edge_ramp))[decided],
                               rtol=0, atol=1e-4)
    assert (filled["trust"][~decided] == 0).all() and (filled["trust"] >= trust - 1e-6).all()
    assert (filled["trust"][decided] > trust[decided] + 0.1).any()


def test_blending_kept_to_the_fills_edge_falls_off_linearly_with_the_hops_to_it():
    """A row of 8 texels, the first one unseen (trust 0) and the rest trusted 0.3, texels 2 mm apart,
    the last joined to the first by a seam edge: with a reach of 6 mm (3 hops) a texel d hops from the
    unseen one keeps 1 - 0.7 min(1, max(0, (4 - d) / 3)) of trust, the seam counting as one hop."""
    inside = np.ones((1, 8), bool)
    chain = np.array([[k, k + 1] for k in range(7)])
    seam = np.array([[7, 0]])
    trust = np.array([[0.0] + [0.3] * 7])
    without_seam = tf.TexelGraph(inside, np.arange(8).reshape(1, 8), chain, np.zeros((0, 2), np.int64), 0.002)
    hops = np.arange(8.0)
    expected = 1 - 0.7 * np.clip((4 - hops) / 3, 0, 1)
    expected[0] = 0.0
    np.testing.assert_allclose(tf.trusted_away_from_fill(trust, without_seam, 0.006)[0], expected, rtol=1e-12)
    np.testing.assert_array_equal(tf.hops_from_unseen(trust, without_seam, limit=4.0)[0],
                                  [0, 1, 2, 3, 4, np.inf, np.inf, np.inf])
    with_seam = tf.TexelGraph(inside, np.arange(8).reshape(1, 8), np.concatenate([chain, seam]), seam, 0.002)
    hops = np.minimum(np.arange(8.0), 8 - np.arange(8.0))
    expected = 1 - 0.7 * np.clip((4 - hops) / 3, 0, 1)
    expected[0] = 0.0
    np.testing.assert_allclose(tf.trusted_away_from_fill(trust, with_seam, 0.006)[0], expected, rtol=1e-12)
    # nothing unseen: nothing blends; a bool trust passes through unchanged
    np.testing.assert_array_equal(tf.trusted_away_from_fill(np.full((1, 8), 0.3), without_seam, 0.006), 1.0)
    decided = np.array([[False] + [True] * 7])
    np.testing.assert_array_equal(tf.trusted_away_from_fill(decided, without_seam, 0.006), decided.astype(float))


def test_the_fill_blends_only_near_the_fill_when_it_is_kept_to_the_edge(hand):
    """On the hand's atlas: with the blending kept to the fill's edge, a texel far from every unseen
    texel keeps its solved value though its trust is low, and one next to the fill moves as it does
    with the blending everywhere."""
    data, graph, points = hand
    rng = np.random.default_rng(0)
    texture = rng.uniform(0.2, 0.8, (SIZE, SIZE, 3))
    unseen = graph.inside & (points[..., 0] > np.quantile(points[graph.inside][:, 0], 0.8))
    trust = np.where(unseen, 0.0, 0.4)
    reach = 3 * graph.texel_width
    hops = tf.hops_from_unseen(trust, graph, limit=10.0)
    everywhere = tf.fill_unseen(texture, trust, graph)
    at_edge = tf.fill_unseen(texture, tf.trusted_away_from_fill(trust, graph, reach), graph)
    far = graph.inside & (hops > 4.5)
    near = graph.inside & (hops == 1)
    assert far.sum() > 1000 and near.sum() > 50
    np.testing.assert_array_equal(at_edge[far], texture[far])
    assert np.abs(everywhere[far] - texture[far]).mean() > 0.05
    assert np.abs(at_edge[near] - texture[near]).mean() > 0.5 * np.abs(everywhere[near] - texture[near]).mean()
