"""Benchmark: what more pose steps would buy a finished fit, stage kind by stage kind.

    .venv/bin/python benchmarks/bench_pose_polish.py FIT SEQ --kind geometry+appearance \\
                     --resolution 160 --steps 150 [--batch 10] [--solve-resolution 160]

The finished fit's avatar (checkpoint.pt) is taken over by a problem built as the fit built its
own, but at `--resolution`; one more stage of `--kind` runs `--steps` Adam steps of its usual
parameters on it (a stage of the fit's own kind, energy and rates: stage_run.StageRun); then the
albedo is solved again and the unseen texels filled (as after the fit's stages, from the frames at
`--solve-resolution`, by default the fit's own working size), and the avatar is scored on all its
frames at 448 px as benchmarks/score_fits.py scores fits (its avatar_scores: L1, PSNR and
silhouette IoU in the mask, Procrustes joint error against gt.npz). `--steps 0` scores the fit with its albedo solved again: the
reference the other rows compare with. One JSON line.

docs/performance.md ("What `preview` lacks against `full`") asks it which steps `preview`'s poses
lack: silhouette steps (geometry), at which working size, or shaded ones (geometry+appearance).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.threads import WAIT_POLICY, configure_threads  # noqa: E402

os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)   # before torch starts OpenMP (pipeline/threads.py)

import torch  # noqa: E402

from pipeline.evaluate.finished_fit import load_finished_fit  # noqa: E402
from pipeline.evaluate.poses import PoseScorer  # noqa: E402
from pipeline.fit.albedo_solve import decided_texels, solve_avatar_albedo  # noqa: E402
from pipeline.fit.checkpoint import FitState  # noqa: E402
from pipeline.fit.problem import build_problem  # noqa: E402
from pipeline.fit.schedule import Schedule, StageKind, StageSpec  # noqa: E402
from pipeline.fit.stage_run import StageRun  # noqa: E402
from pipeline.fit.texture_fill import fill_avatar_albedo  # noqa: E402
from score_fits import avatar_scores  # noqa: E402   (a sibling script: benchmarks/ is on the path)

SCORED_AT = 448


def polish(fit, sequence, kind: StageKind, resolution, steps, batch, solve_resolution=None, seed=0):
    saved, report = load_finished_fit(fit, "cpu")
    settings = dataclasses.replace(saved.settings, resolution=resolution, batch_size=batch)
    frames = report["frames"]
    shadows = bool(report["shadows"]["on"])
    problem = build_problem(sequence, settings, frames, device="cpu")
    problem.avatar.load_state_dict(saved.avatar)
    stage = StageSpec(kind, steps)
    state = FitState.fresh(Schedule((stage,)), "on" if shadows else "off")
    run = StageRun(problem, stage, state, torch.Generator().manual_seed(seed))
    started = time.perf_counter()
    while run.has_work and not run.finished:
        run.step()
    stage_seconds = time.perf_counter() - started
    seen = problem.at_resolution(solve_resolution or saved.settings.resolution)
    with torch.no_grad():
        problem.avatar.measure_occlusion(exact=True)
        solve_avatar_albedo(seen, shadows)
        fill_avatar_albedo(problem.avatar, decided_texels(seen))
    solve_seconds = time.perf_counter() - started - stage_seconds
    images, errors = avatar_scores(problem.avatar, frames, sequence, PoseScorer(sequence), SCORED_AT, shadows)
    return {"fit": str(fit), "kind": kind.value, "resolution": resolution, "steps": steps, "batch": batch,
            "stage_seconds": round(stage_seconds, 1), "solve_seconds": round(solve_seconds, 1),
            f"l1_at_{SCORED_AT}": round(images["l1_mean"], 4), f"psnr_at_{SCORED_AT}": round(images["psnr_mean"], 2),
            "iou_mean": round(sum(images["silhouette_iou"]) / len(frames), 4),
            "joint_mm": round(errors["joints"]["procrustes_mm_mean"], 3), "events": state.events}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit", help="a finished fit's folder")
    parser.add_argument("sequence", help="the synthetic sequence it was fitted to (with gt.npz)")
    parser.add_argument("--kind", default=StageKind.JOINT.value,
                        choices=[StageKind.GEOMETRY.value, StageKind.JOINT.value])
    parser.add_argument("--resolution", type=int, default=160, help="working size of the extra stage (long side)")
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--batch", type=int, default=10)
    parser.add_argument("--solve-resolution", type=int, help="frames the albedo is solved from again (default: "
                                                             "the fit's own working size)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    configure_threads(args.threads)
    print(json.dumps(polish(args.fit, args.sequence, StageKind(args.kind), args.resolution, args.steps, args.batch,
                            args.solve_resolution)), flush=True)


if __name__ == "__main__":
    main()
