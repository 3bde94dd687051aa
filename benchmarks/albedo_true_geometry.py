"""Benchmark: how much of the albedo's error on a synthetic clip is the fitted geometry's.

    .venv/bin/python benchmarks/albedo_true_geometry.py FIT SEQ [--resolution 448] [--true-light] [--falloff]
        [--no-lobe] [--cases "true geometry,fitted geometry"]

The fit's albedo solve (fit/albedo_solve.py, reweighted) is run again on the clip's own frames
with the light, exposure and room light as fitted, four times, the hand's surface in each frame
taken from:
    fitted geometry             the fit's own shape and poses (what the fit does)
    true geometry               the clip's ground truth (gt.npz: shape, personal offsets, poses)
    true poses, fitted shape    the fitted rest surface skinned with the true poses
    fitted poses, true shape    the true rest surface skinned with the fitted poses
The frames the fit left off their silhouettes (IoU under 0.8, as lost_frames rules) are left out
of every solve; the room light's occlusion is drawn as the finished fit draws it. `--true-light`
puts the light at the clip's own, with its size (bench_albedo_pose_polish.put_light_at_truth),
`--falloff` makes it fall off with the square of the distance (renderer.Light.falloff),
`--no-lobe` leaves the fit's specular lobe out (a clip rendered with matte skin), `--cases` picks
the cases. Printed per case, one JSON line: the silhouettes' IoU against the masks, the
albedo's sharpness ratio and MAE against the truth in the visible UV area (as albedo_ceiling.py),
and the new-pose PSNR in the overlap of the avatar wearing that albedo and of the true shape
wearing it (as new_pose_limits.py). `--per-frame` adds each case's IoU per fitted frame and the
frames' L1 in the compared pixels rendered with that case's solved albedo (which poses the energy
prefers, each with its best albedo), and, for the fitted poses, each frame's joint error
(Procrustes-aligned, mm) and how much farther from the camera than the truth the fitted keypoints
stand (mm, their mean depth).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from albedo_ceiling import problem_at, scores  # noqa: E402
from bench_albedo_pose_polish import put_light_at_truth  # noqa: E402
from new_pose_limits import new_pose_figures  # noqa: E402
from pipeline.evaluate.albedo import albedo_truth  # noqa: E402
from pipeline.evaluate.fidelity import true_hand  # noqa: E402
from pipeline.evaluate.poses import PoseScorer  # noqa: E402
from pipeline.fit import albedo_solve  # noqa: E402
from pipeline.fit.lost_frames import LOST_IOU  # noqa: E402
from pipeline.formats import sequence_folder as seq  # noqa: E402
from pipeline.handmodel.lbs import HandModel  # noqa: E402
from pipeline.render.renderer import render  # noqa: E402


CASES = ("fitted geometry", "true geometry", "true poses, fitted shape", "fitted poses, true shape")


def geometries(problem, sequence):
    """{case: posed(batch) -> (vertices, keypoints)} for the four cases of the module's docstring."""
    avatar = problem.avatar
    info = seq.read_sequence_info(sequence)
    gt = seq.read_ground_truth(Path(sequence) / info.ground_truth)
    true_model = HandModel(true_hand(sequence).data)
    frames = np.asarray(problem.frames)

    def true_pose(batch):
        chosen = frames[batch.cpu().numpy()]
        return [torch.as_tensor(array[chosen], dtype=torch.float32) for array in (gt.pose, gt.global_orient, gt.transl)]

    def fitted_pose(batch):
        return avatar.pose[batch] * avatar.pose_mask, avatar.global_orient[batch], avatar.transl[batch]

    def on_true_shape(pose_of):
        def posed(batch):
            pose, orient, transl = pose_of(batch)
            out = true_model(pose=pose, global_orient=orient, transl=transl)
            return out.vertices, out.keypoints
        return posed

    def on_fitted_shape(pose_of):
        def posed(batch):
            pose, orient, transl = pose_of(batch)
            out = avatar.model(avatar.betas, pose, orient, transl, rest_vertices=avatar.displaced_rest())
            return out.vertices, out.keypoints
        return posed

    return {"fitted geometry": on_fitted_shape(fitted_pose), "true geometry": on_true_shape(true_pose),
            "true poses, fitted shape": on_fitted_shape(true_pose),
            "fitted poses, true shape": on_true_shape(fitted_pose)}


