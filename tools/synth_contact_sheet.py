"""Draw docs/synth_contact_sheet.png: frames of synthetic clips from several identities,
motions and lighting presets, each with its mask outline and keypoint skeleton overlaid.

    python tools/synth_contact_sheet.py [--out docs/synth_contact_sheet.png] [--size 256]

Renders small clips into a temporary folder with synth/ (bpy) and composes them with OpenCV.
"""
import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.formats import sequence_folder as seq  # noqa: E402
from synth.dataset import IDENTITIES  # noqa: E402
from synth.options import LIGHTING, parse_clip_args  # noqa: E402

# (motion, frame count, frames to show, label of each): fingers keyframes fall on even frames of 19
SHOTS = (("flip", 5, (0, 2), ("back", "palm")),
         ("fingers", 19, (2, 6, 10, 16), ("fist", "spread", "thumb-index", "thumb-pinky")))
BONES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (0, 9), (9, 10), (10, 11), (11, 12),
         (0, 13), (13, 14), (14, 15), (15, 16), (0, 17), (17, 18), (18, 19), (19, 20), (5, 9), (9, 13), (13, 17)]
DIGIT_COLOURS = [(255, 80, 80), (255, 200, 0), (60, 220, 60), (0, 200, 255), (200, 90, 255)]  # BGR per digit


def overlay(rgb, mask, keypoints):
    """BGR picture with the mask outline (green) and the 21-keypoint skeleton."""
    image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(image, contours, -1, (60, 255, 60), 1, cv2.LINE_AA)
    scale = 4  # sub-pixel drawing
    points = np.round((keypoints - 0.5) * scale).astype(int)  # pixel centres at integer + 0.5
    for a, b in BONES:
        colour = DIGIT_COLOURS[min((max(a, b) - 1) // 4, 4)]
        cv2.line(image, tuple(points[a]), tuple(points[b]), colour, 1, cv2.LINE_AA, shift=2)
    for k, point in enumerate(points):
        colour = (255, 255, 255) if k == 0 else DIGIT_COLOURS[(k - 1) // 4]
        cv2.circle(image, tuple(point), 2 * scale, colour, -1, cv2.LINE_AA, shift=2)
    return image


def label(image, text):
    cv2.putText(image, text, (4, image.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, (4, image.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1, cv2.LINE_AA)
    return image


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", default=str(ROOT / "docs" / "synth_contact_sheet.png"))
    parser.add_argument("--size", type=int, default=256)
    args = parser.parse_args()
    from synth.clip import render_clip

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for i, (name, (seed, size, tone, features)) in enumerate(IDENTITIES.items()):
            row = []
            for s, (motion, frames, shown, names) in enumerate(SHOTS):
                lighting = LIGHTING[(i + s) % len(LIGHTING)]
                out = Path(folder) / f"{name}_{motion}"
                settings = parse_clip_args([
                    "--out", out, "--identity", seed, "--size", size, "--skin-tone", tone, "--features", features,
                    "--motion", motion, "--frames", frames, "--lighting", lighting, "--width", args.size,
                    "--height", args.size, "--azimuth", [0, 25, -20, 10][i], "--elevation", [0, 10, -5, 15][i],
                    "--background", "procedural" if i % 2 else "plain", "--seed", i])
                render_clip(settings, log=lambda message: None)
                info = seq.validate_sequence_folder(out)
                gt = seq.read_ground_truth(out / seq.GT_FILE)
                for frame, pose_name in zip(shown, names):
                    picture = overlay(seq.read_rgb(seq.frame_path(out, info, frame)),
                                      seq.read_mask(seq.mask_path(out, info, frame)), gt.keypoints2d[frame])
                    row.append(label(picture, f"{motion}: {pose_name}, {lighting}"))
                    if len(row) == 1:
                        cv2.putText(picture, name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
                        cv2.putText(picture, name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1,
                                    cv2.LINE_AA)
                print(f"{name} {motion} done", flush=True)
            rows.append(np.concatenate(row, axis=1))
    sheet = np.concatenate(rows, axis=0)
    cv2.imwrite(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]})")


if __name__ == "__main__":
    main()
