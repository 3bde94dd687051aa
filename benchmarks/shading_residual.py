"""Benchmark: where the light model fails to explain a synthetic clip's frames.

    .venv/bin/python benchmarks/shading_residual.py FIT SEQ [--resolution 448] [--picture PNG]

The clip's frames are compared with the model's picture of the true hand wearing the true albedo:
the true geometry (gt.npz, a flat normal map) or the fit's own (its normal map), lit by the fit's
point light and shadows, its specular lobe and exposure gains. The light's strengths are fitted
again for the true albedo (which differs from the fitted one in brightness and contrast): per
colour, linear least squares over every compared pixel of

    I - P = s S0 a + k a + (Y(n) a) . c

(linear light; I the frame over its gain, P the lobe's sheen, S0 the point light's shading with its
ambient and shadows, Y the room light's 8 harmonics at the shading normal, a the true albedo; s, k
and c fitted). What the model then leaves, the ratio I' / (s S0 a + k a + Y a c) (I' = I - P) per pixel, is
binned by what could explain it: the cosine to the point light, how squarely the pixel sees the
surface, the point light's visibility (shadows), the distance to the silhouette's edge, the skin's
tone (the true albedo's luminance), the distance to the light's centre over the frame's median.
Printed per case, one JSON line per binning: per bin the share of pixels, the mean ratio (over the
colours) and the share of the squared residual. A flat ratio is a light model that explains the
frames; the bins that carry the residual say what is missing.
`--true-light` puts the point light at the clip's own light (`--area-samples N`: spread over its
square), `--angular-radius` gives the fit's light a size (render/area_light.py), `--falloff` makes
its light fall off with the square of the distance (renderer.Light.falloff), `--no-lobe` leaves the
fit's specular lobe out (for a clip rendered with matte skin). The room light's occlusion is drawn
as the finished fit draws it (FitSettings.occlusion). The figures of docs/fidelity.md ("The
light's size", "The light's falloff with distance") come from this script.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from albedo_ceiling import problem_at  # noqa: E402
from albedo_true_geometry import geometries  # noqa: E402
from pipeline.evaluate.albedo import albedo_truth  # noqa: E402
from pipeline.fit.albedo_solve import _facing  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.colour_model import srgb_to_linear  # noqa: E402
from pipeline.render.renderer import Appearance, render  # noqa: E402
from pipeline.render.shading import environment_basis_values  # noqa: E402

BINS = {
    "cos_light": np.array([-1.0, 0.0, 0.2, 0.4, 0.6, 0.8, 1.01]),
    "facing": np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.01]),
    "visibility": np.array([0.0, 0.05, 0.5, 0.95, 1.01]),
    "edge_px": np.array([0.0, 2.0, 4.0, 8.0, 16.0, 1e9]),
    "tone": np.array([0.0, 0.15, 0.3, 0.45, 1.01]),
    "light_distance": np.array([0.0, 0.9, 0.95, 0.98, 1.0, 1.02, 1.05, 1.1, 9.0]),
}


@torch.no_grad()
def gather(problem, shadows, posed, albedo, flat_normals, batch_size=4, light_samples=None):
    """Per compared pixel of every fitted frame: {name: (N, ...) array} of the module's quantities,
    and per frame the pixels' places (for the picture). `light_samples` (K, 3): points the point
    light's shading (S0, with its shadows) is averaged over (an area light), instead of its place."""
    avatar, clip = problem.avatar, problem.clip
    normal_map = None if flat_normals else avatar.unit_normal_map()
    columns = {k: [] for k in ("colour", "sheen", "base", "basis", "albedo", "cos_light", "facing", "visibility",
                                "edge_px", "frame", "row", "col", "light_distance")}
    for batch in torch.arange(len(problem.frames)).split(batch_size):
        vertices, _ = posed(batch)
        light = avatar.light(shadows, batch, vertices)
        plain = dataclasses.replace(light, environment=None, specular=None, linear=False)
        unit = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                      outputs=("rgb", "alpha", "shading_normal", "position", "light_visibility", "normal"),
                      appearance=Appearance(torch.ones_like(albedo), normal_map), light=plain, antialiased=False)
        if light_samples is not None:
            unit["rgb"] = torch.stack([render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width,
                                              outputs=("rgb",), appearance=Appearance(torch.ones_like(albedo), normal_map),
                                              light=dataclasses.replace(plain, position=place), antialiased=False)["rgb"]
                                       for place in light_samples]).mean(0)
        true = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("albedo",),
                      appearance=Appearance(albedo, normal_map), antialiased=False)["albedo"]
        if light.specular is not None:     # the lobe alone: the true albedo at 0
            sheen = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("rgb",),
                           appearance=Appearance(torch.zeros_like(albedo), normal_map),
                           light=dataclasses.replace(light, environment=None), antialiased=False)["rgb"]
            sheen = srgb_to_linear(sheen) if light.linear else sheen
        else:
            sheen = torch.zeros_like(unit["rgb"])
        gain = avatar.exposure_gain(batch) if problem.exposure_on else 1.0
        colour = clip.images[batch] / gain
        colour = srgb_to_linear(colour) if light.linear else colour
        true = srgb_to_linear(true) if light.linear else true
        usable = (problem.colour_pixels(batch, albedo_solve=True) & (unit["alpha"][..., 0] > 0.5)).numpy()
        to_light = torch.nn.functional.normalize(light.position.detach() - unit["position"], dim=-1)
        cos_light = (unit["shading_normal"] * to_light).sum(-1)
        facing = _facing(unit["normal"], clip.K[batch])
        for index in range(len(batch)):
            inside = (unit["alpha"][index, ..., 0] > 0.5).numpy().astype(np.uint8)
            edge = cv2.distanceTransform(inside, cv2.DIST_L2, 3)
            here = usable[index]
            rows, cols = np.nonzero(here)
            columns["colour"].append(colour[index].numpy()[here])
            columns["sheen"].append(sheen[index].numpy()[here])
            columns["base"].append(unit["rgb"][index].numpy()[here])
            columns["basis"].append(environment_basis_values(unit["shading_normal"][index]).numpy()[here])
            columns["albedo"].append(true[index].numpy()[here])
            columns["cos_light"].append(cos_light[index].numpy()[here])
            columns["facing"].append(facing[index].numpy()[here])
            columns["visibility"].append(unit["light_visibility"][index, ..., 0].numpy()[here])
            columns["edge_px"].append(edge[here])
            distance = (light.position.detach() - unit["position"][index]).norm(dim=-1).numpy()[here]
            columns["light_distance"].append(distance / np.median(distance))
            columns["frame"].append(np.full(len(rows), int(batch[index])))
            columns["row"].append(rows)
            columns["col"].append(cols)
    return {k: np.concatenate(v).astype(np.float64) for k, v in columns.items()}


