"""Benchmark: self-shadowing on a finished fit, each way with the albedo solved for it.

    .venv/bin/python benchmarks/bench_shadow_decision.py FIT... --sequence SEQ [--resolution PX]
                     [--light-distance M] [--picture PNG --frames 2,8,13,20]

The fit's frames at its working size (or --resolution), every parameter as fitted; then, per
case, the albedo (and the room light, where the fit has one) solved again from every fitted
frame (fit/albedo_solve.solve_avatar_albedo) and scored: L1 in the masks of the fitted frames
(outputs.masked_l1, what `shadows auto` compares) and the albedo against the truth in the
visible UV area (evaluate/albedo.albedo_error after its per-channel scale: what new poses
show). Cases: as fitted (no solve); shadows off; shadows on; with --light-distance, shadows on
with the point light moved along its direction to that many metres from the hand's centre.
One JSON line per fit and case.

--picture draws, for each fit, the fitted `--frames` (indices into its fitted frames): the frame,
the shading the frame itself shows (its colour in linear light over the true albedo at each
pixel, through the fit's UVs) and the fit's shading there (an albedo of 1 under its light, as
fitted, its shadows as decided), both at the same grey scale. The table and picture in
docs/fidelity.md ("Shadows decided with the albedo solved") come from this script.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from albedo_ceiling import problem_at  # noqa: E402
from pipeline.evaluate.albedo import albedo_error, albedo_truth  # noqa: E402
from pipeline.fit.albedo_solve import solve_avatar_albedo  # noqa: E402
from pipeline.fit.outputs import masked_l1  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.colour_model import srgb_to_linear  # noqa: E402
from pipeline.render.renderer import Appearance, render  # noqa: E402

SHADING_SCALE = 1.5   # the pictures' grey: shading / SHADING_SCALE


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fits", nargs="+")
    parser.add_argument("--sequence", required=True)
    parser.add_argument("--resolution", type=int, default=None)
    parser.add_argument("--light-distance", type=float, default=None, metavar="M")
    parser.add_argument("--picture", default=None)
    parser.add_argument("--frames", default="2,8,13,20")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    columns = []
    for fit in args.fits:
        problem, fitted_shadows = problem_at(fit, args.sequence, args.resolution)
        if args.picture:
            columns.append(shading_rows(problem, fitted_shadows, args.sequence, fit,
                                        [int(frame) for frame in args.frames.split(",")]))
        score_cases(problem, fitted_shadows, fit, args)
    if args.picture:
        seq.write_png(args.picture, np.round(np.concatenate(columns, axis=1).clip(0, 1) * 255).astype(np.uint8))


def score_cases(problem, fitted_shadows, fit, args):
    avatar = problem.avatar
    fitted = {name: value.detach().clone() for name, value in avatar.state_dict().items()}
    frames = np.arange(len(problem.frames))
    truth = albedo_truth(args.sequence, avatar.albedo.shape[-1], "cpu", fit)
    cases = [("as fitted", fitted_shadows, False, None), ("shadows off, solved", False, True, None),
             ("shadows on, solved", True, True, None)]
    if args.light_distance:
        cases.append((f"shadows on, light at {args.light_distance} m, solved", True, True, args.light_distance))
    for name, shadows, solve, distance in cases:
        avatar.load_state_dict(fitted)
        with torch.no_grad():
            if distance is not None:
                centre = avatar.posed(torch.as_tensor(frames))[0].mean((0, 1))
                direction = torch.nn.functional.normalize(avatar.light_position - centre, dim=0)
                avatar.light_position.copy_(centre + distance * direction)
            if solve:
                solve_avatar_albedo(problem, shadows)
            l1 = masked_l1(problem, shadows, frames)
        albedo = avatar.albedo.detach().clamp(0, 1).permute(1, 2, 0).double().cpu().numpy()
        error = albedo_error(np.round(albedo * 255) / 255, truth.image, truth.visible)
        print(json.dumps({"fit": str(fit), "case": name, "shadows": shadows, "l1": round(l1, 5),
                          "albedo_mae_scaled": round(error["mae_scaled"], 4),
                          "albedo_psnr_scaled": round(error["psnr_scaled"], 2)}), flush=True)
    avatar.load_state_dict(fitted)


@torch.no_grad()
def shading_rows(problem, shadows, sequence, fit, frames):
    """(rows of frame | the frame's own shading | the fit's shading) for `frames`, stacked (H, 3W, 3)."""
    avatar, clip = problem.avatar, problem.clip
    truth = albedo_truth(sequence, avatar.albedo.shape[-1], "cpu", fit)
    true_albedo = torch.as_tensor(truth.image, dtype=torch.float32).permute(2, 0, 1)
    true_albedo = srgb_to_linear(true_albedo) if avatar.linear_light else true_albedo
    rows = []
    for frame in frames:
        batch = torch.tensor([frame])
        vertices, _ = avatar.posed(batch)
        light = dataclasses.replace(avatar.light(shadows, batch, vertices), specular=None, linear=False)
        ones = dataclasses.replace(avatar.appearance(), albedo=torch.ones_like(avatar.albedo))
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("rgb", "alpha"),
                        appearance=ones, light=light, antialiased=False)
        albedo = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("albedo",),
                        appearance=Appearance(true_albedo), antialiased=False)["albedo"][0]
        inside = (images["alpha"][0] > 0.5).float()
        colour = srgb_to_linear(clip.images[frame]) if avatar.linear_light else clip.images[frame]
        shown = (colour / albedo.clamp(min=0.02)).mean(-1, keepdim=True) * inside / SHADING_SCALE
        fitted = images["rgb"][0].mean(-1, keepdim=True) * inside / SHADING_SCALE
        rows.append(torch.cat([clip.images[frame], shown.expand(-1, -1, 3), fitted.expand(-1, -1, 3)], dim=1))
    return torch.cat(rows, dim=0).cpu().numpy()


if __name__ == "__main__":
    main()
