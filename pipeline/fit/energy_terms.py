"""The registry of the fit's energy terms: each declares its name, default weight, the stages
it counts in, what it needs, and the function that computes it on a batch (losses.py holds the
maths). Adding a term is one entry here plus its function; nothing else names terms.

The default weights are the appendix's Table C.1 where it has the term; the others are ours.
A term with weight 0 (settings.weights) is not computed and costs nothing. The order of the
registry is the order terms are computed and summed (and the order the texture regularisers
draw their random offsets), so it is part of what makes a fit repeat bit for bit.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping

import torch

from ..formats.hand_model_file import ELBOW_KEYPOINT_NAME
from ..handmodel.rotations import axis_angle_to_matrix
from ..render.rasterize import project
from . import losses
from .forearm_mask import MIDDLE_KNUCKLE, forearm_targets
from .schedule import StageKind, half_cosine

# what a term can need from a batch beyond the silhouette render (the energy makes only what is needed)
SHADED = "shaded"              # the avatar rendered with its textures and light ("rgb")

_GEOMETRY = frozenset({StageKind.ALIGN, StageKind.GEOMETRY, StageKind.JOINT})
_SURFACE = frozenset({StageKind.GEOMETRY, StageKind.JOINT})        # the subdivided, displaced surface
_APPEARANCE = frozenset({StageKind.JOINT, StageKind.APPEARANCE})


@dataclasses.dataclass(frozen=True)
class EnergyTerm:
    """One term of the fit's energy.

    `evaluate(batch)` -> scalar tensor, `batch` an energy.BatchData (the posed avatar, the render,
    the frames and masks of the batch, the problem). `stages`: the stage kinds it counts in;
    `stage_factors`: its weight's factor in some of them (1 where not given; settings.stage_factors
    replace them). `stage_fades`: in some of them its weight fades along the stage, a half cosine from
    its weight there at the stage's start to this fraction of it at its end (settings.stage_fades
    replace them).
    `needs`: what it reads that costs a render pass (SHADED). `prepare(problem)`: fixed data made
    once when the problem is built (held in problem.term_data[name]; None: none). `applies(problem)`:
    whether the term exists for this problem at all (e.g. exposure gains only when switched on)."""

    name: str
    weight: float
    stages: frozenset
    evaluate: Callable[[Any], torch.Tensor]
    needs: frozenset = frozenset()
    prepare: Callable[[Any], Any] | None = None
    applies: Callable[[Any], bool] | None = None
    stage_factors: Mapping[StageKind, float] = dataclasses.field(default_factory=dict)
    stage_fades: Mapping[StageKind, float] = dataclasses.field(default_factory=dict)

    def weight_in(self, settings, stage: StageKind | None = None, progress: float | None = None) -> float:
        """Its weight under `settings` (settings.weights; a term missing from them: its default),
        in a stage of kind `stage` times its factor there (settings.stage_factors[name][stage
        name], else its own stage_factors, else 1), and `progress` into that stage (steps taken /
        planned; None: its start) times its fade there (stage_fades)."""
        weight = settings.weights.get(self.name, self.weight)
        if stage is None:
            return weight
        factor = settings.stage_factors.get(self.name, {}).get(stage.value, self.stage_factors.get(stage, 1.0))
        if progress is not None:
            fade = settings.stage_fades.get(self.name, {}).get(stage.value, self.stage_fades.get(stage, 1.0))
            factor *= half_cosine(progress, fade)
        return weight * factor


ENERGY_TERMS: dict[str, EnergyTerm] = {}


def register(term: EnergyTerm) -> EnergyTerm:
    """Add `term` to the registry (after the others: it is computed last)."""
    if term.name in ENERGY_TERMS:
        raise ValueError(f"an energy term named {term.name!r} is registered already")
    ENERGY_TERMS[term.name] = term
    return term


def default_weights() -> dict:
    """{term name: default weight} of every registered term."""
    return {name: term.weight for name, term in ENERGY_TERMS.items()}


def is_on(term: EnergyTerm, settings, problem=None, stage: StageKind | None = None) -> bool:
    """Whether `term` has a weight under `settings` (in a stage of kind `stage`, when given) and,
    with `problem`, applies to it."""
    return term.weight_in(settings, stage) != 0.0 and (problem is None or term.applies is None
                                                       or term.applies(problem))


def terms_for(stage: StageKind, settings, problem=None) -> list:
    """The terms that count in a stage of kind `stage` and are on there (is_on), in registry order."""
    return [term for term in ENERGY_TERMS.values() if stage in term.stages and is_on(term, settings, problem, stage)]


def _term(name, weight, stages, needs=(), prepare=None, applies=None, stage_factors=None, stage_fades=None):
    """Decorator: registers the decorated function as the term's `evaluate`."""
    def add(evaluate):
        register(EnergyTerm(name, weight, frozenset(stages), evaluate, frozenset(needs), prepare, applies,
                            dict(stage_factors or {}), dict(stage_fades or {})))
        return evaluate
    return add


