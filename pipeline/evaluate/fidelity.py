"""Fidelity of an avatar to the true hand (synthetic clips): `harp evaluate AVATAR SEQ
--novel-poses`. Only our generator can give this: the true identity, its rest surface and its
albedo (gt.npz: shape and personal offsets; gt_albedo.png).

    geometry    the fitted rest surface (the avatar's rig.npz) against the true rest surface
                (the shaped template plus the identity's personal offsets), in the model's rest
                frame, over the hand (forearm and wrist cap left out): mean and 95th-percentile
                surface distance (mm, both ways), the angle between their normals at the
                closest points (degrees), and roughness: the mean absolute difference of the
                dihedral angles of corresponding edges (degrees; facets and lumps raise it);
                and the surface distance once the fitted hand is scaled, turned and moved onto
                the truth, with that scale (`apart_from_size`: what the hand's size, which a
                monocular clip barely decides, leaves of the error); and, as references, the
                surface figures of the true template without the personal offsets and of the
                avatar's template without its displacements (`without_personal_detail`)
    new poses   (a) both rendered by our renderer in poses the clip does not contain (fist,
                spread, thumbs-up, pinch and three random poses inside the joint limits) from
                two views (palm and back), under one light: PSNR and SSIM inside the union of
                the two silhouettes and the silhouette IoU (and the PSNR where both silhouettes
                overlap, which leaves the outline out and shows texture and shading alone). The avatar's albedo is first
                multiplied by the per-channel scale that fits the truth best in the visible UV
                area (albedo and light intensity trade off; evaluate/albedo.py), so the figures
                judge shape, pose response and texture, not exposure; the raw PSNR is kept too.
                What limits them: the same figures for the fitted shape with the true albedo
                (`fitted_shape_alone`) and for the true shape with the fitted albedo
                (`fitted_albedo_alone`); and the avatar scaled to the truth's size (`at_true_size`,
                the scale of `apart_from_size`), what the size a monocular clip barely decides
                costs. Shading detail: the fine relief the light shows in
                those renders (the shading normals' departure from their local average, mean
                square over the inner silhouette) of the avatar over the truth's, with and without
                its normal map: near 1 is a physical surface, well above it checkers, facets or
                bumps the true hand lacks, well below it a surface smoother than the hand.
                (b), with `cycles`: the avatar as fitted, under its fitted light, against the
                true hand rendered by Cycles under the clip's own light (cycles_truth.py): what
                a user sees; the true hand by our renderer against the same renders is the floor
    texture     the albedo against the truth in the visible UV area (evaluate/albedo.py), the
                sharpness ratio (gradient energy of the fitted albedo over the truth's, in the
                visible area; also with the albedo at the truth's brightness, the per-channel
                scale applied) and a crop of the most detailed visible region (a tattoo, when the
                identity has one) in the picture

`fidelity.png`: true and fitted side by side in three new poses, and the detail crop.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from .. import metrics
from ..avatar_render import load_avatar, view_orientation
from ..formats import colour_model
from ..formats import hand_model_file as fmt
from ..formats import sequence_folder as seq
from ..handmodel.lbs import HandModel, load_model_data
from ..handmodel.mirror import mirror_axis_angle
from ..handmodel.poses import NAMED_POSES
from ..handmodel.subdivision import subdivide_model_data
from ..render.occlusion import bounce_radiance, hand_lost_light
from ..render.renderer import Appearance, Light, RenderMesh, render
from ..render.shading import vertex_normals
from .albedo import albedo_error, albedo_truth
from .finished_fit import EvaluationError
from .surface_distance import closest_points

FIDELITY_FILE, FIDELITY_PICTURE = "fidelity.json", "fidelity.png"
NAMED = ("fist", "spread", "thumbs_up", "pinch")
RANDOM_POSES, RANDOM_SEED, RANDOM_SPAN = 3, 7, 0.6   # random poses: this share of each joint range about rest
VIEWS = {"palm": (30.0, 10.0), "back": (210.0, 10.0)}   # azimuth, elevation (avatar_render.view_orientation)
SIZE = 256
AMBIENT = 0.6
PICTURE_POSES = ("fist", "thumbs_up", "spread")
HAND_PARTS = [i for i, name in enumerate(fmt.PART_NAMES) if name not in ("forearm", "wrist_cap")]
PSNR_CAP = 100.0
SHADING_DETAIL_SIGMA = 2.0   # pixels at SIZE: the scale below which shading counts as fine relief
SHADING_DETAIL_BORDER = 3    # pixels of the silhouette's rim left out (the outline is not relief)


@dataclasses.dataclass
class TrueHand:
    """The identity of a synthetic sequence on the subdivided model (the fit's topology)."""

    data: fmt.HandModelData          # subdivided; vertices = the true rest surface; betas baked in
    albedo: torch.Tensor             # (3, T, T) gt_albedo in [0, 1]
    template: fmt.HandModelData      # the same without the personal offsets: the shaped template


def true_hand(sequence) -> TrueHand:
    sequence = Path(sequence)
    info = seq.read_sequence_info(sequence)
    if not info.ground_truth or not info.albedo:
        raise EvaluationError(f"the sequence {sequence} has no ground truth (gt.npz and gt_albedo.png)")
    gt = seq.read_ground_truth(sequence / info.ground_truth)
    if gt.personal_offsets is None:
        raise EvaluationError(f"{sequence / info.ground_truth} has no personal offsets (an older synth clip)")
    base = load_model_data(gt.mode, gt.side)
    return TrueHand(identity_on_model(base, gt.betas, gt.personal_offsets),
                    _albedo_tensor(seq.read_rgb(sequence / info.albedo)),
                    identity_on_model(base, gt.betas, np.zeros_like(gt.personal_offsets)))


def identity_on_model(base, betas, offsets):
    """The subdivided HandModelData of a person: the base model shaped by `betas` plus rest
    `offsets` (V, 3), betas baked in (so it is posed with zero betas)."""
    betas = np.asarray(betas, dtype=np.float64)
    person = dataclasses.replace(base, vertices=base.vertices + base.shapedirs @ betas + offsets,
                                 joints=base.joints + base.joint_shapedirs @ betas,
                                 keypoints=base.keypoints + base.keypoint_shapedirs @ betas)
    return subdivide_model_data(person)


def _albedo_tensor(image):
    return torch.as_tensor(np.asarray(image, dtype=np.float32) / 255).permute(2, 0, 1).contiguous()


# ----------------------------------------------------------------------------- geometry

def geometry_errors(fitted: fmt.HandModelData, truth: fmt.HandModelData):
    """Surface distance (mm), normal angle (degrees) and roughness (degrees) of the fitted rest
    surface against the true one, over the hand (see the module docstring)."""
    f_faces, t_faces = _hand_faces(fitted), _hand_faces(truth)
    f_points, t_points = np.unique(f_faces), np.unique(t_faces)
    to_truth, closest, face, bary = closest_points(fitted.vertices[f_points], truth.vertices, t_faces)
    to_fitted, _, _, _ = closest_points(truth.vertices[t_points], fitted.vertices, f_faces)
    distances = np.concatenate([to_truth, to_fitted]) * 1000
    fitted_normals = _normals(fitted.vertices, fitted.faces)[f_points]
    true_normals = _normals(truth.vertices, truth.faces)[t_faces[face]]      # (N, 3 corners, 3)
    interpolated = (bary[..., None] * true_normals).sum(1)
    interpolated /= np.linalg.norm(interpolated, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.clip((fitted_normals * interpolated).sum(1), -1, 1)))
    result = {"surface_mm_mean": float(distances.mean()), "surface_mm_p95": float(np.percentile(distances, 95)),
              "surface_mm_fitted_to_true": float(to_truth.mean() * 1000),
              "surface_mm_true_to_fitted": float(to_fitted.mean() * 1000),
              "normal_deg_mean": float(angles.mean()), "roughness_deg": None}
    if fitted.faces.shape == truth.faces.shape and np.array_equal(fitted.faces, truth.faces):
        result["roughness_deg"] = float(np.abs(_dihedral(fitted.vertices, f_faces) - _dihedral(truth.vertices, f_faces))
                                        .mean())
        result["apart_from_size"] = _error_apart_from_size(fitted, truth, f_points, t_faces, t_points, f_faces)
    return result


