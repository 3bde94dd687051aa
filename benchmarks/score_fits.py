"""Benchmark: finished fits of one synthetic clip scored alike, and their curves in one plot.

    .venv/bin/python benchmarks/score_fits.py FIT... --sequence SEQ [--resolution 448]
                     [--frames-of FIT] [--plot PNG --reference FIT]

Each fit's own report scores it at its own working size (256 px for `fast`, 448 for `full`);
here every finished fit is rendered at one `--resolution` on its frames (or, with --frames-of,
on the frames another fit fitted: fits of different frame counts compared on the same frames)
and scored as the fit's report scores (fit/outputs.image_scores: the render over the
background plate, inside the mask, forearm cuts excluded), with the Procrustes joint and
vertex errors against gt.npz (evaluate/poses.PoseScorer). One JSON line per fit.

--plot draws the fits' anytime curves (those recorded with `harp fit --curve`) in one picture;
a fit without a curve is drawn as one star at its end (its report's fit time, its own L1 and
PSNR, the pose errors above); --reference FIT adds dashed lines 5% above that fit's final L1 and
joint error (the speed issue's target). The figures in docs/performance.md (the 150-frame clip)
come from this script.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.evaluate.finished_fit import fitted_avatar  # noqa: E402
from pipeline.evaluate.poses import PoseScorer  # noqa: E402
from pipeline.fit.clip_data import load_clip  # noqa: E402
from pipeline.fit.outputs import image_scores, render_all  # noqa: E402
from pipeline.fit.problem import _silhouette_weight, build_avatar  # noqa: E402
from pipeline.formats.fit_curve import CURVE_FILE  # noqa: E402
from pipeline.formats.initial_estimate import read_initial_estimate  # noqa: E402

WITHIN = 0.05
PER_FRAME = ("pose", "global_orient", "transl", "exposure")    # the avatar's per-frame parameters


def on_frames(avatar, fitted_frames, frames, sequence):
    """The avatar restricted to `frames` (a subset of the sequence frames it was fitted on)."""
    index = [list(fitted_frames).index(frame) for frame in frames]
    subset = build_avatar(read_initial_estimate(sequence), frames, avatar.albedo.shape[-1], avatar.albedo.device)
    state = {name: value[index] if name in PER_FRAME else value for name, value in avatar.state_dict().items()}
    subset.load_state_dict(state)
    subset.linear_light = avatar.linear_light
    return subset


@torch.no_grad()
def avatar_scores(avatar, frames, sequence, scorer, resolution, shadows):
    """(image_scores of the avatar rendered at `resolution` on its sequence `frames`, inside the masks,
    forearm cuts excluded; its pose errors against gt.npz (PoseScorer.avatar_errors))."""
    clip = load_clip(sequence, resolution, frames, device="cpu")
    _, keypoints = avatar.posed(torch.arange(len(frames)))
    weight, _ = _silhouette_weight(clip, avatar, keypoints)
    rgb, alpha = render_all(avatar, clip, shadows)
    return image_scores(rgb, alpha, clip, weight), scorer.avatar_errors(avatar, frames)


@torch.no_grad()
def score(fit, sequence, scorer, resolution, frames=None):
    avatar, report = fitted_avatar(fit, sequence, device="cpu")
    fitted_frames = report["frames"]
    if frames is not None:
        missing = sorted(set(frames) - set(fitted_frames))
        if missing:
            raise SystemExit(f"{fit} did not fit frames {missing[:5]}...: cannot score it on them")
        avatar = on_frames(avatar, fitted_frames, frames, sequence)
    frames = list(frames if frames is not None else fitted_frames)
    images, errors = avatar_scores(avatar, frames, sequence, scorer, resolution, report["shadows"]["on"])
    return {"fit": str(fit), "preset": report.get("preset"), "frames": len(frames),
            "fit_seconds": round(report["total_seconds"], 1), "l1_own": round(report["metrics"]["l1_mean"], 4),
            "psnr_own": round(report["metrics"]["psnr_mean"], 2), f"l1_at_{resolution}": round(images["l1_mean"], 4),
            f"psnr_at_{resolution}": round(images["psnr_mean"], 2),
            "joint_mm": round(errors["joints"]["procrustes_mm_mean"], 3),
            "vertex_mm": round(errors["vertices"]["procrustes_mm_mean"], 3) if "vertices" in errors else None}


def plot(results, path, reference, labels=None):
    from pipeline.evaluate.plot import plot_curves

    labels = labels or [f"{Path(r['fit']).name} ({r['preset']})" for r in results]
    with_curve = [(r, label) for r, label in zip(results, labels) if (Path(r["fit"]) / CURVE_FILE).is_file()]
    finals = [(label, r["fit_seconds"], {"l1_mean": r["l1_own"], "psnr_mean": r["psnr_own"], "joint_mm": r["joint_mm"],
                                         "vertex_mm": r["vertex_mm"]})
              for r, label in zip(results, labels) if (r, label) not in with_curve]
    targets = None
    if reference is not None:
        targets = {"l1_mean": reference["l1_own"] * (1 + WITHIN), "joint_mm": reference["joint_mm"] * (1 + WITHIN)}
    return plot_curves([r["fit"] for r, _ in with_curve], path, figures=("l1_mean", "joint_mm", "psnr_mean", "vertex_mm"),
                       labels=[label for _, label in with_curve], targets=targets, finals=finals)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("fits", nargs="+")
    parser.add_argument("--sequence", required=True)
    parser.add_argument("--resolution", type=int, default=448)
    parser.add_argument("--frames-of", help="score every fit on the frames this fit fitted")
    parser.add_argument("--plot", help="PNG of the curves")
    parser.add_argument("--reference", help="a fit (one of FIT...) whose final figures set the 5%% targets")
    parser.add_argument("--labels", help="the fits' names in the plot, separated by ';' (default: folder and preset)")
    args = parser.parse_args()
    scorer = PoseScorer(args.sequence)
    frames = None
    if args.frames_of:
        frames = json.loads((Path(args.frames_of) / "report.json").read_text())["frames"]
    results = []
    for fit in args.fits:
        results.append(score(fit, args.sequence, scorer, args.resolution, frames))
        print(json.dumps(results[-1]), flush=True)
    if args.plot:
        reference = next((r for r in results if Path(r["fit"]) == Path(args.reference)), None) if args.reference else None
        labels = [label.strip() for label in args.labels.split(";")] if args.labels else None
        if labels and len(labels) != len(results):
            raise SystemExit(f"--labels names {len(labels)} fits, {len(results)} were given")
        print("wrote", plot(results, args.plot, reference, labels))


if __name__ == "__main__":
    main()
