"""Skinning weights: sparse, normalised, local to their digit, smooth; bends keep volume."""
import numpy as np
import pytest
import torch

from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel import anatomy
from pipeline.handmodel.measurements import bend_volume_loss
from pipeline.handmodel.subdivision import subdivide_model_data


def descendants(parents, joint):
    found = {joint}
    changed = True
    while changed:
        changed = False
        for j, p in enumerate(parents):
            if p in found and j not in found:
                found.add(j)
                changed = True
    return found


def test_weights_are_sparse_normalised_and_nonnegative(model_data, mode):
    for data in (model_data[mode], subdivide_model_data(model_data[mode])):
        dense = data.dense_weights()
        assert ((dense > 0).sum(1) <= 4).all()
        assert (dense >= 0).all()
        np.testing.assert_allclose(dense.sum(1), 1.0, atol=1e-12)


def test_no_digit_is_moved_by_a_neighbouring_digit(model_data, mode):
    data = model_data[mode]
    dense = data.dense_weights()
    for digit_name, joints in anatomy.FINGER_JOINTS.items():
        on_digit = data.vertex_parts == fmt.PART_NAMES.index(digit_name)
        assert on_digit.sum() > 30
        others = [j for name, js in anatomy.FINGER_JOINTS.items() if name != digit_name for j in js]
        assert dense[on_digit][:, others].max() == 0.0, digit_name
        assert dense[on_digit][:, list(joints)].sum(1).mean() > 0.8


def test_rotating_a_joint_moves_only_its_skin(model64, mode):
    model = model64[mode]
    dense = model.data.dense_weights()
    for joint in (0, 1, 2, 5, 13, 15):
        pose = torch.zeros(1, 16, 3, dtype=torch.float64)
        pose[0, joint] = torch.tensor([0.7, -0.3, 0.4], dtype=torch.float64)
        with torch.no_grad():
            moved = (model(pose=pose).vertices[0].numpy() - model.data.vertices)
        influenced = dense[:, sorted(descendants(model.parents, joint))].sum(1) > 0
        if (~influenced).any():  # in hand-only mode the wrist carries every vertex
            assert np.abs(moved[~influenced]).max() < 1e-12
        assert (np.linalg.norm(moved[influenced], axis=1) > 0).all()


def test_weights_vary_smoothly_over_the_surface(model_data, mode):
    """Every joint blends over several millimetres: no weight changes faster than 0.2 per mm
    along an edge (a smoothstep over a digit's radius changes at most ~0.13 per mm)."""
    data = model_data[mode]
    dense = data.dense_weights()
    edges = np.concatenate([data.faces[:, [0, 1]], data.faces[:, [1, 2]], data.faces[:, [2, 0]]])
    jump = np.abs(dense[edges[:, 0]] - dense[edges[:, 1]]).max(1)
    length_mm = 1000 * np.linalg.norm(data.vertices[edges[:, 0]] - data.vertices[edges[:, 1]], axis=1)
    assert (jump / length_mm).max() < 0.2
    assert jump.max() < 0.9


@pytest.mark.parametrize("joint, degrees, limit", [(1, 90, 15.0), (2, 90, 10.0), (5, 90, 10.0)])
def test_bending_a_finger_does_not_collapse_it(joint, degrees, limit):
    cm3, percent = bend_volume_loss("hand", joint, degrees)
    assert 0 <= percent < limit, (cm3, percent)
