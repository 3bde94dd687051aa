"""Evaluation of a finished fit (method_facts.md, "Evaluation"):

    held out   frames the fit never saw (fit(..., hold_out_every=N), held_out.py): the appearance
               and shape stay frozen, only per-frame pose and translation and the light are fitted
               to them on the fit's own energy; then PSNR and L1 in the mask, MS-SSIM and
               silhouette IoU, per frame and mean (outputs.evaluate)
    albedo     the fitted albedo.png against the sequence's gt_albedo.png in the visible UV area
               (texels seen in at least one frame), raw and after the best per-channel scale
    poses      Procrustes-aligned joint and vertex errors (mm) of init.npz and of the fit against
               gt.npz

`harp evaluate FIT SEQUENCE` runs what applies and writes FIT/evaluation.json. Colours: both
albedo images hold 8-bit display values in [0, 1]. The fit treats the 8-bit frames as linear,
so its albedo lives in the same value space as the sRGB-encoded gt_albedo.png, up to the factor
that albedo and light intensity trade (hence the scaled figures).
"""
from __future__ import annotations

import dataclasses
import json
import math
import types
from pathlib import Path

import cv2
import numpy as np
import torch

from .. import metrics
from ..formats import avatar_folder as av
from ..formats import sequence_folder as seq
from ..formats.initial_estimate import read_initial_estimate
from ..handmodel.lbs import HandModel, load_model_data
from ..handmodel.uv_atlas import uv_mask as atlas_mask
from ..render.antialias import edge_topology
from ..render.interpolate import fragments, interpolate
from ..render.rasterize import rasterize
from ..render.renderer import RenderMesh
from .avatar import Avatar
from .clip_data import load_clip
from .energy import batch_energy
from .fitting import CHECKPOINT_FILE
from .held_out import REPORT_KEY
from .outputs import REPORT_FILE, evaluate, render_all
from .perceptual import perceptual_term
from .settings import WEIGHTS, Stage

EVALUATION_FILE = "evaluation.json"
ALBEDO_PICTURE = "albedo_comparison.png"
HELD_OUT_TERMS = ("silhouette", "keypoint_anchor", "photometric", "perceptual")
FROZEN = ("betas", "displacement", "albedo", "normal_map")     # taken from the fit, never changed
LIGHT = ("light_position", "ambient_logit")                      # taken from the fit, then fitted
PER_FRAME = ("global_orient", "transl", "pose")                   # from init.npz, then fitted


class EvaluationError(ValueError):
    """The fit or the sequence cannot be evaluated (one-line message)."""


def _device(device):
    return device or ("cuda" if torch.cuda.is_available() else "cpu")


def read_report(fit_folder):
    """report.json of a finished fit."""
    path = Path(fit_folder) / REPORT_FILE
    if not path.is_file():
        raise EvaluationError(f"not a finished fit (no {REPORT_FILE}): {Path(fit_folder)}")
    return json.loads(path.read_text())


def load_fit(fit_folder, device=None):
    """(checkpoint dict, report dict) of a finished fit folder."""
    folder = Path(fit_folder)
    report = read_report(folder)
    if not (folder / CHECKPOINT_FILE).is_file():
        raise EvaluationError(f"the fit in {folder} has no {CHECKPOINT_FILE}")
    return torch.load(folder / CHECKPOINT_FILE, map_location=_device(device), weights_only=False), report


def fitted_avatar(fit_folder, sequence, device=None):
    """The fit's Avatar (its frames, every parameter as in checkpoint.pt) and the report."""
    device = _device(device)
    saved, report = load_fit(fit_folder, device)
    initial = read_initial_estimate(sequence)
    model = HandModel.load(initial.mode, initial.side, subdivided=True, device=device)
    avatar = Avatar(model, initial, np.asarray(report["frames"]), saved["avatar"]["albedo"].shape[-1])
    avatar.load_state_dict(saved["avatar"])
    return avatar, report


# ----------------------------------------------------------------------------- held-out frames