def _error_apart_from_size(fitted, truth, f_points, t_faces, t_points, f_faces):
    """The surface distance left once the fitted hand is scaled, turned and moved onto the truth
    (the similarity that fits corresponding hand vertices best), and that scale. A monocular
    clip decides a hand's size only through perspective and the shape prior (a hand twice as
    big twice as far looks the same): this part of the error is what the size leaves."""
    f_vertices, t_vertices = (torch.as_tensor(np.asarray(v, dtype=np.float64)) for v in (fitted.vertices, truth.vertices))
    hand = torch.as_tensor(f_points)
    aligned_hand = metrics.procrustes_align(f_vertices[hand], t_vertices[hand])
    centred = f_vertices[hand] - f_vertices[hand].mean(0)
    scale = float((aligned_hand - aligned_hand.mean(0)).norm() / centred.norm())
    moved = f_vertices.clone()
    moved[hand] = aligned_hand
    moved = moved.numpy()
    to_truth = closest_points(moved[f_points], truth.vertices, t_faces)[0]
    to_fitted = closest_points(truth.vertices[t_points], moved, f_faces)[0]
    distances = np.concatenate([to_truth, to_fitted]) * 1000
    return {"scale": scale, "surface_mm_mean": float(distances.mean()),
            "surface_mm_p95": float(np.percentile(distances, 95))}


