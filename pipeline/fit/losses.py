"""The fit's energy terms (appendix C.3, Table C.1), as plain functions of tensors.

Geometry: silhouette, keypoint anchor, displacement size (the surface's Laplacian, normal
consistency and edge-length terms are in surface_regularisers.py). Appearance: photometric L1 in the eroded
mask, and the UV-space regularisers of the albedo texture and the normal map. The perceptual
term lives in perceptual.py. Shapes: B frames, V vertices, F faces, H x W images.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import gaussian_filter1d

from ..render.shading import sphere_radiance_basis

KEYPOINT_UNIT = 0.1   # the anchor measures distances in units of 10 cm


def silhouette_loss(alpha, mask, weight=None):
    """Mean absolute difference of rendered alpha (B, H, W, 1) and target mask (B, H, W, 1),
    each pixel weighted by `weight` (B, H, W, 1) when given (0: the mask says nothing there)."""
    difference = (alpha - mask).abs()
    return (difference if weight is None else difference * weight).mean()


def keypoint_anchor_loss(keypoints, initial_keypoints, root=0):
    """Mean over frames and keypoints of the squared change of root-relative 3D keypoints
    (B, K, 3) against their initial estimate, in units of 10 cm."""
    relative = keypoints - keypoints[:, root:root + 1]
    initial = initial_keypoints - initial_keypoints[:, root:root + 1]
    return ((relative - initial) / KEYPOINT_UNIT).square().sum(-1).mean()


def displacement_loss(displacements):
    """Sum of squared per-vertex displacements (V,) along the normals (metres^2)."""
    return displacements.square().sum()


def displacement_smoothness_loss(displacements, edges, unit=1e-3):
    """Mean squared difference of the displacements (V,) of the ends of every edge (E, 2), in
    units of `unit` (1 mm): the roughness of the displacement field itself, blind to the
    template's own curvature (which a Laplacian of the positions also penalises)."""
    return ((displacements.index_select(0, edges[:, 0]) - displacements.index_select(0, edges[:, 1])) / unit).square().mean()


def direction_loss(vectors, targets, found):
    """Mean over the rows where `found` (N,) of 1 - cos of the angle between vectors (N, 2) and
    unit targets (N, 2); 0 where none is found."""
    if not bool(found.any()):
        return vectors.new_zeros(())
    unit = F.normalize(vectors[found], dim=-1, eps=1e-9)
    return (1 - (unit * targets[found]).sum(-1)).mean()


def shape_prior_loss(betas, target):
    """Mean squared distance of the shape parameters (S,) from a target shape (S,), in the shape
    space's own units (one standard deviation of the population each)."""
    return (betas - target).square().mean()


SIZE_UNIT = 0.01         # one per cent of the hand's size
SIZE_TOLERANCE = 0.03    # the size prior's free band: the keypoints' metric size is good to about this


def size_prior_loss(size, target, tolerance=SIZE_TOLERANCE):
    """Squared relative change of the hand's size (a scalar, HandModel.size) from a target size
    beyond a free band of +-`tolerance`, in per cent (log ratio / SIZE_UNIT): 0 within the band,
    1 for a hand 1% beyond it."""
    beyond = torch.relu(torch.log(size / target).abs() - tolerance)
    return (beyond / SIZE_UNIT).square()


def eroded_mask(mask, pixels=2):
    """Binary erosion of (B, H, W, 1) masks by a square of radius `pixels` (no gradient): a pixel
    stays where the whole square around it is inside; beyond the image counts as inside (a hand
    cut by the frame's edge keeps its pixels there). The square's minimum is taken along the rows,
    then along the columns: the same minimum, and a tenth of max_pool2d's time over a square
    window on a CPU (1.6 s of a 150-frame fit's start)."""
    inside = (mask[..., 0] > 0.5).to(mask.dtype)
    side = 2 * pixels + 1
    padded = F.pad(inside, (pixels, pixels, pixels, pixels), value=1.0)
    return padded.unfold(2, side, 1).amin(-1).unfold(1, side, 1).amin(-1)[..., None]