@dataclasses.dataclass
class HeldOutResult:
    frames: np.ndarray        # (K,) sequence frame indices
    metrics: dict             # outputs.evaluate after fitting pose and light (+ silhouette_iou_mean)
    metrics_before: dict      # the same at the initial estimate with the fit's light
    loss_before: float        # held-out energy (HELD_OUT_TERMS, the fit's weights) over all K frames
    loss_after: float
    history: list             # per step: loss and terms before the step's update
    events: list
    shadows: bool
    avatar: Avatar            # its per-frame parameters are the held-out frames'

    def to_json(self):
        return {"frames": self.frames.tolist(), "steps": len(self.history), "terms": list(HELD_OUT_TERMS),
                "loss_before": self.loss_before, "loss_after": self.loss_after,
                "loss_history": [entry["loss"] for entry in self.history], "shadows": self.shadows,
                "events": self.events, "metrics": self.metrics, "metrics_before": self.metrics_before}


def evaluate_held_out(fit_folder, sequence, frames=None, steps=100, device=None):
    """Fit pose, translation and light to frames the fit left out, appearance and shape frozen.

    The per-frame parameters start from init.npz; shape, displacements, albedo and normal map
    come from the fit's checkpoint and are not optimised; the light starts from the fit's.
    Adam (the fit's learning rates: geometry for the per-frame parameters, appearance for the
    light) minimises the fit's silhouette, keypoint-anchor, photometric and perceptual terms
    with the fit's weights (batch_energy, the other terms weighted zero); every step sees every
    held-out frame. Self-shadowing is as the fit decided. `frames` default to the report's
    held-out frames."""
    device = _device(device)
    saved, report = load_fit(fit_folder, device)
    frames = np.asarray(report.get(REPORT_KEY, []) if frames is None else frames, dtype=np.int64)
    if steps < 0:
        raise EvaluationError(f"held-out steps must be 0 or more, got {steps}")
    if not len(frames):
        raise EvaluationError(f"the fit in {fit_folder} held out no frames (fit with hold_out_every=N)")
    initial = read_initial_estimate(sequence)
    if frames.min() < 0 or frames.max() >= initial.frame_count:
        raise EvaluationError(f"held-out frames {frames.tolist()} outside the clip's {initial.frame_count} frames")
    settings = saved.get("settings", {})
    model = HandModel.load(initial.mode, initial.side, subdivided=True, device=device)
    fitted = saved["avatar"]
    avatar = Avatar(model, initial, frames, fitted["albedo"].shape[-1])
    with torch.no_grad():
        for name in FROZEN + LIGHT:
            getattr(avatar, name).copy_(fitted[name])
    for name in FROZEN:
        getattr(avatar, name).requires_grad_(False)
    shadows = bool(saved["state"]["shadows"]["on"])
    clip = load_clip(sequence, settings.get("resolution"), frames, device=device)

    index = torch.arange(len(frames), device=device)
    with torch.no_grad():
        rest_reference, initial_keypoints = avatar.posed(index)
    initial_keypoints = initial_keypoints[:, :21]
    topology = edge_topology(avatar.mesh.faces)
    face_pairs = topology.faces[topology.faces[:, 1] >= 0]
    uv_mask = torch.as_tensor(atlas_mask(model.data.uvs, model.data.faces_uv, avatar.albedo.shape[-1]),
                              device=device, dtype=clip.images.dtype)
    _, perceptual = perceptual_term(settings.get("perceptual_weights"), device)
    weights = {**WEIGHTS, **settings.get("weights", {})}
    energy_settings = types.SimpleNamespace(
        weights={name: (value if name in HELD_OUT_TERMS else 0.0) for name, value in weights.items()})
    stage = Stage("held-out", steps, geometry=True, appearance=True)
    generator = torch.Generator().manual_seed(int(settings.get("seed", 0)))
    chunks = index.split(int(settings.get("batch_size", 6)))

    def over_all_frames(backward):
        """Energy over every held-out frame (chunks weighted by size); gradients accumulate."""
        total, terms = 0.0, dict.fromkeys(HELD_OUT_TERMS, 0.0)
        for chunk in chunks:
            loss, parts = batch_energy(avatar, clip, chunk, energy_settings, stage, initial_keypoints,
                                       rest_reference, topology.edges, face_pairs, perceptual, uv_mask, shadows,
                                       generator)
            share = len(chunk) / len(frames)
            if backward and torch.isfinite(loss):
                (loss * share).backward()
            total += float(loss.detach()) * share
            for name in HELD_OUT_TERMS:
                terms[name] += parts.get(name, 0.0) * share
        return total, terms

    with torch.no_grad():
        loss_before, _ = over_all_frames(False)
    metrics_before = _with_means(evaluate(*render_all(avatar, clip, shadows), clip))
    optimised = [getattr(avatar, name) for name in PER_FRAME + LIGHT]
    optimiser = torch.optim.Adam([
        {"params": [getattr(avatar, name) for name in PER_FRAME], "lr": settings.get("lr_geometry", 1e-3)},
        {"params": [getattr(avatar, name) for name in LIGHT], "lr": settings.get("lr_appearance", 1e-2)}])
    history, events = [], []
    for step in range(steps):
        previous = [p.detach().clone() for p in optimised]
        optimiser.zero_grad(set_to_none=True)
        loss, terms = over_all_frames(True)
        if math.isfinite(loss):
            if avatar.pose.grad is not None:
                avatar.pose.grad *= avatar.pose_mask      # the wrist is no joint without a forearm
            optimiser.step()
        if not math.isfinite(loss) or not all(bool(torch.isfinite(p).all()) for p in optimised):
            with torch.no_grad():
                for parameter, value in zip(optimised, previous):
                    parameter.copy_(value)
            events.append(f"non-finite loss at held-out step {step + 1}: stopped there")
            break
        history.append({"step": step + 1, "loss": loss, **terms})
    with torch.no_grad():
        loss_after, _ = over_all_frames(False)
    scores = _with_means(evaluate(*render_all(avatar, clip, shadows), clip))
    return HeldOutResult(frames, scores, metrics_before, loss_before, loss_after, history, events, shadows, avatar)