def area_points(lamp, count):
    """(count^2, 3) points spread over a square area light's face (synth/lighting.py: it faces
    the hand's pivot, its x axis horizontal), at the centres of a count x count grid."""
    centre = np.asarray(lamp["position"], dtype=np.float64)
    towards = centre - np.array([0.0, 0.0, 0.4]) if "target" not in lamp else centre - np.asarray(lamp["target"])
    z = towards / np.linalg.norm(towards)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    steps = (np.arange(count) + 0.5) / count - 0.5
    return np.array([centre + lamp["size_m"] * (u * x + v * y) for u in steps for v in steps])


def fitted_prediction(data):
    """(N, 3) s S0 a + k a + (Y a) . c with s, k and c fitted per colour by least squares (module docstring)."""
    target = data["colour"] - data["sheen"]
    prediction = np.empty_like(target)
    for channel in range(3):
        a = data["albedo"][:, channel]
        design = np.concatenate([(data["base"][:, channel] * a)[:, None], a[:, None], data["basis"] * a[:, None]],
                                axis=1)
        coefficients, *_ = np.linalg.lstsq(design, target[:, channel], rcond=None)
        prediction[:, channel] = design @ coefficients
    return target, prediction


def binned(data, target, prediction):
    ratio = (target / np.maximum(prediction, 1e-4)).mean(1)
    squared = np.square(target - prediction).sum(1)
    tone = data["albedo"] @ np.array([0.2126, 0.7152, 0.0722])
    features = {**{k: data[k] for k in ("cos_light", "facing", "visibility", "edge_px", "light_distance")}, "tone": tone}
    tables = {}
    for name, edges in BINS.items():
        places = np.clip(np.digitize(features[name], edges) - 1, 0, len(edges) - 2)
        rows = []
        for b in range(len(edges) - 1):
            chosen = places == b
            if not chosen.any():
                continue
            rows.append({"bin": [round(float(edges[b]), 2), round(float(edges[b + 1]), 2)],
                         "pixels": round(float(chosen.mean()), 3),
                         "ratio": round(float(np.median(ratio[chosen])), 3),
                         "residual": round(float(squared[chosen].sum() / squared.sum()), 3)})
        tables[name] = rows
    return tables


