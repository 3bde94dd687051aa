"""A crop that follows the hand (harp import-video --crop): a hand crossing a wide frame is cut
out of every frame at one size, each frame with its own principal point, so the hand is as large
in every frame; the intrinsics stay exact (the true hand, rendered with each frame's K, lands on
the imported masks), and the initial fit and the fit work in those cameras."""
import dataclasses
import shutil

import numpy as np
import pytest
import torch

from pipeline import sequence_import as si
from pipeline.evaluate.exact_clips import BACKGROUND, write_clip
from pipeline.fit import fit
from pipeline.formats import avatar_folder as av
from pipeline.formats import sequence_folder as seq
from pipeline.handmodel.lbs import HandModel
from pipeline.init import initialise_sequence
from pipeline.render.renderer import RenderMesh, render
from synth.motions import OPEN

pytestmark = pytest.mark.usefixtures("one_torch_thread")

FRAMES = 6
SIZE = 240
HAND_PX = 64


@pytest.fixture(scope="module")
def crossing(tmp_path_factory):
    """(source folder, imported folder): the hand crosses the frame from left to right."""
    root = tmp_path_factory.mktemp("crossing")
    shift = np.stack([np.linspace(-0.3, 0.3, FRAMES), np.zeros(FRAMES)], axis=1)
    info = write_clip(root / "source", OPEN, frames=FRAMES, size=SIZE, hand_px=HAND_PX, shift=shift, turn_degrees=5)
    si.import_video(root / "source" / "rgb", root / "source" / "mask", root / "seq", K=info.K, side="right",
                    log=lambda _: None)
    return root / "source", root / "seq"


def _mask_box_side(mask):
    rows, cols = np.nonzero(mask)
    return max(rows.max() - rows.min(), cols.max() - cols.min()) + 1


def test_the_crop_follows_the_hand_and_keeps_it_large(crossing):
    source, folder = crossing
    info = seq.read_sequence_info(folder)
    crop = info.metadata["crop"]
    assert crop["follows_the_hand"] and info.principal_points is not None
    assert crop["clip_window_side"] > 2 * crop["side"]           # one window would show the hand half as large
    x0 = np.asarray(crop["x0"])
    assert np.all(np.diff(x0) > 0)                                # the window moves with the hand
    # the exposure meter is the whole source frame's background (the crop moves over the scene)
    np.testing.assert_allclose(info.background_colour, np.broadcast_to(BACKGROUND, (FRAMES, 3)), atol=1 / 255)
    for index in range(info.frame_count):
        side = _mask_box_side(seq.read_mask(seq.mask_path(folder, info, index)))
        assert side > 0.6 * info.width, (index, side)


def test_each_frames_intrinsics_put_the_true_hand_on_its_mask(crossing):
    source, folder = crossing
    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(source / seq.GT_FILE)
    model = HandModel.load(gt.mode, gt.side)
    frame_K = torch.as_tensor(info.frame_K(), dtype=torch.float32)
    with torch.no_grad():
        alpha = render(torch.as_tensor(gt.vertices, dtype=torch.float32), RenderMesh.from_model_data(model.data),
                       frame_K, info.height, info.width)["alpha"][..., 0].numpy() > 0.5
    ious = []
    for index in range(info.frame_count):
        mask = seq.read_mask(seq.mask_path(folder, info, index))
        ious.append((alpha[index] & mask).sum() / (alpha[index] | mask).sum())
    print("IoU of the true hand under each frame's K against the imported masks", np.round(ious, 3))
    assert min(ious) > 0.93
    # one K for every frame (the first's) would miss the hand in the others
    with torch.no_grad():
        fixed = render(torch.as_tensor(gt.vertices, dtype=torch.float32), RenderMesh.from_model_data(model.data),
                       frame_K[0], info.height, info.width)["alpha"][..., 0].numpy() > 0.5
    last = seq.read_mask(seq.mask_path(folder, info, info.frame_count - 1))
    assert (fixed[-1] & last).sum() < 0.2 * last.sum()


