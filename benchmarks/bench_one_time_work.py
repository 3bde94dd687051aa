"""Benchmark: a fit's work outside its steps, piece by piece, on one core.

    .venv/bin/python benchmarks/bench_one_time_work.py SEQ [--fit FIT] [--threads 1] [--out JSON]

The fit problem is built as `harp fit SEQ` builds it (`fast`, fitting._set_up); then, each once
and in this order, as the fit first meets them:
- `calibration`: the calibration step (estimate.measure_step_costs: throwaway steps of every
  kind the schedule takes), with the step costs it measured. Its first steps also pay for the
  pieces below that a step needs (the masks' erosion, the sheen table) and for torch's first
  optimiser (which imports torch._dynamo);
- `erosion`: the masks eroded for the photometric term and for the albedo solve
  (FitProblem.photometric_inside, albedo_solve_inside; measured on a fresh problem, before
  any step);
- `background_plates`: every frame's background with the hand filled in (ClipData.backgrounds,
  clip_data.harmonic_fill), made on first use: the shadow decision half-way through the joint
  stage, or the outputs; and per frame;
- `shadow_probe`: what `shadows auto` does besides (fitting._decide_shadows): the albedo solved
  from light_probe.PROBE_FRAMES frames without and with shadows (the light held), and those frames'
  L1 in the masks each way.
With --fit (a finished fit of every frame of SEQ, `harp fit SEQ --out FIT`): the albedo solved
again as the fit's last work does, on that fit's avatar (its shadows as decided): from the frames
at the working size with the room light (`final_solve_working_size`), then at `solve_resolution`
with the light held (`final_solve_finer`); the avatar's parameters are put back after each.
Seconds of wall time; one JSON object, printed and written to --out. The figures in
docs/performance.md ("The joint stage's time outside its steps") come from this script, run
alone on the 150-frame sun clip.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402


def _timed(function):
    start = time.perf_counter()
    value = function()
    return value, time.perf_counter() - start


def run(sequence, threads=1, fit=None):
    torch.set_num_threads(threads)
    from pipeline.fit import estimate, fitting, light_probe
    from pipeline.fit.albedo_solve import solved_albedo
    from pipeline.fit.checkpoint import FitState
    from pipeline.fit.outputs import masked_l1

    def problem_of():
        return fitting._set_up(Path(sequence), fitting.FitJob(), {}).problem

    figures = {"sequence": str(sequence), "threads": threads}
    problem = problem_of()
    figures["frames"] = len(problem.frames)
    _, figures["erosion"] = _timed(lambda: (problem.photometric_inside, problem.albedo_solve_inside))

    problem = problem_of()
    schedule = problem.settings.schedule()
    state = FitState.fresh(schedule, problem.settings.shadows)
    costs, figures["calibration"] = _timed(lambda: estimate.measure_step_costs(
        problem, state, estimate.active_stages(problem, schedule)))
    figures["step_seconds"] = {f"{kind.stage.value}{' shadows' if kind.shadows else ''}": round(seconds, 4)
                               for kind, seconds in costs.seconds.items()}

    _, figures["background_plates"] = _timed(lambda: problem.clip.backgrounds)
    figures["background_plates_per_frame"] = figures["background_plates"] / len(problem.frames)

    probe = light_probe.probe_frames(len(problem.frames))
    with torch.no_grad():
        for shadows in (False, True):
            label = "with_shadows" if shadows else "without_shadows"
            _, figures[f"shadow_probe_solve_{label}"] = _timed(
                lambda: solved_albedo(problem, shadows, frames=probe, solve_environment=False))
            _, figures[f"shadow_probe_l1_{label}"] = _timed(lambda: masked_l1(problem, shadows, probe))
    figures["shadow_probe"] = sum(value for key, value in figures.items() if key.startswith("shadow_probe_"))
    if fit is not None:
        figures.update(_final_solves(problem, Path(fit)))
    return {key: round(value, 3) if isinstance(value, float) else value for key, value in figures.items()}


def _final_solves(problem, fit):
    """{name: seconds} of the two final albedo solves on the avatar of the finished fit `fit`."""
    import copy

    from pipeline.fit.albedo_solve import solve_avatar_albedo
    from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint

    saved = load_checkpoint(fit / CHECKPOINT_FILE)
    try:
        problem.avatar.load_state_dict(saved.avatar)
    except RuntimeError as error:
        raise SystemExit(f"{fit} is not a fit of every frame of the sequence with fast's settings "
                         f"({error})") from None
    kept = copy.deepcopy(problem.avatar.state_dict())
    shadows = bool(saved.state.shadows.on)
    figures = {"fit": str(fit), "fit_shadows": shadows, "fit_specular": problem.avatar.light().specular is not None}
    _, figures["final_solve_working_size"] = _timed(lambda: solve_avatar_albedo(problem, shadows))
    problem.avatar.load_state_dict(kept)
    finer = problem.at_resolution(problem.settings.solve_resolution)
    _, figures["final_solve_finer"] = _timed(lambda: solve_avatar_albedo(finer, shadows, solve_environment=False))
    problem.avatar.load_state_dict(kept)
    return figures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence")
    parser.add_argument("--fit", default=None, help="a finished fit of SEQ: also time its final albedo solves")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args(argv)
    figures = run(args.sequence, args.threads, args.fit)
    text = json.dumps(figures, indent=1)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