def picture(problem, data, target, prediction, path, frames):
    """Per chosen frame: the frame, the model's picture (the fitted strengths) and the ratio
    (0.6 blue .. 1 white .. 1.4 red), side by side; one row per frame."""
    height, width = problem.clip.height, problem.clip.width
    ratio = (target / np.maximum(prediction, 1e-4)).mean(1)
    rows = []
    for frame in frames:
        chosen = data["frame"] == frame
        r, c = data["row"][chosen].astype(int), data["col"][chosen].astype(int)
        shown = np.zeros((height, width, 3))
        model = np.zeros((height, width, 3))
        ratio_image = np.ones((height, width, 3))
        shown[r, c] = target[chosen]
        model[r, c] = prediction[chosen]
        t = np.clip((ratio[chosen] - 1) / 0.4, -1, 1)[:, None]
        ratio_image[r, c] = np.where(t > 0, (1, 1, 1) - t * (0, 1, 1), (1, 1, 1) + t * (1, 1, 0))
        encode = lambda x: np.clip(x, 0, 1) ** (1 / 2.2)   # noqa: E731  (for the eye only)
        rows.append(np.concatenate([encode(shown), encode(model), ratio_image], axis=1))
    image = (np.concatenate(rows, axis=0) * 255).round().astype(np.uint8)
    cv2.imwrite(str(path), image[..., ::-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--resolution", type=int, default=448)
    parser.add_argument("--picture", type=Path, help="frames, model and ratio of 5 frames (the true geometry)")
    parser.add_argument("--true-light", action="store_true",
                        help="the point light at the clip's own light (gt.npz: its first lamp's centre)")
    parser.add_argument("--area-samples", type=int, default=0,
                        help="with --true-light: the shading averaged over N x N points of its area light's square")
    parser.add_argument("--angular-radius", type=float,
                        help="the fit's light given this size (degrees; render/area_light.py, 16 points) instead of "
                             "its own")
    parser.add_argument("--cases", default="true geometry,fitted geometry", help="comma-separated")
    parser.add_argument("--falloff", action="store_true", help="the light falls off with the square of the distance")
    parser.add_argument("--no-lobe", action="store_true", help="leave the fit's specular lobe out (a matte clip)")
    args = parser.parse_args(argv)
    torch.set_grad_enabled(False)
    problem, shadows = problem_at(args.fit, args.sequence, args.resolution)
    problem.avatar.area_samples = 16
    problem.avatar.occlusion = problem.settings.occlusion_drawn      # as the finished fit shades
    problem.avatar.light_falloff = args.falloff
    if args.no_lobe:
        problem.avatar.switch_specular(False)
    if args.angular_radius is not None:
        problem.avatar.light_angle.fill_(math.radians(args.angular_radius))
    light_samples = None
    if args.true_light:
        info = seq.read_sequence_info(args.sequence)
        lamp = seq.read_ground_truth(Path(args.sequence) / info.ground_truth).light["lights"][0]
        dtype = problem.avatar.light_position.dtype
        problem.avatar.light_position.data = torch.as_tensor(lamp["position"], dtype=dtype)
        if args.area_samples and lamp.get("size_m"):
            light_samples = torch.as_tensor(area_points(lamp, args.area_samples), dtype=dtype)
    truth = albedo_truth(args.sequence, problem.avatar.albedo.shape[-1], "cpu", args.fit)
    albedo = torch.as_tensor(truth.image, dtype=torch.float32).permute(2, 0, 1).contiguous()
    cases = geometries(problem, args.sequence)
    for case, flat in (("true geometry", True), ("fitted geometry", False)):
        if case not in args.cases.split(","):
            continue
        data = gather(problem, shadows, cases[case], albedo, flat, light_samples=light_samples)
        target, prediction = fitted_prediction(data)
        relative = float(np.abs(target - prediction).mean() / np.abs(target).mean())
        print(json.dumps({"case": case, "pixels": len(target), "relative_l1": round(relative, 4),
                          **binned(data, target, prediction)}), flush=True)
        if args.picture and case == "true geometry":
            count = len(problem.frames)
            picture(problem, data, target, prediction, args.picture,
                    [0, count // 3, count * 2 // 5, count // 2, count - 1])


if __name__ == "__main__":
    main()