def _with_means(scores):
    return {**scores, "silhouette_iou_mean": float(np.mean(scores["silhouette_iou"]))}


# ----------------------------------------------------------------------------- albedo

def visible_texels(vertices, mesh: RenderMesh, K, height, width, texture_size, supersample=None, batch_size=4):
    """(T, T) bool image of the UV atlas (row 0 = v 1): texels that hold the UV of a visible
    surface point at some pixel centre of some frame.

    vertices (F, V, 3) camera frame, metres; K (3, 3) for the height x width images. The frames
    are rendered `supersample` times finer (default: at least two samples per texel width) so
    that the seen texels form a solid area, not a sampling pattern."""
    vertices = torch.as_tensor(vertices, dtype=torch.float32)
    device = vertices.device
    supersample = supersample or max(1, math.ceil(2 * texture_size / max(height, width)))
    K = torch.as_tensor(K, dtype=vertices.dtype, device=device).clone()
    K[:2] *= supersample
    faces, uvs, faces_uv = (t.to(device) for t in (mesh.faces, mesh.uvs, mesh.faces_uv))
    seen = torch.zeros(texture_size * texture_size, dtype=torch.bool, device=device)
    for chunk in vertices.split(batch_size):
        rast = rasterize(chunk, faces, K, height * supersample, width * supersample)
        uv = interpolate(uvs.to(chunk.dtype), fragments(chunk, faces, K, rast), faces_uv)
        column = (uv[:, 0] * texture_size).floor().long().clamp(0, texture_size - 1)
        row = ((1 - uv[:, 1]) * texture_size).floor().long().clamp(0, texture_size - 1)
        seen[row * texture_size + column] = True
    return seen.view(texture_size, texture_size).cpu().numpy()


def albedo_error(fitted, truth, visible):
    """Errors of a fitted albedo (H, W, 3) against the true one (H, W, 3), both in [0, 1], over
    the `visible` (H, W) texels: mean absolute error and PSNR (dB, peak 1) as they are, and after
    multiplying the fitted albedo by the per-channel scale that fits the truth best in least
    squares (albedo and light intensity trade off, so the scale is not the fit's to know)."""
    f = np.asarray(fitted, dtype=np.float64)[visible]
    g = np.asarray(truth, dtype=np.float64)[visible]
    if not len(f):
        raise EvaluationError("no visible texels to compare")
    scale = (f * g).sum(0) / np.maximum((f * f).sum(0), 1e-12)

    def errors(difference):
        return float(np.abs(difference).mean()), float(10 * np.log10(1 / max(np.square(difference).mean(), 1e-12)))

    mae, psnr = errors(f - g)
    mae_scaled, psnr_scaled = errors(f * scale - g)
    return {"mae": mae, "psnr": psnr, "scale": scale.tolist(), "mae_scaled": mae_scaled, "psnr_scaled": psnr_scaled,
            "texels": int(len(f))}


