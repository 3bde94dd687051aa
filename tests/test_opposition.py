"""The thumb opposes: inside the joint limits it can reach every fingertip."""
import pytest
import torch

from pipeline.handmodel import anatomy
from pipeline.handmodel.poses import NAMED_POSES


def reach(model, finger, steps=150):
    """Smallest thumb-tip to fingertip distance found by moving only those two digits,
    with every joint kept inside its limits by construction."""
    limits = model.joint_limits
    joints = list(anatomy.FINGER_JOINTS["thumb"]) + list(anatomy.FINGER_JOINTS[finger])
    mask = torch.zeros(16, 3, dtype=torch.float64)
    mask[joints] = 1
    free = torch.zeros(16, 3, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([free], lr=0.08)
    names = list(model.data.keypoint_names)
    thumb, tip = names.index("thumb_tip"), names.index(f"{finger}_tip")
    for _ in range(steps):
        pose = mask * (limits[..., 0] + (limits[..., 1] - limits[..., 0]) * torch.sigmoid(free))
        keypoints = model(pose=pose[None]).keypoints[0]
        distance = (keypoints[thumb] - keypoints[tip]).norm()
        optimiser.zero_grad()
        distance.backward()
        optimiser.step()
    return distance.item()


@pytest.mark.parametrize("finger", ["index", "middle", "ring", "pinky"])
def test_thumb_reaches_each_fingertip(model64, finger):
    assert reach(model64["hand"], finger) < 0.004


def test_named_pinch_touches(model64):
    model = model64["hand"]
    names = list(model.data.keypoint_names)
    keypoints = model(pose=torch.as_tensor(NAMED_POSES["pinch"])[None]).keypoints[0]
    assert (keypoints[names.index("thumb_tip")] - keypoints[names.index("index_tip")]).norm() < 0.005