PHOTOMETRIC_EROSION = 2    # pixels
# the albedo solve reads one pixel nearer the mask's edge: where a finger's side turns away, those
# pixels are the only ones that show the skin where the palm's tone meets the back's (phone-like
# clip: new poses +0.4-0.7 dB, held out +0.4-0.6 dB; docs/fidelity.md)
ALBEDO_SOLVE_EROSION = 1   # pixels


def photometric_loss(rendered, image, mask, erosion=PHOTOMETRIC_EROSION, inside=None):
    """L1 between rendered and input images (B, H, W, 3) inside the mask eroded by `erosion`
    pixels, averaged over the covered pixels and channels. `inside` (B, H, W, 1): that eroded
    mask, when the caller has it already (FitProblem.photometric_inside: the erosion on a CPU
    cost as much as the rest of the term)."""
    inside = eroded_mask(mask, erosion) if inside is None else inside.to(rendered.dtype)
    count = inside.sum().clamp(min=1) * rendered.shape[-1]
    return ((rendered - image).abs() * inside).sum() / count


def _shifted(texture, generator, sigma_px):
    """The texture (C, H, W) sampled at every texel plus a random offset (sigma in texels)."""
    channels, height, width = texture.shape
    offset = torch.randn(height, width, 2, generator=generator, dtype=texture.dtype).to(texture.device) * sigma_px
    ys, xs = torch.meshgrid(torch.arange(height, dtype=texture.dtype, device=texture.device),
                            torch.arange(width, dtype=texture.dtype, device=texture.device), indexing="ij")
    grid = torch.stack([(xs + 0.5 + offset[..., 0]) / width * 2 - 1,
                        (ys + 0.5 + offset[..., 1]) / height * 2 - 1], dim=-1)
    return F.grid_sample(texture[None], grid[None], mode="bilinear", padding_mode="border", align_corners=False)[0]


def texture_smoothness_loss(texture, uv_mask, generator=None, sigma_px=2.0):
    """E_t_reg: sum over texels in the UV mask of |T(I) - T(I + eps)|_1 / 3 with eps ~ N(0, 2 px),
    normalised by the number of masked texels. texture (C, H, W), uv_mask (H, W) bool."""
    difference = (texture - _shifted(texture, generator, sigma_px)).abs().sum(0) / 3
    return (difference * uv_mask).sum() / uv_mask.sum().clamp(min=1)


def normal_map_loss(normal_map, uv_mask, generator=None, sigma_px=2.0):
    """E_n_reg: smoothness as for the albedo plus |G(I) - (0, 0, 1)|^2, all / 3, per masked texel."""
    smooth = (normal_map - _shifted(normal_map, generator, sigma_px)).abs().sum(0)
    flat = normal_map.new_tensor([0.0, 0.0, 1.0]).view(3, 1, 1)
    pull = (normal_map - flat).square().sum(0)
    return ((smooth + pull) / 3 * uv_mask).sum() / uv_mask.sum().clamp(min=1)


def _per_frame_step(values, times):
    """Differences of consecutive per-frame values (F, ...) divided by their time gaps (frames)."""
    gaps = (times[1:] - times[:-1]).to(values.dtype).clamp(min=1)
    return (values[1:] - values[:-1]) / gaps.view(-1, *([1] * (values.dim() - 1)))


def _per_frame_acceleration(values, times):
    """Accelerations of per-frame values (F, ...) per frame^2 at the inner frames (F - 2, ...): the
    change of velocity at frame i over half the span (t[i+1] - t[i-1])."""
    velocity = _per_frame_step(values, times)
    half_span = ((times[2:] - times[:-2]).to(values.dtype) / 2).clamp(min=1)
    return (velocity[1:] - velocity[:-1]) / half_span.view(-1, *([1] * (values.dim() - 1)))


