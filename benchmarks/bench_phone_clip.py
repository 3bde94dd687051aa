"""Benchmark: the phone-like synthetic clip of issue 30's acceptance, through the artist's path.

    .venv/bin/python benchmarks/bench_phone_clip.py OUT [--frames 30] [--identity 3] [--preset fast]
        [--masks exact,video] [--window hand|mask] [--crop auto|frame|clip] [--size 1024] [--landmark-offsets] [--threads 2]
        [--pictures DIR] [--seed 0] [--fit-options JSON]

1. synth/render.py: the hand as a phone sees it: 1080 x 1920 portrait frames, a 26 mm-equivalent
   lens (44 degrees across the short side), the hand (with its forearm) a third of the frame
   tall at 0.4 m, Cycles skin with subsurface scattering and a specular lobe, the `room` light
   (a window's soft key and a room's coloured environment), the `flip` motion;
2. synth/imported.py: `harp import-video` on those frames, with the clip's exact masks
   ("exact") and with masks made from the frames alone ("video"), the ground truth carried
   through the crop (`--window`, `--crop`, `--size`: the import's; other than the defaults, their own
   folders);
3. `harp init` (MediaPipe; `--landmark-offsets`, its own folders), `harp fit --hold-out-every 5` with the preset;
4. `harp evaluate --novel-poses`: held-out frames (both protocols), the surface against the
   truth, new poses against Cycles renders of the true hand, the albedo's sharpness.
Prints each step's time and the acceptance figures beside their targets (issue 30: held-out
PSNR >= 30 dB, new-pose PSNR in the overlap >= 28 dB, surface <= 0.6 mm, albedo sharpness >= 0.6,
the video alone within 1 dB of the exact masks' held-out PSNR); writes OUT/bench_phone_clip[_VARIANT].json.
Finished steps are kept: rerun to resume.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from pipeline.evaluate import evaluate_fit, summary_lines  # noqa: E402
from pipeline.evaluate.evaluation import HELD_OUT_PICTURE  # noqa: E402
from pipeline.fit import fit  # noqa: E402
from pipeline.fit.outputs import GRID_FILE  # noqa: E402
from pipeline.fit.settings import PRESETS  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.sequence_import import DEFAULT_SIZE  # noqa: E402
from pipeline.init import initialise_sequence  # noqa: E402
from synth.imported import import_with_ground_truth  # noqa: E402
from timing import timed  # noqa: E402

PHONE = ["--width", "1080", "--height", "1920", "--fov", "44", "--distance", "0.4", "--lighting", "room",
         "--mode", "arm", "--motion", "flip", "--samples", "16"]
TARGETS = {"held_out_psnr": 30.0, "new_pose_overlap_psnr": 28.0, "surface_mm": 0.6, "albedo_sharpness": 0.6}
VIDEO_ALONE_GAP_DB = 1.0


def acceptance(evaluation):
    """The issue's four figures of one evaluated fit."""
    fidelity = evaluation["fidelity"]
    return {"held_out_psnr": evaluation["held_out"]["metrics"]["psnr_mean"],
            "held_out_iou": evaluation["held_out"]["metrics"]["silhouette_iou_mean"],
            "held_out_from_keypoints_psnr": evaluation.get("held_out_from_keypoints", {}).get("metrics", {})
            .get("psnr_mean"),
            "fitted_psnr": evaluation["fit_frames"].get("psnr_mean"),
            "new_pose_overlap_psnr": fidelity["new_poses"]["psnr_overlap_mean"],
            "new_pose_overlap_psnr_at_true_size": fidelity["new_poses"].get("at_true_size", {}).get("psnr_overlap_mean"),
            "surface_mm": fidelity["geometry"]["surface_mm_mean"],
            "albedo_sharpness": fidelity["texture"]["sharpness_ratio"]}


