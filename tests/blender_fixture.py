"""The fitted avatar the Blender tests bind, with the fit's own word on where the hand is: its
posed surface and keypoints at every fitted frame (the reference Blender must reproduce).

Made with torch (a tiny Cycles clip of a hand and forearm, a 12-step fit) where torch is
installed. Blender's own Python has no torch, and neither have the environments in which
tools/blender_versions.py runs the add-on's tests under each Blender: there the tests read the
one that script made beforehand with the project's .venv, named by HARP_BLENDER_FIXTURE.

    .venv/bin/python tests/blender_fixture.py FOLDER     makes one in FOLDER
"""
from __future__ import annotations

import dataclasses
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np

ENVIRONMENT = "HARP_BLENDER_FIXTURE"
REFERENCE_FILE = "reference.npz"
SIDES = ("right", "left")
FRAMES, FRAME_SIZE, TEXTURE_SIZE = 4, 96, 64      # the clip's frames (square, px) and the fitted texture (px)
FIT = dict(progress="none", max_steps=12, texture_size=TEXTURE_SIZE, batch_size=2, resolution=FRAME_SIZE,
           device="cpu")


@dataclasses.dataclass
class PreparedAvatar:
    clip: Path               # the sequence folder the avatar was fitted to
    avatar: Path             # the avatar folder
    surfaces: np.ndarray     # (F, V, 3) the fitted surface at every fitted frame (camera frame, metres)
    keypoints: np.ndarray    # (F, 21, 3) the fitted keypoints likewise


def prepare(folder, side="right") -> PreparedAvatar:
    """Render the clip of a `side` hand, fit it and write the fit's reference into
    `folder`/`side` (needs torch)."""
    import torch

    from pipeline.evaluate.finished_fit import fitted_avatar, posed_surfaces
    from pipeline.fit import fit
    from synth_clips import render_tiny_clip

    folder = Path(folder) / side
    threads = torch.get_num_threads()
    torch.set_num_threads(1)    # as fast for a fit this small, and fair to whatever else runs
    try:
        clip = render_tiny_clip(folder / "clip", frames=FRAMES, mode="arm", side=side)
        fit(clip, folder / "avatar", **FIT)
        avatar, _ = fitted_avatar(folder / "avatar", clip, "cpu")
        surfaces = posed_surfaces(avatar)
        with torch.no_grad():
            _, keypoints = avatar.posed(torch.arange(avatar.pose.shape[0]))
    finally:
        torch.set_num_threads(threads)
    np.savez(folder / REFERENCE_FILE, surfaces=surfaces.double().numpy(), keypoints=keypoints[:, :21].double().numpy())
    return load(folder)


def load(folder) -> PreparedAvatar:
    folder = Path(folder)
    with np.load(folder / REFERENCE_FILE) as reference:
        return PreparedAvatar(folder / "clip", folder / "avatar", reference["surfaces"], reference["keypoints"])


def prepared(folder, side="right") -> PreparedAvatar:
    """For the tests: made in `folder` where torch is installed, else the one HARP_BLENDER_FIXTURE
    names (the test is skipped when there is neither)."""
    if importlib.util.find_spec("torch") is not None:
        return prepare(folder, side)
    named = os.environ.get(ENVIRONMENT)
    if not named:
        import pytest

        pytest.skip(f"no torch to fit an avatar, and no {ENVIRONMENT} (tools/blender_versions.py sets it)")
    return load(Path(named) / side)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))    # synth_clips
    for side in SIDES:
        print(f"prepared {prepare(Path(sys.argv[1]), side).avatar}")
