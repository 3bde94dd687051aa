"""The fidelity measure (pipeline/evaluate/fidelity.py) on analytic cases: the true identity
scored against itself, a known displacement of the rest surface, and the point-to-mesh
distance against dense sampling."""
import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pipeline.evaluate import fidelity
from pipeline.evaluate.exact_clips import write_clip
from pipeline.evaluate.surface_distance import closest_points
from pipeline.formats import avatar_folder as av
from pipeline.formats import sequence_folder as seq
from pipeline.init import initialise_sequence
from pipeline.render.shading import vertex_normals
from synth.motions import RELAXED

pytestmark = pytest.mark.usefixtures("one_torch_thread")



def test_shading_detail_of_known_reliefs():
    """A flat surface has none; normals tilted by +-a column by column (a checker far below the
    average's scale) keep all of their energy, a^2 / (1 + a^2); a slow tilt across the image, none."""
    alpha = np.zeros((96, 96))
    alpha[8:88, 8:88] = 1
    flat = np.zeros((96, 96, 3))
    flat[..., 2] = 1
    assert fidelity.shading_detail(flat, alpha) < 1e-12
    columns = np.arange(96)[None, :].repeat(96, 0)
    amplitude = 0.1
    ripple = np.stack([amplitude * (-1.0) ** columns, np.zeros((96, 96)), np.ones((96, 96))], -1)
    ripple /= np.linalg.norm(ripple, axis=-1, keepdims=True)
    measured = fidelity.shading_detail(ripple, alpha)
    expected = amplitude ** 2 / (1 + amplitude ** 2)
    assert abs(measured - expected) < 0.02 * expected, measured
    slow = np.stack([0.3 * columns / 96, np.zeros((96, 96)), np.ones((96, 96))], -1)
    slow /= np.linalg.norm(slow, axis=-1, keepdims=True)
    assert fidelity.shading_detail(slow, alpha) < 0.01 * measured

def test_closest_points_against_dense_sampling():
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(30, 3))
    faces = rng.integers(0, 30, size=(40, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    points = rng.normal(size=(300, 3)) * 1.5
    distance, closest, face, bary = closest_points(points, vertices, faces, candidates=len(faces))
    u, v = np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 401))
    inside = u + v <= 1
    u, v = u[inside], v[inside]
    corners = vertices[faces]
    samples = (corners[:, :1] * (1 - u - v)[None, :, None] + corners[:, 1:2] * u[None, :, None]
               + corners[:, 2:] * v[None, :, None]).reshape(-1, 3)
    sampled, _ = cKDTree(samples).query(points)
    assert np.all(sampled >= distance - 1e-12) and np.abs(sampled - distance).max() < 0.01
    np.testing.assert_allclose((bary[:, :, None] * vertices[faces[face]]).sum(1), closest, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(closest - points, axis=1), distance, atol=1e-12)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """An exact clip of a person with personal offsets (gt.npz) and an albedo with detail."""
    folder = tmp_path_factory.mktemp("clip") / "clip"
    write_clip(folder, RELAXED, frames=3, size=96, betas=np.linspace(-0.5, 0.5, 12))
    gt = seq.read_ground_truth(folder / seq.GT_FILE)
    rng = np.random.default_rng(1)
    gt.personal_offsets = rng.normal(scale=2e-4, size=(len(gt.vertices[0]), 3))   # a fraction of a mm
    seq.write_ground_truth(folder / seq.GT_FILE, gt)
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


