"""`harp batch`: tiny exact clips (no Blender) through init, fit and evaluation, the table, a clip
that fails beside those that finish, the same figures in worker processes as one by one, and a
batch that goes on with --resume."""
import csv
import importlib.util
import json

import numpy as np
import pytest

from pipeline.batch import BatchError, read_list, run_batch
from pipeline.cli import main
from pipeline.evaluate.exact_clips import write_clip
from synth.motions import FIST, OPEN

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = dict(init="gt-noise", hold_out_every=3, held_out_steps=2, novel_poses=False, max_steps=2, resolution=96,
            texture_size=64, batch_size=2, shadows="off", device="cpu", progress="none", log=lambda message: None)


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("clips")
    write_clip(root / "turning", OPEN, size=96, frames=6, turn_degrees=30)
    write_clip(root / "closing", np.stack([OPEN + (FIST - OPEN) * t for t in np.linspace(0, 0.5, 6)]), size=96,
               frames=6, turn_degrees=5)
    (root / "broken.mp4").write_bytes(b"this is not a video")
    return root


def figures(row):
    """A row without its times."""
    return {k: v for k, v in row.items() if not k.endswith("_s")}


def test_a_batch_lists_every_clip_and_a_failure_with_its_reason(clips, tmp_path):
    inputs = [(str(clips / name), None) for name in ("turning", "broken.mp4", "closing")]
    table = run_batch(inputs, tmp_path / "batch", jobs=2, **TINY)
    assert [row["clip"] for row in table] == ["turning", "broken", "closing"]
    assert [row["status"] for row in table] == ["done", "failed", "done"]
    assert "broken.mp4" in table[1]["reason"] and table[1]["reason"].count("\n") == 0
    for row in (table[0], table[2]):
        assert row["attempts"] == 1 and row["frames"] == 4            # 6 frames, every 3rd held out
        for key in ("fitted_psnr", "held_out_psnr", "held_out_keypoints_psnr", "joint_mm", "joint_initial_mm"):
            assert np.isfinite(row[key]), key
        assert row["fit_s"] > 0 and row["evaluate_s"] > 0
    with open(tmp_path / "batch" / "batch.csv") as handle:
        written = list(csv.DictReader(handle))
    assert [r["status"] for r in written] == ["done", "failed", "done"]
    assert float(written[0]["joint_mm"]) == pytest.approx(table[0]["joint_mm"])
    markdown = (tmp_path / "batch" / "batch.md").read_text()
    assert "| turning | done |" in markdown and "| broken | failed |" in markdown

    # the same clip fitted alone, in this process, gives the same figures bit for bit
    alone = run_batch([(str(clips / "closing"), None)], tmp_path / "alone", jobs=1, **TINY)
    assert figures(alone[0]) == figures(table[2])

    # --resume: the finished clips are read back, not fitted again; the failed one is tried again
    again = run_batch(inputs, tmp_path / "batch", resume=True, jobs=2, **TINY)
    assert [figures(row) for row in again[::2]] == [figures(row) for row in table[::2]]
    assert again[1]["status"] == "failed" and again[1]["attempts"] == 2
    with pytest.raises(BatchError, match="--resume"):
        run_batch(inputs, tmp_path / "batch", **TINY)


def test_bad_inputs_are_named_before_anything_runs(clips, tmp_path):
    with pytest.raises(BatchError, match="input not found"):
        run_batch([(str(clips / "missing.mp4"), None)], tmp_path / "a", **TINY)
    (tmp_path / "plain").mkdir()
    with pytest.raises(BatchError, match="not a sequence folder"):
        run_batch([(str(tmp_path / "plain"), None)], tmp_path / "b", **TINY)
    listing = tmp_path / "clips.txt"
    listing.write_text(f"# two clips\n{clips / 'turning'}\n\nbroken.mp4 masks_folder\n")
    (tmp_path / "broken.mp4").write_bytes(b"x")
    (tmp_path / "masks_folder").mkdir()
    assert read_list(listing) == [(str(clips / "turning"), None),
                                  (str(tmp_path / "broken.mp4"), str(tmp_path / "masks_folder"))]
    listing.write_text("a b c\n")
    with pytest.raises(BatchError, match="INPUT \\[MASKS\\]"):
        read_list(listing)


def test_harp_batch_without_ray_installed_says_how_to_install_it(clips, tmp_path, without_ray, capsys):
    code = main(["batch", str(clips / "turning"), "--out", str(tmp_path / "r"), "--executor", "ray",
                 "--progress", "none", "--init", "gt-noise"])
    assert code == 1
    assert "pip install .[cluster]" in capsys.readouterr().err


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray (the cluster extra) is not installed")
def test_a_batch_on_a_local_ray_gives_the_figures_of_the_clips_fitted_one_by_one(clips, tmp_path):
    inputs = [(str(clips / name), None) for name in ("turning", "closing")]
    on_ray = run_batch(inputs, tmp_path / "ray", executor="ray", **TINY)
    one_by_one = [run_batch([item], tmp_path / f"alone_{number}", jobs=1, **TINY)[0]
                  for number, item in enumerate(inputs)]
    assert [figures(row) for row in on_ray] == [figures(row) for row in one_by_one]     # bit for bit
    assert all(row["status"] == "done" and row["attempts"] == 1 for row in on_ray)
