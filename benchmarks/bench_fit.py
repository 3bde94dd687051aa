"""Benchmark: the fit on synthetic clips with exact ground truth (the acceptance figures of the fit).

    .venv/bin/python benchmarks/bench_fit.py [--work DIR] [--only demo,held_out,pose,sun]

demo      `harp demo`: the 30-frame 256x256 `flip` clip under `ambient` light, MediaPipe
          initialisation, the `fast` preset; wall time, silhouette IoU per frame, PSNR / L1 /
          MS-SSIM in the mask, albedo error in the visible UV area, pose errors; the shadows
          decision of `auto` under flat light.
held_out  the same clip fitted with every 5th frame left out, then pose, translation and light
          fitted on the held-out frames with the appearance frozen: PSNR / L1 / MS-SSIM there.
pose      the same clip from `--init gt-noise` (10 degrees per joint, 1 cm): Procrustes-aligned
          joint error of the initial estimate, of the geometry stages alone and of the full fit.
sun       the clip under the `sun` preset (MediaPipe initialisation): shadows on, off and auto.
perceptual  the demo clip fitted with photometric L1 alone (perceptual weight 0), to compare
          with the demo's fit (photometric + the weight-free perceptual term).
Figures go to stdout and to DIR/bench_fit.json (merged with earlier runs).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pipeline.demo import render_demo_clip, run_demo  # noqa: E402
from pipeline.evaluate import evaluate_fit  # noqa: E402
from pipeline.fit import fit  # noqa: E402
from pipeline.init import initialise_sequence  # noqa: E402

SECTIONS = ("demo", "held_out", "pose", "sun", "perceptual")


def quiet(message):
    print(f"  {message}", flush=True)


def clip_copy(source, target, init_method="mediapipe"):
    """A sequence folder sharing `source`'s frames, with its own init.npz."""
    target = Path(target)
    if not (target / "init.npz").is_file():
        target.mkdir(parents=True, exist_ok=True)
        for name in ("rgb", "mask", "sequence.json", "gt.npz", "gt_albedo.png"):
            if not (target / name).exists():
                (target / name).symlink_to(Path(source).resolve() / name)
        initialise_sequence(target, init_method, None, mode="auto", log=quiet)
    return target


def image_scores(metrics):
    iou = np.array(metrics["silhouette_iou"])
    return {"iou_min": float(iou.min()), "iou_mean": float(iou.mean()), "frames_iou_below_0.95": int((iou < 0.95).sum()),
            "psnr_mean": metrics["psnr_mean"], "psnr_min": metrics["psnr_min"], "l1_mean": metrics["l1_mean"],
            "ms_ssim_mean": metrics.get("ms_ssim_mean")}


def joints_mm(evaluation, which):
    return evaluation["poses"][which]["joints"]["procrustes_mm_mean"]


def bench_demo(work):
    result = run_demo(work / "demo", progress="none", log=quiet)
    report = json.loads((work / "demo" / "avatar" / "report.json").read_text())
    albedo = result["evaluation"]["albedo"]
    return {"wall_seconds": result["seconds"], "fit_seconds": report["total_seconds"],
            "stage_seconds": report["stage_seconds"], **image_scores(result["metrics"]),
            "albedo_mae": albedo["mae"], "albedo_psnr": albedo["psnr"], "albedo_mae_scaled": albedo["mae_scaled"],
            "albedo_psnr_scaled": albedo["psnr_scaled"], "pose_init_mm": joints_mm(result["evaluation"], "initial"),
            "pose_fit_mm": joints_mm(result["evaluation"], "fit"), "shadows_auto": report["shadows"]}


def demo_clip(work):
    clip = work / "demo" / "clip"
    if not (clip / "gt.npz").is_file():
        render_demo_clip(clip, quiet)
    return clip


def bench_held_out(work):
    clip = clip_copy(demo_clip(work), work / "held_out_clip")
    out = work / "held_out_fit"
    report = fit(clip, out, preset="fast", progress="none", hold_out_every=5)
    evaluation = evaluate_fit(out, clip)
    held = evaluation["held_out"]
    return {"held_out_frames": held["frames"], "fitted": image_scores(report["metrics"]),
            "held_out": {name: held["metrics"][name] for name in ("psnr_mean", "l1_mean", "ms_ssim_mean", "silhouette_iou_mean")
                         if name in held["metrics"]}}


def bench_pose(work):
    clip = clip_copy(demo_clip(work), work / "pose_clip", "gt-noise")
    figures = {}
    for label, steps in (("geometry_only", (200, 0, 0)), ("full", None)):
        out = work / f"pose_{label}"
        overrides = {"steps": steps} if steps else {}
        start = time.time()
        fit(clip, out, preset="fast", progress="none", **overrides)
        evaluation = evaluate_fit(out, clip)
        figures["initial_mm"] = joints_mm(evaluation, "initial")
        figures[f"{label}_mm"] = joints_mm(evaluation, "fit")
        figures[f"{label}_seconds"] = time.time() - start
    figures["full_reduction"] = 1 - figures["full_mm"] / figures["initial_mm"]
    return figures


def bench_sun(work):
    source = work / "sun_source"
    if not (source / "gt.npz").is_file():
        render_demo_clip(source, quiet, lighting="sun")
    clip = clip_copy(source, work / "sun_clip")
    figures = {}
    for shadows in ("on", "off", "auto"):
        out = work / f"sun_{shadows}"
        report = fit(clip, out, preset="fast", progress="none", shadows=shadows)
        figures[shadows] = {**image_scores(report["metrics"]), "seconds": report["total_seconds"],
                            "shadows": report["shadows"], "ambient": report["ambient"]}
    return figures


def bench_perceptual(work):
    from pipeline.fit.settings import WEIGHTS

    clip = clip_copy(demo_clip(work), work / "perceptual_clip")
    out = work / "photometric_only"
    report = fit(clip, out, preset="fast", progress="none", weights={**WEIGHTS, "perceptual": 0.0})
    evaluation = evaluate_fit(out, clip)
    albedo = evaluation["albedo"]
    return {"photometric_only": {**image_scores(report["metrics"]), "albedo_mae": albedo["mae"],
                                 "albedo_psnr": albedo["psnr"]}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", default="/tmp/harp_bench_fit", help="folder for clips and fits")
    parser.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results_file = work / "bench_fit.json"
    results = json.loads(results_file.read_text()) if results_file.is_file() else {}
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads", flush=True)
    for section in args.only.split(","):
        if section not in SECTIONS:
            raise SystemExit(f"unknown section {section!r}; choose from {SECTIONS}")
        if section == "demo" and (work / "demo").exists():
            shutil.rmtree(work / "demo")
        print(f"[{section}]", flush=True)
        results[section] = globals()[f"bench_{section}"](work)
        print(json.dumps(results[section], indent=1), flush=True)
        results_file.write_text(json.dumps(results, indent=1))
    print(f"wrote {results_file}")


if __name__ == "__main__":
    main()
