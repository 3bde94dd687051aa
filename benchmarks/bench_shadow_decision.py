"""Benchmark: self-shadowing on a finished fit, each way with the albedo solved for it.

    .venv/bin/python benchmarks/bench_shadow_decision.py FIT SEQ [--resolution PX] [--light-distance M]

The fit's frames at its working size (or --resolution), every parameter as fitted; then, per
case, the albedo (and the room light, where the fit has one) solved again from every fitted
frame (fit/albedo_solve.solve_avatar_albedo) and scored: L1 in the masks of the fitted frames
(outputs.masked_l1, what `shadows auto` compares) and the albedo against the truth in the
visible UV area (evaluate/albedo.albedo_error after its per-channel scale: what new poses
show). Cases: as fitted (no solve); shadows off; shadows on; with --light-distance, shadows on
with the point light moved along its direction to that many metres from the hand's centre.
One JSON line per case. The table in docs/fidelity.md ("Shadows decided with the albedo
solved") comes from this script.
"""
from __future__ import annotations

import argparse
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--resolution", type=int, default=None)
    parser.add_argument("--light-distance", type=float, default=None, metavar="M")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    problem, fitted_shadows = problem_at(args.fit, args.sequence, args.resolution)
    avatar = problem.avatar
    fitted = {name: value.detach().clone() for name, value in avatar.state_dict().items()}
    frames = np.arange(len(problem.frames))
    truth = albedo_truth(args.sequence, avatar.albedo.shape[-1], "cpu", args.fit)
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
        print(json.dumps({"fit": str(args.fit), "case": name, "shadows": shadows, "l1": round(l1, 5),
                          "albedo_mae_scaled": round(error["mae_scaled"], 4),
                          "albedo_psnr_scaled": round(error["psnr_scaled"], 2)}), flush=True)


if __name__ == "__main__":
    main()