def personal_detail(description, truth: TrueHand):
    """How much of the error is the personal shape, which lies mostly below a working pixel: the
    surface figures of the true shaped template without the personal offsets (what a fit that
    found the true size and proportions but no personal detail scores), and of the fitted
    template (the avatar's shape parameters without its displacements: what its displacements
    are measured against)."""
    def summary(data):
        errors = geometry_errors(data, truth.data)
        return {key: errors[key] for key in ("surface_mm_mean", "surface_mm_p95", "normal_deg_mean")}
    result = {"true_template": summary(truth.template)}
    if description.get("betas") is not None:
        base = load_model_data(truth.data.mode, truth.data.side)
        result["fitted_template"] = summary(identity_on_model(base, description["betas"],
                                                              np.zeros_like(base.vertices)))
    return result


def _hand_faces(data):
    corner_parts = data.vertex_parts[data.faces]
    return data.faces[np.isin(corner_parts, HAND_PARTS).all(1)]


def _normals(vertices, faces):
    points = torch.as_tensor(np.asarray(vertices, dtype=np.float64))[None]
    return vertex_normals(points, torch.as_tensor(np.asarray(faces, dtype=np.int64)))[0].numpy()


def _dihedral(vertices, faces):
    """Angle (degrees) between the normals of the two faces of every interior edge, in a fixed
    edge order for a given face list."""
    corners = np.stack([faces, np.roll(faces, -1, 1)], 2).reshape(-1, 2)
    keys = np.sort(corners, 1)
    order = np.lexsort((keys[:, 1], keys[:, 0]))
    keys, owner = keys[order], np.repeat(np.arange(len(faces)), 3)[order]
    pair = np.nonzero((keys[1:] == keys[:-1]).all(1))[0]
    v = np.asarray(vertices, dtype=np.float64)[faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-18)
    cosine = (normals[owner[pair]] * normals[owner[pair + 1]]).sum(1)
    return np.degrees(np.arccos(np.clip(cosine, -1, 1)))


# ----------------------------------------------------------------------------- new poses

def novel_poses(side="right"):
    """{name: (16, 3)} the measure's poses: the named ones and RANDOM_POSES seeded random ones,
    each joint drawn within RANDOM_SPAN of its range on either side of rest (wrist kept still)."""
    limits = load_model_data("hand").joint_limits                      # (16, 3, 2) radians
    rng = np.random.default_rng(RANDOM_SEED)
    poses = {name: NAMED_POSES[name] for name in NAMED}
    for k in range(RANDOM_POSES):
        pose = rng.uniform(limits[..., 0], limits[..., 1]) * RANDOM_SPAN
        pose[0] = 0.0
        poses[f"random{k + 1}"] = pose
    return {name: mirror_axis_angle(pose) if side == "left" else pose for name, pose in poses.items()}


@dataclasses.dataclass
class Framing:
    """Where a new pose is shown: the camera (at the origin, OpenCV frame) and the hand's placement."""
    K: torch.Tensor              # (3, 3)
    global_orient: torch.Tensor  # (1, 3)
    pose: torch.Tensor           # (1, 16, 3)
    shift: torch.Tensor          # (3,) added to the posed model: the hand's box centred at `distance`
    distance: float              # metres from the camera to the hand's box centre
    size: int


