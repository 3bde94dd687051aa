"""What a finished fit writes: the avatar folder, report.json with metrics, a picture grid of
input / render / difference, and an overlay video."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from .. import metrics
from ..formats import avatar_folder as av
from ..formats import colour_model, environment_light, light_size, specular_lobe
from ..formats.fit_report import HELD_OUT_FRAMES, write_report
from ..render.renderer import render

GRID_FILE = "fit_grid.png"
VIDEO_FILE = "overlay.mp4"


@torch.no_grad()
def render_all(avatar, clip, shadows, exposure=False, batch_size=8, frames=None):
    """Rendered rgb and alpha (F, H, W, C) of every fitted frame (or of `frames`, indices into
    the fitted frames); rgb is composited over the clip's background plates
    (clip_data.background_plates), as a camera would have seen it; with `exposure` the hand's
    colour takes each frame's exposure gain first."""
    rgb, alpha = [], []
    chosen = torch.arange(len(clip.frames), device=clip.images.device) if frames is None else \
        torch.as_tensor(frames, dtype=torch.long, device=clip.images.device)
    for start in range(0, len(chosen), batch_size):
        batch = chosen[start:start + batch_size]
        vertices, _ = avatar.posed(batch)
        plates = clip.backgrounds[batch].to(vertices.dtype)
        images = render(vertices, avatar.mesh, clip.K[batch], clip.height, clip.width, outputs=("rgb", "alpha"),
                        appearance=avatar.appearance(), light=avatar.light(shadows, batch, vertices),
                        background=torch.zeros(3, dtype=vertices.dtype, device=vertices.device) if exposure else plates)
        if exposure:   # over black, the colour is alpha times the hand's: gain it, then composite
            images["rgb"] = images["rgb"] * avatar.exposure_gain(batch) + (1 - images["alpha"]) * plates
        rgb.append(images["rgb"].clamp(max=1.0))     # the camera clips at white
        alpha.append(images["alpha"])
    return torch.cat(rgb), torch.cat(alpha)


def score_renders(problem, shadows):
    """(rgb, alpha, image_scores) of the problem's avatar in every fitted frame, rendered as the
    fit sees them (exposure gains, silhouette weights)."""
    rgb, alpha = render_all(problem.avatar, problem.clip, shadows, problem.exposure_on)
    return rgb, alpha, image_scores(rgb, alpha, problem.clip, problem.silhouette_weight)


def masked_l1(problem, shadows, frames):
    """Mean L1 inside the masks (as image_scores counts it) of the problem's avatar rendered as
    the fit sees it in `frames` (indices into the fitted frames), with self-shadowing or without."""
    frames = torch.as_tensor(frames, dtype=torch.long, device=problem.clip.images.device)
    rgb, _ = render_all(problem.avatar, problem.clip, shadows, problem.exposure_on, frames=frames)
    masks = problem.clip.masks[frames]
    if problem.silhouette_weight is not None:
        masks = masks * problem.silhouette_weight[frames]
    return float(_frame_l1s(rgb * masks, problem.clip.images[frames] * masks, masks).mean())


def _frame_l1s(composed, target, masks):
    """(F,) each frame's L1 inside its mask."""
    return torch.stack([metrics.l1(composed[i:i + 1], target[i:i + 1], masks[i:i + 1]) for i in range(len(composed))])


def image_scores(rgb, alpha, clip, weight=None):
    """Per-frame silhouette IoU and, inside the mask, L1 and PSNR of the render composited over
    the background plate (render_all) against the frame; MS-SSIM on the masked frames.
    A mask pixel the render misses shows the plate there and counts as an error; a silhouette
    edge pixel blends hand and background as the photograph's does. Pixels of zero `weight`
    (F, H, W, 1) (unrecorded, beyond a mask's cut) count in no figure."""
    masks = clip.masks if weight is None else clip.masks * weight
    target = clip.images * masks
    composed = rgb * masks
    iou = metrics.silhouette_iou(alpha if weight is None else alpha * weight, masks)
    l1 = _frame_l1s(composed, target, masks)
    psnr = torch.stack([metrics.psnr(composed[i:i + 1], target[i:i + 1], masks[i:i + 1]) for i in range(len(rgb))])
    result = {"silhouette_iou": iou.tolist(), "l1": l1.tolist(), "psnr": psnr.tolist(),
              "silhouette_iou_min": float(iou.min()), "psnr_mean": float(psnr.mean()),
              "psnr_min": float(psnr.min()), "l1_mean": float(l1.mean()),
              "image_comparison": "render over the background plate, inside the mask"}
    if min(clip.height, clip.width) >= 176:
        # in float32: double precision changed no figure above 1e-5 and took 15x as long (266 s
        # against 17 s for 150 frames at 448 px, where it was most of the work after the stages)
        ms = metrics.ms_ssim(composed.float(), target.float())
        result.update(ms_ssim=ms.tolist(), ms_ssim_mean=float(ms.mean()))
    return result