POSE_SMOOTHNESS = ("velocity", "acceleration", "adaptive")     # FitSettings.pose_smoothness

STILL_SPEED = 0.6            # rad/s: a joint turning this fast in the smoothed initial estimate is half still
MOTION_SMOOTHING_S = 1 / 6   # s: the initial estimate's joint rotations are smoothed over this (a Gaussian's sigma)


def joint_stillness(pose, fps, still_speed=STILL_SPEED, smoothing_s=MOTION_SMOOTHING_S):
    """(F, J) in (0, 1]: how still each joint holds at each frame in the joint rotations `pose`
    (F, J, 3) of consecutive frames at `fps`: 1 / (1 + (speed / still_speed)^2), the speed (rad/s)
    that of the rotations smoothed over `smoothing_s` (a noisy start's jitter averages out, a
    finger's swing stays), its square averaged over twice that, less what the start's jitter still
    adds to it (a short clip smooths little of it away: a still joint must read still there too).
    The temporal pose term ("adaptive") holds a still joint's velocity and a moving one's
    acceleration."""
    pose = np.asarray(pose, dtype=np.float64)
    if len(pose) < 2:
        return np.ones(pose.shape[:2])
    sigma = smoothing_s * fps
    # the centred step per frame (one-sided at the ends): np.gradient
    speed_sq = (np.gradient(gaussian_filter1d(pose, sigma, axis=0, mode="nearest"), axis=0) ** 2).sum(2)
    # independent jitter of variance s^2 per frame: its second differences have variance 6 s^2 (a smooth motion's
    # are small at video rates), and it adds s^2 times the smoothed step's squared weights to the squared speed
    jitter_var = (np.diff(pose, 2, axis=0) ** 2).sum(2).mean(0) / 6 if len(pose) >= 3 else np.zeros(pose.shape[1])
    speed_sq = speed_sq - _smoothed_step_noise_gain(len(pose), sigma)[:, None] * jitter_var[None, :]
    speed_sq = np.maximum(gaussian_filter1d(speed_sq, 2 * sigma, axis=0, mode="nearest"), 0) * fps ** 2
    return 1 / (1 + speed_sq / still_speed ** 2)


def _smoothed_step_noise_gain(frames, sigma):
    """(frames,) the variance of joint_stillness's smoothed centred step at each frame per unit
    variance of independent per-frame noise: the squared weights of that linear operator, summed.
    Frames farther than the Gaussian's reach from both ends share one value, so long clips are
    measured on a short one."""
    reach = int(4 * sigma + 0.5) + 2                   # the kernel's radius (scipy truncates at 4 sigma), and a step
    size = min(frames, 2 * reach + 1)
    operator = np.gradient(gaussian_filter1d(np.eye(size), sigma, axis=0, mode="nearest"), axis=0)
    gain = (operator ** 2).sum(1)
    if size == frames:
        return gain
    return np.concatenate([gain[:reach], np.full(frames - 2 * reach, gain[reach]), gain[-reach:]])


