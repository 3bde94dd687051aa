"""The fitted hand's size and depth along a fit, against a synthetic clip's truth: where a fit
lets the size wander (one camera sees a larger hand farther away as it sees a smaller one nearer).

    python benchmarks/bench_size_drift.py SEQ OUT [--seed S] [--fit-options JSON] [--every N]
        [--threads T] [--picture PNG] [--pulls N]
    python benchmarks/bench_size_drift.py --replot OUT/size_drift.json [OUT2/size_drift.json ...] --picture PNG
        [--labels A,B,...] [--title T]

Fits SEQ (a sequence folder with gt.npz and init.npz) with `fast`, every 5th frame held out, into
OUT, and every N steps (default 20) records the scale that brings the fitted frames' 21 keypoints
onto the true ones (each frame's spread about its centroid over the truth's, averaged: above 1,
the fitted hand is small) and the mean depth error of those keypoints (mm, positive: too far).
Writes OUT/size_drift.json (rows: stage index, stage name, step, scale, depth) and, with
--picture, both against the fit's steps with the stages marked.

With --pulls N, every N steps of the geometry and joint stages it also prints (lines "PULL") and
stores (OUT/size_pulls.json) each energy term's pull along the valley: the change of its weighted
value over every fitted frame when the hand grows by 1% and moves 1% farther from the camera (the
shape along the gradient of its size, each frame's translation so that its keypoints' centroid
scales about the camera; a central difference of +-0.5%). Positive: the term resists the growth. `--fit-options`: FitSettings
overrides as JSON, e.g. '{"weights": {"size_prior": 1}, "size_anchor": "alignment",
"size_tolerance": 0}'.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def keypoint_scale_and_depth(problem, true_keypoints):
    """(scale, depth mm) of the fitted frames' keypoints against the truth's (module docstring)."""
    with torch.no_grad():
        _, keypoints = problem.avatar.posed(problem.all_frames())
    fitted = keypoints[:, :21].double().cpu()
    truth = true_keypoints[torch.as_tensor(np.asarray(problem.frames))]
    spread = lambda points: (points - points.mean(1, keepdim=True)).square().sum((1, 2)).sqrt()  # noqa: E731
    scale = float((spread(truth) / spread(fitted)).mean())
    depth = float((fitted[..., 2].mean(1) - truth[..., 2].mean(1)).mean() * 1000)
    return scale, depth


def valley_step(problem, relative):
    """(shape change, (F, 3) translation change) that grows the hand by `relative` and moves each
    fitted frame `relative` farther along its line of sight (its keypoints' centroid scaled about
    the camera), so that it looks nearly the same: the shape moves along the gradient of
    HandModel.size."""
    avatar = problem.avatar
    frames = problem.all_frames()
    with torch.enable_grad():
        betas = avatar.betas.detach().clone().requires_grad_(True)
        size = avatar.model.size(betas)
        gradient, = torch.autograd.grad(size, betas)
    shape_step = relative * float(size) * gradient / gradient.square().sum()
    with torch.no_grad():
        before = avatar.posed(frames)[1][:, :21].mean(1)
        avatar.betas += shape_step
        after = avatar.posed(frames)[1][:, :21].mean(1)
        avatar.betas -= shape_step
    return shape_step, (1 + relative) * before - after


def term_values(problem, stage, chunk=6):
    """{term: weighted value} of the stage's terms over every fitted frame (no self-shadowing; the
    texture terms' random offsets drawn alike each time)."""
    from pipeline.fit.energy import batch_energy
    from pipeline.fit.energy_terms import terms_for

    generator = torch.Generator().manual_seed(0)
    frames = problem.all_frames()
    weights = {term.name: term.weight_in(problem.settings, stage.kind) for term in terms_for(stage.kind, problem.settings, problem)}
    values = {}
    for part in frames.split(chunk):
        _, terms = batch_energy(problem, stage, part, False, generator)
        for name, value in terms.items():
            values[name] = values.get(name, 0.0) + weights[name] * value * len(part) / len(frames)
    return values


def valley_pulls(problem, stage, relative=0.005):
    """{term: change of its weighted value per 1% of growth along the valley (valley_step)}."""
    avatar = problem.avatar
    shape_step, translation_step = valley_step(problem, relative)
    with torch.no_grad():
        avatar.betas += shape_step
        avatar.transl += translation_step
        larger = term_values(problem, stage)
        avatar.betas -= 2 * shape_step
        avatar.transl -= 2 * translation_step
        smaller = term_values(problem, stage)
        avatar.betas += shape_step
        avatar.transl += translation_step
    return {name: (larger[name] - smaller[name]) / (2 * relative * 100) for name in larger}


class ValleyPulls:
    """A fit observer that every `every` steps of the geometry and joint stages records valley_pulls."""

    def __init__(self, every):
        self.every, self.rows = every, []

    def start(self, problem, state):
        pass

    def end(self, problem, state):
        pass

    def step(self, problem, state):
        from pipeline.fit.schedule import StageKind

        if state.stage >= len(state.schedule) or state.step % self.every:
            return
        stage = state.schedule[state.stage]
        if stage.kind not in (StageKind.GEOMETRY, StageKind.JOINT):
            return
        pulls = valley_pulls(problem, stage)
        self.rows.append({"stage_name": stage.name, "step": int(state.step), "pulls": {k: round(v, 7) for k, v in pulls.items()}})
        named = " ".join(f"{name}={value:+.1e}" for name, value in sorted(pulls.items(), key=lambda kv: kv[1]) if value)
        print(f"PULL {stage.name} step {state.step}: total {sum(pulls.values()):+.1e}; {named}", flush=True)