# --- geometry (appendix Table C.1; the temporal terms are ours: hands move smoothly at video rates)

@_term("silhouette", 7.0, _GEOMETRY | {StageKind.HELD_OUT})
def _silhouette(batch):
    return losses.silhouette_loss(batch.images["alpha"], batch.masks, batch.silhouette_weight)


def _anchor_size(problem):
    """With settings.anchor_size "free": the initial estimate's hand size (HandModel.size of its
    shape), the size its keypoints, the anchor's targets, have; else None (the anchor in metres)."""
    if problem.settings.anchor_size != "free":
        return None
    return problem.avatar.model.size(_initial_betas(problem)).detach()


# 10 (Table C.1) in the alignment, a tenth of it after: at 10 throughout it pulled the poses back to the
# noisy initial keypoints once the silhouette had placed them (joint error 1.34 mm at the alignment's end, 2.32
# at the fit's); at a tenth the joints stay put and the photometric fit gains (docs/study.md, section 4).
# The held-out refinement weighs it as the fit's later stages do: at 10 it held the held-out poses on the
# keypoints, 1.5 dB below the poses the image asks for on the demo clip (docs/fit.md, held-out frames).
# After the alignment it also holds the hand's size, which no frame tells: at 0 there the joints came 15-23%
# nearer the truth on the phone-like and demo clips' 3 seeds each, but the size wandered (0.4-1.0% smaller on
# the phone-like clip, one demo seed 4% larger) and neither the palm's size held nor the whole hand's gave it
# back without giving back the joints (docs/fidelity.md, "The hand's size is not in the clip")
@_term("keypoint_anchor", 10.0, _GEOMETRY | {StageKind.HELD_OUT}, prepare=_anchor_size,
       stage_factors={StageKind.GEOMETRY: 0.1, StageKind.JOINT: 0.1, StageKind.HELD_OUT: 0.1})
def _keypoint_anchor(batch):
    keypoints = at_anchor_size(batch.problem, batch.keypoints[:, :21])
    return losses.keypoint_anchor_loss(keypoints, batch.problem.anchor_keypoints[batch.frames])


def at_anchor_size(problem, keypoints):
    """Posed keypoints (B, K, 3) of the avatar as the keypoint anchor compares them: as they are, or
    with settings.anchor_size "free" brought to the initial estimate's size (blind to the hand's size)."""
    initial_size = problem.term_data.get("keypoint_anchor")
    if initial_size is None:
        return keypoints
    avatar = problem.avatar
    return keypoints * (initial_size / avatar.model.size(avatar.betas))


def _joint_stillness(problem):
    """(F, 16) how still each joint holds at each fitted frame in the initial estimate (losses.joint_stillness),
    when the temporal pose term is "adaptive"; else None."""
    if problem.settings.pose_smoothness != "adaptive":
        return None
    stillness = losses.joint_stillness(problem.initial.pose, problem.clip.info.fps)[problem.frames]
    return torch.as_tensor(stillness, dtype=problem.avatar.pose.dtype, device=problem.device)


@_term("temporal_pose", 10.0, _GEOMETRY, prepare=_joint_stillness)
def _temporal_pose(batch):
    # over every frame (no rendering involved): the batch's frames feel their neighbours
    avatar = batch.problem.avatar
    return losses.temporal_pose_loss(avatar.pose * avatar.pose_mask, avatar.frame_numbers,
                                     batch.problem.settings.pose_smoothness,
                                     batch.problem.term_data.get("temporal_pose"))


def _reference_depth(problem):
    """The initial estimate's mean depth over the fitted frames (metres), when the translations'
    smoothness is measured as the camera sees them (settings.translation_smoothness "camera")."""
    if problem.settings.translation_smoothness != "camera":
        return None
    return float(problem.initial.transl[problem.clip.frames, 2].mean())


@_term("temporal_global", 1.0, _GEOMETRY, prepare=_reference_depth)
def _temporal_global(batch):
    avatar = batch.problem.avatar
    return losses.temporal_global_loss(axis_angle_to_matrix(avatar.global_orient), avatar.transl, avatar.frame_numbers,
                                       reference_depth=batch.problem.term_data.get("temporal_global"))


@_term("displacement", 2.0, _SURFACE)
def _displacement(batch):
    return losses.displacement_loss(batch.displacement_field)


@_term("laplacian", 4.0, _SURFACE)
def _laplacian(batch):
    return batch.problem.surface.laplacian_loss(batch.vertices)


# the displacement field's own roughness: smooth reposed fingers (docs/fidelity.md)
@_term("displacement_smoothness", 1.0, _SURFACE)
def _displacement_smoothness(batch):
    return losses.displacement_smoothness_loss(batch.displacement_field, batch.problem.surface.edges)


