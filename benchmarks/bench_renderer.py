"""Benchmark: forward+backward time per frame of the renderer on the subdivided hand model.

    .venv/bin/python benchmarks/bench_renderer.py [--frames 8] [--sizes 256 448] [--profile]

Three workloads: silhouette only; textured and shaded with a normal map; the same with
shadows; each on the reference primitives (`render(..., fused=False)`) and the fused path
(the default), timed in alternating rounds in one run so that both see the same machine, with
the median of the rounds. --profile adds a breakdown by stage and the top operators
(torch.profiler).

--then DIR adds the renderer of an earlier commit, timed in the same alternating rounds (the
reference path shares render()'s composition with the fused one, so it speeds up with it):

    git archive 377ae01 pipeline | tar -x -C DIR && mv DIR/pipeline DIR/pipeline_then
    .venv/bin/python benchmarks/bench_renderer.py --then DIR

(377ae01: the renderer when the speed issue was filed.)
"""
from __future__ import annotations

import argparse
import importlib
import sys

import numpy as np
import torch
from timing import alternating_medians, seconds_per_call

from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.render import antialias, interpolate, rasterize
from pipeline.render.renderer import Appearance, Light, RenderMesh, render

WORKLOADS = {
    "silhouette": dict(outputs=("alpha",), shadows=False),
    "shaded + normal map": dict(outputs=("rgb", "alpha"), shadows=False),
    "shaded + shadows": dict(outputs=("rgb", "alpha"), shadows=True),
}


def scene(frames, mode, device):
    model = HandModel.load(mode, subdivided=True, device=device)
    names = list(NAMED_POSES)
    pose = torch.as_tensor(np.stack([NAMED_POSES[names[i % len(names)]] for i in range(frames)]),
                           dtype=torch.float32, device=device)
    generator = torch.Generator().manual_seed(0)
    orient = (torch.tensor([np.pi, 0.0, 0.0]) + 0.4 * torch.randn(frames, 3, generator=generator)).to(device)
    transl = torch.tensor([0.0, 0.09, 0.5], device=device).expand(frames, 3)
    with torch.no_grad():
        points = model(pose=pose, global_orient=orient, transl=transl).vertices
    mesh = RenderMesh.from_model_data(model.data, device=device)
    return model, points, mesh


def parameters(device):
    albedo = torch.rand(3, 512, 512, device=device).mul(0.2).add(0.6).requires_grad_(True)
    normal_map = torch.zeros(3, 512, 512, device=device)
    normal_map[2] = 1
    normal_map.requires_grad_(True)
    light = torch.tensor([0.3, -0.3, 0.1], device=device, requires_grad=True)
    ambient = torch.tensor(0.6, device=device, requires_grad=True)
    return albedo, normal_map, light, ambient


def run(points, mesh, size, workload, params, fused=True):
    albedo, normal_map, light_position, ambient = params
    vertices = points.clone().requires_grad_(True)
    K = torch.tensor([[size * 2.0, 0, size / 2], [0, size * 2.0, size / 2], [0, 0, 1]], device=points.device)
    images = render(vertices, mesh, K, size, size, outputs=workload["outputs"],
                    appearance=Appearance(albedo, normal_map),
                    light=Light(light_position, ambient, shadows=workload["shadows"]), fused=fused)
    loss = sum(image.mean() for image in images.values())
    loss.backward()


def run_then(then, then_mesh, points, size, workload, params):
    """run() on the renderer of an earlier commit (the module pipeline_then.render.renderer)."""
    albedo, normal_map, light_position, ambient = params
    vertices = points.clone().requires_grad_(True)
    K = torch.tensor([[size * 2.0, 0, size / 2], [0, size * 2.0, size / 2], [0, 0, 1]], device=points.device)
    images = then.render(vertices, then_mesh, K, size, size,
                         outputs=workload["outputs"], appearance=then.Appearance(albedo, normal_map),
                         light=then.Light(light_position, ambient, shadows=workload["shadows"]))
    loss = sum(image.mean() for image in images.values())
    loss.backward()


def stage_breakdown(points, mesh, size, repeats):
    """Milliseconds per frame of the silhouette path's stages."""
    K = torch.tensor([[size * 2.0, 0, size / 2], [0, size * 2.0, size / 2], [0, 0, 1]], device=points.device)
    frames = points.shape[0]
    rast = rasterize.rasterize(points, mesh.faces, K, size, size)
    frags = interpolate.fragments(points, mesh.faces, K, rast)
    ones = torch.ones(len(frags.pixel), 1, device=points.device)
    alpha = interpolate.to_image(ones, frags)
    topology = mesh.edges()
    stages = {
        "rasterize": lambda: rasterize.rasterize(points, mesh.faces, K, size, size),
        "fragments (barycentrics)": lambda: interpolate.fragments(points, mesh.faces, K, rast),
        "antialias": lambda: antialias.antialias(alpha, points, K, rast, topology),
    }
    return {name: 1000 * seconds_per_call(f, repeats) / frames for name, f in stages.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 448])
    parser.add_argument("--mode", choices=("hand", "arm"), default="hand")
    parser.add_argument("--repeats", type=int, default=7, help="alternating rounds of each path")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--then", metavar="DIR", help="also time the earlier renderer in DIR/pipeline_then")
    args = parser.parse_args()
    model, points, mesh = scene(args.frames, args.mode, args.device)
    params = parameters(args.device)
    then = None
    if args.then:
        sys.path.insert(0, args.then)
        then = importlib.import_module("pipeline_then.render.renderer")
        then_mesh = then.RenderMesh.from_model_data(model.data, device=args.device)
    print(f"{args.mode} model subdivided: {model.data.num_vertices} vertices, {len(model.data.faces)} faces; "
          f"{args.frames} frames; {args.device}; torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"forward+backward, ms per frame (median of {args.repeats} alternating rounds): "
          + ("then / " if then else "") + "reference / fused = speed-up" + (" over then" if then else ""))
    width = 38 if then else 30
    print(f"{'workload':<22}" + "".join(f"{f'{s}x{s}':>{width}}" for s in args.sizes))
    for name, workload in WORKLOADS.items():
        cells = []
        for size in args.sizes:
            calls = [lambda: run(points, mesh, size, workload, params, fused=False),
                     lambda: run(points, mesh, size, workload, params, fused=True)]
            if then:
                calls.insert(0, lambda: run_then(then, then_mesh, points, size, workload, params))
            medians = alternating_medians(calls, args.repeats)
            cells.append(" / ".join(f"{1000 * m / args.frames:.1f}" for m in medians)
                         + f" = {medians[0] / medians[-1]:.2f}x")
        print(f"{name:<22}" + "".join(f"{cell:>{width}}" for cell in cells))
    if args.profile:
        size = args.sizes[0]
        print(f"\nsilhouette stages at {size}x{size} (forward, ms/frame):")
        for name, value in stage_breakdown(points, mesh, size, args.repeats).items():
            print(f"  {name:<26}{value:8.2f}")
        from torch.profiler import ProfilerActivity, profile
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            run(points, mesh, size, WORKLOADS["shaded + shadows"], params)
        print(f"\ntop operators, shaded + shadows at {size}x{size}, {args.frames} frames:")
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))


if __name__ == "__main__":
    main()
