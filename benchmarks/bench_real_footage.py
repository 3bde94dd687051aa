"""Benchmark: a real video, from the footage alone, through the whole pipeline.

    .venv/bin/python benchmarks/bench_real_footage.py VIDEO [--work DIR] [--preset fast]
        [--hold-out-every 10] [--size 448] [--max-frames N] [--pictures DIR] [--threads 1]
        [--environment auto|on|off] [--specular auto|on|off] [--crop auto|frame|clip] [--seed 0]
        [--fit-options JSON]

1. `harp import-video VIDEO` without masks (MediaPipe landmarks + GrabCut make them),
2. `harp init` (MediaPipe keypoints, the initial fit),
3. `harp fit --hold-out-every N` with the preset,
4. `harp evaluate`: the held-out frames fitted in pose and light, scored against the built-in
   masks and the frames (PSNR / L1 / MS-SSIM in the mask, silhouette IoU).
Prints wall time of each step and the figures; writes bench_real_footage.json into the avatar
folder (DIR/avatar_PRESET, with _environment_SETTING and _specular_SETTING for those options, _seedS for
a seed other than 0 and _NAME_VALUE for each --fit-options override: FitSettings fields as JSON). With
`--pictures DIR2`: DIR2/real_masks.png (masks over frames), real_fit_grid.png (fitted frames),
real_held_out_grid.png (held-out frames). Finished steps are kept: rerun to resume.
Measured on the MediaPipe sample video (see docs/real_footage.md).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pipeline.evaluate import evaluate_fit  # noqa: E402
from pipeline.evaluate.evaluation import HELD_OUT_PICTURE  # noqa: E402
from pipeline.fit import fit  # noqa: E402
from pipeline.fit.outputs import GRID_FILE  # noqa: E402
from pipeline.fit.settings import PRESETS  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.fit_report import read_report  # noqa: E402
from pipeline.init import initialise_sequence  # noqa: E402
from pipeline.sequence_import import import_video  # noqa: E402
from timing import timed  # noqa: E402


def log(message):
    print(f"  {message}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("video")
    parser.add_argument("--work", default="bench_real_footage", help="working folder (default: bench_real_footage)")
    parser.add_argument("--preset", default="fast", choices=tuple(PRESETS))
    parser.add_argument("--hold-out-every", type=int, default=10)
    parser.add_argument("--size", type=int, default=448)
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--pictures", default=None, help="also copy the pictures here (e.g. docs/)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1, pinned runs)")
    parser.add_argument("--environment", choices=("auto", "on", "off"), default=None,
                        help="the fit's environment light (default: the fit's default); its own avatar folder")
    parser.add_argument("--specular", choices=("auto", "on", "off"), default=None,
                        help="the fit's specular lobe (default: the fit's default); its own avatar folder")
    parser.add_argument("--crop", choices=("auto", "frame", "clip"), default="auto",
                        help="the import's crop (harp import-video --crop; the work folder keeps one sequence)")
    parser.add_argument("--seed", type=int, default=0, help="the fit's seed (its own avatar folder other than 0)")
    parser.add_argument("--fit-options", default="{}",
                        help='FitSettings overrides as JSON, e.g. \'{"anchor_size": "free"}\' (their own avatar folders)')
    args = parser.parse_args(argv)
    fit_options = json.loads(args.fit_options)
    if not isinstance(fit_options, dict):
        parser.error(f"--fit-options takes a JSON object, got {args.fit_options!r}")
    torch.set_num_threads(args.threads)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    sequence = work / "sequence"
    avatar = work / (f"avatar_{args.preset}" + (f"_environment_{args.environment}" if args.environment else "")
                     + (f"_specular_{args.specular}" if args.specular else "") + (f"_seed{args.seed}" if args.seed else "")
                     + "".join(f"_{name}_{value}" for name, value in sorted(fit_options.items())))
    figures = {"video": str(args.video), "preset": args.preset, "threads": args.threads,
               "environment": args.environment, "specular": args.specular, "seed": args.seed,
               "fit_options": fit_options}

    if not (sequence / seq.SEQUENCE_FILE).is_file():
        timed(figures, "import", lambda: import_video(args.video, None, sequence, size=args.size,
                                                      max_frames=args.max_frames, log=log, crop=args.crop))
    info = seq.validate_sequence_folder(sequence)
    figures.update(frames=info.frame_count, size=info.width, crop=info.metadata.get("crop"),
                   source_size=info.metadata.get("source_size"), valid_region=info.valid_region)
    if not (sequence / "init.npz").is_file():
        timed(figures, "init", lambda: initialise_sequence(sequence, "mediapipe", log=log))
    if not (avatar / "report.json").is_file():
        timed(figures, "fit", lambda: fit(sequence, avatar, preset=args.preset, progress="bar",
                                          hold_out_every=args.hold_out_every, device="cpu",
                                          environment=args.environment, specular=args.specular, seed=args.seed,
                                          **fit_options))
    report = read_report(avatar)
    evaluation = timed(figures, "evaluate", lambda: evaluate_fit(avatar, sequence, device="cpu", progress="bar"))

    fitted, held = report["metrics"], evaluation["held_out"]["metrics"]
    figures.update(
        mode=json.loads((avatar / "avatar.json").read_text()).get("mode"), fit_frames=len(report["frames"]), exposure=report.get("exposure", {}).get("decision"),
        mask_cut_frames=report.get("mask_cut_frames"), shadows="on" if report.get("shadows", {}).get("on") else "off",
        fitted={"psnr_mean": fitted["psnr_mean"], "iou_mean": float(np.mean(fitted["silhouette_iou"])),
                "iou_min": float(np.min(fitted["silhouette_iou"])), "l1_mean": fitted["l1_mean"],
                "ms_ssim_mean": fitted.get("ms_ssim_mean")},
        held_out={"frames": len(evaluation["held_out"]["frames"]), "psnr_mean": held["psnr_mean"],
                  "iou_mean": held["silhouette_iou_mean"], "iou_min": float(np.min(held["silhouette_iou"])),
                  "l1_mean": held["l1_mean"], "ms_ssim_mean": held.get("ms_ssim_mean")})
    figures["fit_seconds_reported"] = report.get("total_seconds")
    figures["environment_decision"] = report.get("environment", {}).get("decision")
    figures["specular_decision"] = report.get("specular", {}).get("decision")
    (avatar / "bench_real_footage.json").write_text(json.dumps(figures, indent=2))
    print(json.dumps(figures, indent=2))
    if args.pictures:
        target = Path(args.pictures)
        target.mkdir(parents=True, exist_ok=True)
        for source, name in ((sequence / seq.MASK_PREVIEW_FILE, "real_masks.png"),
                             (avatar / GRID_FILE, "real_fit_grid.png"),
                             (avatar / HELD_OUT_PICTURE, "real_held_out_grid.png")):
            shutil.copyfile(source, target / name)
            print(f"wrote {target / name}")


if __name__ == "__main__":
    main()