def silhouette_ious(problem, posed, batch_size=6):
    clip, ious = problem.clip, []
    for batch in torch.arange(len(problem.frames)).split(batch_size):
        vertices, _ = posed(batch)
        alpha = render(vertices, problem.avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("alpha",))["alpha"]
        drawn, mask = alpha[..., 0] > 0.5, clip.masks[batch][..., 0] > 0.5
        ious += ((drawn & mask).sum((1, 2)).float() / (drawn | mask).sum((1, 2)).clamp(min=1).float()).tolist()
    return np.asarray(ious)


def frame_l1(problem, posed, shadows, batch_size=4):
    """(F,) mean absolute difference in each frame's compared pixels between the frame and the
    avatar, as it stands, posed by `posed`."""
    avatar, clip, errors = problem.avatar, problem.clip, []
    for batch in torch.arange(len(problem.frames)).split(batch_size):
        vertices, _ = posed(batch)
        rgb = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("rgb",),
                     appearance=avatar.appearance(), light=avatar.light(shadows, batch, vertices))["rgb"]
        if problem.exposure_on:
            rgb = rgb * avatar.exposure_gain(batch)
        difference = (rgb - clip.images[batch]).abs().mean(-1)
        errors += [float(d[pixels].mean()) for d, pixels in zip(difference, problem.compared_pixels(batch))]
    return np.asarray(errors)


def pose_errors(problem, sequence):
    """Per fitted frame: the joints' error after a Procrustes alignment (mm) and the fitted
    keypoints' mean depth minus the true keypoints' (mm; positive: too far from the camera)."""
    scorer = PoseScorer(sequence)
    frames = np.asarray(problem.frames)
    reference, _ = scorer.truth(frames)
    errors = scorer.avatar_errors(problem.avatar, frames, reference)["joints"]
    avatar = problem.avatar
    fitted = scorer.model(avatar.betas.double(), (avatar.pose * avatar.pose_mask).double(),
                          avatar.global_orient.double(), avatar.transl.double()).keypoints[:, :21]
    depth = (fitted[..., 2] - reference["joints"][..., 2].to(fitted)).mean(-1) * 1000
    return {"joints_procrustes_mm": np.round(errors["procrustes_mm"], 2).tolist(),
            "depth_error_mm": depth.round(decimals=1).tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit")
    parser.add_argument("sequence")
    parser.add_argument("--resolution", type=int, default=448, help="working resolution of the solve (0: the fit's own)")
    parser.add_argument("--per-frame", action="store_true", help="per-frame IoU, L1, joint error and depth error")
    parser.add_argument("--true-light", action="store_true", help="the light at the clip's own, with its size")
    parser.add_argument("--falloff", action="store_true", help="the light falls off with the square of the distance")
    parser.add_argument("--no-lobe", action="store_true", help="leave the fit's specular lobe out (a matte clip)")
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: " + ", ".join(CASES))
    args = parser.parse_args(argv)
    torch.set_grad_enabled(False)
    problem, shadows = problem_at(args.fit, args.sequence, args.resolution)
    truth = albedo_truth(args.sequence, problem.avatar.albedo.shape[-1], "cpu", args.fit)
    kept, fitted_albedo = None, problem.avatar.albedo.detach().clone()
    problem.avatar.occlusion = problem.settings.occlusion_drawn      # as the finished fit shades
    problem.avatar.light_falloff = args.falloff
    if args.true_light:
        put_light_at_truth(problem.avatar, args.sequence)
    if args.no_lobe:
        problem.avatar.switch_specular(False)
    for case, posed in geometries(problem, args.sequence).items():
        if case not in args.cases.split(","):
            continue
        ious = silhouette_ious(problem, posed)
        if kept is None:                      # the fitted geometry's: the frames the fit keeps
            kept = [int(i) for i in np.flatnonzero(ious >= LOST_IOU)]
        problem.avatar.posed = posed
        albedo = albedo_solve.solved_albedo(problem, shadows, frames=kept)[0]
        figures = new_pose_figures(args.fit, args.sequence, albedo.permute(1, 2, 0).numpy())
        per_frame = {}
        if args.per_frame:
            problem.avatar.albedo.data.copy_(albedo)
            per_frame = {"iou": ious.round(3).tolist(), "l1": frame_l1(problem, posed, shadows).round(4).tolist()}
            problem.avatar.albedo.data.copy_(fitted_albedo)        # each case's solve starts from the fit's albedo
        if args.per_frame and case == "fitted geometry":
            per_frame.update(pose_errors(problem, args.sequence))
        print(json.dumps({"case": case, "iou_mean": round(float(ious.mean()), 4), "iou_min": round(float(ious.min()), 4),
                          "frames_solved": len(kept), **scores(albedo, truth), **figures, **per_frame}), flush=True)


if __name__ == "__main__":
    main()
