"""Benchmark: what limits the fitted albedo's sharpness on a synthetic clip.

    .venv/bin/python benchmarks/albedo_ceiling.py FIT SEQ [--resolution 448 ...]

The fit's albedo solve (fit/albedo_solve.py) is run again on the fit's frames, its geometry,
poses and light as fitted, twice per working resolution:
    frames      the clip's own frames (Cycles): what the fit does
    ideal       the frames replaced, inside the avatar's silhouette, by our renderer's picture of
                the fitted avatar wearing the true albedo (gt_albedo.png at its own size): frames
                the fitted geometry, light and renderer explain exactly, so only the pixels'
                sampling of the texture and the solve itself limit what comes back
each with the reweighted solve and with the plain one (every pixel alike). Printed per case:
the sharpness ratio and the MAE against the truth in the visible UV area
(evaluate/fidelity.sharpness_ratio, evaluate/albedo.albedo_error), the same figures the
fidelity measure reports. One JSON line per case.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.evaluate.albedo import albedo_error, albedo_truth  # noqa: E402
from pipeline.evaluate.fidelity import sharpness_ratio, true_hand  # noqa: E402
from pipeline.evaluate.finished_fit import load_finished_fit  # noqa: E402
from pipeline.fit import albedo_solve  # noqa: E402
from pipeline.fit.problem import build_problem  # noqa: E402
from pipeline.render.renderer import render  # noqa: E402


def problem_at(fit, sequence, resolution):
    """The fit's problem over its frames at a working resolution, every parameter as fitted."""
    saved, report = load_finished_fit(fit, "cpu")
    settings = dataclasses.replace(saved.settings, resolution=resolution) if resolution else saved.settings
    problem = build_problem(Path(sequence), settings, report["frames"], "cpu", shared=dict(saved.avatar))
    problem.avatar.load_state_dict(saved.avatar)
    return problem, bool(saved.state.shadows.on)


@torch.no_grad()
def show_true_albedo(problem, shadows, true_albedo, batch_size=4, footprint=1):
    """Replace the frames, inside the avatar's silhouette, by the fitted avatar rendered with the
    true albedo (its exposure gains applied as the solve reads them). `footprint` > 1 renders
    that many times finer and averages each pixel's footprint, as a camera's pixel (and Cycles'
    pixel filter) integrates the surface it sees, instead of sampling the pixel's centre."""
    avatar, clip = problem.avatar, problem.clip
    appearance = dataclasses.replace(avatar.appearance(), albedo=true_albedo)
    light = avatar.light(shadows)
    scale = torch.tensor([footprint, footprint, 1.0], dtype=clip.K.dtype)[:, None]
    for batch in torch.arange(len(problem.frames)).split(batch_size):
        vertices, _ = avatar.posed(batch)
        K = clip.K[batch] * scale
        K[:, :2, 2] = (clip.K[batch][:, :2, 2] + 0.5) * footprint - 0.5   # the same pixel grid, finer
        images = render(vertices, avatar.mesh, K, clip.height * footprint, clip.width * footprint,
                        outputs=("rgb", "alpha"), appearance=appearance, light=light, antialiased=False)
        rgb, alpha = (torch.nn.functional.avg_pool2d(images[name].permute(0, 3, 1, 2), footprint).permute(0, 2, 3, 1)
                      for name in ("rgb", "alpha"))
        rgb = rgb / alpha.clamp(min=1e-6)                   # the hand's own colour where a pixel is partly covered
        rgb = rgb * avatar.exposure_gain(batch) if problem.exposure_on else rgb
        inside = alpha > 0.5
        clip.images[batch] = torch.where(inside, rgb, clip.images[batch])


def scores(albedo, truth):
    image = albedo.permute(1, 2, 0).double().numpy()
    error = albedo_error(image, truth.image, truth.visible)
    return {"sharpness_ratio": round(sharpness_ratio(image, truth.image, truth.visible), 4),
            "mae": round(error["mae"], 5)}


def solve(problem, shadows, plain, supersample):
    reweightings = albedo_solve.REWEIGHTINGS
    albedo_solve.REWEIGHTINGS = 0 if plain else reweightings
    try:
        start = time.perf_counter()
        albedo, _ = albedo_solve.solved_albedo(problem, shadows, supersample=supersample)
        return albedo, time.perf_counter() - start
    finally:
        albedo_solve.REWEIGHTINGS = reweightings


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--resolution", type=int, nargs="*", default=[0],
                        help="working resolutions (0: the fit's own)")
    parser.add_argument("--reweighted-only", action="store_true", help="skip the plain solve")
    parser.add_argument("--footprint", type=int, default=1,
                        help="ideal frames rendered this many times finer and averaged per pixel")
    parser.add_argument("--supersample", type=int, nargs="*", default=[1],
                        help="solve textures this many times finer than the fit's (albedo_solve.solved_albedo)")
    args = parser.parse_args(argv)
    torch.set_grad_enabled(False)
    true_albedo = true_hand(args.sequence).albedo
    for resolution in args.resolution:
        problem, shadows = problem_at(args.fit, args.sequence, resolution)
        size = problem.avatar.albedo.shape[-1]
        truth = albedo_truth(args.sequence, size, "cpu", args.fit)
        fitted = scores(problem.avatar.albedo.detach().clamp(0, 1), truth)
        print(json.dumps({"case": "as fitted", "texture": size, **fitted}), flush=True)
        for frames in ("frames", "ideal"):
            if frames == "ideal":
                show_true_albedo(problem, shadows, true_albedo, footprint=args.footprint)
            for supersample in args.supersample:
                for plain in (False,) if args.reweighted_only else (False, True):
                    albedo, seconds = solve(problem, shadows, plain, supersample)
                    print(json.dumps({"case": frames, "footprint": args.footprint if frames == "ideal" else 1, "solve": "plain" if plain else "reweighted",
                                      "resolution": problem.clip.width, "texture": size, "supersample": supersample,
                                      **scores(albedo, truth), "seconds": round(seconds, 1)}), flush=True)


if __name__ == "__main__":
    main()
