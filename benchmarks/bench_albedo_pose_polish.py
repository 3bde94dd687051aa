"""Benchmark: the poses polished against the solved albedo, on a finished fit.

    .venv/bin/python benchmarks/bench_albedo_pose_polish.py FIT SEQ OUT [--steps 150] [--move-shape]
        [--light-size] [--texture-size 512] [--solve-sequence SEQ_LARGER --solve-resolution 896] [--checkpoint]
        [--true-light] [--fit-options JSON]

The fit's work after the stages done again on its final state (fitting._after_the_stages: the
albedo and room light solved from the working frames, then the albedo alone from the frames at
`solve_resolution`, then the fill; the frames the final surface leaves off their silhouettes left
out, as the fit leaves them), with `--steps` joint-stage steps (stage_run.StageRun, the
fit's own energy and rates) between the first solve and a second one: poses, light and exposure
move, the solved albedo and normal map stay (and the shape, unless --move-shape). The fit's last
pose steps ran against the albedo its gradient steps had made, blurrier than the solved one; these
see the solved albedo's edges. `--steps 0`: the work after the stages done again, the reference.
`--light-size`: the light's size decided before the first solve, as a fit with `light_size`
"auto" does. `--texture-size`: the albedo and normal map resampled to that size first, so the solves
fill a finer (or coarser) texture. `--solve-sequence`: the same clip imported larger (the same crop,
`harp import-video --size`), from which the frames are read (the working frames shrunk from it, the
finer solve's at `--solve-resolution`, default the fit's). The avatar (the fit folder with the new
albedo.png) goes to OUT and is scored against the synthetic SEQ's true hand (evaluate/fidelity.py),
its sharpness also at 256 texels (each albedo shrunk to 256 against the truth at 256: the figure
that compares texture sizes); one JSON line. `--fit-options`: FitSettings fields that replace the
checkpoint's for the replay (e.g. '{"albedo_openness": "on"}'). `--checkpoint` also writes the replayed avatar into
OUT's checkpoint.pt, which `harp evaluate OUT SEQ` reads (the held-out frames scored on it). The figures of docs/fidelity.md
("The poses polished against the solved albedo") come from this script.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pipeline.evaluate.albedo import albedo_truth, texture_at  # noqa: E402
from pipeline.evaluate.fidelity import evaluate_fidelity, sharpness_ratio  # noqa: E402
from pipeline.evaluate.finished_fit import load_finished_fit  # noqa: E402
from pipeline.fit.albedo_solve import solve_avatar_albedo  # noqa: E402
from pipeline.fit.fitting import solve_and_fill_again  # noqa: E402
from pipeline.fit.checkpoint import CHECKPOINT_FILE, FitState, save_checkpoint  # noqa: E402
from pipeline.fit.light_probe import probe_frames  # noqa: E402
from pipeline.fit.light_size import decide_light_size  # noqa: E402
from pipeline.fit.lost_frames import frames_kept, frames_off_their_silhouettes  # noqa: E402
from pipeline.fit.problem import build_problem  # noqa: E402
from pipeline.fit.schedule import Schedule, StageKind, StageSpec  # noqa: E402
from pipeline.fit.stage_run import StageRun  # noqa: E402
from pipeline.fit.texel_footprint import fitting_texture_size, pixel_footprint  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.formats.png_file import write_png  # noqa: E402

SHAPE = ("betas", "displacement")
COMPARED_SIZE = 256


def replay_problem(fit, sequence, texture_size=None, solve_resolution=None, fit_options=None):
    """The fit's problem over its frames of `sequence`, every parameter as fitted, its textures
    resampled to `texture_size` and its finer solve at `solve_resolution` where given, the settings
    `fit_options` ({field: value}) replaced; its shadows."""
    saved, report = load_finished_fit(fit, "cpu")
    settings = dataclasses.replace(saved.settings, **(fit_options or {}))
    if solve_resolution:
        settings = dataclasses.replace(settings, solve_resolution=solve_resolution)
    problem = build_problem(Path(sequence), settings, report["frames"], "cpu", shared=dict(saved.avatar))
    problem.avatar.load_state_dict(saved.avatar)
    if texture_size:
        problem.avatar.resize_textures(texture_size)
    return problem, bool(saved.state.shadows.on)


def put_light_at_truth(avatar, sequence):
    """Move the avatar's point light to the synthetic clip's own (gt.npz's first light, camera frame) and
    give it that light's size: the disc of its square's area seen from the hand's centre (the mean
    of the fitted frames' translations), as an angular radius. Returns (position, that radius in degrees)."""
    info = seq.read_sequence_info(sequence)
    lamp = seq.read_ground_truth(Path(sequence) / info.ground_truth).light["lights"][0]
    position = torch.as_tensor(lamp["position"], dtype=avatar.light_position.dtype)
    distance = float((position - avatar.transl.detach().mean(0).to(position.dtype)).norm())
    radius = math.atan(lamp.get("size_m", 0.0) / math.sqrt(math.pi) / distance)
    with torch.no_grad():
        avatar.light_position.copy_(position)
        avatar.light_angle.fill_(radius)
    return lamp["position"], math.degrees(radius)


def polished(fit, sequence, steps, move_shape=False, seed=0, light_size=False, texture_size=None,
             solve_resolution=None, fit_options=None, true_light=False):
    """The fit's avatar after the work after the stages with `steps` polishing steps (and with
    `light_size`, the light's size decided first, as FitSettings.light_size "auto" does; with
    `texture_size`, `solve_resolution` and `fit_options`, replay_problem's; with `true_light`, the point
    light put at the clip's own and held there, put_light_at_truth); seconds, the light size's decision
    (None without it), {"pixel_footprint", "fitting_texture_size", "solve_px"} of the finer solve's frames."""
    problem, shadows = replay_problem(fit, sequence, texture_size, solve_resolution, fit_options)
    started = time.perf_counter()
    if true_light:
        position, degrees = put_light_at_truth(problem.avatar, sequence)
        print(f"the point light put at the clip's own, {position}, an angular radius of {degrees:.1f} degrees",
              file=sys.stderr)
    problem.avatar.occlusion = problem.settings.occlusion_drawn     # as fitting._after_the_stages draws it
    problem.avatar.measure_occlusion(exact=True)
    painting = frames_kept(frames_off_their_silhouettes(problem), len(problem.frames))   # as the fit leaves out
    decision = None
    if light_size:
        decision = decide_light_size(problem, shadows, probe_frames(len(problem.frames), kept=painting))
    if steps:
        solve_avatar_albedo(problem, shadows, frames=painting)
        kept = problem.frozen
        problem.frozen = tuple(kept) + ("albedo", "normal_map") + (() if move_shape else SHAPE) \
            + (("light_position",) if true_light else ())
        stage = StageSpec(StageKind.JOINT, steps)
        run = StageRun(problem, stage, FitState.fresh(Schedule((stage,)), "on" if shadows else "off"),
                       torch.Generator().manual_seed(seed))
        while run.has_work and not run.finished:
            run.step()
        problem.frozen = kept
        problem.avatar.measure_occlusion(exact=True)
    solve_and_fill_again(problem, shadows, frames=painting)     # the fit's work after the stages, once more
    seconds = time.perf_counter() - started
    seen = problem.at_resolution(problem.settings.solve_resolution)
    footprint = pixel_footprint(seen)
    texels = {"pixel_footprint": footprint, "fitting_texture_size": fitting_texture_size(footprint),
              "solve_px": max(seen.clip.height, seen.clip.width)}
    return problem.avatar, seconds, decision, texels


def write_replayed(avatar, fit, out, checkpoint=False):
    """The fit folder copied to `out` with the replayed `avatar`'s albedo.png, and with `checkpoint` its
    parameters in out's checkpoint.pt (which `harp evaluate OUT SEQ` reads). Returns the (H, W, 3) albedo."""
    shutil.copytree(fit, out, dirs_exist_ok=True)
    albedo = avatar.albedo.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    write_png(Path(out) / av.ALBEDO_FILE, np.round(albedo * 255).astype(np.uint8))
    if checkpoint:
        saved, _ = load_finished_fit(fit, "cpu")
        state = {name: value.detach().clone() for name, value in avatar.state_dict().items()}
        save_checkpoint(Path(out) / CHECKPOINT_FILE, dataclasses.replace(saved, avatar=state))
    return albedo

def sharpness_at(albedo, sequence, size=COMPARED_SIZE):
    """The sharpness ratio of an (H, W, 3) albedo shrunk (or grown) to `size` against the truth at `size`."""
    truth = albedo_truth(sequence, size)
    return sharpness_ratio(texture_at(albedo, size), truth.image, truth.visible)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("out", type=Path, help="where the polished avatar folder is written")
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--move-shape", action="store_true", help="let the shape and displacements move too")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--light-size", action="store_true", help="decide the light's size first (light_size.py)")
    parser.add_argument("--texture-size", type=int, help="resample the textures to this size first")
    parser.add_argument("--solve-sequence", type=Path,
                        help="the same clip imported larger: the frames the solves read (SEQ scores the avatar)")
    parser.add_argument("--solve-resolution", type=int, help="the finer solve's frames (long side, px)")
    parser.add_argument("--checkpoint", action="store_true",
                        help="write OUT's checkpoint.pt with the replayed avatar, so that `harp evaluate OUT SEQ` "
                             "scores its held-out frames")
    parser.add_argument("--true-light", action="store_true",
                        help="the point light put at the synthetic clip's own, with its size, and held there")
    parser.add_argument("--fit-options", type=json.loads, default={},
                        help="FitSettings fields (JSON) replacing the checkpoint's for the replay")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    avatar, seconds, decision, texels = polished(args.fit, args.solve_sequence or args.sequence, args.steps,
                                                 args.move_shape, light_size=args.light_size,
                                                 texture_size=args.texture_size,
                                                 solve_resolution=args.solve_resolution,
                                                 fit_options=args.fit_options, true_light=args.true_light)
    albedo = write_replayed(avatar, args.fit, args.out, args.checkpoint)
    result = evaluate_fidelity(args.out, args.sequence)
    texture, poses = result["texture"], result["new_poses"]
    print(json.dumps({"fit": str(args.fit), "steps": args.steps, "move_shape": args.move_shape,
                      "true_light": args.true_light,
                      "seconds": round(seconds, 1), "light_size": decision, "texture_size": albedo.shape[0],
                      **texels, f"sharpness_at_{COMPARED_SIZE}": round(sharpness_at(albedo, args.sequence), 3),
                      "new_poses_overlap": round(poses["psnr_overlap_mean"], 2),
                      "true_shape_wearing_the_albedo": round(poses["fitted_albedo_alone"]["psnr_overlap_mean"], 2),
                      "at_true_size": round(poses["at_true_size"]["psnr_overlap_mean"], 2) if "at_true_size" in poses else None,
                      "albedo_psnr_scaled": round(texture["psnr_scaled"], 2), "albedo_mae_scaled": round(texture["mae_scaled"], 4),
                      "contrast": round(texture["tones"]["contrast"], 3) if texture.get("tones") else None, "sharpness": round(texture["sharpness_ratio"], 3)}))


if __name__ == "__main__":
    main()