@_term("normal_consistency", 0.1, _SURFACE)
def _normal_consistency(batch):
    return batch.problem.surface.normal_consistency_loss(batch.vertices)


@_term("edge_length", 0.2, _SURFACE)
def _edge_length(batch):
    return batch.problem.surface.edge_length_loss(batch.vertices, batch.problem.reference_edge_lengths[batch.frames])


def _forearm_targets(problem):
    """((F, 2) unit directions, (F,) bool) where each frame's mask takes the forearm from the
    wrist (forearm_mask.py), with the wrist and knuckle of the avatar as the problem starts."""
    avatar, clip = problem.avatar, problem.clip
    with torch.no_grad():
        _, keypoints = avatar.posed_coarse(torch.arange(len(clip.frames), device=clip.images.device))
        pixels = project(keypoints[:, [0, MIDDLE_KNUCKLE]], clip.K).cpu().numpy()
    directions, found = forearm_targets(clip.masks[..., 0].cpu().numpy() > 0.5, pixels[:, 0], pixels[:, 1])
    return (torch.as_tensor(directions, dtype=clip.images.dtype, device=clip.images.device),
            torch.as_tensor(found, device=clip.images.device))


def _has_forearm(problem):
    return ELBOW_KEYPOINT_NAME in problem.avatar.model.data.keypoint_names


# ours: in hand + forearm mode, the forearm's direction in the image towards where the mask takes
# it (where it leaves the picture, when it does; forearm_mask.py): the silhouette pulls only at
# outlines that already nearly agree, and nothing else tells the forearm where to point
@_term("forearm_direction", 1.0, _GEOMETRY | {StageKind.HELD_OUT}, prepare=_forearm_targets, applies=_has_forearm)
def _forearm_direction(batch):
    targets, found = batch.problem.term_data["forearm_direction"]
    elbow = batch.problem.avatar.model.data.keypoint_names.index(ELBOW_KEYPOINT_NAME)
    pixels = project(batch.keypoints[:, [0, elbow]], batch.problem.clip.K[batch.frames])
    return losses.direction_loss(pixels[:, 1] - pixels[:, 0], targets[batch.frames], found[batch.frames])


def _initial_betas(problem):
    """(S,) the initial estimate's shape (a resumed fit's avatar holds its fitted one)."""
    return torch.as_tensor(problem.initial.betas, dtype=problem.avatar.betas.dtype, device=problem.device)


# ours, off (weight 0): the shape held near the initial estimate's (from the keypoints' bone lengths) against
# the drift of long fits; measured on the phone-like clip at weights 1 and 0.1 it was worse on every figure
# (held out -0.7 to -1 dB, joints +0.3 mm, surface +0.15 mm): it keeps the silhouettes from correcting the
# proportions, and the size's drift is the held scale's to stop (docs/fidelity.md)
@_term("shape_prior", 0.0, _GEOMETRY, prepare=_initial_betas)
def _shape_prior(batch):
    return losses.shape_prior_loss(batch.problem.avatar.betas, batch.problem.term_data["shape_prior"])


# what the size prior can measure (settings.size_measure): HandModel.size over the whole hand's keypoints or the
# palm's, or the shape's scale parameter alone (the size of an average-proportioned hand at that scale)
SIZE_MEASURES = ("hand", "palm", "scale")


def measured_size(problem, betas):
    """The size the size prior holds, of shape `betas` (S,), as settings.size_measure measures it."""
    model, measure = problem.avatar.model, problem.settings.size_measure
    if measure == "scale":
        scale_only = torch.zeros_like(betas)
        index = model.data.shape_names.index("scale")
        scale_only[index] = betas[index]
        return model.size(scale_only)
    return model.size(betas, measure)


def _size_target(problem):
    """The size the size prior holds: the initial estimate's (measured_size of its shape: from the
    keypoints' bone lengths), or with size_anchor "alignment" a placeholder (NaN, read by no
    stage: the term is silent in the alignment) that a later stage's run fills in place with the
    size the alignment left (stage_run.anchor_size; batch workers share the tensor)."""
    size = measured_size(problem, _initial_betas(problem)).detach()
    return torch.full_like(size, float("nan")) if problem.settings.size_anchor == "alignment" else size