def write_truth_avatar(folder, clip, normal_shift_m=0.0, scale=1.0):
    """An avatar folder holding the true identity itself (optionally displaced along its rest
    normals by `normal_shift_m`, or scaled by `scale` about the wrist joint) with the true albedo."""
    truth = fidelity.true_hand(clip)
    rig = truth.data
    if normal_shift_m:
        import torch
        normals = vertex_normals(torch.as_tensor(rig.vertices)[None], torch.as_tensor(rig.faces.astype(np.int64)))[0]
        rig = dataclasses.replace(rig, vertices=rig.vertices + normal_shift_m * normals.numpy())
    if scale != 1.0:
        wrist = rig.joints[0]
        rig = dataclasses.replace(rig, vertices=wrist + scale * (rig.vertices - wrist),
                                  joints=wrist + scale * (rig.joints - wrist),
                                  keypoints=wrist + scale * (rig.keypoints - wrist))
    info = seq.read_sequence_info(clip)
    poses = av.AvatarPoses(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.5]]), np.zeros((1, 16, 3)), np.array([0]))
    betas = seq.read_ground_truth(clip / seq.GT_FILE).betas
    description = {"mode": rig.mode, "side": rig.side, "betas": np.asarray(betas).tolist(),
                   "light": {"position": [0.1, -0.2, 0.0], "ambient": 0.6, "shadows": False},
                   "camera": {"K": np.asarray(info.K).tolist(), "width": info.width, "height": info.height}}
    albedo = seq.read_rgb(clip / seq.GT_ALBEDO_FILE)
    normal = av.encode_normal_map(np.broadcast_to([0.0, 0.0, 1.0], albedo.shape))
    return av.write_avatar_folder(folder, av.AvatarFiles(description, rig, poses, albedo, normal))


def test_the_truth_scores_perfectly(clip, tmp_path):
    folder = write_truth_avatar(tmp_path / "truth", clip)
    result = fidelity.evaluate_fidelity(folder, clip)
    geometry, poses, texture = result["geometry"], result["new_poses"], result["texture"]
    assert geometry["surface_mm_mean"] < 1e-6 and geometry["surface_mm_p95"] < 1e-6
    assert geometry["normal_deg_mean"] < 1e-3 and geometry["roughness_deg"] < 1e-3
    # the avatar folder's flat normal map is 8-bit: (128, 128, 255) tilts normals by 0.3 degrees,
    # so the renders differ by a hair (62 dB); without it they are identical (the cap)
    assert poses["psnr_mean"] > 60 and poses["iou_mean"] == 1.0 and poses["ssim_mean"] > 0.9999
    avatar_model, appearance, _ = fidelity.load_avatar(folder)
    truth = fidelity.true_hand(clip)
    renders = fidelity.render_posed([(avatar_model, fidelity.Appearance(appearance.albedo)),
                                     (fidelity.HandModel(truth.data), fidelity.Appearance(truth.albedo))],
                                    fidelity.HandModel(truth.data), fidelity.NAMED_POSES["fist"], 30.0, 10.0)
    assert fidelity.image_scores(*renders[0], *renders[1])["psnr"] == fidelity.PSNR_CAP
    assert len(poses["rows"]) == 7 * 2
    assert poses["fitted_shape_alone"]["psnr_mean"] > 60 and poses["fitted_albedo_alone"]["psnr_mean"] > 60
    assert poses["at_true_size"]["psnr_mean"] > 60
    assert geometry["apart_from_size"]["scale"] == pytest.approx(1.0, abs=1e-9)
    assert geometry["apart_from_size"]["surface_mm_mean"] < 1e-6
    # the personal offsets (0.2 mm per axis) are what the true template lacks; the avatar's
    # template (its betas, the true ones, without its displacements) is that template
    template = geometry["without_personal_detail"]
    assert 0.05 < template["true_template"]["surface_mm_mean"] < 0.5
    assert template["fitted_template"] == pytest.approx(template["true_template"], rel=1e-9)
    assert texture["mae"] < 2 / 255 and texture["sharpness_ratio"] == pytest.approx(1.0, abs=0.02)
    assert (folder / fidelity.FIDELITY_PICTURE).is_file()
    assert json.loads((folder / fidelity.FIDELITY_FILE).read_text())["geometry"] == geometry