def temporal_pose_loss(pose, times, measure="velocity", stillness=None):
    """Mean over frames of the squared velocity ("velocity": the change between consecutive
    frames) or acceleration of the joint rotations (F, J, 3) per frame of time (radians^2 per
    frame^2 or frame^4): fingers move smoothly at video rates. `times` (F,) are the frames'
    indices in the clip, so subsampled or held-out gaps count as longer. The velocity holds
    every frame towards its neighbours' mean, a moving finger's extremes too; the acceleration
    lets a finger move at a steady speed and still holds one frame's jitter (three times as hard
    per unit weight: independent noise of variance s^2 gives steps of 2 s^2, accelerations of 6).
    "adaptive": each joint's velocity times its `stillness` (F, J) (joint_stillness) plus its
    acceleration times the rest, so that a joint that holds still is held to one pose and a
    moving one only to a smooth motion."""
    if measure not in POSE_SMOOTHNESS:
        raise ValueError(f"pose smoothness must be one of {', '.join(POSE_SMOOTHNESS)}, got {measure!r}")
    if measure == "acceleration":
        return (_per_frame_acceleration(pose, times).square().sum((1, 2)).mean() if len(pose) >= 3
                else pose.new_zeros(()))
    if len(pose) < 2:
        return pose.new_zeros(())
    if measure == "velocity":
        return _per_frame_step(pose, times).square().sum((1, 2)).mean()
    if stillness is None:
        raise ValueError("the adaptive pose smoothness needs the joints' stillness")
    velocity_sq = _per_frame_step(pose, times).square().sum(2)                     # (F - 1, J)
    held_still = (velocity_sq * (stillness[1:] + stillness[:-1]) / 2).sum(1).mean()
    if len(pose) < 3:
        return held_still
    acceleration_sq = _per_frame_acceleration(pose, times).square().sum(2)         # (F - 2, J)
    return held_still + (acceleration_sq * (1 - stillness[1:-1])).sum(1).mean()


def exposure_loss(log_gains, times, measured, known, spread=0.02):
    """Per-frame log colour gains (F, 3): their mean squared acceleration per frame^2 (exposure
    drifts smoothly), plus their squared distance in units of `spread` from the gains `measured`
    (F, 3) where `known` (F,) (the background's colour: a rotating hand's shading may not pass
    for exposure), plus the square of their mean (the albedo carries the average)."""
    total = log_gains.mean(0).square().sum()
    if known.any():
        total = total + ((log_gains[known] - measured[known]) / spread).square().sum(1).mean()
    if len(log_gains) >= 3:
        total = total + _per_frame_acceleration(log_gains, times).square().sum(1).mean()
    return total


def environment_prior_loss(coefficients):
    """Sum of squares of the environment light's coefficients (8, 3): no environment is the
    prior (a uniform room, all in the ambient ratio)."""
    return coefficients.square().sum()


def environment_realisable_loss(coefficients, ambient):
    """Mean over directions spread over the sphere and colours of the square of how far the radiance of
    the world that the environment coefficients (8, 3) and the ambient ratio stand for
    (a + sum_k c_k R_k(d), formats/environment_light.py) falls below 0: a room cannot shine
    less than no light, and Blender's world clips what does."""
    radiance = ambient + sphere_radiance_basis(coefficients.dtype, coefficients.device) @ coefficients
    return torch.nn.functional.relu(-radiance).square().mean()


def camera_relative_translations(translations, reference_depth):
    """Translations (F, 3) as the camera sees them, in metres at `reference_depth` (a constant):
    (x / z, y / z, log z) times that depth. A whole scene scaled about the camera (a larger hand
    farther away) leaves their differences as they were; at the reference depth a small step is
    the same length in either."""
    depth = translations[:, 2:3].clamp(min=1e-3)
    return torch.cat([translations[:, :2] / depth, depth.log()], 1) * reference_depth


def temporal_global_loss(rotations, translations, times, translation_unit=0.01, reference_depth=None):
    """Mean squared acceleration of the hand's global rotation matrices (F, 3, 3) and
    translations (F, 3) (in units of 1 cm) per frame^2: the whole hand may turn fast but smoothly.
    Rotation matrices instead of axis-angle vectors: no jump at 180 degrees. The acceleration
    at frame i is the change of velocity over half the span (t[i+1] - t[i-1]). With
    `reference_depth` (metres), the translations are measured as the camera sees them
    (camera_relative_translations): metres favour a nearer, smaller hand, whose steps are shorter."""
    if len(rotations) < 3:
        return rotations.new_zeros(())
    if reference_depth is not None:
        translations = camera_relative_translations(translations, reference_depth)
    return (_per_frame_acceleration(rotations, times).square().sum((1, 2)).mean()
            + _per_frame_acceleration(translations / translation_unit, times).square().sum(1).mean())
