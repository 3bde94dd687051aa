"""The `harp` command: the quick-start demo and the model subcommands, end to end."""
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from pipeline.cli import main
from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel.measurements import joint_limits_markdown

ROOT = Path(__file__).resolve().parents[1]


def test_demo_builds_the_model_and_its_picture(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    for mode in fmt.MODES:
        built = fmt.load_hand_model(tmp_path / "model" / f"hand_model_{mode}.npz")
        shipped = fmt.load_hand_model(fmt.model_path(mode))
        assert np.allclose(built.vertices, shipped.vertices, atol=1e-12)
    image = cv2.imread(str(tmp_path / "hand_model.png"))
    assert image is not None and image.shape[0] == 600 and image.shape[1] == 9 * 300
    assert (image < 250).mean() > 0.1  # something was drawn
    out = capsys.readouterr().out
    assert "hand length" in out and "palm width" in out


def test_preview_of_the_left_hand(tmp_path):
    assert main(["model", "preview", "--side", "left", "--size", "120", "--out", str(tmp_path / "left.png")]) == 0
    right = tmp_path / "right.png"
    assert main(["model", "preview", "--size", "120", "--out", str(right)]) == 0
    left_image, right_image = cv2.imread(str(tmp_path / "left.png")), cv2.imread(str(right))
    # the first tile (palm view) of the left hand is the mirror image of the right's
    tile = lambda image: image[20:120, :120].astype(float)
    assert np.abs(tile(left_image) - tile(right_image)[:, ::-1]).mean() < 12


def test_bad_model_folder_gives_one_clear_line(tmp_path, capsys):
    assert main(["model", "info", "--model", str(tmp_path / "missing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hand model file not found" in err[0]


def test_console_script_is_installed():
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "--help"], capture_output=True, text=True)
    assert result.returncode == 0 and "demo" in result.stdout


def test_docs_joint_limit_table_matches_the_code():
    assert joint_limits_markdown() in (ROOT / "docs" / "hand_model.md").read_text()
