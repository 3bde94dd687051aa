"""The fitted albedo against the true one (synthetic clips): the fitted albedo.png against the
sequence's gt_albedo.png in the visible UV area (texels seen in at least one frame), raw and
after the best per-channel scale, and for skin of two tones how each tone's brightness came out
(tone_contrast).

Colours: both albedo images hold 8-bit display values in [0, 1]. The fit treats the 8-bit
frames as linear, so its albedo lives in the same value space as the sRGB-encoded
gt_albedo.png, up to the factor that albedo and light intensity trade (hence the scaled
figures).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import torch

from ..fit.problem import default_device
from ..formats import avatar_folder as av
from ..formats import sequence_folder as seq
from ..handmodel.lbs import HandModel, load_model_data
from ..handmodel.uv_atlas import uv_mask as atlas_mask
from ..render.renderer import RenderMesh
from ..render.texel_visibility import visible_texels
from .finished_fit import EvaluationError, fitted_avatar, posed_surfaces

ALBEDO_PICTURE = "albedo_comparison.png"


def albedo_error(fitted, truth, visible):
    """Errors of a fitted albedo (H, W, 3) against the true one (H, W, 3), both in [0, 1], over
    the `visible` (H, W) texels: mean absolute error and PSNR (dB, peak 1) as they are, and after
    multiplying the fitted albedo by the per-channel scale that fits the truth best in least
    squares (albedo and light intensity trade off, so the scale is not the fit's to know)."""
    f = np.asarray(fitted, dtype=np.float64)[visible]
    g = np.asarray(truth, dtype=np.float64)[visible]
    if not len(f):
        raise EvaluationError("no visible texels to compare")
    scale = best_scale(f, g)

    def errors(difference):
        return float(np.abs(difference).mean()), float(10 * np.log10(1 / max(np.square(difference).mean(), 1e-12)))

    mae, psnr = errors(f - g)
    mae_scaled, psnr_scaled = errors(f * scale - g)
    return {"mae": mae, "psnr": psnr, "scale": scale.tolist(), "mae_scaled": mae_scaled, "psnr_scaled": psnr_scaled,
            "texels": int(len(f)), "tones": tone_contrast(f, g)}


def best_scale(fitted, truth):
    """(3,) the per-channel factor that brings fitted colours (N, 3) nearest the true ones in least
    squares."""
    return (fitted * truth).sum(0) / np.maximum((fitted * fitted).sum(0), 1e-12)


MIN_TONE_SHARE = 0.05     # of the visible texels each tone needs for tone_contrast to compare them
MIN_TONE_STEP = 1.5       # and how much brighter the light tone must be than the dark one (medians)


def tone_cut(brightness):
    """The brightness that splits skin of two tones (light palm, dark back): half-way between the
    10th and 90th percentiles of `brightness` (of the texels compared)."""
    return (np.percentile(brightness, 10) + np.percentile(brightness, 90)) / 2


def tone_contrast(fitted, truth):
    """How the fitted albedo gets the hand's light and dark skin (a palm and the back of a dark
    hand) against each other, from fitted and true colours (N, 3) of the same texels: the truth's
    texels split at tone_cut of their brightness; per tone the
    median of fitted over true brightness (mean of the channels); `contrast` the dark tone's over
    the light tone's (1: right; light and albedo trade only a common factor, so this is the
    fit's error); `psnr_scaled_per_tone` the PSNR after the best per-channel scale of each tone
    (what the right contrast would give). None for skin of one tone: either tone under
    MIN_TONE_SHARE of the texels, or the light one less than MIN_TONE_STEP times as bright."""
    brightness = truth.mean(1)
    dark = brightness < tone_cut(brightness)
    if min(dark.mean(), 1 - dark.mean()) < MIN_TONE_SHARE or \
            np.median(brightness[~dark]) < MIN_TONE_STEP * np.median(brightness[dark]):
        return None
    ratios = {}
    scaled = np.empty_like(fitted)
    for name, tone in (("dark", dark), ("light", ~dark)):
        ratios[name] = float(np.median(fitted[tone].mean(1) / np.maximum(brightness[tone], 1e-3)))
        scaled[tone] = fitted[tone] * best_scale(fitted[tone], truth[tone])
    return {"dark": ratios["dark"], "light": ratios["light"], "contrast": ratios["dark"] / ratios["light"],
            "dark_share": float(dark.mean()),
            "psnr_scaled_per_tone": float(10 * np.log10(1 / max(np.square(scaled - truth).mean(), 1e-12)))}


@dataclasses.dataclass
class AlbedoTruth:
    """The true albedo of a synthetic sequence at a texture size, and which texels the clip shows."""

    image: np.ndarray             # (T, T, 3) gt_albedo.png resized to T, values in [0, 1]
    visible: np.ndarray           # (T, T) bool: seen in some frame, inside the UV charts
    visible_fraction: float       # of the UV charts' area
    source: str                   # what the visibility was computed from
    ground_truth_size: list       # gt_albedo.png's own [width, height]


def texture_at(image, size):
    """An (H, H, C) texture at `size` x `size` texels: area-averaged where it shrinks, bilinear where
    it grows (the truth is compared at the fitted albedo's size, and albedos of two sizes at one)."""
    if image.shape[:2] == (size, size):
        return image
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA if image.shape[0] > size else cv2.INTER_LINEAR)


