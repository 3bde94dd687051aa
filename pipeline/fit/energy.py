"""The fit's energy for one batch of frames: renders the avatar and sums the weighted terms."""
from __future__ import annotations

import torch

from ..handmodel.rotations import axis_angle_to_matrix
from ..render.renderer import render
from . import losses


def batch_energy(avatar, clip, batch, settings, stage, initial_keypoints, rest_reference, edges, face_pairs,
                 perceptual, uv_mask, shadows, generator):
    """(total loss, {term: value}) for frames `batch` (indices into the fit's frames)."""
    weights = settings.weights
    vertices, keypoints = avatar.posed_coarse(batch) if stage.coarse else avatar.posed(batch)
    outputs = ("alpha", "rgb") if stage.appearance else ("alpha",)
    mesh = avatar.coarse_mesh if stage.coarse else avatar.mesh
    images = render(vertices, mesh, clip.K, clip.height, clip.width, outputs=outputs,
                    appearance=avatar.appearance() if stage.appearance else None,
                    light=avatar.light(shadows) if stage.appearance else None,
                    background=torch.zeros(3, dtype=vertices.dtype, device=vertices.device))
    masks, frames = clip.masks[batch], clip.images[batch]
    terms = {}
    if stage.geometry:
        terms["silhouette"] = losses.silhouette_loss(images["alpha"], masks)
        terms["keypoint_anchor"] = losses.keypoint_anchor_loss(keypoints[:, :21], initial_keypoints[batch])
        # over every frame (no rendering involved): the batch's frames feel their neighbours
        terms["temporal_pose"] = losses.temporal_pose_loss(avatar.pose * avatar.pose_mask, avatar.frame_numbers)
        terms["temporal_global"] = losses.temporal_global_loss(axis_angle_to_matrix(avatar.global_orient),
                                                               avatar.transl, avatar.frame_numbers)
    if stage.geometry and not stage.coarse:
        terms["displacement"] = losses.displacement_loss(avatar.displacement)
        terms["laplacian"] = losses.laplacian_loss(vertices, edges)
        terms["normal_consistency"] = losses.normal_consistency_loss(vertices, avatar.mesh.faces, face_pairs)
        terms["edge_length"] = losses.edge_length_loss(vertices, rest_reference[batch], edges)
    if stage.appearance:
        rendered = images["rgb"]
        target = frames * masks
        terms["photometric"] = losses.photometric_loss(rendered, target, masks)
        terms["perceptual"] = perceptual(rendered * masks, target, masks)
        terms["texture"] = losses.texture_smoothness_loss(avatar.albedo, uv_mask, generator)
        terms["normal_map"] = losses.normal_map_loss(torch.nn.functional.normalize(avatar.normal_map, dim=0),
                                                     uv_mask, generator)
    total = sum(weights.get(name, 0.0) * value for name, value in terms.items())
    return total, {name: float(value.detach()) for name, value in terms.items()}