def metrics_line(scores):
    """One line of a fit's image figures (image_scores' result), for logs."""
    iou = scores["silhouette_iou"]
    return (f"silhouette IoU min {min(iou):.3f} (mean {sum(iou) / len(iou):.3f}), PSNR in the mask "
            f"{scores['psnr_mean']:.1f} dB (min {scores['psnr_min']:.1f}), L1 {scores['l1_mean']:.4f}"
            + (f", MS-SSIM {scores['ms_ssim_mean']:.3f}" if "ms_ssim_mean" in scores else ""))   # >= 176 px only


def write_outputs(out, problem, state, held_out=(), estimate=None, validation_frames=(), elapsed=None):
    """The avatar folder, report.json, fit_grid.png and overlay.mp4 of a finished fit; returns
    the report. `held_out` are the sequence frames left out for evaluation; `estimate` is the
    fit's time estimate and its trace (estimate.FitEstimate.report); `validation_frames` those
    kept out to score the fit as it ran (their checks are in `state.validation`); `elapsed()`
    the seconds the fit has taken so far in this process, the observers' measuring left out
    (report.json's wall_seconds)."""
    out = Path(out)
    start = time.time()
    avatar, clip, settings = problem.avatar, problem.clip, problem.settings
    shadows = bool(state.shadows.on)
    rgb, alpha, scores = score_renders(problem, shadows)
    _write_avatar(out, problem, state, shadows)
    write_grid(out / GRID_FILE, clip, rgb)
    _write_video(out / VIDEO_FILE, clip, rgb)
    last = {}
    for entry in state.history:
        last[entry["stage"]] = entry
    report = {
        "sequence": str(problem.sequence), "frames": clip.frames.tolist(), "preset": settings.preset,
        "schedule": {stage.name: stage.steps for stage in state.schedule},   # the steps in force (a budget's)
        "stage_seconds": dict(zip([stage.name for stage in state.schedule], state.stage_seconds)),
        "total_seconds": state.fit_seconds, "measure_seconds": state.measure_seconds,
        "output_seconds": time.time() - start, "after_stages_seconds": state.after_stages_seconds,
        "final_losses": last, "metrics": scores,
        "shadows": dataclasses.asdict(state.shadows), "events": state.events, "restarted_frames": state.restarted,
        "light_search": state.light_search, "size_anchor": state.size_anchor, "depth_anchor": state.depth_anchor,
        "perceptual_term": problem.perceptual_name, "ambient": avatar.ambient.item(),
        "light_position": avatar.light_position.detach().cpu().tolist(),
        "appearance": "known (frozen)" if problem.known_appearance else "fitted", "texture_fill": state.texture_fill,
        "albedo_solve": state.albedo_solve, "albedo_passes": state.albedo_passes,
        "albedo_solve_left_out": state.solve_left_out,
        "environment": {"requested": settings.environment, "decision": state.environment,
                        "coefficients": environment_light.to_description(avatar.light().environment)},
        "light_size": {"requested": settings.light_size, "decision": state.light_size,
                       "degrees": round(math.degrees(avatar.light_angle.item()), 3)},
        "specular": {"requested": settings.specular, "decision": state.specular,
                     "lobe": specular_lobe.to_description(*(avatar.specular() or (None, None)))},
        "exposure": {"decision": problem.exposure_note,
                     "gain": torch.exp(avatar.exposure.detach()).cpu().tolist() if problem.exposure_on else None},
        "occlusion": {"requested": settings.occlusion, "frame_measurements": avatar.occlusion_measurements,
                      "seconds": avatar.occlusion_seconds},
        "mask_cut_frames": problem.mask_cut_frames,
        "cpu_threads": torch.get_num_threads(), "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
    }
    if estimate is not None:
        report["estimate"] = estimate
    if elapsed is not None:
        report["wall_seconds"] = elapsed()
    if len(held_out):
        report[HELD_OUT_FRAMES] = [int(i) for i in held_out]
    if len(validation_frames):
        report["validation"] = {"frames": [int(i) for i in validation_frames], "checks": state.validation,
                                "best": state.best}
    write_report(out, report)
    return report


