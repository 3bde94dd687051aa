"""The fit's energy for one batch of frames: renders the avatar and sums the weighted terms."""
from __future__ import annotations

import torch

from ..handmodel.rotations import axis_angle_to_matrix
from ..render.renderer import render
from . import losses
from .problem import FitProblem
from .settings import Stage


def batch_energy(problem: FitProblem, stage: Stage, batch, shadows, generator):
    """(total loss, {term: value}) for frames `batch` (indices into the problem's frames) in
    `stage`, self-shadowing on or off; `generator` draws the texture regularisers' offsets."""
    avatar, clip, weights = problem.avatar, problem.clip, problem.settings.weights
    vertices, keypoints = avatar.posed_coarse(batch) if stage.coarse else avatar.posed(batch)
    outputs = ("alpha", "rgb") if stage.appearance else ("alpha",)
    mesh = avatar.coarse_mesh if stage.coarse else avatar.mesh
    images = render(vertices, mesh, clip.K, clip.height, clip.width, outputs=outputs,
                    appearance=avatar.appearance() if stage.appearance else None,
                    light=avatar.light(shadows) if stage.appearance else None,
                    background=torch.zeros(3, dtype=vertices.dtype, device=vertices.device))
    masks, frames = clip.masks[batch], clip.images[batch]
    terms = {}

    def add(name, term):
        """A term switched off (weight 0) is not computed: it costs nothing."""
        if weights.get(name, 0.0) != 0.0:
            terms[name] = term()

    if stage.geometry:
        weight = None if problem.silhouette_weight is None else problem.silhouette_weight[batch]
        add("silhouette", lambda: losses.silhouette_loss(images["alpha"], masks, weight))
        add("keypoint_anchor", lambda: losses.keypoint_anchor_loss(keypoints[:, :21], problem.anchor_keypoints[batch]))
        # over every frame (no rendering involved): the batch's frames feel their neighbours
        add("temporal_pose", lambda: losses.temporal_pose_loss(avatar.pose * avatar.pose_mask, avatar.frame_numbers))
        add("temporal_global", lambda: losses.temporal_global_loss(axis_angle_to_matrix(avatar.global_orient),
                                                                   avatar.transl, avatar.frame_numbers))
    if stage.geometry and not stage.coarse:
        field = avatar.displacement_field()
        add("displacement", lambda: losses.displacement_loss(field))
        add("laplacian", lambda: losses.laplacian_loss(vertices, problem.edges))
        add("displacement_smoothness", lambda: losses.displacement_smoothness_loss(field, problem.edges))
        add("normal_consistency", lambda: losses.normal_consistency_loss(vertices, avatar.mesh.faces,
                                                                         problem.face_pairs))
        add("edge_length", lambda: losses.edge_length_loss(vertices, problem.reference_vertices[batch], problem.edges))
    if stage.appearance:
        rendered = images["rgb"] * avatar.exposure_gain(batch) if problem.exposure_on else images["rgb"]
        target = frames * masks
        add("photometric", lambda: losses.photometric_loss(rendered, target, masks,
                                                           inside=problem.photometric_inside[batch]))
        add("perceptual", lambda: problem.perceptual(rendered * masks, target, masks))
        add("texture", lambda: losses.texture_smoothness_loss(avatar.albedo, problem.uv_mask, generator))
        add("normal_map", lambda: losses.normal_map_loss(torch.nn.functional.normalize(avatar.normal_map, dim=0),
                                                         problem.uv_mask, generator))
        if problem.exposure_on:
            add("exposure", lambda: losses.exposure_loss(avatar.exposure, avatar.frame_numbers,
                                                                     *problem.exposure_measured))
    total = sum((weights[name] * value for name, value in terms.items()), vertices.new_zeros(()))
    return total, {name: float(value.detach()) for name, value in terms.items()}