def framing(truth_model, pose, azimuth, elevation, size=SIZE) -> Framing:
    """The camera frames the truth's hand (forearm left out) in `pose` seen from a view."""
    orient = view_orientation(azimuth, elevation)[None]
    joint_pose = torch.as_tensor(pose, dtype=torch.float32)[None]
    with torch.no_grad():
        truth = truth_model(pose=joint_pose, global_orient=orient).vertices
    hand = torch.as_tensor(np.isin(truth_model.data.vertex_parts, HAND_PARTS))
    low, high = truth[:, hand].amin(1), truth[:, hand].amax(1)
    focal = 2.0 * size
    distance = focal * (high - low)[0, :2].max().item() / (0.8 * size)
    shift = torch.tensor([0.0, 0.0, distance]) - 0.5 * (low + high)[0]
    K = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    return Framing(K, orient, joint_pose, shift, distance, size)


class ResizedHand:
    """A HandModel whose posed hand is scaled by `scale` about its wrist (keypoint 0): the avatar
    at another size, posed alike (the wrist is the rest frame's origin, so posing a hand scaled
    about it gives the posed hand scaled about the posed wrist)."""

    def __init__(self, model, scale):
        self.model, self.scale, self.data = model, float(scale), model.data

    def __call__(self, **pose):
        out = self.model(**pose)
        wrist = out.keypoints[:, :1]
        return dataclasses.replace(out, **{name: wrist + self.scale * (getattr(out, name) - wrist)
                                           for name in ("vertices", "joints", "keypoints")})


def render_posed(subjects, truth_model, pose, azimuth, elevation, size=SIZE, shading_normals=False, linear=False):
    """[(rgb, alpha) (1, H, W, C)] of each (HandModel, Appearance) in `subjects` in `pose` from a
    view, all placed alike (framing()) and lit by a point light up and left of the camera, shaded
    in linear light or not (the avatar's colour model, formats/colour_model.py); with
    `shading_normals`, (rgb, alpha, shading normal) each."""
    frame = framing(truth_model, pose, azimuth, elevation, size)
    d = frame.distance
    light = Light(torch.tensor([0.3 * d, -0.4 * d, 0.2 * d]), torch.tensor(AMBIENT), linear=linear)
    return render_framed(subjects, frame, light, shading_normals)


def render_framed(subjects, frame: Framing, light, shading_normals=False, occlusion=False):
    """[(rgb, alpha) (1, H, W, C)] of each (HandModel, Appearance) in `subjects` placed by `frame`
    under `light`, over black; with `shading_normals`, (rgb, alpha, shading normal) each; with
    `occlusion`, the room light held back where each hand is in its own way (render/occlusion.py)."""
    images = []
    outputs = ("rgb", "alpha") + (("shading_normal",) if shading_normals else ())
    with torch.no_grad():
        for model, appearance in subjects:
            vertices = model(pose=frame.pose, global_orient=frame.global_orient).vertices + frame.shift
            mesh = RenderMesh.from_model_data(model.data)
            lit = dataclasses.replace(light, occlusion=hand_lost_light(vertices, model.data),
                                      bounce=bounce_radiance(appearance.albedo, light.ambient, light.linear)) \
                if occlusion else light
            out = render(vertices, mesh, frame.K, frame.size, frame.size,
                         outputs=outputs, appearance=appearance, light=lit, background=torch.zeros(3))
            images.append(tuple(out[name] for name in outputs))
    return images


def image_scores(avatar_rgb, avatar_alpha, truth_rgb, truth_alpha):
    """PSNR and SSIM inside the union of the silhouettes, and the silhouette IoU, of one render
    pair ((1, H, W, C) tensors); identical images give PSNR_CAP."""
    union = ((avatar_alpha > 0.5) | (truth_alpha > 0.5)).double()
    both = ((avatar_alpha > 0.5) & (truth_alpha > 0.5)).double()
    a, b = avatar_rgb.double(), truth_rgb.double()
    return {"psnr": _capped_psnr(a, b, union), "ssim": float(metrics.ssim(a, b, union)[0]),
            "iou": float(metrics.silhouette_iou(avatar_alpha, truth_alpha)[0]),
            "psnr_overlap": _capped_psnr(a, b, both)}


def _capped_psnr(a, b, mask):
    """PSNR (dB) inside the mask; identical images give PSNR_CAP."""
    mse = float(((a - b).square() * mask).sum() / (mask.sum() * a.shape[-1]).clamp(min=1))
    return PSNR_CAP if mse <= 10 ** (-PSNR_CAP / 10) else float(10 * np.log10(1 / mse))


