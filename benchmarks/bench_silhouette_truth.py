"""Benchmark: what the silhouette term asks of a synthetic clip's true hand. Our renderer draws the
true posed mesh (gt.npz) onto the clip's masks at the fit's working size, and the same hand without
its personal offsets (the shaped template, as a fit's avatar starts, its displacements zero), and
the true mesh 1% larger about its keypoints' centre (what 1% of size does to the outline); with
--avatar, also a fit's avatar of that clip in its own poses (poses.npz: the frames it fitted).

    .venv/bin/python benchmarks/bench_silhouette_truth.py SEQ [--avatar AVATAR] [--resolution 256] [--threads 1]

Prints, for each, the outline's mean and median offset from the masks' outline (pixels; positive:
drawn larger; the rendered area minus the mask's, over the mask's outline, its run along the
frame's border left out), its range over the frames, and the IoU (mean and median: a frame a fit
lost weighs on the mean). The true mesh should sit on its masks to a small fraction of a pixel
(the renderer and the masks agree); the template's offset, read against the 1% line, is the size
the silhouette asks of an avatar that lacks the personal offsets.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from pipeline.evaluate.fidelity import load_model_data  # noqa: E402
from pipeline.fit.clip_data import load_clip  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.render.renderer import RenderMesh, render  # noqa: E402


def outline_offsets(points, mesh, clip):
    """(F,) mean outline offset (pixels) and (F,) IoU of `points` (F, V, 3) drawn against the clip's masks."""
    offsets, ious = [], []
    for index in range(len(clip.frames)):
        with torch.no_grad():
            alpha = render(points[index:index + 1], mesh, clip.K[index], clip.height, clip.width)["alpha"][0, ..., 0]
        alpha, mask = alpha.numpy(), clip.masks[index, ..., 0].numpy() > 0.5
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        border = mask[0].sum() + mask[-1].sum() + mask[:, 0].sum() + mask[:, -1].sum()
        outline = sum(cv2.arcLength(contour, True) for contour in contours) - border
        offsets.append((alpha.sum() - mask.sum()) / max(outline, 1.0))
        drawn = alpha > 0.5
        ious.append((drawn & mask).sum() / max((drawn | mask).sum(), 1))
    return np.array(offsets), np.array(ious)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--avatar", type=Path, help="also draw this fit of SEQ in its fitted poses")
    parser.add_argument("--resolution", type=int, default=256, help="the working size's long side (fast: 256)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    try:
        info = seq.validate_sequence_folder(args.sequence)
        avatar = av.read_avatar_folder(args.avatar) if args.avatar else None
        poses = av.read_poses(args.avatar) if args.avatar else None
    except (seq.SequenceFolderError, av.AvatarFolderError) as error:
        parser.error(str(error))
    if not info.ground_truth:
        parser.error(f"{args.sequence} has no ground truth (a synthetic clip's gt.npz)")
    truth = seq.read_ground_truth(args.sequence / info.ground_truth)
    if truth.vertices is None or truth.personal_offsets is None:
        parser.error(f"{args.sequence / info.ground_truth} has no posed vertices or personal offsets (an older synth clip)")
    clip = load_clip(args.sequence, resolution=args.resolution)
    base = load_model_data(truth.mode, truth.side)
    mesh, model = RenderMesh.from_model_data(base), HandModel(base)
    frames = clip.frames

    def tensor(array):
        return torch.as_tensor(np.asarray(array), dtype=torch.float32)

    true_points = tensor(truth.vertices[frames])
    betas = tensor(truth.betas)
    with torch.no_grad():
        posed = model(betas=betas, pose=tensor(truth.pose[frames]), global_orient=tensor(truth.global_orient[frames]),
                      transl=tensor(truth.transl[frames]))
    centre = posed.keypoints[:, :21].mean(1, keepdim=True)
    cases = {"the true mesh": true_points,
             "the template without the personal offsets": posed.vertices,
             "the true mesh 1% larger": centre + 1.01 * (true_points - centre)}
    print(f"{args.sequence}: {len(frames)} frames at {clip.width} x {clip.height} px")
    for name, points in cases.items():
        report(name, *outline_offsets(points, mesh, clip))
    if avatar is not None:
        with torch.no_grad():
            fitted = HandModel(avatar.rig)(pose=tensor(poses.pose), global_orient=tensor(poses.global_orient),
                         transl=tensor(poses.transl)).vertices
        report(f"the avatar {args.avatar.name} in its {len(poses)} poses",
               *outline_offsets(fitted, RenderMesh.from_model_data(avatar.rig),
                                load_clip(args.sequence, resolution=args.resolution, frames=poses.frames)))


def report(name, offsets, ious):
    print(f"  {name}: outline offset {offsets.mean():+.3f} px, median {np.median(offsets):+.3f} "
          f"({offsets.min():+.3f} to {offsets.max():+.3f}), IoU {ious.mean():.4f} (median {np.median(ious):.4f})")


if __name__ == "__main__":
    main()
