"""A synthetic clip taken the way a user's footage is: its full frames (say 1080 x 1920, as a
phone records them) through `harp import-video`, with the ground truth carried through the
import's crop.

The import cuts a window around the hand from each frame and resizes it
(pipeline/sequence_import.py). The camera frame does not move, so the 3D ground truth (poses,
translations, keypoints3d, vertices, the light) holds as it is; only keypoints2d change: they
are the keypoints3d projected with each imported frame's intrinsics. Frames the import leaves
out are left out of the ground truth too (sequence.json `metadata.source_frames`). The clip's
synth metadata (settings, identity, camera) comes along, so that the Cycles truth in new poses
(pipeline/evaluate/cycles_truth.py) renders the same person; the import's own metadata stays
beside it (`metadata.import`).

    python synth/imported.py SOURCE OUT [--video-alone] [--size 1024]

With `--video-alone` the import makes its own masks from the frames (MediaPipe + GrabCut),
as it does for an artist's video; by default it takes the clip's exact masks.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.camera import project  # noqa: E402
from pipeline.sequence_import import DEFAULT_SIZE, import_video  # noqa: E402

SYNTH_KEYS = ("generator", "settings", "identity", "camera", "blender")   # synth/clip.py's metadata


def import_with_ground_truth(source, out, video_alone=False, size=DEFAULT_SIZE, log=print, **import_options):
    """Import the synthetic clip `source` (a sequence folder written by synth/render.py) into
    `out` as `harp import-video` imports footage, with its exact masks or (`video_alone`) masks
    made from the frames; write `out`'s gt.npz and gt_albedo.png. Returns out's SequenceInfo."""
    source, out = Path(source), Path(out)
    info = seq.read_sequence_info(source)
    if info.ground_truth is None:
        raise ValueError(f"{source} has no ground truth: not a synthetic clip")
    gt = seq.read_ground_truth(source / info.ground_truth)
    frames_folder = seq.frame_path(source, info, 0).parent
    masks_folder = None if video_alone else seq.mask_path(source, info, 0).parent
    imported = import_video(frames_folder, masks_folder, out, size=size, K=info.frame_K()[0], side=info.hand_side,
                            fps=info.fps, overwrite=True, log=log, **import_options)
    kept = np.asarray(imported.metadata["source_frames"], dtype=int)
    frame_K = imported.frame_K()
    keypoints3d = gt.keypoints3d[kept]
    keypoints2d = np.stack([project(points, K)[0] for points, K in zip(keypoints3d, frame_K)])
    seq.write_ground_truth(out / seq.GT_FILE, seq.GroundTruth(
        mode=gt.mode, side=gt.side, betas=gt.betas, global_orient=gt.global_orient[kept], transl=gt.transl[kept],
        pose=gt.pose[kept], keypoints3d=keypoints3d, keypoints2d=keypoints2d,
        vertices=None if gt.vertices is None else gt.vertices[kept], personal_offsets=gt.personal_offsets,
        light=gt.light))
    shutil.copyfile(source / info.albedo, out / seq.GT_ALBEDO_FILE)
    synth = {key: info.metadata[key] for key in SYNTH_KEYS if key in (info.metadata or {})}
    imported.ground_truth, imported.albedo = seq.GT_FILE, seq.GT_ALBEDO_FILE
    imported.metadata = {**synth, "import": imported.metadata, "source_frames": imported.metadata["source_frames"]}
    seq.write_sequence_info(out, imported)
    return imported


def main(argv=None):
    parser = argparse.ArgumentParser(prog="imported.py", description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="a sequence folder written by synth/render.py")
    parser.add_argument("out", type=Path, help="the imported sequence folder (replaced)")
    parser.add_argument("--video-alone", action="store_true", help="masks made from the frames, not the clip's")
    parser.add_argument("--size", type=int, default=DEFAULT_SIZE,
                        help=f"the imported frames' largest side (default {DEFAULT_SIZE}; a smaller window keeps its own)")
    args = parser.parse_args(argv)
    import_with_ground_truth(args.source, args.out, video_alone=args.video_alone, size=args.size)


if __name__ == "__main__":
    main()