def shading_detail(normals, alpha):
    """The fine relief in one render's shading: the mean over the silhouette (less its rim) of
    |n - local average of n|^2, for shading normals (H, W, 3) and alpha (H, W); the average is a
    Gaussian of SHADING_DETAIL_SIGMA pixels taken over the silhouette alone."""
    inside = (np.asarray(alpha) > 0.5).astype(np.float64)
    normals = np.asarray(normals, np.float64) * inside[..., None]
    weight = cv2.GaussianBlur(inside, (0, 0), SHADING_DETAIL_SIGMA)
    average = cv2.GaussianBlur(normals, (0, 0), SHADING_DETAIL_SIGMA) / np.maximum(weight, 1e-9)[..., None]
    kernel = np.ones((2 * SHADING_DETAIL_BORDER + 1,) * 2, np.uint8)
    core = cv2.erode(inside.astype(np.uint8), kernel).astype(bool)
    if not core.any():
        return 0.0
    return float(np.square(normals - average).sum(-1)[core].mean())


# ----------------------------------------------------------------------------- texture

def sharpness_ratio(fitted, truth, visible):
    """Gradient energy (squared differences to the right and below neighbours, both texels
    visible) of the fitted albedo over the truth's; (H, W, 3) images, (H, W) visible."""
    def energy(image):
        dx = np.square(np.diff(image, axis=1)).sum(-1)[visible[:, 1:] & visible[:, :-1]]
        dy = np.square(np.diff(image, axis=0)).sum(-1)[visible[1:] & visible[:-1]]
        return dx.sum() + dy.sum()
    return float(energy(np.asarray(fitted, np.float64)) / max(energy(np.asarray(truth, np.float64)), 1e-12))


def detail_window(truth, visible, fraction=0.25, least_seen=0.5):
    """(row, column, side) of the square window of the truth's albedo with the most gradient
    energy in its visible texels: its most detailed visible region (a tattoo, scars, nails), among
    the windows at least `least_seen` visible where there are any (else among all)."""
    size = truth.shape[0]
    side = max(8, int(size * fraction))

    def window_sums(image):
        integral = cv2.integral(np.ascontiguousarray(image, dtype=np.float64))
        return integral[side:, side:] - integral[:-side, side:] - integral[side:, :-side] + integral[:-side, :-side]

    gradient = np.zeros(truth.shape[:2])
    gradient[:, 1:] += np.square(np.diff(truth, axis=1)).sum(-1)
    gradient[1:] += np.square(np.diff(truth, axis=0)).sum(-1)
    sums = window_sums(gradient * visible)
    seen = window_sums(visible) / side ** 2
    if (seen >= least_seen).any():
        sums = np.where(seen >= least_seen, sums, -1.0)
    row, column = np.unravel_index(np.argmax(sums), sums.shape)
    return int(row), int(column), side


# ----------------------------------------------------------------------------- all of it

