"""The model export: exact round trip, clear errors on bad files."""
import dataclasses

import numpy as np
import pytest

from pipeline.formats import hand_model_file as fmt


def test_round_trip_is_exact(model_data, mode, tmp_path):
    data = model_data[mode]
    path = fmt.save_hand_model(data, tmp_path / "model.npz")
    again = fmt.load_hand_model(path)
    for field in dataclasses.fields(fmt.HandModelData):
        a, b = getattr(data, field.name), getattr(again, field.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), field.name
        else:
            assert a == b, field.name


def test_format_module_needs_no_torch():
    import subprocess
    import sys

    code = ("import sys, pipeline.formats.hand_model_file as f; "
            "f.load_hand_model(f.model_path('arm')); "
            "assert 'torch' not in sys.modules, 'torch was imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_missing_file_gives_clear_error(tmp_path):
    with pytest.raises(fmt.HandModelFileError, match="not found"):
        fmt.load_hand_model(tmp_path / "nothing.npz")


def test_corrupt_file_gives_clear_error(tmp_path):
    path = tmp_path / "broken.npz"
    path.write_bytes(b"not a zip file at all")
    with pytest.raises(fmt.HandModelFileError, match="cannot read"):
        fmt.load_hand_model(path)


def test_inconsistent_arrays_are_refused(model_data, tmp_path):
    data = dataclasses.replace(model_data["hand"], skin_weights=model_data["hand"].skin_weights * 2)
    with pytest.raises(fmt.HandModelFileError, match="sum to 1"):
        fmt.save_hand_model(data, tmp_path / "bad.npz")
    data = dataclasses.replace(model_data["hand"], faces=model_data["hand"].faces + 100000)
    with pytest.raises(fmt.HandModelFileError, match="faces index"):
        data.validate()


def test_unknown_mode_is_refused():
    with pytest.raises(fmt.HandModelFileError, match="unknown model mode"):
        fmt.model_path("foot")
