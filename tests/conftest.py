import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel.lbs import HandModel, load_model_data

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))  # blender_reference


@pytest.fixture(scope="session", params=fmt.MODES)
def mode(request):
    return request.param


@pytest.fixture(scope="session")
def model_data():
    return {mode: fmt.load_hand_model(fmt.model_path(mode)) for mode in fmt.MODES}


@pytest.fixture(scope="session")
def model64():
    return {mode: HandModel.load(mode, dtype=torch.float64) for mode in fmt.MODES}


def random_pose(generator, batch, scale, dtype=torch.float64):
    return scale * torch.randn(batch, 16, 3, generator=generator, dtype=dtype)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def one_torch_thread():
    """One torch thread for a test's small fits: they are as fast on one, and on a shared
    machine two threads fighting other jobs made a 1 s fit take 23 s."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(autouse=True)
def keep_torch_threads():
    """`harp` commands run in-process (main([...])) set torch's thread count
    (pipeline/threads.py); each test leaves it as it found it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)
