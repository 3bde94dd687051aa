import sys
from pathlib import Path

import numpy as np
import pytest

from blender_fixture import prepared
from pipeline.formats import hand_model_file as fmt

try:
    import torch
except ImportError:  # a Blender-only environment (tools/blender_versions.py): only the bpy tests run
    torch = None

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))  # blender_reference


@pytest.fixture(scope="session", params=fmt.MODES)
def mode(request):
    return request.param


@pytest.fixture(scope="session")
def model_data():
    return {mode: fmt.load_hand_model(fmt.model_path(mode)) for mode in fmt.MODES}


@pytest.fixture(scope="session")
def model64():
    from pipeline.handmodel.lbs import HandModel

    return {mode: HandModel.load(mode, dtype=torch.float64) for mode in fmt.MODES}


@pytest.fixture(scope="session")
def prepared_avatar(tmp_path_factory):
    """A fitted hand + forearm avatar, its clip and the fit's posed surfaces (tests/blender_fixture.py)."""
    return prepared(tmp_path_factory.mktemp("prepared"))


@pytest.fixture(scope="module")
def prepared_left_avatar(tmp_path_factory):
    """The same for a left hand + forearm."""
    return prepared(tmp_path_factory.mktemp("prepared_left"), "left")


@pytest.fixture
def empty_scene():
    """Blender (the bpy module) with a new, empty scene."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def random_pose(generator, batch, scale, dtype=None):
    return scale * torch.randn(batch, 16, 3, generator=generator, dtype=dtype or torch.float64)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def one_torch_thread():
    """One torch thread for a test's small fits: they are as fast on one, and on a shared
    machine two threads fighting other jobs made a 1 s fit take 23 s."""
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(autouse=True)
def keep_torch_threads():
    """`harp` commands run in-process (main([...])) set torch's thread count
    (pipeline/threads.py); each test leaves it as it found it."""
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def without_ray(monkeypatch):
    """`import ray` fails, as where the cluster extra is not installed."""
    import builtins
    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