def met(name, value):
    target = TARGETS[name]
    return value <= target if name == "surface_mm" else value >= target


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--identity", type=int, default=3, help="synth/render.py --identity (default 3)")
    parser.add_argument("--preset", default="fast", choices=tuple(PRESETS))
    parser.add_argument("--masks", default="exact,video", help="comma-separated: exact, video (default both)")
    parser.add_argument("--window", choices=("hand", "mask"), default="hand", help="harp import-video --window")
    parser.add_argument("--crop", choices=("auto", "frame", "clip"), default="auto", help="harp import-video --crop")
    parser.add_argument("--size", type=int, default=DEFAULT_SIZE,
                        help=f"harp import-video --size (default {DEFAULT_SIZE}: the hand's 873 px window kept)")
    parser.add_argument("--landmark-offsets", action="store_true", help="harp init --landmark-offsets")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="the fit's seed (its own avatar folders other than 0)")
    parser.add_argument("--fit-options", default="{}",
                        help='FitSettings overrides as JSON, e.g. \'{"colour_model": "display"}\' (their own folders)')
    parser.add_argument("--pictures", type=Path, help="copy the fit and held-out grids here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    fit_options = json.loads(args.fit_options)
    if not isinstance(fit_options, dict):
        parser.error(f"--fit-options takes a JSON object, got {args.fit_options!r}")
    kinds = [kind for kind in args.masks.split(",") if kind]
    if not kinds or any(kind not in ("exact", "video") for kind in kinds):
        parser.error(f"--masks takes exact and/or video, got {args.masks!r}")
    args.out.mkdir(parents=True, exist_ok=True)
    source = args.out / "source"
    figures = {"frames": args.frames, "identity": args.identity, "preset": args.preset, "threads": args.threads,
               "window": args.window, "crop": args.crop, "size": args.size, "landmark_offsets": args.landmark_offsets,
               "seed": args.seed, "fit_options": fit_options}
    variant = (f"_window_{args.window}" if args.window != "hand" else "") + (f"_crop_{args.crop}" if args.crop != "auto"
                                                                             else "") \
        + (f"_size{args.size}" if args.size != DEFAULT_SIZE else "") + ("_landmark_offsets" if args.landmark_offsets
                                                                         else "")
    fit_variant = (f"_seed{args.seed}" if args.seed else "") + "".join(
        f"_{name}_{value}" for name, value in sorted(fit_options.items()))
    if not (source / seq.SEQUENCE_FILE).is_file():
        timed(figures, "render", lambda: subprocess.run(
            [sys.executable, str(ROOT / "synth" / "render.py"), "--out", str(source), "--overwrite", *PHONE,
             "--frames", str(args.frames), "--identity", str(args.identity)], check=True))
    for kind in kinds:
        sequence = args.out / f"sequence_{kind}{variant}"
        avatar = args.out / f"avatar_{kind}{variant}_{args.preset}{fit_variant}"
        if not (sequence / seq.GT_FILE).is_file():
            timed(figures, f"{kind}_import", lambda: import_with_ground_truth(
                source, sequence, video_alone=kind == "video", log=lambda line: print(f"  {line}", flush=True),
                window=args.window, crop=args.crop, size=args.size))
        if not (sequence / "init.npz").is_file():
            timed(figures, f"{kind}_init", lambda: initialise_sequence(sequence, "mediapipe", log=lambda *a: None,
                                                                              landmark_offsets=args.landmark_offsets))
        if not (avatar / "report.json").is_file():
            timed(figures, f"{kind}_fit", lambda: fit(sequence, avatar, preset=args.preset, progress="bar",
                                                      hold_out_every=5, device="cpu", seed=args.seed,
                                                      **fit_options))
        evaluation = timed(figures, f"{kind}_evaluate", lambda: evaluate_fit(avatar, sequence, device="cpu",
                                                                              novel_poses=True, progress="bar"))
        figures[kind] = acceptance(evaluation)
        print(f"{kind} masks:", flush=True)
        for line in summary_lines(evaluation):
            print(f"  {line}", flush=True)
        if args.pictures:
            args.pictures.mkdir(parents=True, exist_ok=True)
            for picture, name in ((avatar / GRID_FILE, f"phone_{kind}{variant}_fit_grid.png"),
                                  (avatar / HELD_OUT_PICTURE, f"phone_{kind}{variant}_held_out_grid.png")):
                shutil.copyfile(picture, args.pictures / name)
    print("acceptance (issue 30):")
    for kind in kinds:
        for name, target in TARGETS.items():
            value = figures[kind][name]
            print(f"  {kind} masks: {name} {value:.2f} (target {'<=' if name == 'surface_mm' else '>='} "
                  f"{target}): {'met' if met(name, value) else 'not met'}")
    if {"exact", "video"} <= set(kinds):
        gap = figures["exact"]["held_out_psnr"] - figures["video"]["held_out_psnr"]
        figures["video_alone_gap_db"] = gap
        print(f"  the video alone {gap:.2f} dB below the exact masks' held-out PSNR (target <= {VIDEO_ALONE_GAP_DB}): "
              f"{'met' if gap <= VIDEO_ALONE_GAP_DB else 'not met'}")
    (args.out / f"bench_phone_clip{variant}{fit_variant}.json").write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