def _crop_keypoints(gt, info):
    """The true 2D keypoints (F, 21, 2) as each frame's crop shows them."""
    crop = info.metadata["crop"]
    corners = np.stack(np.broadcast_arrays(np.asarray(crop["x0"]), np.asarray(crop["y0"])), axis=-1).astype(float)
    corners = np.broadcast_to(corners, (info.frame_count, 2))[:, None]
    return (gt.keypoints2d - corners) * info.width / crop["side"]


@pytest.fixture(scope="module")
def crossing_fit(crossing, tmp_path_factory):
    """(report, avatar folder) of a short fit of the crossing clip from the true hand (the
    source's gt.npz: the same 3D camera as the imported frames')."""
    source, folder = crossing
    info = seq.read_sequence_info(folder)
    shutil.copy(source / seq.GT_FILE, folder / seq.GT_FILE)
    seq.write_sequence_info(folder, dataclasses.replace(info, ground_truth=seq.GT_FILE))
    initialise_sequence(folder, method="gt-noise", mode="hand", noise_degrees=0.0, noise_translation_m=0.0,
                        log=lambda _: None)
    out = tmp_path_factory.mktemp("crossing_fit") / "avatar"
    return fit(folder, out, progress="none", max_steps=12, texture_size=64, batch_size=3, shadows="off",
               device="cpu"), out


def test_the_initial_fit_works_in_each_frames_camera(crossing, tmp_path):
    """The same keypoints seen through the following crops and through one window for the clip
    give the same initial hand in 3D (one camera: only the pixels differ)."""
    source, folder = crossing
    gt = seq.read_ground_truth(source / seq.GT_FILE)
    one = si.import_video(source / "rgb", source / "mask", tmp_path / "one", K=seq.read_sequence_info(source).K,
                          side="right", crop="clip", log=lambda _: None)
    estimates = []
    for sequence in (folder, tmp_path / "one"):
        info = seq.read_sequence_info(sequence)
        np.save(tmp_path / "keypoints.npy", _crop_keypoints(gt, info))
        estimates.append(initialise_sequence(sequence, method="keypoints", keypoint_file=tmp_path / "keypoints.npy",
                                             mode="hand", log=lambda _: None))
    assert one.principal_points is None
    np.testing.assert_allclose(estimates[0].keypoints3d, estimates[1].keypoints3d, atol=2e-4)


def test_the_fit_works_in_each_frames_camera(crossing, crossing_fit):
    _, folder = crossing
    report, out = crossing_fit
    print("fitted IoU", report["metrics"]["silhouette_iou_min"])
    assert report["metrics"]["silhouette_iou_min"] > 0.9
    description = av.read_avatar_json(out)
    np.testing.assert_allclose(description["camera"]["principal_points"],
                               seq.read_sequence_info(folder).principal_points, atol=1e-4)


