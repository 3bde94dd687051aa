"""Benchmark: the room light's occlusion measured per frame (render/occlusion.py), drawing every
face of the fit's subdivided mesh into the depth maps against drawing its unsubdivided surface
(hand_lost_light, what the fit does).

    .venv/bin/python benchmarks/bench_occlusion.py [--mode arm] [--threads 1] [--repeats 3]

Eight frames of the subdivided model (fist, pinch, spread, thumbs-up, twice); prints the best of
`--repeats` per frame for each, and the mean difference of the ambient's blocked share O_0.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.handmodel.poses import NAMED_POSES  # noqa: E402
from pipeline.render import occlusion  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", default="arm", choices=("hand", "arm"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = HandModel.load(args.mode, subdivided=True)
    names = ["fist", "pinch", "spread", "thumbs_up"] * 2
    pose = torch.stack([torch.as_tensor(NAMED_POSES[name], dtype=torch.float32) for name in names])
    placed = torch.tensor([[0.0, 0.0, 0.5]]).repeat(len(names), 1)
    points = model(None, pose, torch.zeros(len(names), 3), placed).vertices
    faces = torch.as_tensor(model.data.faces, dtype=torch.long)
    focus = occlusion.hand_focus(model.data.vertex_parts)
    ways = {"every face": lambda: occlusion.lost_light(points, faces, focus),
            "unsubdivided surface": lambda: occlusion.hand_lost_light(points, model.data)}
    seconds, results = {name: [] for name in ways}, {}
    for _ in range(args.repeats):
        for name, measure in ways.items():      # interleaved: a machine that slows down slows both
            start = time.perf_counter()
            results[name] = measure()
            seconds[name].append(time.perf_counter() - start)
    for name in ways:
        print(f"{name}: {min(seconds[name]) / len(names):.3f} s per frame (best of {args.repeats}, "
              f"{args.threads} thread(s), {len(model.data.faces)} faces)")
    difference = (results["every face"][..., 0] - results["unsubdivided surface"][..., 0]).abs().mean()
    print(f"mean |difference| of O_0: {difference:.4f}")


if __name__ == "__main__":
    main()
