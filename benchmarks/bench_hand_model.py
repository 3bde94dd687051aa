"""Benchmark: forward and forward+backward time of the hand model for a batch of frames.

    .venv/bin/python benchmarks/bench_hand_model.py [--frames 32] [--device cpu]
"""
from __future__ import annotations

import argparse

import torch
from timing import seconds_per_call

from pipeline.handmodel.lbs import HandModel


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    args = parser.parse_args()
    dtype = getattr(torch, args.dtype)
    print(f"{args.frames} frames, {args.dtype}, {args.device}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    print(f"{'model':<22}{'vertices':>9}{'forward ms':>12}{'fwd+bwd ms':>12}")
    for mode in ("hand", "arm"):
        for subdivided in (False, True):
            model = HandModel.load(mode, subdivided=subdivided, dtype=dtype, device=args.device)
            generator = torch.Generator().manual_seed(0)
            pose = (0.3 * torch.randn(args.frames, 16, 3, generator=generator)).to(args.device, dtype)
            orient = torch.randn(args.frames, 3, generator=generator).to(args.device, dtype)
            transl = torch.randn(args.frames, 3, generator=generator).to(args.device, dtype)
            betas = torch.zeros(model.num_betas, device=args.device, dtype=dtype)
            params = [t.requires_grad_(True) for t in (pose, orient, transl, betas)]

            def forward():
                with torch.no_grad():
                    model(betas=betas, pose=pose, global_orient=orient, transl=transl)

            def forward_backward():
                for p in params:
                    p.grad = None
                out = model(betas=betas, pose=pose, global_orient=orient, transl=transl)
                out.vertices.square().sum().backward()

            name = f"{mode}{' subdivided' if subdivided else ''}"
            print(f"{name:<22}{model.data.num_vertices:>9}{1000 * seconds_per_call(forward, args.repeats):>12.2f}"
                  f"{1000 * seconds_per_call(forward_backward, args.repeats):>12.2f}")


if __name__ == "__main__":
    main()