def _write_avatar(out, problem, state, shadows):
    avatar, clip, settings = problem.avatar, problem.clip, problem.settings
    model_data = avatar.model.data
    betas = avatar.betas.detach().cpu().numpy().astype(np.float64)
    rig = dataclasses.replace(model_data, vertices=avatar.rest_mesh().cpu().numpy().astype(np.float64),
                              joints=model_data.joints + model_data.joint_shapedirs @ betas,
                              keypoints=model_data.keypoints + model_data.keypoint_shapedirs @ betas,
                              metadata={**model_data.metadata, "betas_baked_in": betas.tolist()})
    normals = torch.nn.functional.normalize(avatar.normal_map.detach(), dim=0).cpu().numpy().transpose(1, 2, 0)
    poses = av.AvatarPoses(*(value.detach().cpu().numpy() for value in
                             (avatar.global_orient, avatar.transl, avatar.pose * avatar.pose_mask)), clip.frames)
    description = {
        "mode": model_data.mode, "side": model_data.side, "betas": betas.tolist(),
        "light": {"position": avatar.light_position.detach().cpu().tolist(), "ambient": avatar.ambient.item(),
                  "shadows": shadows, "environment": environment_light.to_description(avatar.light().environment),
                  specular_lobe.KEY: specular_lobe.to_description(*(avatar.specular() or (None, None))),
                  light_size.KEY: light_size.to_description(avatar.light_angle),
                  colour_model.KEY: settings.colour_model, "occlusion": settings.occlusion_drawn,
                  "falloff": avatar.falloff_reach()},
        "camera": camera_description(clip),
        "footage": {"sequence": str(problem.sequence.resolve()), "fps": clip.info.fps,
                    "frame_count": clip.info.frame_count, "width": clip.info.width, "height": clip.info.height},
        "settings": {k: v for k, v in vars(settings).items() if k != "weights"} | {"weights": settings.weights},
        "stage_seconds": state.stage_seconds, "perceptual_term": problem.perceptual_name,
        "initialisation": problem.initial.source,
    }
    albedo = _to_uint8(avatar.albedo.detach().permute(1, 2, 0))
    av.write_avatar_folder(out, av.AvatarFiles(description, rig, poses, albedo, av.encode_normal_map(normals)))


def camera_description(clip) -> dict:
    """avatar.json's camera: K of the first fitted frame at the working size, and every fitted
    frame's principal point where they differ (a crop that follows the hand)."""
    K = clip.K.cpu().double().numpy()
    entry = {"K": K[0].tolist(), "width": clip.width, "height": clip.height}
    if not np.allclose(K[:, :2, 2], K[0, :2, 2]):
        entry["principal_points"] = K[:, :2, 2].tolist()
    return entry


def _to_uint8(image):
    return (image.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)


def write_grid(path, clip, rgb, columns=6):
    """Rows: input, render over the background plate, |difference| x4, for sampled frames."""
    picks = np.unique(np.linspace(0, len(clip.frames) - 1, min(columns, len(clip.frames))).astype(int))
    rows = [clip.images[picks], rgb[picks], ((rgb - clip.images).abs() * 4)[picks]]
    tiles = [np.concatenate(list(_to_uint8(row)), axis=1) for row in rows]
    cv2.imwrite(str(path), np.concatenate(tiles, axis=0)[:, :, ::-1])


def _write_video(path, clip, rgb, fps=None):
    """Input | render over the background plate, side by side (mp4)."""
    fps = fps or max(1.0, clip.info.fps * len(clip.frames) / max(clip.info.frame_count, 1))
    composite = _to_uint8(rgb)
    inputs = _to_uint8(clip.images)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (2 * clip.width, clip.height))
    for a, b in zip(inputs, composite):
        writer.write(np.concatenate([a, b], axis=1)[:, :, ::-1])
    writer.release()