def evaluate_fidelity(avatar_folder, sequence, picture=True, cycles=False):
    """Every fidelity figure of an avatar folder against its synthetic sequence's true hand;
    writes fidelity.json (and fidelity.png) into the avatar folder and returns the figures.
    With `cycles`, also the avatar under its fitted light against Cycles renders of the true
    hand under the clip's light (cycles_truth.py; part (b), a few seconds per render)."""
    folder = Path(avatar_folder)
    truth = true_hand(sequence)
    avatar_model, appearance, files = load_avatar(folder)
    if files.rig.side != truth.data.side:
        raise EvaluationError(f"the avatar is a {files.rig.side} hand, the sequence shows a {truth.data.side} one")
    size = appearance.albedo.shape[-1]
    known = albedo_truth(sequence, size, fit_folder=folder)
    linear = colour_model.is_linear(files.description.get("light", {}))   # both hands drawn in the avatar's model
    fitted_albedo = appearance.albedo.permute(1, 2, 0).double().numpy()
    texture = albedo_error(fitted_albedo, known.image, known.visible)
    texture.update(sharpness_ratio=sharpness_ratio(fitted_albedo, known.image, known.visible),
                   # the same at the truth's brightness (the per-channel scale): an albedo too light
                   # all over has larger steps between its texels without being any sharper
                   sharpness_ratio_scaled=sharpness_ratio(fitted_albedo * np.asarray(texture["scale"]), known.image,
                                                          known.visible),
                   visible_fraction_of_uv_area=known.visible_fraction)
    scale = torch.tensor(texture["scale"], dtype=torch.float32).view(3, 1, 1)
    scaled = Appearance((appearance.albedo * scale).clamp(0, 1), appearance.normal_map)
    truth_model = HandModel(truth.data)
    truth_appearance = Appearance(truth.albedo)
    # what limits the new-pose figures: the fitted shape with the true albedo, the true shape
    # with the fitted albedo
    shape_alone = Appearance(truth.albedo, appearance.normal_map)
    albedo_alone = Appearance(scaled.albedo)
    geometry = geometry_errors(files.rig, truth.data)
    # the avatar at the truth's size as well: a monocular clip barely decides the size (a hand twice as
    # big twice as far looks the same), so this is what the new poses would score if it did
    true_size = geometry.get("apart_from_size", {}).get("scale")
    parts = {"fitted_shape_alone": [], "fitted_albedo_alone": [], **({"at_true_size": []} if true_size else {})}
    poses, renders, rows = novel_poses(truth.data.side), {}, []
    without_normal_map = Appearance(appearance.albedo)
    details = []     # (avatar, avatar without its normal map, truth) per pose and view
    for name, pose in poses.items():
        for view, (azimuth, elevation) in VIEWS.items():
            (a_rgb, a_alpha, a_normal), (raw_rgb, _, _), (s_rgb, s_alpha, _), (c_rgb, c_alpha, _), \
                (t_rgb, t_alpha, t_normal), (_, flat_alpha, flat_normal), *resized = render_posed(
                    [(avatar_model, scaled), (avatar_model, appearance), (avatar_model, shape_alone),
                     (truth_model, albedo_alone), (truth_model, truth_appearance), (avatar_model, without_normal_map)]
                    + ([(ResizedHand(avatar_model, true_size), scaled)] if true_size else []),
                    truth_model, pose, azimuth, elevation, shading_normals=True,
                    linear=linear)
            scores = image_scores(a_rgb, a_alpha, t_rgb, t_alpha)
            scores["psnr_raw"] = image_scores(raw_rgb, a_alpha, t_rgb, t_alpha)["psnr"]
            rows.append({"pose": name, "view": view, **scores})
            parts["fitted_shape_alone"].append(image_scores(s_rgb, s_alpha, t_rgb, t_alpha))
            parts["fitted_albedo_alone"].append(image_scores(c_rgb, c_alpha, t_rgb, t_alpha))
            if resized:
                parts["at_true_size"].append(image_scores(resized[0][0], resized[0][1], t_rgb, t_alpha))
            renders[name, view] = (a_rgb[0].numpy(), t_rgb[0].numpy())
            # the shading normals do not depend on the albedo: the scaled avatar's are the avatar's
            details.append([shading_detail(normal[0].numpy(), alpha[0, ..., 0].numpy()) for normal, alpha in
                            ((a_normal, a_alpha), (flat_normal, flat_alpha), (t_normal, t_alpha))])
    keys = ("psnr", "ssim", "iou", "psnr_overlap")
    result = {
        "geometry": {**geometry,
                     "without_personal_detail": personal_detail(files.description, truth)},
        "new_poses": {"rows": rows, **{f"{key}_mean": float(np.mean([r[key] for r in rows])) for key in keys + ("psnr_raw",)},
                      "poses": list(poses), "views": VIEWS, "albedo_scale": texture["scale"],
                      **{part: {f"{key}_mean": float(np.mean([r[key] for r in part_rows])) for key in keys}
                         for part, part_rows in parts.items()},
                      "shading_detail": shading_detail_summary(details)},
        "texture": texture,
    }
    if cycles:
        result["cycles"] = cycles_scores(sequence, files.description, avatar_model, appearance, truth_model,
                                         truth_appearance, poses)
    if picture:
        window = detail_window(known.image, known.visible)
        result["picture"] = str(write_picture(folder / FIDELITY_PICTURE, renders, fitted_albedo, known.image, window,
                                              known.visible))
    (folder / FIDELITY_FILE).write_text(json.dumps(result, indent=1))
    return result


