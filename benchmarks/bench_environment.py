"""The environment light measured on exact clips (pipeline/evaluate/exact_clips.py): a clip lit by a
coloured room (blue from the left, warm from below) beside the point light, and the same clip
without it, each fitted with `--environment auto` and `off`, over seeds. Prints, per clip and
setting: the decision and the fitted colour strength (the truth's beside it), the fitted-frame
PSNR and the held-out PSNR (neighbours protocol).

    .venv/bin/python benchmarks/bench_environment.py OUT [--seeds 0,1,2] [--steps 200] [--frames 10]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.evaluate.exact_clips import AMBIENT, coloured_room, write_clip  # noqa: E402
from pipeline.evaluate.held_out import evaluate_held_out  # noqa: E402
from pipeline.fit.fitting import fit  # noqa: E402
from pipeline.formats import environment_light as el  # noqa: E402
from pipeline.init import initialise_sequence  # noqa: E402
from synth.motions import OPEN  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--steps", type=int, default=200, help="steps a stage at most")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--size", type=int, default=96)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for clip_name, environment in (("room", coloured_room()), ("plain", None)):
        clip = args.out / clip_name / "clip"
        if not (clip / "sequence.json").is_file():
            write_clip(clip, OPEN, frames=args.frames, size=args.size, turn_degrees=20, environment=environment)
        truth = 0.0 if environment is None else el.colour_strength(environment, AMBIENT)
        for seed in (int(s) for s in args.seeds.split(",")):
            initialise_sequence(clip, "gt-noise", seed=seed, log=lambda *a: None)
            for setting in ("auto", "off"):
                out = args.out / clip_name / f"{setting}_seed{seed}"
                result_file = out / "bench_environment.json"
                if not result_file.is_file():      # a finished fit is kept; its held-out evaluation runs again
                    started = time.perf_counter()
                    if (out / "report.json").is_file():
                        report = json.loads((out / "report.json").read_text())
                    else:
                        report = fit(clip, out, max_steps=args.steps, progress="none", resolution=args.size,
                                     texture_size=64, environment=setting, seed=seed, hold_out_every=5)
                    held_out = evaluate_held_out(out, clip, protocol="neighbours")
                    decision = report["environment"]["decision"] or {}
                    result_file.write_text(json.dumps({
                        "on": decision.get("on", False), "colour_strength": decision.get("colour_strength"),
                        "fitted_psnr": report["metrics"]["psnr_mean"], "held_out_psnr": held_out.metrics["psnr_mean"],
                        "seconds": time.perf_counter() - started}))
                result = json.loads(result_file.read_text())
                rows.append((clip_name, setting, seed, truth, result))
                strength = "" if result["colour_strength"] is None else f"{result['colour_strength']:.3f}"
                print(f"{clip_name:6s} {setting:5s} seed {seed}: on {str(result['on']):5s} colour strength "
                      f"{strength:6s} (truth {truth:.3f}) fitted PSNR {result['fitted_psnr']:.2f} held-out PSNR "
                      f"{result['held_out_psnr']:.2f} dB, {result['seconds']:.0f} s", flush=True)
    print("\nmean (spread) over seeds")
    for clip_name in ("room", "plain"):
        for setting in ("auto", "off"):
            picked = [r for c, s, _, _, r in rows if c == clip_name and s == setting]
            for figure in ("fitted_psnr", "held_out_psnr"):
                values = np.array([r[figure] for r in picked])
                print(f"{clip_name:6s} {setting:5s} {figure:14s} {values.mean():.2f} "
                      f"({values.min():.2f}-{values.max():.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