def evaluate_albedo(fit_folder, sequence, device=None, picture=True):
    """The fit's albedo.png against the sequence's gt_albedo.png (resized to the fitted size) in
    the visible UV area; visibility from the ground-truth meshes of every frame of the clip
    (gt.npz vertices, else the hand model at the true parameters, else the fitted meshes).
    Writes albedo_comparison.png (fitted | true | error) into the fit folder."""
    device = _device(device)
    folder, sequence = Path(fit_folder), Path(sequence)
    info = seq.read_sequence_info(sequence)
    if not info.albedo or not (sequence / info.albedo).is_file():
        raise EvaluationError(f"the sequence {sequence} has no ground-truth albedo")
    fitted = seq.read_rgb(folder / av.ALBEDO_FILE).astype(np.float64) / 255
    truth = seq.read_rgb(sequence / info.albedo).astype(np.float64) / 255
    size = fitted.shape[0]
    if truth.shape[:2] != fitted.shape[:2]:
        shrink = truth.shape[0] > size
        truth = cv2.resize(truth, fitted.shape[1::-1], interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    vertices, data, source = _visibility_meshes(folder, sequence, info, device)
    mesh = RenderMesh.from_model_data(data, device=device)
    visible = visible_texels(vertices, mesh, info.K, info.height, info.width, size)
    in_atlas = atlas_mask(data.uvs, data.faces_uv, size)
    visible &= in_atlas
    result = {**albedo_error(fitted, truth, visible),
              "visible_fraction_of_uv_area": float(visible.sum() / in_atlas.sum()), "texture_size": size,
              "ground_truth_size": list(seq.png_size(sequence / info.albedo)), "visibility_from": source}
    if picture:
        write_albedo_picture(folder / ALBEDO_PICTURE, fitted, truth, visible)
        result["picture"] = ALBEDO_PICTURE
    return result


def _visibility_meshes(folder, sequence, info, device):
    if info.ground_truth:
        gt = seq.read_ground_truth(sequence / info.ground_truth)
        data = load_model_data(gt.mode, gt.side)
        if gt.vertices is not None:
            return torch.as_tensor(gt.vertices, dtype=torch.float32, device=device), data, "gt.npz vertices"
        model = HandModel.load(gt.mode, gt.side, device=device)
        with torch.no_grad():
            out = model(*(torch.as_tensor(a, device=device) for a in (gt.betas, gt.pose, gt.global_orient, gt.transl)))
        return out.vertices, data, "hand model at the gt.npz parameters"
    avatar, _ = fitted_avatar(folder, sequence, device)
    with torch.no_grad():
        vertices, _ = avatar.posed(torch.arange(avatar.pose.shape[0], device=device))
    return vertices, avatar.model.data, "fitted meshes"


def write_albedo_picture(path, fitted, truth, visible, minimum_size=256):
    """fitted | true | |difference| x4 (mean over channels, colour-mapped); texels outside the
    visible area are dimmed (and black in the error panel)."""
    dim = np.where(visible[..., None], 1.0, 0.35)
    error = np.clip(np.abs(fitted - truth).mean(-1) * 4, 0, 1)
    heat = cv2.applyColorMap(np.round(error * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1] / 255
    heat = heat * visible[..., None]
    panels = np.concatenate([fitted * dim, truth * dim, heat], axis=1)
    zoom = max(1, math.ceil(minimum_size / fitted.shape[0]))
    panels = np.repeat(np.repeat(panels, zoom, axis=0), zoom, axis=1)
    seq.write_png(path, np.round(np.clip(panels, 0, 1) * 255).astype(np.uint8))
    return Path(path)


# ----------------------------------------------------------------------------- poses

POSE_COMPARISON = (
    "joints: the 21 keypoints (MediaPipe order) of the hand model at each estimate's own shape "
    "and pose, against the model at the gt.npz shape and pose (which reproduces gt.npz keypoints3d; "
    "gt_keypoint_check_mm is the largest difference); vertices: the hand model's vertices, no "
    "personal geometry on either side (pose and shape only); surface: the rendered surface, "
    "against gt.npz vertices (with the person's true offsets): the fit's displaced surface at the "
    "unsubdivided vertices, the initial estimate's plain model. procrustes_mm: mean distance after "
    "a per-frame similarity (Procrustes) alignment; camera_mm: in the camera frame, unaligned.")


def point_errors(prediction, target):
    """Per-frame mean distances (mm) between corresponding points (F, N, 3) given in metres:
    after a per-frame Procrustes (similarity) alignment of the prediction, and unaligned."""
    p = torch.as_tensor(prediction, dtype=torch.float64).cpu()
    t = torch.as_tensor(target, dtype=torch.float64).cpu()
    aligned = metrics.procrustes_error(p, t) * 1000
    camera = (p - t).norm(dim=-1).mean(-1) * 1000
    return {"procrustes_mm_mean": float(aligned.mean()), "camera_mm_mean": float(camera.mean()),
            "procrustes_mm": aligned.tolist(), "camera_mm": camera.tolist()}


def base_vertex_index(base, subdivided):
    """(V,) index, in a subdivided model, of each vertex of the model it was made from (the
    subdivision keeps them, reordered, at their exact rest positions)."""
    lookup = {row.tobytes(): i for i, row in enumerate(np.ascontiguousarray(subdivided.vertices))}
    try:
        return np.array([lookup[row.tobytes()] for row in np.ascontiguousarray(base.vertices)])
    except KeyError:
        raise EvaluationError("the fit's model is not a subdivision of the hand model") from None


def _hand(model, betas, pose, global_orient, transl):
    with torch.no_grad():
        out = model(*(torch.as_tensor(np.asarray(a), dtype=torch.float64)
                      for a in (betas, pose, global_orient, transl)))
    return out.keypoints[:, :21], out.vertices


def _estimate_errors(model, params, truth, surface=None):
    joints, vertices = _hand(model, *params)
    result = {"joints": point_errors(joints, truth["joints"])}
    if truth.get("vertices") is not None:
        result["vertices"] = point_errors(vertices, truth["vertices"])
    if truth.get("surface") is not None:
        result["surface"] = point_errors(vertices if surface is None else surface, truth["surface"])
    return result


def evaluate_poses(fit_folder, sequence, device=None, held_out: HeldOutResult | None = None):
    """Joint and vertex errors (mm) of the initial estimate and of the fit against gt.npz, on the
    fit's frames (both on the same frames), and on the held-out frames after their pose fit
    when `held_out` is given. See POSE_COMPARISON for what is compared."""
    sequence = Path(sequence)
    info = seq.read_sequence_info(sequence)
    if not info.ground_truth:
        raise EvaluationError(f"the sequence {sequence} has no ground truth")
    gt = seq.read_ground_truth(sequence / info.ground_truth)
    initial = read_initial_estimate(sequence)
    avatar, report = fitted_avatar(fit_folder, sequence, device)
    model = HandModel.load(initial.mode, initial.side, dtype=torch.float64)
    gt_model = model if (gt.mode, gt.side) == (initial.mode, initial.side) else \
        HandModel.load(gt.mode, gt.side, dtype=torch.float64)
    base_index = base_vertex_index(model.data, avatar.model.data)
    same_model = gt.mode == initial.mode

    def truth(frames):
        joints, vertices = _hand(gt_model, gt.betas, gt.pose[frames], gt.global_orient[frames], gt.transl[frames])
        check = float(np.abs(joints.numpy() - gt.keypoints3d[frames]).max() * 1000)
        surface = gt.vertices[frames] if same_model and gt.vertices is not None else None
        return {"joints": joints, "vertices": vertices if same_model else None, "surface": surface}, check

    def initial_params(frames):
        return initial.betas, initial.pose[frames], initial.global_orient[frames], initial.transl[frames]

    def avatar_errors(fitted, reference):
        with torch.no_grad():
            surface, _ = fitted.posed(torch.arange(fitted.pose.shape[0], device=fitted.pose.device))
            params = [fitted.betas, fitted.pose * fitted.pose_mask, fitted.global_orient, fitted.transl]
        return _estimate_errors(model, [p.detach().cpu().numpy() for p in params], reference,
                                surface[:, base_index].cpu())

    frames = np.asarray(report["frames"])
    reference, check = truth(frames)
    result = {"comparison": POSE_COMPARISON, "frames": frames.tolist(), "gt_keypoint_check_mm": check,
              "initial": _estimate_errors(model, initial_params(frames), reference),
              "fit": avatar_errors(avatar, reference)}
    if held_out is not None:
        reference, check = truth(held_out.frames)
        result["held_out"] = {"frames": held_out.frames.tolist(),
                              "initial": _estimate_errors(model, initial_params(held_out.frames), reference),
                              "fit": avatar_errors(held_out.avatar, reference)}
        result["gt_keypoint_check_mm"] = max(result["gt_keypoint_check_mm"], check)
    return result


# ----------------------------------------------------------------------------- all of it

def evaluate_fit(fit_folder, sequence, held_out_steps=100, device=None):
    """Every evaluation that applies to this fit and sequence: held-out frames if the report
    lists some, albedo if the sequence has gt_albedo.png, poses if it has gt.npz. Writes
    evaluation.json into the fit folder and returns its content."""
    folder, sequence = Path(fit_folder), Path(sequence)
    report = read_report(folder)
    info = seq.validate_sequence_folder(sequence)
    scores = report.get("metrics", {})
    result = {"fit_folder": str(folder), "sequence": str(sequence),
              "fit_frames": {"frames": report.get("frames"), "psnr_mean": scores.get("psnr_mean"),
                             "l1_mean": scores.get("l1_mean"), "ms_ssim_mean": scores.get("ms_ssim_mean"),
                             "silhouette_iou_mean": float(np.mean(scores["silhouette_iou"]))
                             if scores.get("silhouette_iou") else None}}
    held_out = None
    if report.get(REPORT_KEY):
        held_out = evaluate_held_out(folder, sequence, steps=held_out_steps, device=device)
        result["held_out"] = held_out.to_json()
    if info.albedo:
        result["albedo"] = evaluate_albedo(folder, sequence, device=device)
    if info.ground_truth:
        result["poses"] = evaluate_poses(folder, sequence, device=device, held_out=held_out)
    (folder / EVALUATION_FILE).write_text(json.dumps(result, indent=2))
    return result


def summary_lines(result):
    """A few lines of figures from an evaluate_fit result."""
    lines = []

    def images(scores):
        text = f"PSNR {scores['psnr_mean']:.2f} dB, L1 {scores['l1_mean']:.4f}"
        if scores.get("ms_ssim_mean") is not None:
            text += f", MS-SSIM {scores['ms_ssim_mean']:.3f}"
        return text + f", IoU {scores['silhouette_iou_mean']:.3f}"

    if result["fit_frames"].get("psnr_mean") is not None:
        lines.append(f"fitted frames ({len(result['fit_frames']['frames'])}): {images(result['fit_frames'])}")
    if "held_out" in result:
        held = result["held_out"]
        before = held["metrics_before"]
        lines.append(f"held-out frames ({len(held['frames'])}, {held['steps']} pose+light steps): "
                     f"{images(held['metrics'])} (at the initial pose: PSNR {before['psnr_mean']:.2f} dB, "
                     f"IoU {before['silhouette_iou_mean']:.3f}; loss {held['loss_before']:.4f} -> "
                     f"{held['loss_after']:.4f})")
    if "albedo" in result:
        a = result["albedo"]
        scale = ", ".join(f"{s:.2f}" for s in a["scale"])
        lines.append(f"albedo in the visible UV area ({a['visible_fraction_of_uv_area']:.0%} of it): "
                     f"MAE {a['mae']:.4f}, PSNR {a['psnr']:.2f} dB; after per-channel scale ({scale}): "
                     f"MAE {a['mae_scaled']:.4f}, PSNR {a['psnr_scaled']:.2f} dB")
    if "poses" in result:
        poses = result["poses"]
        for label, entry in (("fitted frames", poses), ("held-out frames", poses.get("held_out"))):
            if entry is None:
                continue
            parts = []
            for kind in ("joints", "vertices", "surface"):
                if kind in entry["initial"]:
                    parts.append(f"{kind} {entry['initial'][kind]['procrustes_mm_mean']:.2f} -> "
                                 f"{entry['fit'][kind]['procrustes_mm_mean']:.2f}")
            lines.append(f"pose error, {label} (Procrustes-aligned mm, initial -> fit): {'; '.join(parts)}")
    return lines
