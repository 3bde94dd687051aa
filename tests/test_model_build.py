"""The shipped model files are what the builder makes, and the two modes fit together."""
import dataclasses

import numpy as np
import pytest

from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel.build import build_model_data


@pytest.fixture(scope="module")
def rebuilt():
    return build_model_data()


def test_rebuild_reproduces_shipped_files(rebuilt, model_data, mode):
    for field in dataclasses.fields(fmt.HandModelData):
        a, b = getattr(rebuilt[mode], field.name), getattr(model_data[mode], field.name)
        if isinstance(a, np.ndarray):
            assert a.shape == b.shape, field.name
            if np.issubdtype(a.dtype, np.floating):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, err_msg=field.name)
            else:
                assert np.array_equal(a, b), field.name
        else:
            assert a == b, field.name


def test_modes_share_the_hand_surface(model_data):
    hand, arm = model_data["hand"], model_data["arm"]
    n = hand.shared_vertex_count
    assert n == arm.shared_vertex_count and n > 0.9 * hand.num_vertices
    assert np.array_equal(hand.vertices[:n], arm.vertices[:n])
    assert np.array_equal(hand.shapedirs[:n, :, :10], arm.shapedirs[:n, :, :10])
    shared_faces = lambda f: {tuple(sorted(x)) for x in f if (x < n).all()}
    assert shared_faces(hand.faces) == shared_faces(arm.faces)
