"""synth's numpy parts: motions inside the joint limits, rotations, viewpoint, identity, UV
sampling and albedo (no bpy needed)."""
import numpy as np
import pytest
import torch

from pipeline.formats import camera
from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel import mirror
from pipeline.handmodel.anatomy import default_joint_limits
from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.rotations import axis_angle_to_matrix as torch_axis_angle_to_matrix
from pipeline.formats import rotations
from pipeline.handmodel import uv_raster
from synth import appearance, identity, motions, viewpoint


@pytest.fixture(scope="module")
def right():
    return {mode: fmt.load_hand_model(fmt.model_path(mode)) for mode in fmt.MODES}


def test_model_limits_are_the_anatomy_limits(right):
    np.testing.assert_allclose(right["hand"].joint_limits, default_joint_limits())


@pytest.mark.parametrize("name", motions.MOTIONS)
@pytest.mark.parametrize("mode", fmt.MODES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_pose_is_inside_the_limits(right, name, mode, seed):
    limits = right[mode].joint_limits
    motion = motions.make_motion(name, 150, 30.0, limits, mode, seed)
    assert motion.pose.shape == (150, 16, 3) and motion.rotation.shape == (150, 3)
    assert (motion.pose >= limits[..., 0] - 1e-12).all() and (motion.pose <= limits[..., 1] + 1e-12).all()
    left_limits = mirror.mirror_model_data(right[mode]).joint_limits
    left = mirror.mirror_axis_angle(motion.pose)
    assert (left >= left_limits[..., 0] - 1e-12).all() and (left <= left_limits[..., 1] + 1e-12).all()
    if mode == "hand":
        assert not motion.pose[:, 0].any()  # the wrist duplicates the global rotation there
    # smooth: at 30 fps no joint turns more than 12 degrees between frames
    assert np.abs(np.diff(motion.pose, axis=0)).max() < np.radians(12)


def test_key_poses_need_no_clipping(right):
    limits = right["hand"].joint_limits
    for pose in (motions.RELAXED, motions.OPEN, motions.FIST, motions.SPREAD, *motions.OPPOSITION.values()):
        assert (pose >= limits[..., 0]).all() and (pose <= limits[..., 1]).all()


def test_motions_do_what_they_say(right):
    flip = motions.make_motion("flip", 151, 30.0, right["hand"].joint_limits)
    assert np.degrees(flip.rotation[75, 1]) == pytest.approx(180.0)
    assert np.abs(flip.rotation[[0, -1]]).max() < 1e-12
    model = HandModel(right["hand"], dtype=torch.float64)
    names = list(right["hand"].keypoint_names)
    for finger, pose in motions.OPPOSITION.items():  # the thumb tip touches each fingertip
        keypoints = model(pose=torch.as_tensor(pose)[None]).keypoints[0]
        assert (keypoints[names.index("thumb_tip")] - keypoints[names.index(f"{finger}_tip")]).norm() < 0.003


def test_rotations_match_torch():
    rng = np.random.default_rng(0)
    w = np.concatenate([rng.normal(size=(200, 3)), np.pi * np.eye(3), [[0, 0, 0], [1e-9, 0, 0]]])
    R = rotations.axis_angle_to_matrix(w)
    np.testing.assert_allclose(R, torch_axis_angle_to_matrix(torch.as_tensor(w)).numpy(), atol=1e-12)
    back = rotations.matrix_to_axis_angle(R)
    np.testing.assert_allclose(rotations.axis_angle_to_matrix(back), R, atol=1e-12)
    assert np.linalg.norm(back, axis=1).max() <= np.pi + 1e-12


def test_viewpoint_places_the_pivot_on_the_optical_axis():
    K = viewpoint.camera_intrinsics(448, 448)
    np.testing.assert_allclose(K, [[2000, 0, 224], [0, 2000, 224], [0, 0, 1]])
    pivot = np.array([0.0, 0.09, 0.0])
    view = viewpoint.view_rotation(0, 0)
    orient, transl = viewpoint.place_hand(view, np.zeros((1, 3)), pivot, 1.2)
    R = rotations.axis_angle_to_matrix(orient[0])
    pixel, depth = camera.project((R @ pivot + transl[0])[None], K)
    np.testing.assert_allclose(pixel[0], [224, 224], atol=1e-9)
    assert depth[0] == pytest.approx(1.2)
    # azimuth 0 sees the back of the hand (+z palmar points away), fingers (+y) up in the image
    np.testing.assert_allclose(view @ [0, 0, 1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(view @ [0, 1, 0], [0, -1, 0], atol=1e-12)
    # azimuth 90 looks from the thumb side (+x) towards -x
    np.testing.assert_allclose(viewpoint.view_rotation(90, 0) @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    with pytest.raises(ValueError, match="either"):
        viewpoint.camera_intrinsics(448, 448, focal=1000, fov=30)


def test_identity_geometry(right):
    data = right["arm"]
    person = identity.make_identity(4)
    assert np.array_equal(person.betas, identity.make_identity(4).betas)
    offsets = identity.personal_offsets(data, person)
    size = np.linalg.norm(offsets, axis=1)
    assert 0.5e-3 < size.max() < 4e-3                      # a few millimetres
    for _, tip in identity.FINGERTIPS.values():            # fingertip keypoints stay on the skin
        nearest = np.argmin(np.linalg.norm(data.vertices - data.keypoints[tip], axis=1))
        assert size[nearest] < 0.6e-3
    nails = identity.nail_weight(data, data.vertices, data.vertex_parts)
    for digit, part in identity.DIGIT_PART.items():         # one nail per digit, on its own digit
        assert (nails[data.vertex_parts == part] > 0.5).sum() >= 1
    assert nails[data.vertex_parts == 0].max() == 0


def test_uv_sampling_reproduces_texel_centres(right):
    data = right["hand"]
    face, bary = uv_raster.rasterize_uv(data.uvs, data.faces_uv, 128)
    rows, cols = np.nonzero(face >= 0)
    uv = np.einsum("nk,nkc->nc", bary[rows, cols], data.uvs[data.faces_uv[face[rows, cols]]])
    np.testing.assert_allclose(uv[:, 0], (cols + 0.5) / 128, atol=1e-12)
    np.testing.assert_allclose(uv[:, 1], 1 - (rows + 0.5) / 128, atol=1e-12)
    assert 0.3 < (face >= 0).mean() < 0.9


def test_albedo_follows_skin_tone(right):
    data = right["hand"]
    light = appearance.make_appearance(data, identity.make_identity(1, skin_tone=0.0, features=()), 128)
    dark = appearance.make_appearance(data, identity.make_identity(1, skin_tone=1.0, features=()), 128)
    assert light.albedo.shape == (128, 128, 3) and light.albedo.dtype == np.uint8
    back = light.uv_mask
    assert light.albedo[back].mean() > 190 and dark.albedo[back].mean() < 110
    again = appearance.make_appearance(data, identity.make_identity(1, skin_tone=0.0, features=()), 128)
    np.testing.assert_array_equal(again.albedo, light.albedo)


def test_dataset_plan_meets_every_lighting_preset():
    from synth import dataset

    clips = dataset.plan(list(dataset.IDENTITIES), ["flip", "fingers"], list(dataset.VIEWS), ["ambient", "sun", "three"])
    assert len(clips) == len(dataset.IDENTITIES) * 2 * len(dataset.VIEWS) == len({name for name, _ in clips})
    presets = {}
    for name, _ in clips:
        identity, motion, view, preset = name.split("_")
        for key in (identity, motion, view, (identity, motion)):
            presets.setdefault(key, set()).add(preset)
    assert all(found == {"ambient", "sun", "three"} for found in presets.values())
    full = dataset.plan(["medium-light"], ["flip"], ["front"], ["ambient", "sun", "three"], full=True)
    assert [name.split("_")[-1] for name, _ in full] == ["ambient", "sun", "three"]