@pytest.mark.blender
@pytest.mark.parametrize("through", ["bind", "footage camera"])
def test_blenders_camera_follows_each_frames_crop(crossing, crossing_fit, empty_scene, through):
    """Blender's camera, its lens shift keyed per frame, sees the true hand's keypoints where each
    frame's K puts them (the bound avatar's camera, and the footage camera of the sequence)."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    from harp_addon.scene import CAPTURE_TO_WORLD, FIRST_FRAME, bind_avatar, footage_camera

    source, folder = crossing
    info = seq.read_sequence_info(folder)
    gt = seq.read_ground_truth(source / seq.GT_FILE)
    camera = bind_avatar(crossing_fit[1], sequence=folder).camera if through == "bind" else footage_camera(folder)
    frame_K = info.frame_K()
    worst = 0.0
    for index in range(info.frame_count):
        empty_scene.frame_set(FIRST_FRAME + index)
        expected = (gt.keypoints3d[index] @ frame_K[index].T)[:, :2] / gt.keypoints3d[index][:, 2:]
        for point, pixel in zip(gt.keypoints3d[index], expected):
            world = CAPTURE_TO_WORLD[:3, :3] @ point + CAPTURE_TO_WORLD[:3, 3]
            view = world_to_camera_view(empty_scene, camera, Vector(world))
            worst = max(worst, abs(view.x * info.width - pixel[0]), abs((1 - view.y) * info.height - pixel[1]))
    print(f"worst keypoint error {worst:.2e} px")
    assert worst < 0.05


def test_crop_clip_keeps_one_window_and_a_hand_that_fits_nowhere_else_says_so(crossing, tmp_path):
    source, _ = crossing
    one = si.import_video(source / "rgb", source / "mask", tmp_path / "one", side="right", crop="clip",
                          log=lambda _: None)
    assert one.principal_points is None and not one.metadata["crop"].get("follows_the_hand")
    still = tmp_path / "still"
    write_clip(still, OPEN, frames=3, size=96, turn_degrees=5)          # the hand fills the frame already
    auto = si.import_video(still / "rgb", still / "mask", tmp_path / "auto", side="right", log=lambda _: None)
    assert auto.principal_points is None
    with pytest.raises(si.ImportVideoError, match="does not fit inside the frame"):
        si.import_video(still / "rgb", still / "mask", tmp_path / "frame", side="right", crop="frame",
                        log=lambda _: None)


def test_hand_boxes_cut_the_mask_to_the_landmarks():
    hand = np.array([[40, 10], [60, 10], [50, 50], [40, 50]], dtype=float)          # 4 points: a 20 x 40 box
    landmarks = np.repeat(hand[None], 3, axis=0)
    masks = np.array([[30, 0, 70, 200],        # a forearm reaching down past the hand: cut
                      [42, 20, 58, 45],        # a mask inside the hand's box: kept whole
                      [200, 0, 260, 90]])      # the landmarks miss this mask (a wrong detection): kept whole
    boxes = si.hand_boxes(masks, landmarks, growth=0.1)                         # grown by 4 px on each side
    np.testing.assert_array_equal(boxes, [[36, 6, 64, 54], [42, 20, 58, 45], [200, 0, 260, 90]])
    np.testing.assert_array_equal(si.hand_boxes(masks, None), masks)
    guessed = si.hand_boxes(masks, landmarks, detected=[False, True, True], growth=0.1)  # interpolated: whole
    np.testing.assert_array_equal(guessed[0], masks[0])


def test_the_crop_holds_the_hand_not_the_whole_forearm(tmp_path):
    """A hand with its forearm reaching to the frame's bottom edge: the window around the hand
    (MediaPipe's landmarks) is far smaller than the whole mask's, the hand in it as whole as
    in the source, and each frame's K still puts the true hand on its mask."""
    pytest.importorskip("mediapipe")  # without it the window falls back to the mask's
    info = write_clip(tmp_path / "source", OPEN, frames=4, size=256, mode="arm", hand_px=330, shift=(0.0, 0.2),
                      turn_degrees=10)
    lines = []
    imported = {window: si.import_video(tmp_path / "source" / "rgb", tmp_path / "source" / "mask", tmp_path / window,
                                        K=info.K, side="right", window=window, log=lines.append)
                for window in ("hand", "mask")}
    hand, whole = imported["hand"], imported["mask"]
    assert hand.metadata["crop"]["holds"] == "hand" and whole.metadata["crop"]["holds"] == "mask"
    assert hand.metadata["crop"]["side"] < 0.6 * whole.metadata["crop"]["side"]
    assert any("around the hand" in line for line in lines)
    gt = seq.read_ground_truth(tmp_path / "source" / seq.GT_FILE)
    model = HandModel.load(gt.mode, "right", dtype=torch.float64)
    K = torch.as_tensor(hand.frame_K())
    alpha = render(torch.as_tensor(gt.vertices, dtype=torch.float64), RenderMesh.from_model_data(model.data, dtype=torch.float64), K,
                   hand.height, hand.width, outputs=("alpha",))["alpha"][..., 0].numpy() >= 0.5
    for index in range(hand.frame_count):
        mask = seq.read_mask(seq.mask_path(tmp_path / "hand", hand, index)) > 0
        assert (mask & alpha[index]).sum() / (mask | alpha[index]).sum() > 0.95
        tips = np.stack([K[index].numpy() @ point / point[2] for point in gt.keypoints3d[index][[4, 8, 12, 16, 20]]])
        assert (tips[:, :2] > 2).all() and (tips[:, :2] < hand.width - 2).all()   # every fingertip inside
        assert mask[-1].any()                                                      # the forearm leaves the crop
