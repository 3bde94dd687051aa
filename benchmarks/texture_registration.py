"""Benchmark: how far the fitted avatar puts its texture from where the true hand has it, frame by
frame, on a synthetic clip.

    .venv/bin/python benchmarks/texture_registration.py FIT SEQ [--size 448]

The fitted surface and the true one (SEQ's gt.npz vertices, which share the model's UV layout)
are rendered in each fitted frame at `--size` pixels on the long side; at every pixel inside both
silhouettes the UV each shows is compared, in texels of the fit's texture (pixels more than
CHART_JUMP texels apart, where the two fall on different UV charts, are counted apart). The
distances are split by the true texel's distance to the true albedo's tone boundary (new_pose_limits.py's
band), by the view cosine of the true surface, and by frame: a frame the fit turned over shows
as one frame several texels off. One JSON line; docs/fidelity.md ("Frames the fit left off their
silhouettes stay out of the albedo solve") quotes it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))   # new_pose_limits

import numpy as np  # noqa: E402
import torch  # noqa: E402

from new_pose_limits import tone_boundary_distance  # noqa: E402
from pipeline.evaluate.albedo import albedo_truth  # noqa: E402
from pipeline.evaluate.finished_fit import fitted_avatar, posed_surfaces  # noqa: E402
from pipeline.fit.albedo_solve import _facing  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.handmodel.lbs import load_model_data  # noqa: E402
from pipeline.render.renderer import RenderMesh, render  # noqa: E402
from pipeline.render.texture import bilinear_texels  # noqa: E402

CHART_JUMP = 20.0   # texels: farther apart, the two UVs lie on different charts
BAND = 3.0          # texels from the tone boundary (new_pose_limits.py's default)


def summary(distances):
    return {"pixels": int(len(distances)), "median": round(float(np.median(distances)), 3),
            "mean": round(float(distances.mean()), 3), "p90": round(float(np.percentile(distances, 90)), 3)} \
        if len(distances) else {"pixels": 0}


@torch.no_grad()
def registration(fit, sequence, size=448):
    info = seq.read_sequence_info(sequence)
    truth_data = seq.read_ground_truth(sequence / info.ground_truth)
    if truth_data.vertices is None:
        raise SystemExit(f"{sequence} has no ground-truth vertices (gt.npz)")
    avatar, report = fitted_avatar(fit, sequence, "cpu")
    frames = np.asarray(report["frames"])
    fitted_vertices = posed_surfaces(avatar)
    true_vertices = torch.as_tensor(truth_data.vertices, dtype=torch.float32)[frames]
    true_mesh = RenderMesh.from_model_data(load_model_data(truth_data.mode, truth_data.side))
    texture = avatar.albedo.shape[-1]
    truth = albedo_truth(sequence, texture, "cpu", fit)
    boundary = tone_boundary_distance(truth.image, truth.visible)
    scale = size / max(info.height, info.width)
    height, width = round(info.height * scale), round(info.width * scale)
    K = torch.as_tensor(info.frame_K(), dtype=torch.float32)[frames].clone()
    K[:, :2] *= scale
    distances, band, facing, frame_of = [], [], [], []
    for i in range(len(frames)):
        fitted = render(fitted_vertices[i:i + 1], avatar.mesh, K[i:i + 1], height, width, outputs=("uv", "alpha"),
                        antialiased=False)
        true = render(true_vertices[i:i + 1], true_mesh, K[i:i + 1], height, width, outputs=("uv", "alpha", "normal"),
                      antialiased=False)
        both = (fitted["alpha"][0, ..., 0] > 0.5) & (true["alpha"][0, ..., 0] > 0.5)
        distances.append(((fitted["uv"][0] - true["uv"][0]) * texture).norm(dim=-1)[both].numpy())
        rows, columns, weights = bilinear_texels(true["uv"][0][both], texture)   # the renderer's own lookup
        nearest = weights.argmax(1, keepdim=True)
        band.append(boundary[rows.gather(1, nearest)[:, 0].numpy(), columns.gather(1, nearest)[:, 0].numpy()] < BAND)
        facing.append(_facing(true["normal"], K[i:i + 1])[0][both].numpy())
        frame_of.append(np.full(int(both.sum()), i))
    distances, band, facing, frame_of = map(np.concatenate, (distances, band, facing, frame_of))
    same_chart = distances < CHART_JUMP
    figures = {"fit": str(fit), "size": size, "texture": texture,
               "chart_jumps": round(float(1 - same_chart.mean()), 4),
               "all": summary(distances[same_chart]),
               "band": summary(distances[same_chart & band]), "rest": summary(distances[same_chart & ~band]),
               "by_view_cosine": {f"{low}-{high}": summary(distances[same_chart & (facing >= low) & (facing < high)])
                                  for low, high in ((0.0, 0.2), (0.2, 0.4), (0.4, 0.7), (0.7, 1.01))},
               "by_frame": {int(frames[i]): round(float(np.median(distances[same_chart & (frame_of == i)])), 2)
                            for i in range(len(frames)) if (same_chart & (frame_of == i)).any()}}
    return figures


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--size", type=int, default=448, help="pixels on the long side (default 448)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(json.dumps(registration(args.fit, args.sequence, args.size)))


if __name__ == "__main__":
    main()
