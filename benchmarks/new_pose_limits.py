"""Benchmark: where the new-pose error of a fitted synthetic avatar lies in its albedo.

    .venv/bin/python benchmarks/new_pose_limits.py FIT SEQ [--picture PNG] [--band 3] [--broad 3,10,30]

The albedo's squared error against the truth (after the fidelity measure's per-channel scale,
evaluate/albedo.py) over the texels the clip showed, split by the texel's distance to the true
albedo's tone boundary (where a light palm meets a dark back: under `--band` texels, or farther)
and by whether the fit's frames decide the texel (albedo_solve.decided_texels at the fit's
solve resolution) or the texture fill made it. Then the new-pose figures
(evaluate/fidelity.evaluate_fidelity, on a copy of the fit) with the true albedo, at the fit's
brightness, put into one region at a time: the band the clip showed, the rest it showed, the
texels it never showed. How far each moves the new-pose PSNR says how much that region costs.
The same by scale: over the texels the clip showed, the truth's broad tones (a Gaussian of each
`--broad` sigma over those texels alone, shown_blur) under the fitted detail, and the fitted broad
tones under the truth's detail; at the first sigma the truth's broad tones also only where the
clip saw a texel squarely (albedo_solve.texel_trust at least 0.5) or only edge-on, and only on the
truth's dark or light tone.
--picture: three new poses from the palm and the back: the true hand, the true shape wearing
the fitted albedo (scaled), their difference x4. Also the albedo's brightness error (after the
scale) by signed distance to the tone boundary (signed_profile). One JSON line; docs/fidelity.md
("What limits new poses: the tone boundary") comes from this script.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))   # albedo_ceiling

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from albedo_ceiling import problem_at  # noqa: E402
from pipeline.avatar_render import load_avatar  # noqa: E402
from pipeline.evaluate.albedo import albedo_truth, best_scale, tone_cut  # noqa: E402
from pipeline.evaluate.fidelity import VIEWS, evaluate_fidelity, novel_poses, render_posed, true_hand  # noqa: E402
from pipeline.fit.albedo_solve import decided_texels, texel_trust  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402
from pipeline.formats import colour_model  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.png_file import write_png  # noqa: E402
from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.render.renderer import Appearance  # noqa: E402

PICTURE_POSES = ("spread", "thumbs_up", "random1")
BROAD_TEXELS = 3.0      # the Gaussian's sigma (texels of a 512 texture) that parts broad tones from detail
PICTURE_SIZE = 192      # pixels per panel


def tone_boundary_distance(truth, visible):
    """(T, T) texels from each texel to the nearest boundary between the truth's two tones (split
    at evaluate/albedo.tone_cut of the visible texels' brightness, as the fidelity measure splits them)."""
    brightness = truth.mean(-1)
    dark = (brightness < tone_cut(brightness[visible])).astype(np.uint8)
    boundary = cv2.morphologyEx(dark, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    return cv2.distanceTransform((~boundary).astype(np.uint8), cv2.DIST_L2, 3)


def signed_profile(fitted, truth, visible, reach=5):
    """{signed texels from the tone boundary (negative on the dark side): the mean brightness of
    the truth, of the fitted albedo, and their difference} over the visible texels, out to
    `reach` texels either side (farther texels counted at the last step). The difference's shape
    tells a boundary blurred (a bump on each side that fades with the distance) from the two tones'
    contrast (a level offset on each side) and from a boundary in the wrong place (one side only)."""
    brightness_true, brightness_fitted = truth.mean(-1), fitted.mean(-1)
    dark = brightness_true < tone_cut(brightness_true[visible])
    distance = tone_boundary_distance(truth, visible)
    signed = np.clip(np.where(dark, -np.ceil(distance), np.floor(distance)), -reach, reach)
    profile = {}
    for step in range(-reach, reach + 1):
        region = visible & (signed == step)
        if region.sum() >= 20:
            profile[step] = {"texels": int(region.sum()), "truth": round(float(brightness_true[region].mean()), 4),
                             "fitted": round(float(brightness_fitted[region].mean()), 4),
                             "difference": round(float((brightness_fitted - brightness_true)[region].mean()), 4)}
    return profile


def shown_blur(image, shown, sigma):
    """`image` (T, T, 3) blurred by a Gaussian of `sigma` texels over the texels `shown` alone (the
    blur of image times the mask over the blur of the mask): the texels outside (other charts' fill,
    the atlas's background) do not bleed into the broad tones at the charts' borders."""
    weight = shown.astype(np.float32)
    blurred = cv2.GaussianBlur(image.astype(np.float32) * weight[..., None], (0, 0), sigma)
    return (blurred / np.maximum(cv2.GaussianBlur(weight, (0, 0), sigma), 1e-6)[..., None]).astype(np.float64)


def new_pose_figures(fit, sequence, albedo):
    """fidelity's new-pose PSNR in the overlap, and the true shape's wearing `albedo` (T, T, 3 in
    [0, 1]), with `albedo` as the fit's albedo.png (on a temporary copy of the fit)."""
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / "fit"
        shutil.copytree(fit, copy, ignore=shutil.ignore_patterns("*.mp4", "*.png", "checkpoint.pt"))
        shutil.copy(Path(fit) / av.NORMAL_FILE, copy / av.NORMAL_FILE)
        write_png(copy / av.ALBEDO_FILE, np.round(np.clip(albedo, 0, 1) * 255).astype(np.uint8))
        result = evaluate_fidelity(copy, sequence, picture=False)["new_poses"]
    return {"overlap_psnr": round(result["psnr_overlap_mean"], 2),
            "fitted_albedo_alone": round(result["fitted_albedo_alone"]["psnr_overlap_mean"], 2)}


def picture(fit, sequence, scale, path):
    truth = true_hand(sequence)
    _, appearance, files = load_avatar(fit)
    linear = colour_model.is_linear(files.description.get("light", {}))
    truth_model = HandModel(truth.data)
    scaled = Appearance((appearance.albedo * torch.tensor(scale, dtype=torch.float32).view(3, 1, 1)).clamp(0, 1))
    poses, rows = novel_poses(truth.data.side), []
    for name in PICTURE_POSES:
        row = []
        for azimuth, elevation in VIEWS.values():
            (true_rgb, _), (worn_rgb, _) = render_posed([(truth_model, Appearance(truth.albedo)), (truth_model, scaled)],
                                                        truth_model, poses[name], azimuth, elevation, size=PICTURE_SIZE,
                                                        linear=linear)
            a, b = true_rgb[0].numpy(), worn_rgb[0].numpy()
            error = np.clip(np.abs(a - b).mean(-1) * 4, 0, 1)
            heat = cv2.applyColorMap(np.uint8(error * 255), cv2.COLORMAP_INFERNO)[..., ::-1] / 255
            row += [a, b, heat]
        rows.append(np.concatenate(row, 1))
    write_png(path, np.round(np.clip(np.concatenate(rows, 0), 0, 1) * 255).astype(np.uint8))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--band", type=float, default=3.0, help="texels from the tone boundary (default 3)")
    parser.add_argument("--broad", default=str(BROAD_TEXELS),
                        help="the broad tones' Gaussian sigmas, texels of a 512 texture, comma-separated (default 3): "
                             "the truth's broad tones at each; at the first, also split by how squarely the clip saw "
                             "a texel and by the truth's tone")
    parser.add_argument("--picture", type=Path)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    fitted = seq.read_rgb(args.fit / av.ALBEDO_FILE).astype(np.float64) / 255
    truth = albedo_truth(args.sequence, fitted.shape[0], "cpu", args.fit)
    shown, visible = truth.image, truth.visible
    problem, _ = problem_at(args.fit, args.sequence, None)
    decided = decided_texels(problem.at_resolution(problem.settings.solve_resolution)).cpu().numpy()
    scale = best_scale(fitted[visible], shown[visible])
    squared = np.square(fitted * scale - shown).mean(-1)
    band = tone_boundary_distance(shown, visible) < args.band
    total = squared[visible].sum()
    split = {}
    for name, region in (("band_decided", band & decided), ("band_filled", band & ~decided),
                         ("rest_decided", ~band & decided), ("rest_filled", ~band & ~decided)):
        region = region & visible
        split[name] = {"texel_share": round(float(region.sum() / visible.sum()), 3),
                       "error_share": round(float(squared[region].sum() / total), 3),
                       "rmse": round(float(np.sqrt(squared[region].mean())), 4) if region.any() else None}
    true_at_fit_brightness = shown / scale
    figures = {"fit": str(args.fit), "band_texels": args.band, "albedo_psnr_scaled":
               round(float(10 * np.log10(1 / squared[visible].mean())), 2), "error_split": split,
               "signed_profile": signed_profile(fitted * scale, shown, visible),
               "new_poses": {"as_fitted": new_pose_figures(args.fit, args.sequence, fitted)}}
    for name, region in (("true_in_the_band_shown", band & visible), ("true_in_the_rest_shown", ~band & visible),
                         ("true_where_never_shown", ~visible)):
        albedo = np.where(region[..., None], true_at_fit_brightness, fitted)
        figures["new_poses"][name] = new_pose_figures(args.fit, args.sequence, albedo)
    squarely_seen = texel_trust(problem.at_resolution(problem.settings.solve_resolution)).cpu().numpy() >= 0.5
    dark = shown.mean(-1) < tone_cut(shown.mean(-1)[visible])
    for number, texels in enumerate(float(value) for value in args.broad.split(",")):
        sigma = texels * fitted.shape[0] / 512
        broad = lambda image: shown_blur(image, visible, sigma)  # noqa: E731
        fitted_broad, true_broad = broad(fitted), broad(true_at_fit_brightness)
        suffix = "" if texels == BROAD_TEXELS else f"_sigma{texels:g}"
        cases = [("true_broad_tones", visible, true_broad + fitted - fitted_broad),
                 ("true_detail", visible, fitted_broad + true_at_fit_brightness - true_broad)]
        if number == 0:   # where the broad tones' error lies: seen squarely or edge-on, the dark tone or the light
            tones = true_broad + fitted - fitted_broad
            cases += [("true_broad_tones_squarely_seen", visible & squarely_seen, tones),
                      ("true_broad_tones_edge_on", visible & ~squarely_seen, tones),
                      ("true_broad_tones_dark_tone", visible & dark, tones),
                      ("true_broad_tones_light_tone", visible & ~dark, tones)]
        for name, region, albedo in cases:
            figures["new_poses"][name + suffix] = new_pose_figures(args.fit, args.sequence,
                                                                   np.where(region[..., None], albedo, fitted))
    figures["texel_shares"] = {"squarely_seen": round(float((visible & squarely_seen).sum() / visible.sum()), 3),
                               "dark_tone": round(float((visible & dark).sum() / visible.sum()), 3)}
    if args.picture:
        picture(args.fit, args.sequence, scale, args.picture)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