def test_a_known_displacement_is_measured(clip, tmp_path):
    folder = write_truth_avatar(tmp_path / "shifted", clip, normal_shift_m=0.001)
    geometry = fidelity.evaluate_fidelity(folder, clip, picture=False)["geometry"]
    assert geometry["surface_mm_mean"] == pytest.approx(1.0, rel=0.03)
    assert geometry["surface_mm_fitted_to_true"] == pytest.approx(1.0, rel=0.03)
    assert geometry["roughness_deg"] < 1.0             # an offset surface is as smooth as the original


def test_a_wrong_size_is_told_apart(clip, tmp_path):
    """A hand 3% too big: a surface error of about 3% of its size, all of it the size (the
    similarity finds the scale and leaves nothing); in new poses only the fitted shape loses,
    the true shape with the fitted (true) albedo scores as the truth."""
    folder = write_truth_avatar(tmp_path / "bigger", clip, scale=1.03)
    result = fidelity.evaluate_fidelity(folder, clip, picture=False)
    geometry, poses = result["geometry"], result["new_poses"]
    assert geometry["surface_mm_mean"] > 0.5
    assert geometry["apart_from_size"]["scale"] == pytest.approx(1 / 1.03, rel=1e-6)
    assert geometry["apart_from_size"]["surface_mm_mean"] < 1e-6
    assert poses["fitted_shape_alone"]["psnr_mean"] == pytest.approx(poses["psnr_mean"], abs=1.0)
    assert poses["fitted_shape_alone"]["iou_mean"] < 0.98
    assert poses["fitted_albedo_alone"]["psnr_mean"] > 60 and poses["fitted_albedo_alone"]["iou_mean"] == 1.0
    # scaled back to the truth's size (about its wrist, as it was made) the avatar is the truth again
    assert poses["at_true_size"]["psnr_mean"] > 60 and poses["at_true_size"]["iou_mean"] == 1.0
    assert poses["at_true_size"]["psnr_overlap_mean"] > poses["psnr_overlap_mean"] + 10


def test_only_a_synth_clip_has_a_cycles_truth(clip):
    from pipeline.evaluate.cycles_truth import CyclesTruthUnavailable, synth_settings

    with pytest.raises(CyclesTruthUnavailable, match="not rendered by synth/render.py"):
        synth_settings(clip)


def test_cycles_truth_shows_the_true_hand_where_our_renderer_does(tmp_path):
    """Part (b)'s Cycles render of the true identity in a new pose and view covers the pixels
    our renderer's render of it covers (the same placement and camera through Blender's rig),
    and the avatar scored against it gives finite figures in every pose and view."""
    pytest.importorskip("bpy")
    import torch

    from pipeline.evaluate.cycles_truth import cycles_truth
    from pipeline.handmodel.lbs import HandModel
    from synth_clips import render_tiny_clip

    clip = render_tiny_clip(tmp_path / "clip", frames=2)
    truth = fidelity.true_hand(clip)
    model = HandModel(truth.data)
    pose = fidelity.novel_poses()["thumbs_up"]
    frames = [fidelity.framing(model, pose, *fidelity.VIEWS[view], size=96) for view in ("palm", "back")]
    for (rgb, alpha), view in zip(cycles_truth(clip, frames), ("palm", "back")):
        (ours, ours_alpha), = fidelity.render_posed([(model, fidelity.Appearance(truth.albedo))], model, pose,
                                                    *fidelity.VIEWS[view], size=96)
        ours_mask, cycles_mask = ours_alpha[0, ..., 0].numpy() > 0.5, alpha > 0.5
        assert (ours_mask & cycles_mask).sum() / (ours_mask | cycles_mask).sum() > 0.95, view
        assert rgb[cycles_mask].mean() > 0.2 and rgb[~cycles_mask].max() == 0     # skin over black
    poses = {"thumbs_up": pose}
    description = {"light": {"position": [0.0, -0.2, 0.0], "ambient": 0.5, "shadows": False}}
    scores = fidelity.cycles_scores(clip, description, model, fidelity.Appearance(truth.albedo), model,
                                    fidelity.Appearance(truth.albedo), poses)
    assert len(scores["rows"]) == len(fidelity.VIEWS)
    assert all(np.isfinite(row[key]) for row in scores["rows"] for key in ("psnr", "ssim", "iou"))
    assert scores["iou_mean"] > 0.95 and torch.isfinite(torch.tensor(scores["renderer_floor"]["psnr_mean"]))