# ours: the hand's size held where the alignment left it (settings.size_anchor; or at the initial estimate's,
# from the keypoints' bone lengths, good to 2-3%), within a free band (settings.size_tolerance; default none),
# measured by the shape's scale parameter alone (settings.size_measure; or over the whole hand or the palm). One
# camera barely sees a hand's size (a larger hand farther away looks the same), and a fit can let it wander,
# which costs new poses about 1.5 dB per per cent (docs/performance.md): the alignment sets it from every frame's
# silhouettes at once, and the later stages' batches let the scale parameter wander while Adam fits the
# proportions around it. Held (the default since 2026-11-29), 3 seeds each: on the phone-like clip new
# poses +0.4-1.8 dB, surface 1.38/0.71/0.74 -> 0.63/0.60/0.66 mm, joints and held out level; on the demo new poses
# +0.06-0.35 dB and surface 0.03-0.15 mm better, held out, joints and IoU within the seeds' spread
# (docs/fidelity.md). Weight 0 lets it drift, as it did before.
@_term("size_prior", 1.0, _GEOMETRY, prepare=_size_target)
def _size_prior(batch):
    problem = batch.problem
    if problem.settings.size_anchor == "alignment" and batch.stage.kind is StageKind.ALIGN:
        return problem.avatar.betas.new_zeros(())      # nothing held yet: the alignment sets the size
    return losses.size_prior_loss(measured_size(problem, problem.avatar.betas), problem.term_data["size_prior"],
                                  problem.settings.size_tolerance)


def scene_depth(translations):
    """The scene's depth: the geometric mean of the fitted frames' depths (F, 3) translations."""
    return translations[:, 2].clamp(min=1e-3).log().mean().exp()


def _depth_placeholder(problem):
    """NaN, read by no stage: the alignment sets the depth, and the first stage after it fills this
    in place with the depth it left (stage_run.anchor_size; batch workers share the tensor)."""
    return problem.avatar.transl.new_full((), float("nan")).detach()


# ours, off by default (weight 0): the scene's depth (scene_depth) held where the alignment left it, as the size
# prior holds the shape's scale. A larger hand farther away looks the same: with the scale alone held, the other
# shape parameters and the depths still move the whole scene together in the joint stage. Held, on the phone-like
# clip's 3 seeds the size came right (1.0-1.7% small -> 0.1-0.3%) and new poses gained 0.7-1.25 dB; but on the
# demo clip the alignment leaves the depth where MediaPipe put it (6% far), the joint stage's drift is what brings
# the size near the truth, and held there the hand ended 4.4% large on 3 seeds: new poses -1.4 to -1.8 dB
# (docs/fidelity.md, "The scene's depth held where the alignment left it")
@_term("depth_prior", 0.0, _GEOMETRY, prepare=_depth_placeholder)
def _depth_prior(batch):
    problem = batch.problem
    if batch.stage.kind is StageKind.ALIGN:
        return problem.avatar.betas.new_zeros(())      # nothing held yet: the alignment sets the depth
    return losses.size_prior_loss(scene_depth(problem.avatar.transl), problem.term_data["depth_prior"], 0.0)


# --- appearance

@_term("photometric", 1.0, _APPEARANCE | {StageKind.HELD_OUT}, needs=(SHADED,))
def _photometric(batch):
    return losses.photometric_loss(batch.rendered, batch.target, batch.masks,
                                   inside=batch.problem.photometric_inside[batch.frames])


@_term("perceptual", 1.0, _APPEARANCE | {StageKind.HELD_OUT}, needs=(SHADED,))
def _perceptual(batch):
    return batch.problem.perceptual(batch.rendered * batch.masks, batch.target, batch.masks)


@_term("texture", 2.0, _APPEARANCE)
def _texture(batch):
    return losses.texture_smoothness_loss(batch.problem.avatar.albedo, batch.problem.uv_mask, batch.generator)


@_term("normal_map", 0.5, _APPEARANCE)
def _normal_map(batch):
    return losses.normal_map_loss(batch.problem.avatar.unit_normal_map(), batch.problem.uv_mask, batch.generator)


# per-frame exposure gains: smooth over time, average 1, near what the background shows (when on)
@_term("exposure", 1.0, _APPEARANCE, applies=lambda problem: problem.exposure_on)
def _exposure(batch):
    avatar = batch.problem.avatar
    return losses.exposure_loss(avatar.exposure, avatar.frame_numbers, *batch.problem.exposure_measured)


# ours: the environment light's coefficients held towards none (a uniform room), so that what the light
# need not explain stays in the albedo only where the frames agree on it; on only while the light is in use
@_term("environment", 0.1, _APPEARANCE,
       applies=lambda problem: bool(problem.avatar.environment_on))
def _environment(batch):
    return losses.environment_prior_loss(batch.problem.avatar.environment)


# ours: the world the environment and the ambient stand for nowhere darker than no light (the albedo
# solve holds its environment so too); otherwise the bind's world, which clips it, lights the hand differently
@_term("environment_realisable", 100.0, _APPEARANCE,
       applies=lambda problem: bool(problem.avatar.environment_on))
def _environment_realisable(batch):
    avatar = batch.problem.avatar
    return losses.environment_realisable_loss(avatar.environment, avatar.ambient)
