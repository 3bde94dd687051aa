"""Our renderer against Blender (Cycles, pixel-centre sampled) on the posed hand model:
the same silhouette and the same depth, through the one OpenCV-to-Blender camera conversion."""
import numpy as np
import pytest
import torch

from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.render.renderer import RenderMesh, render

pytest.importorskip("bpy")
from blender_reference import render_mask_and_depth  # noqa: E402

CASES = [  # mode, pose, global orientation (axis-angle), translation (m), focal, (cx, cy), size
    ("hand", "rest", (np.pi, 0.0, 0.0), (0.0, 0.09, 0.50), 600, (128, 128), (256, 256)),
    ("hand", "fist", (2.6, 0.8, 0.3), (0.01, 0.07, 0.45), 700, (120, 140), (256, 240)),
    ("hand", "spread", (0.2, np.pi / 2, 0.1), (-0.01, 0.0, 0.40), 500, (128, 128), (256, 256)),
    ("hand", "pinch", (np.pi / 2, 0.0, 0.5), (0.0, -0.05, 0.35), 450, (150, 110), (300, 220)),
    ("arm", "thumbs_up", (np.pi, 0.3, 0.0), (0.0, 0.15, 0.90), 560, (128, 128), (256, 256)),
    ("arm", "point", (1.9, -0.9, 0.4), (0.02, 0.0, 0.70), 480, (140, 120), (280, 240)),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_silhouette_and_depth_match_blender(case):
    mode, pose_name, orient, transl, focal, (cx, cy), (width, height) = CASES[case]
    model = HandModel.load(mode, subdivided=True, dtype=torch.float64)
    pose = torch.as_tensor(NAMED_POSES[pose_name])[None]
    vertices = model(pose=pose, global_orient=torch.tensor([orient], dtype=torch.float64),
                     transl=torch.tensor([transl], dtype=torch.float64)).vertices
    K = np.array([[focal, 0, cx], [0, focal, cy], [0, 0, 1]], dtype=float)
    alpha, depth = render_mask_and_depth(vertices[0].numpy(), model.data.faces, K, width, height)
    ours = render(vertices, RenderMesh.from_model_data(model.data, dtype=torch.float64), torch.tensor(K),
                  height, width, outputs=("alpha", "depth"), antialiased=False)
    our_mask = ours["alpha"][0, ..., 0].numpy() > 0.5
    their_mask = alpha > 0.5
    assert their_mask.sum() > 2000  # the hand is in view
    iou = (our_mask & their_mask).sum() / (our_mask | their_mask).sum()
    assert iou >= 0.995
    both = our_mask & their_mask
    difference = np.abs(ours["depth"][0, ..., 0].numpy()[both] - depth[both])
    assert difference.mean() < 1e-3
    assert np.median(difference) < 1e-4
