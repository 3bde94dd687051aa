"""synth/imported.py: a synthetic clip through `harp import-video` keeps exact ground truth.
The reference is independent of the carried keypoints: the true surface (gt.npz vertices),
rendered with each imported frame's intrinsics, must cover the imported masks."""
import numpy as np
import torch

from pipeline.evaluate.exact_clips import write_clip
from pipeline.formats import sequence_folder as seq
from pipeline.handmodel.lbs import HandModel
from pipeline.render.renderer import RenderMesh, render
from synth.imported import import_with_ground_truth
from synth.motions import OPEN


def test_the_ground_truth_follows_the_import_crop(tmp_path):
    source, out = tmp_path / "source", tmp_path / "imported"
    shifts = [(-0.25, -0.2), (-0.1, -0.05), (0.05, 0.1), (0.25, 0.2)]   # the hand moves across a large frame
    write_clip(source, OPEN, frames=4, size=256, hand_px=70, shift=shifts)
    info = import_with_ground_truth(source, out, size=64, crop="frame", log=lambda *a: None)
    assert info.principal_points is not None and info.width == 64   # a following crop (one K per frame), resized
    gt, source_gt = seq.read_ground_truth(out / seq.GT_FILE), seq.read_ground_truth(source / seq.GT_FILE)
    assert gt.frame_count == 4 and np.array_equal(gt.pose, source_gt.pose)
    assert (out / seq.GT_ALBEDO_FILE).read_bytes() == (source / seq.GT_ALBEDO_FILE).read_bytes()

    model = HandModel.load(gt.mode, "right", dtype=torch.float64)
    K = torch.as_tensor(info.frame_K())
    alpha = render(torch.as_tensor(gt.vertices, dtype=torch.float64), RenderMesh.from_model_data(model.data,
                   dtype=torch.float64), K, 64, 64, outputs=("alpha",))["alpha"][..., 0].numpy() >= 0.5
    for index in range(4):
        mask = seq.read_mask(seq.mask_path(out, info, index)) > 0
        iou = (mask & alpha[index]).sum() / (mask | alpha[index]).sum()
        assert iou > 0.9, (index, iou)
        # the carried keypoints lie on the hand's silhouette's box in the imported frame
        rows, columns = np.nonzero(mask)
        u, v = gt.keypoints2d[index].T
        assert columns.min() - 3 <= u.min() and u.max() <= columns.max() + 3
        assert rows.min() - 3 <= v.min() and v.max() <= rows.max() + 3


def test_a_clip_without_ground_truth_is_refused(tmp_path):
    source = tmp_path / "source"
    write_clip(source, OPEN, frames=3, size=64)
    info = seq.read_sequence_info(source)
    info.ground_truth = None
    seq.write_sequence_info(source, info)
    try:
        import_with_ground_truth(source, tmp_path / "out", log=lambda *a: None)
    except ValueError as error:
        assert "no ground truth" in str(error)
    else:
        raise AssertionError("imported a clip without ground truth")