def cycles_scores(sequence, description, avatar_model, appearance, truth_model, truth_appearance, poses):
    """Part (b): in every new pose and view, the avatar as fitted (its albedo unscaled, its fitted
    light moved with the hand) against Cycles' render of the true hand under the clip's light;
    and, as the floor our renderer sets, the true hand rendered by ours under that fitted light
    against the same Cycles render. {"rows", "psnr_mean", ..., "renderer_floor": {...}} or
    {"unavailable": why}."""
    from .cycles_truth import CyclesTruthUnavailable, cycles_truth, fitted_light, synth_settings

    try:
        _, metadata = synth_settings(sequence)
        cases = [(name, view) for name in poses for view in VIEWS]
        frames = [framing(truth_model, poses[name], *VIEWS[view]) for name, view in cases]
        renders = cycles_truth(sequence, frames)
    except CyclesTruthUnavailable as reason:
        return {"unavailable": str(reason)}
    rows, floor = [], []
    for (name, view), frame, (rgb, alpha) in zip(cases, frames, renders):
        light = fitted_light(description, metadata, frame)
        (a_rgb, a_alpha), (t_rgb, t_alpha) = render_framed(
            [(avatar_model, appearance), (truth_model, truth_appearance)], frame, light,
            occlusion=bool(description["light"].get("occlusion", False)))
        cycles_rgb = torch.as_tensor(rgb[None], dtype=a_rgb.dtype)
        cycles_alpha = torch.as_tensor(alpha[None, ..., None], dtype=a_rgb.dtype)
        rows.append({"pose": name, "view": view, **image_scores(a_rgb, a_alpha, cycles_rgb, cycles_alpha)})
        floor.append(image_scores(t_rgb, t_alpha, cycles_rgb, cycles_alpha))
    keys = ("psnr", "ssim", "iou", "psnr_overlap")
    return {"rows": rows, **{f"{key}_mean": float(np.mean([r[key] for r in rows])) for key in keys},
            "renderer_floor": {f"{key}_mean": float(np.mean([r[key] for r in floor])) for key in keys}}


def shading_detail_summary(details):
    """The avatar's shading detail over the truth's, averaged over the renders (module docstring),
    from (avatar, avatar without its normal map, truth) figures per render."""
    details = np.asarray(details, np.float64)
    truth = np.maximum(details[:, 2], 1e-12)
    return {"ratio": float(np.mean(details[:, 0] / truth)),
            "ratio_without_normal_map": float(np.mean(details[:, 1] / truth)),
            "truth_mean": float(details[:, 2].mean())}


NOT_SCORED = 0.5     # the grey the detail crops show where the albedo is not scored


def write_picture(path, renders, fitted_albedo, true_albedo, window, visible=None):
    """Rows: three new poses (palm view), truth | avatar; then the detail crops, truth | avatar,
    grey outside `visible` ((H, W) bool: the texels the texture figures score, those the clip
    showed): texels outside the UV charts are never drawn, and their fill would read as a blocky
    texture."""
    from ..preview_render import label

    tiles = []
    for name in PICTURE_POSES:
        avatar, truth = renders[name, "palm"]
        tiles.append(np.concatenate([label(_bytes(truth), f"true, {name}"), label(_bytes(avatar), "avatar")], 1))
        avatar, truth = renders[name, "back"]
        tiles.append(np.concatenate([label(_bytes(truth), "true, back"), label(_bytes(avatar), "avatar")], 1))
    row, column, side = window
    shown = np.ones(true_albedo.shape[:2], bool) if visible is None else np.asarray(visible, bool)
    crops = [cv2.resize(np.where(shown[..., None], image, NOT_SCORED)[row:row + side, column:column + side],
                        (SIZE, SIZE), interpolation=cv2.INTER_NEAREST)
             for image in (true_albedo, fitted_albedo)]
    tiles.append(np.concatenate([label(_bytes(crops[0]), "true albedo, detail"),
                                 label(_bytes(crops[1]), "fitted albedo" + ("" if visible is None else
                                                                            " (grey: not seen)"))], 1))
    grid = [np.concatenate(tiles[i:i + 2], 1) for i in range(0, len(tiles) - 1, 2)]
    grid.append(np.concatenate([tiles[-1], np.zeros_like(tiles[-1])], 1))
    seq.write_png(path, np.concatenate(grid, 0))
    return Path(path)


def _bytes(image):
    return np.ascontiguousarray((np.clip(image, 0, 1) * 255).round().astype(np.uint8))