class SizeTrack:
    """A fit observer (fitting.fit's `observers`) that records the size and depth every `every` steps."""

    def __init__(self, true_keypoints, every):
        self.true_keypoints, self.every, self.rows = true_keypoints, every, []

    def _record(self, problem, state):
        finished = state.stage >= len(state.schedule)     # the end: after the work that follows the stages
        scale, depth = keypoint_scale_and_depth(problem, self.true_keypoints)
        self.rows.append({"stage": int(state.stage), "stage_name": "end" if finished else state.schedule[state.stage].name,
                          "step": int(state.step),
                          "scale": round(scale, 5), "depth_mm": round(depth, 3)})

    def start(self, problem, state):
        self._record(problem, state)

    def step(self, problem, state):
        if state.step % self.every == 0:
            self._record(problem, state)

    def end(self, problem, state):
        self._record(problem, state)


def picture(runs, path, title):
    """Draw the size and the depth error of each run ({label: rows}) against the fit's steps, the
    stages marked (those of the first run)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for label, rows in runs.items():
        rows = [row for row in rows if row["stage_name"] != "end"]     # the end repeats the last stage's shape
        offsets, total, x = {}, 0, []
        for row in rows:                          # the steps laid end to end, stage after stage
            if row["stage"] not in offsets:
                offsets[row["stage"]] = total
            total = max(total, offsets[row["stage"]] + row["step"])
            x.append(offsets[row["stage"]] + row["step"])
        axes[0].plot(x, [row["scale"] for row in rows], marker=".", label=label)
        axes[1].plot(x, [row["depth_mm"] for row in rows], marker=".", label=label)
        if len(axes[0].lines) == 1:              # the stages, from the first run
            names = {row["stage"]: row["stage_name"] for row in rows}
            for stage, start in offsets.items():
                for axis in axes:
                    axis.axvline(start, color="lightgrey", linewidth=0.8, linestyle="--")
                axes[0].annotate(names[stage], (start, 1.0), xytext=(3, 4), textcoords="offset points", fontsize=8)
    axes[0].axhline(1.0, color="grey", linewidth=0.8)
    axes[0].set_ylabel("truth's size / fit's")
    axes[1].axhline(0.0, color="grey", linewidth=0.8)
    axes[1].set_ylabel("depth error, mm")
    axes[1].set_xlabel("steps of the fit")
    if len(runs) > 1:
        axes[1].legend(fontsize=7)
    axes[0].set_title(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", nargs="?", type=Path)
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fit-options", default="{}")
    parser.add_argument("--every", type=int, default=20)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--picture", type=Path, default=None)
    parser.add_argument("--replot", type=Path, nargs="+", default=None,
                        help="draw the picture of written size_drift.json files (several: in one picture, each "
                             "labelled with its title or --labels)")
    parser.add_argument("--labels", default=None, help="with --replot: each file's label, separated by commas")
    parser.add_argument("--title", default=None, help="with --replot: the picture's title (default: the first file's)")
    parser.add_argument("--pulls", type=int, default=0, metavar="N",
                        help="every N steps of the geometry and joint stages, each term's pull along the valley")
    args = parser.parse_args()
    if args.replot:
        written = [json.loads(path.read_text()) for path in args.replot]
        labels = args.labels.split(",") if args.labels else [run["title"] for run in written]
        if len(labels) != len(written):
            parser.error(f"--labels names {len(labels)} runs for {len(written)} files")
        picture({label: run["rows"] for label, run in zip(labels, written)} if len(written) > 1 else {"": written[0]["rows"]},
                args.picture, args.title or written[0]["title"])
        return
    from pipeline.threads import configure_threads
    configure_threads(args.threads)
    from pipeline.fit.fitting import fit
    from pipeline.formats import sequence_folder as seq

    info = seq.read_sequence_info(args.sequence)
    truth = seq.read_ground_truth(args.sequence / info.ground_truth)
    track = SizeTrack(torch.as_tensor(np.asarray(truth.keypoints3d), dtype=torch.float64), args.every)
    options = json.loads(args.fit_options)
    pulls = ValleyPulls(args.pulls) if args.pulls else None
    fit(args.sequence, args.out, observers=(track,) + ((pulls,) if pulls else ()), seed=args.seed, hold_out_every=5,
        progress="bar", **options)
    title = f"{args.sequence.name}, seed {args.seed}" + (f", {args.fit_options}" if options else "")
    last_of_stage = {row["stage"]: row for row in track.rows}       # the start, then where each stage ended
    for row in [track.rows[0], *last_of_stage.values()]:
        print(f"{row['stage_name']:>20} step {row['step']:4d}: scale {row['scale']:.4f}, depth {row['depth_mm']:+.1f} mm")
    (args.out / "size_drift.json").write_text(json.dumps({"title": title, "rows": track.rows}, indent=1))
    if pulls:
        (args.out / "size_pulls.json").write_text(json.dumps({"title": title, "rows": pulls.rows}, indent=1))
    if args.picture:
        picture({"": track.rows}, args.picture, title)


if __name__ == "__main__":
    main()
