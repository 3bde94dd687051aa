"""The skin's specular lobe measured on exact clips (pipeline/evaluate/exact_clips.py): a clip
whose skin is drawn with an oily lobe (roughness 0.4, level 0.6) and the same clip without one,
each fitted with `--specular auto` and `off`, over seeds. Prints, per clip and setting: the
decision, the fitted roughness and level (the truth's beside them) and the highlight `auto`
decides by, the fitted-frame PSNR and the held-out PSNR (neighbours protocol).

    .venv/bin/python benchmarks/bench_specular.py OUT [--seeds 0,1,2] [--steps 200] [--frames 10]
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

from pipeline.evaluate.exact_clips import write_clip  # noqa: E402
from pipeline.evaluate.held_out import evaluate_held_out  # noqa: E402
from pipeline.fit.fitting import fit  # noqa: E402
from pipeline.init import initialise_sequence  # noqa: E402
from synth.motions import OPEN  # noqa: E402

CLIPS = (("shiny", (0.4, 0.6)), ("plain", None))
SETTINGS = ("auto", "off")


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
    for clip_name, lobe in CLIPS:
        clip = args.out / clip_name / "clip"
        if not (clip / "sequence.json").is_file():
            write_clip(clip, OPEN, frames=args.frames, size=args.size, turn_degrees=20, specular=lobe)
        for seed in (int(s) for s in args.seeds.split(",")):
            initialise_sequence(clip, "gt-noise", seed=seed, log=lambda *a: None)
            for setting in SETTINGS:
                result = _measured(clip, args.out / clip_name / f"{setting}_seed{seed}", setting, seed, args)
                rows.append((clip_name, setting, result))
                fitted = "" if result["roughness"] is None else \
                    f"roughness {result['roughness']:.2f} level {result['level']:.2f} highlight {result['highlight']:.3f} "
                print(f"{clip_name:6s} {setting:5s} seed {seed}: on {str(result['on']):5s} {fitted}(truth {lobe}) "
                      f"fitted PSNR {result['fitted_psnr']:.2f} held-out PSNR {result['held_out_psnr']:.2f} dB, "
                      f"{result['seconds']:.0f} s", flush=True)
    print("\nmean (spread) over seeds")
    for clip_name, _ in CLIPS:
        for setting in SETTINGS:
            picked = [r for c, s, r in rows if c == clip_name and s == setting]
            for figure in ("fitted_psnr", "held_out_psnr"):
                values = np.array([r[figure] for r in picked])
                print(f"{clip_name:6s} {setting:5s} {figure:14s} {values.mean():.2f} "
                      f"({values.min():.2f}-{values.max():.2f})")
    return 0


def _measured(clip, out, setting, seed, args):
    """The figures of one fit (kept in OUT/.../bench_specular.json; a finished fit is kept, its
    held-out evaluation runs again)."""
    result_file = out / "bench_specular.json"
    if result_file.is_file():
        return json.loads(result_file.read_text())
    started = time.perf_counter()
    if (out / "report.json").is_file():
        report = json.loads((out / "report.json").read_text())
    else:
        report = fit(clip, out, max_steps=args.steps, progress="none", resolution=args.size, texture_size=64,
                     specular=setting, seed=seed, hold_out_every=5)
    held_out = evaluate_held_out(out, clip, protocol="neighbours")
    decision = report["specular"]["decision"] or {}
    result = {"on": decision.get("on", False), "roughness": decision.get("roughness"), "level": decision.get("level"),
              "highlight": decision.get("highlight"), "fitted_psnr": report["metrics"]["psnr_mean"],
              "held_out_psnr": held_out.metrics["psnr_mean"], "seconds": time.perf_counter() - started}
    result_file.write_text(json.dumps(result))
    return result


if __name__ == "__main__":
    sys.exit(main())