def test_an_albedo_darker_all_over_is_as_sharp_at_the_truths_brightness(clip, tmp_path):
    """The true avatar with its albedo at 0.8: its steps between texels are 0.8 as large (the plain
    ratio 0.64), and at the truth's brightness (the per-channel scale) they are the truth's."""
    folder = write_truth_avatar(tmp_path / "darker", clip)
    albedo = seq.read_rgb(folder / av.ALBEDO_FILE)
    seq.write_png(folder / av.ALBEDO_FILE, np.round(albedo * 0.8).astype(np.uint8))
    texture = fidelity.evaluate_fidelity(folder, clip, picture=False)["texture"]
    assert texture["sharpness_ratio"] == pytest.approx(0.64, abs=0.04)   # 8-bit rounding: 0.665
    assert texture["sharpness_ratio_scaled"] == pytest.approx(1.0, abs=0.06)   # the rounding again: 1.04


def test_the_detail_crops_show_grey_where_the_texture_is_not_scored(tmp_path):
    """fidelity.png's detail crops: the truth's and the avatar's albedo where the clip showed them,
    grey (NOT_SCORED) where it did not, in both; a texel outside the charts is never drawn."""
    size = 64
    true_albedo = np.random.default_rng(0).uniform(0.2, 0.8, (size, size, 3))
    fitted_albedo = np.clip(true_albedo + 0.1, 0, 1)
    visible = np.zeros((size, size), bool)
    visible[:, : size // 2] = True                      # the crop's left half was seen
    render = np.zeros((fidelity.SIZE, fidelity.SIZE, 3))
    renders = {(name, view): (render, render) for name in fidelity.PICTURE_POSES for view in fidelity.VIEWS}
    path = fidelity.write_picture(tmp_path / "fidelity.png", renders, fitted_albedo, true_albedo,
                                  (0, 0, size), visible)
    picture = seq.read_rgb(path).astype(np.float64) / 255
    crops = picture[3 * fidelity.SIZE:, : 2 * fidelity.SIZE]
    true_crop, fitted_crop = crops[:, : fidelity.SIZE], crops[:, fidelity.SIZE:]
    scale = fidelity.SIZE // size                       # each texel drawn as scale x scale pixels
    below_label = slice(2 * scale * 4, None)            # rows clear of the label at the top
    for crop, albedo in ((true_crop, true_albedo), (fitted_crop, fitted_albedo)):
        seen = crop[below_label, : fidelity.SIZE // 2 - scale]
        expected = np.repeat(np.repeat(albedo, scale, 0), scale, 1)[below_label, : fidelity.SIZE // 2 - scale]
        assert np.abs(seen - expected).max() < 1 / 255 + 1e-9
        assert np.abs(crop[below_label, fidelity.SIZE // 2:] - fidelity.NOT_SCORED).max() < 1 / 255 + 1e-9


def test_the_detail_window_is_a_mostly_seen_one():
    """A sharp pattern of which the clip saw a thin strip loses to a milder one it saw whole."""
    size = 64
    truth = np.full((size, size, 3), 0.5)
    truth[:16, :16] = np.indices((16, 16)).sum(0)[..., None] % 2            # a fine checker, top left
    truth[40:56, 40:56] = 0.5 + 0.2 * (np.indices((16, 16))[1][..., None] % 2)   # milder stripes, bottom right
    visible = np.zeros((size, size), bool)
    visible[:16, :3] = True                                                  # a strip of the checker seen
    visible[40:56, 40:56] = True
    row, column, side = fidelity.detail_window(truth, visible, fraction=0.25)
    assert side == 16 and (row, column) == (40, 40)
    assert fidelity.detail_window(truth, visible, least_seen=0.0)[:2] == (0, 0)   # by energy alone: the strip