def albedo_truth(sequence, size, device=None, fit_folder=None) -> AlbedoTruth:
    """gt_albedo.png at `size` texels and the visible UV area: texels holding a surface point
    seen at a pixel centre of some frame of the clip, from the ground-truth meshes (gt.npz
    vertices, else the hand model at the true parameters, else the fitted meshes of
    `fit_folder`)."""
    device = default_device(device)
    sequence = Path(sequence)
    info = seq.read_sequence_info(sequence)
    if not info.albedo or not (sequence / info.albedo).is_file():
        raise EvaluationError(f"the sequence {sequence} has no ground-truth albedo")
    truth = texture_at(seq.read_rgb(sequence / info.albedo).astype(np.float64) / 255, size)
    vertices, K, data, source = _visibility_meshes(fit_folder, sequence, info, device)
    mesh = RenderMesh.from_model_data(data, device=device)
    visible = visible_texels(vertices, mesh, K, info.height, info.width, size)
    in_atlas = atlas_mask(data.uvs, data.faces_uv, size)
    visible &= in_atlas
    return AlbedoTruth(truth, visible, float(visible.sum() / in_atlas.sum()), source,
                       list(seq.png_size(sequence / info.albedo)))


def evaluate_albedo(fit_folder, sequence, device=None, picture=True):
    """The fit's albedo.png against the sequence's gt_albedo.png (resized to the fitted size) in
    the visible UV area (albedo_truth). Writes albedo_comparison.png (fitted | true | error)
    into the fit folder."""
    folder = Path(fit_folder)
    fitted = seq.read_rgb(folder / av.ALBEDO_FILE).astype(np.float64) / 255
    size = fitted.shape[0]
    truth = albedo_truth(sequence, size, device, folder)
    result = {**albedo_error(fitted, truth.image, truth.visible), "visible_fraction_of_uv_area": truth.visible_fraction,
              "texture_size": size, "ground_truth_size": truth.ground_truth_size, "visibility_from": truth.source}
    if picture:
        write_albedo_picture(folder / ALBEDO_PICTURE, fitted, truth.image, truth.visible)
        result["picture"] = ALBEDO_PICTURE
    return result


def _visibility_meshes(folder, sequence, info, device):
    """(vertices (F, V, 3), their frames' K (F, 3, 3), model data, where they came from)."""
    frame_K = info.frame_K()
    if info.ground_truth:
        gt = seq.read_ground_truth(sequence / info.ground_truth)
        data = load_model_data(gt.mode, gt.side)
        if gt.vertices is not None:
            return torch.as_tensor(gt.vertices, dtype=torch.float32, device=device), frame_K, data, "gt.npz vertices"
        model = HandModel.load(gt.mode, gt.side, device=device)
        with torch.no_grad():
            out = model(*(torch.as_tensor(a, device=device) for a in (gt.betas, gt.pose, gt.global_orient, gt.transl)))
        return out.vertices, frame_K, data, "hand model at the gt.npz parameters"
    if folder is None:
        raise EvaluationError(f"the sequence {sequence} has no ground truth to tell the visible texels")
    avatar, report = fitted_avatar(folder, sequence, device)
    return posed_surfaces(avatar), frame_K[np.asarray(report["frames"])], avatar.model.data, "fitted meshes"


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
