"""`harp evaluate FIT SEQUENCE`: every evaluation that applies to a finished fit, written to
FIT/evaluation.json (method_facts.md, "Evaluation"):

    held out   frames the fit never saw: pose and light fitted, appearance frozen (held_out.py)
    albedo     the fitted albedo against gt_albedo.png in the visible UV area (albedo.py)
    poses      Procrustes-aligned joint and vertex errors of init.npz and the fit (poses.py)
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..fit.progress import progress_log
from ..formats import sequence_folder as seq
from ..formats.fit_report import HELD_OUT_FRAMES, read_report
from .albedo import evaluate_albedo
from .fidelity import evaluate_fidelity
from .held_out import KEYPOINT_PROTOCOL_STEPS, evaluate_held_out
from .poses import evaluate_poses

EVALUATION_FILE = "evaluation.json"
HELD_OUT_PICTURE = "held_out_grid.png"


def evaluate_fit(fit_folder, sequence, held_out_steps=300, device=None, novel_poses=False, progress="none",
                 cycles=False):
    """Every evaluation that applies to this fit and sequence: held-out frames if the report
    lists some (and their picture, HELD_OUT_PICTURE), albedo if the sequence has gt_albedo.png,
    poses if it has gt.npz, and with `novel_poses` the avatar against the true hand
    (fidelity.py; `cycles` adds its part against Cycles renders). Writes evaluation.json into the fit folder and returns its content.
    `progress` ("bar", "jsonl", "none") shows the held-out fit's steps and names each part."""
    log = progress_log(progress)
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
    if report.get(HELD_OUT_FRAMES):
        log(f"held-out frames {report[HELD_OUT_FRAMES]}: fitting pose and light from the fitted neighbours' "
            f"poses (at most {held_out_steps} steps), then from the keypoints ({KEYPOINT_PROTOCOL_STEPS} steps)")
        held_out = evaluate_held_out(folder, sequence, steps=held_out_steps, device=device, progress=progress,
                                     picture=folder / HELD_OUT_PICTURE)
        result["held_out"] = held_out.to_json()
        result["held_out_from_keypoints"] = evaluate_held_out(
            folder, sequence, steps=KEYPOINT_PROTOCOL_STEPS, device=device, progress=progress,
            protocol="keypoints").to_json()
    if info.albedo:
        log("albedo against the truth")
        result["albedo"] = evaluate_albedo(folder, sequence, device=device)
    if info.ground_truth:
        log("poses against the truth")
        result["poses"] = evaluate_poses(folder, sequence, device=device, held_out=held_out)
    if novel_poses:
        log("the avatar against the true hand in new poses")
        result["fidelity"] = evaluate_fidelity(folder, sequence, cycles=cycles)
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
    for key, start in (("held_out", "the fitted neighbours' poses"), ("held_out_from_keypoints", "the keypoints")):
        if key in result:
            held = result[key]
            before = held["metrics_before"]
            lines.append(f"held-out frames ({len(held['frames'])}, from {start}, {held['steps']} pose+light steps): "
                         f"{images(held['metrics'])} (at the start: PSNR {before['psnr_mean']:.2f} dB, "
                         f"IoU {before['silhouette_iou_mean']:.3f}; loss {held['loss_before']:.4f} -> "
                         f"{held['loss_after']:.4f})")
    if "albedo" in result:
        a = result["albedo"]
        scale = ", ".join(f"{s:.2f}" for s in a["scale"])
        lines.append(f"albedo in the visible UV area ({a['visible_fraction_of_uv_area']:.0%} of it): "
                     f"MAE {a['mae']:.4f}, PSNR {a['psnr']:.2f} dB; after per-channel scale ({scale}): "
                     f"MAE {a['mae_scaled']:.4f}, PSNR {a['psnr_scaled']:.2f} dB")
        tones = a.get("tones")
        if tones:
            lines.append(f"albedo of dark and light skin ({tones['dark_share']:.0%} dark): fitted over true brightness "
                         f"x{tones['dark']:.2f} and x{tones['light']:.2f}, contrast x{tones['contrast']:.2f} "
                         f"(1: right); each tone scaled on its own: PSNR {tones['psnr_scaled_per_tone']:.2f} dB")
    if "fidelity" in result:
        geometry, poses, texture = (result["fidelity"][k] for k in ("geometry", "new_poses", "texture"))
        lines.append(f"fidelity to the true hand: surface {geometry['surface_mm_mean']:.2f} mm (95%: "
                     f"{geometry['surface_mm_p95']:.2f}), normals {geometry['normal_deg_mean']:.1f} deg, roughness "
                     f"{geometry['roughness_deg'] or float('nan'):.1f} deg; new poses PSNR {poses['psnr_mean']:.1f} dB "
                     f"(overlap {poses['psnr_overlap_mean']:.1f}), SSIM {poses['ssim_mean']:.3f}, IoU "
                     f"{poses['iou_mean']:.3f}; albedo sharpness {texture['sharpness_ratio']:.2f}"
                     + (f" ({texture['sharpness_ratio_scaled']:.2f} at the truth's brightness)"
                        if "sharpness_ratio_scaled" in texture else ""))
        size = geometry.get("apart_from_size")
        if size and "fitted_shape_alone" in poses:
            shape, albedo = poses["fitted_shape_alone"], poses["fitted_albedo_alone"]
            template = geometry["without_personal_detail"]
            fitted_template = template.get("fitted_template", {}).get("surface_mm_mean", float("nan"))
            lines.append(f"what limits it: apart from its size (scale {size['scale']:.3f}) the surface is "
                         f"{size['surface_mm_mean']:.2f} mm off (the true template without its personal offsets: "
                         f"{template['true_template']['surface_mm_mean']:.2f} mm, the avatar's without its "
                         f"displacements: {fitted_template:.2f} mm); in new poses the fitted shape with the true albedo "
                         f"scores PSNR {shape['psnr_mean']:.1f} dB (IoU {shape['iou_mean']:.3f}), the true shape "
                         f"with the fitted albedo {albedo['psnr_mean']:.1f} dB"
                         + (f"; the avatar at the truth's size {poses['at_true_size']['psnr_mean']:.1f} dB (overlap "
                            f"{poses['at_true_size']['psnr_overlap_mean']:.1f})" if "at_true_size" in poses else ""))
        cycles = result["fidelity"].get("cycles")
        if cycles and "unavailable" in cycles:
            lines.append(f"against Cycles: {cycles['unavailable']}")
        elif cycles:
            floor = cycles["renderer_floor"]
            lines.append(f"against Cycles renders of the true hand under the clip's light: PSNR {cycles['psnr_mean']:.1f} "
                         f"dB (overlap {cycles['psnr_overlap_mean']:.1f}), SSIM {cycles['ssim_mean']:.3f}, IoU "
                         f"{cycles['iou_mean']:.3f}; the true hand by our renderer: PSNR {floor['psnr_mean']:.1f} dB, "
                         f"SSIM {floor['ssim_mean']:.3f}")
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
