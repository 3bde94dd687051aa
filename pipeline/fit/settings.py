"""Fit settings: presets, the planned schedule (schedule.py) and the energy weights (the
registry's defaults, energy_terms.py)."""
from __future__ import annotations

import dataclasses
import math

from ..formats import colour_model
from .energy_terms import ENERGY_TERMS, SIZE_MEASURES, default_weights
from .losses import POSE_SMOOTHNESS, SIZE_TOLERANCE
from .schedule import Schedule, StageKind

# the default energy weights, one per registered term (energy_terms.py: Table C.1 and ours)
WEIGHTS = default_weights()
ALBEDO_FILL_CHOICES = ("decided", "feathered", "edge")   # FitSettings.albedo_fill
# FitSettings.occlusion: in the stages and after them, after them only, not at all
OCCLUSION_CHOICES = ("on", "after", "off")


# settings that earlier versions stored; the step costs are now measured (estimate.py)
RETIRED = ("seconds_per_step", "seconds_per_align_frame")


@dataclasses.dataclass
class FitSettings:
    preset: str = "fast"
    resolution: int = 256          # long side of the working images, pixels
    texture_size: int = 256
    batch_size: int = 6
    # geometry; geometry + appearance; appearance (fast's: the albedo is solved after the stages, and the appearance
    # stage's second hundred steps bought nothing beyond the seeds' spread: docs/performance.md)
    steps: tuple = (200, 300, 100)
    align_steps: int = 100          # coarse alignment of every frame before the geometry stage
    # the alignment renders and compares its silhouettes this many times smaller than the working frames
    # (FitProblem.alignment_view): it renders every frame in every step, and 84% of its step was rendering. At 2,
    # `fast`'s alignment of the 150-frame sun clip took 80 s against 165 on one core, the phone-like and demo clips'
    # 17.5 / 20 s against 36 / 35, their aligned poses' joint error and IoU level (1.244 / 1.243 mm, 0.9357 both);
    # at 3 and 4 the IoU began to fall (0.9348, 0.9324) for 21-28 s more saved (docs/performance.md)
    align_downscale: int = 2
    lr_align_rotation: float = 1e-2
    lr_align_translation: float = 1e-3
    lr_geometry: float = 1e-3       # rotations (rad) and translations (m) per Adam step
    lr_betas: float = 1e-2          # shape units per step
    lr_displacement: float = 1e-4   # metres per step
    # displacements per point of the unsubdivided mesh, carried to the subdivided one ("coarse"),
    # or per subdivided point ("fine"; also checkpoints from before the choice). `fast`, `balanced` (retired):
    # the coarse grid's reposed hands are 26-37% less rough, its other figures equal or better;
    # `paper` keeps the fine grid, whose new poses score 0.7-1.2 dB higher at 448 px (docs/fidelity.md)
    displacement_grid: str = "coarse"
    lr_appearance: float = 1e-2
    # the joint and appearance stages (the last to move their parameters) end at this fraction of their
    # learning rates, along a half cosine (stage_run.learning_rate_factor). 1: constant, the default and fast's:
    # at 0.1 the exact sweep clip's joint error ended at its curve's minimum (0.41 mm, against 0.60 at constant
    # rates), but at fast's steps the demo clip's fit needs them: held-out PSNR 0.32-0.44 dB and joints 0.09-0.13
    # mm worse on three seeds of three (docs/fit.md, "Learning rates that fall within a stage"); 0.1 in `full`,
    # which has twice the steps
    final_rate_fraction: float = 1.0
    # in the same stages, the rates halve after each window of stage_run.PLATEAU_WINDOW steps whose mean loss
    # fell by less than this share of the window's before (down to stage_run.PLATEAU_FLOOR); 0: never, the
    # default: at 0.01 the exact sweep clip's joints ended at their minimum (0.43 mm), but the demo clip lost
    # 0.26 dB held out (its noisy batch losses read as a plateau; docs/fit.md)
    plateau_tolerance: float = 0.0
    solve_albedo: bool = True       # the final albedo solved from the frames (albedo_solve.py)
    # passes of the albedo's solves and fill after the stages (fitting.solve_and_fill_again), each starting from the
    # last pass's albedo and room light. 2, the default: as a second pass replayed on 3 seeds of each clip on fits with
    # the occlusion drawn after the stages (87750ff): phone-like new poses +0.22-0.29 dB, the albedo 0.17-0.27 dB nearer
    # the truth; the demo +0.05-0.06; 39-43 s more on 24 frames, 34 s on the 150-frame sun clip on one core
    # (docs/fidelity.md). 1: one pass from the stages' albedo (`preview`)
    albedo_passes: int = 2
    # the long side, pixels, of the frames the albedo solve reads a second time, the light held
    # (FitProblem.at_resolution, fitting._after_the_stages): the stages fit the shape, poses and light at `resolution`,
    # but the texture can take what finer frames show of the skin (never above the clip's own size). None or 0: the
    # working frames alone. `fast` and `full`: 1024, the most the import keeps (sequence_import.DEFAULT_SIZE), so the
    # clip's own size; at 448 on the phone-like clip held out +0.31-0.39 dB and new poses +0.25 dB on 3 seeds of 3,
    # the 150-frame sun clip's L1 level, about 44 s on 150 frames (docs/fidelity.md, "The albedo solved again from
    # the footage's own pixels, the light held"); at its own 873 px with grow_texture, the section "Texture detail
    # at the footage's resolution"
    solve_resolution: int | None = None
    # the finer solve fills a texture as fine as its frames hold (texel_footprint.fitting_texture_size: a texel
    # two pixels across at the median pixel), where that is finer than the stages' texture_size: on the phone-like
    # clip imported at its 873 px (harp import-video now keeps the hand at up to 1024 px) a 512 texture in place of
    # 256 (docs/fidelity.md, "Texture detail at the footage's resolution"). A texture_size given is kept as given.
    grow_texture: bool = True
    shadows: str = "auto"          # auto | on | off
    exposure: str = "auto"         # per-frame exposure gains: auto | on | off (problem.py decides auto)
    # the environment light (spherical harmonics beside the point light): auto | on | off; `auto` fits
    # it and keeps it where its colour changes with direction (fitting.py): on an exact clip lit by a
    # coloured room it was kept on 3 seeds of 3 (fitted frames +1.0 dB), off on every clip without one
    # (the demo's 3 seeds level with `off`; docs/fidelity.md)
    environment: str = "auto"
    # the skin's specular lobe (a roughness and a level, formats/specular_lobe.py): auto | on | off; `auto` fits
    # it and keeps it where it carries a visible share of the light (fitting.py)
    specular: str = "auto"
    # the light's size (render/area_light.py): "auto" tries a point and discs 6-19 degrees in radius after the
    # stages and keeps the one whose shadows explain the frames best (light_size.py), "off" keeps HARP's point
    # light. Only a fit with self-shadowing decides one
    light_size: str = "auto"
    # the light's inverse-square falloff (render/renderer.Light.falloff): "on" shades the point light's direct light
    # by (d0 / d)^2, d0 the light's distance from the hand's mean place (Avatar.falloff_reach), as a lamp or a window
    # a metre away lights the nearer fingers more than the wrist; "off" is HARP's light, as strong everywhere on the
    # hand. On the phone-like clip under its own window: one albedo solve 8-9% nearer the truth, the fit's whole
    # work after the stages sharper by 0.01-0.03 on 3 seeds, new poses level; the fit does not search the light's
    # distance yet, and a whole fit with it on (its light 0.4 m away) lost 2 dB held out: off (docs/fidelity.md,
    # "The light's falloff with distance")
    light_falloff: str = "off"
    # how the albedo and light make the frames' values (formats/colour_model.py): "linear" (sRGB decoded, shaded
    # in linear light and encoded, as a camera and Blender do) or "display" (the frames' 8-bit values shaded as
    # they are, as HARP does and fits did before). linear, on 3 seeds: held-out PSNR level on the demo and the
    # phone-like clip, the latter's albedo nearer the truth on every seed (mean error 0.08-0.14 against 0.15-0.17),
    # and the Blender bind shading as the fit does (34.2 dB against 21.1 where the room light is realisable;
    # docs/fidelity.md, "Shading in linear light")
    colour_model: str = "linear"
    # the room light (ambient and environment) held back where the hand itself stands in its way (render/occlusion.py):
    # "on" (in the stages' steps and after them), "after", the default (drawn from the work after the stages on: the
    # albedo solve, the light's decisions, the outputs and the held-out frames' evaluation, the stages' steps shading
    # without it; one measurement per frame at the final poses, the one the openness weight takes anyway) | "off"
    # (every point sees the whole room, HARP's light). "after" against "off", whole fits at 87750ff, 3 seeds each:
    # the phone-like clip held out +0.11-0.28 dB, new poses +0.25-0.38, the albedo 0.28-0.46 dB nearer the truth;
    # the demo held out +0.37-0.52 (back within 0.2 dB of the albedo solved from every pixel alike), new poses
    # +0.23-0.32; "on" scored as "after" for 4-6 measurements per frame (docs/fidelity.md, "The occlusion drawn
    # after the stages")
    occlusion: str = "after"
    # frames the alignment left off their silhouettes started again from their neighbours (lost_frames.py):
    # "on" | "off", the default: on the phone-like clip (2 seeds) the fitted and held-out frames gained 0.4-1.3 dB
    # and the albedo came nearer the truth, but the hand's size moved (surface 0.68 -> 2.31 and 0.73 -> 0.87 mm,
    # new poses worse); with the size held (energy_terms size_prior), 3 seeds: held out +0.76 dB, the surface still
    # worse on 2; with the scale held where the alignment left it (the default), 3 seeds: joints -0.04 to -0.2 mm,
    # the albedo sharper, but new poses -0.6 to -2.3 dB, the hand 0.7-3.2% large (docs/fit.md)
    restart_lost_frames: str = "off"
    # the point light's direction and the ambient ratio searched over the whole sphere before the first stage that
    # fits them (light_search.py): "on", the default, | "off" (the light starts in front of the hand, above the
    # camera). On the phone-like clip's 3 seeds every one then found the window, where one had before: held out
    # 27.91 -> 28.96 dB on the mean, new poses +1.1 dB, the albedo nearer the truth but a tenth less sharp (which
    # the lobe's sheen of the room, added after it, brought back); the demo level (docs/fit.md); about 5 s
    light_search: str = "on"
    # the albedo solve's pixels weighted by how squarely they see the surface (albedo_solve._facing): "on" |
    # "off", the default: on the phone-like clip's seed 0 it lost 0.3 dB held out and its albedo was no nearer
    # the truth (one seed; docs/fidelity.md)
    albedo_facing: str = "off"
    # the albedo solve's pixels weighed by how much of the room their surface sees (albedo_solve.openness):
    # the hollows of a fist, lit by the skin around them more than by the room, leave the albedo to the fill. On the
    # demo's 3 seeds the albedo 1.9-2.1 dB nearer the truth, new poses +0.31-0.50 dB, held out -0.54-0.71 dB (the
    # hollows Cycles darkens; with occlusion "on" as well, within 0.2 dB: docs/fidelity.md)
    albedo_openness: str = "on"
    # what the fill keeps of the solved albedo (texture_fill.fill_unseen): "decided", the default, every texel the
    # frames decide kept as solved; "feathered", each texel as far as pixels that see its skin squarely decide it
    # (albedo_solve.texel_trust: a texel seen mostly edge-on blends into the fill); or "edge", only the skin seen
    # almost only edge-on (fitting.EDGE_SQUARE_SHARE) blended, within fitting.EDGE_BLEND_REACH of the fill. On a
    # real clip that never turns the palm to the camera, "decided" draws a dark jagged line along the hand's side
    # where the solved texels meet the fill, and both others remove it; on the phone-like clip's 3 seeds "edge"
    # cost new poses 0.13-0.20 dB (seed 0: "feathered" 0.52): the decided skin's edge is seen edge-on all along,
    # and there it holds the tone boundary (docs/real_footage.md)
    albedo_fill: str = "decided"
    # frames kept out of the fit and scored as it runs: the best state is written (validation.py). Off until it
    # is shown to help: with `fast` on the demo clip (3 seeds) it left held-out PSNR level (27.76 dB both), joints
    # 0.11 mm worse, 10% more time; on the sun clip it went back to an earlier state whose surface was 36% worse
    # (docs/fit.md). Not measured on balanced and paper.
    validation_frames: int = 0
    max_frames: int = 150          # longer clips are subsampled, keeping view coverage; 150: a 5-second
    #                                phone clip whole (on the 150-frame study clip, `fast` over all frames
    #                                against 60 of them: 4% more time, L1 0.0299 against 0.0333 and joint
    #                                error 2.12 against 3.21 mm: docs/performance.md)
    # the size the size_prior term holds (energy_terms.py): "alignment", the default, the hand's size where the
    # alignment left it (every frame's silhouettes at once), the term silent in the alignment itself; or "initial",
    # the initial estimate's (from the keypoints' bone lengths, good to about 3%: give it that free band,
    # losses.SIZE_TOLERANCE). Along the fit a larger hand farther away looks the same, and the later stages'
    # batches drift along that valley (phone-like seed 0: 0.2% off after the alignment, 2.3% small after the
    # geometry stage, 4% large after the joint stage; docs/fidelity.md)
    size_anchor: str = "alignment"
    size_tolerance: float = 0.0    # the size prior's free band around that size (a fraction): held exactly
    # what the size prior measures (energy_terms.SIZE_MEASURES): "scale", the default, the shape's scale parameter
    # alone (every proportion free); "hand", the spread of all 21 keypoints at rest; "palm", of the wrist and the
    # knuckles alone (the fingers' lengths free). What wanders in the later stages is the scale parameter, moved
    # along while Adam fits its neighbours (the fingers' lengths); held where the alignment left it, on the
    # phone-like clip's 3 seeds: "scale" new poses +0.4-1.8 dB, surface 0.60-0.66 mm, joints level; "hand" and
    # "palm" held the proportions back and cost the joints 0.06-0.16 mm (docs/fidelity.md)
    size_measure: str = "scale"
    # how the temporal term measures the hand's translations: "metres", as the camera's frame holds them, or
    # "camera", as the camera sees them (image position and log depth, losses.camera_relative_translations), blind
    # to the whole scene's scale, which metres are not: they favour a nearer, smaller hand
    # On the phone-like clip's 3 seeds: new poses +0.2-1.6 dB with exact masks, held out +0.1-0.3 dB from the video
    # alone, but the fitted frames 0.1-1.1 dB lower and the joints 0.03-0.13 mm worse on both paths; on the demo
    # level: off (docs/fidelity.md)
    translation_smoothness: str = "metres"
    # what the temporal pose term measures of the joint rotations (losses.temporal_pose_loss): "velocity", their
    # change between frames, "acceleration", the change of that change, or "adaptive" (the default), each joint's
    # velocity where the initial estimate, smoothed over time, holds it still and its acceleration where it moves
    # (losses.joint_stillness). The velocity holds every frame towards its neighbours' mean, so a finger that bends
    # and straightens is pulled short of its swing; the acceleration lets still fingers keep more of the start's
    # noise. On the study's clips (gt-noise, fast, fit seeds 0-2) "adaptive" took the `fingers` clips' joints from
    # 2.42-2.71 mm (velocity) to 1.44-1.65 (acceleration 1.50-1.73), ending within 3% of the curve's lowest, and held
    # the `flip` clips' at the velocity's (acceleration: 27-34% higher); the MediaPipe-started demo level within its
    # seeds' spread; on 6-frame clips 4-7% behind the velocity (docs/study.md, section 7)
    pose_smoothness: str = "adaptive"
    # what the keypoint anchor holds of the initial estimate's keypoints: "held", their root-relative positions in
    # metres (their size too: MediaPipe's, good to 2-3%), or "free", the same with the fitted hand brought to
    # the initial estimate's size first (energy_terms._keypoint_anchor): the pose and the proportions held, the
    # size left to the silhouettes and the size prior. On the phone-like clip's 3 seeds the size wandered as far
    # either way (new poses -0.9 / +0.7 / +1.4 dB, joints level or worse): "held" (docs/fidelity.md)
    anchor_size: str = "held"
    weights: dict = dataclasses.field(default_factory=default_weights)
    # {term: {stage name: factor}}: a term's weight in a stage, times this (energy_terms.EnergyTerm.stage_factors)
    stage_factors: dict = dataclasses.field(default_factory=dict)
    # {term: {stage name: fraction}}: a term's weight fading along a stage to this fraction of its start, a half
    # cosine (energy_terms.EnergyTerm.stage_fades)
    stage_fades: dict = dataclasses.field(default_factory=dict)
    perceptual_weights: str | None = None   # local VGG16 file; default: weight-free pyramid
    checkpoint_seconds: float = 120.0
    budget_seconds: float | None = None   # the steps are cut to end within this (budget.py)
    seed: int = 0

    def __post_init__(self):
        colour_model.checked(self.colour_model)
        if self.occlusion not in OCCLUSION_CHOICES:
            raise ValueError(f"occlusion must be one of {', '.join(OCCLUSION_CHOICES)}, got {self.occlusion!r}")
        if self.restart_lost_frames not in ("on", "off"):
            raise ValueError(f"restart_lost_frames must be 'on' or 'off', got {self.restart_lost_frames!r}")
        if self.light_size not in ("auto", "off"):
            raise ValueError(f"light_size must be 'auto' or 'off', got {self.light_size!r}")
        if self.light_falloff not in ("on", "off"):
            raise ValueError(f"light_falloff must be 'on' or 'off', got {self.light_falloff!r}")
        if self.light_search not in ("on", "off"):
            raise ValueError(f"light_search must be 'on' or 'off', got {self.light_search!r}")
        if self.size_anchor not in ("initial", "alignment"):
            raise ValueError(f"size_anchor must be 'initial' or 'alignment', got {self.size_anchor!r}")
        if self.translation_smoothness not in ("metres", "camera"):
            raise ValueError(f"translation_smoothness must be 'metres' or 'camera', got {self.translation_smoothness!r}")
        if self.pose_smoothness not in POSE_SMOOTHNESS:
            raise ValueError(f"pose_smoothness must be one of {', '.join(POSE_SMOOTHNESS)}, got {self.pose_smoothness!r}")
        if self.anchor_size not in ("held", "free"):
            raise ValueError(f"anchor_size must be 'held' or 'free', got {self.anchor_size!r}")
        if self.size_measure not in SIZE_MEASURES:
            raise ValueError(f"size_measure must be one of {', '.join(map(repr, SIZE_MEASURES))}, got {self.size_measure!r}")
        if not 0 <= self.size_tolerance < 1:
            raise ValueError(f"size_tolerance must be a fraction from 0 to 1, got {self.size_tolerance!r}")
        if self.albedo_facing not in ("on", "off"):
            raise ValueError(f"albedo_facing must be 'on' or 'off', got {self.albedo_facing!r}")
        if self.albedo_openness not in ("on", "off"):
            raise ValueError(f"albedo_openness must be 'on' or 'off', got {self.albedo_openness!r}")
        if self.albedo_fill not in ALBEDO_FILL_CHOICES:
            raise ValueError(f"albedo_fill must be one of {', '.join(ALBEDO_FILL_CHOICES)}, got {self.albedo_fill!r}")
        if not isinstance(self.align_downscale, int) or self.align_downscale < 1:
            raise ValueError(f"align_downscale must be a whole number from 1 (the working size), "
                             f"got {self.align_downscale!r}")
        if self.solve_resolution and self.solve_resolution < 16:
            raise ValueError(f"solve_resolution must be at least 16 px (0 or None: the working resolution), "
                             f"got {self.solve_resolution}")
        if not isinstance(self.albedo_passes, int) or self.albedo_passes < 1:
            raise ValueError(f"albedo_passes must be a whole number from 1, got {self.albedo_passes!r}")
        if not 0.0 < self.final_rate_fraction <= 1.0:
            raise ValueError(f"final_rate_fraction must be in (0, 1] (1: constant rates), "
                             f"got {self.final_rate_fraction}")
        if not 0.0 <= self.plateau_tolerance < 1.0:
            raise ValueError(f"plateau_tolerance must be in [0, 1) (0: off), got {self.plateau_tolerance}")
        # a misspelt term or stage would otherwise leave the weight as it was, without a word
        stages = {kind.value for kind in StageKind}
        for field, per_term in (("stage_factors", self.stage_factors), ("stage_fades", self.stage_fades)):
            for term, factors in per_term.items():
                if term not in ENERGY_TERMS:
                    raise ValueError(f"{field}: no energy term named {term!r}; the terms: {', '.join(ENERGY_TERMS)}")
                unknown = sorted(set(factors) - stages)
                if unknown:
                    raise ValueError(f"{field}[{term!r}]: no stage named {unknown[0]!r}; "
                                     f"the stages: {', '.join(sorted(stages))}")
                negative = [stage for stage, value in factors.items() if not value >= 0]
                if negative:
                    raise ValueError(f"{field}[{term!r}][{negative[0]!r}] must be 0 or more, got {factors[negative[0]]!r}")

    @property
    def occlusion_in_stages(self) -> bool:
        """Whether the stages' gradient steps shade with the room light's occlusion."""
        return self.occlusion == "on"

    @property
    def occlusion_drawn(self) -> bool:
        """Whether the finished avatar is shaded with it (the work after the stages, the outputs,
        the evaluation, the renders of the avatar)."""
        return self.occlusion != "off"

    def schedule(self) -> Schedule:
        """The planned schedule: the alignment (ours: it widens the basin the three stages start
        from), then the appendix's three stages."""
        geometry, joint, appearance = self.steps
        return Schedule.of_steps({StageKind.ALIGN: self.align_steps, StageKind.GEOMETRY: geometry,
                                  StageKind.JOINT: joint, StageKind.APPEARANCE: appearance})

    @classmethod
    def from_dict(cls, values):
        """FitSettings from vars() of one (as a checkpoint stores them); unknown keys are an error
        (RETIRED ones are dropped: checkpoints from before their retirement still load)."""
        values = {k: v for k, v in values.items() if k not in RETIRED}
        values.setdefault("displacement_grid", "fine")   # saved before the coarse grid existed
        values.setdefault("validation_frames", 0)        # saved before validation inside the fit
        values.setdefault("stage_factors", {})
        values.setdefault("stage_fades", {})             # saved before weights faded along a stage
        values.setdefault("environment", "off")          # saved before the environment light
        values.setdefault("specular", "off")             # saved before the specular lobe
        values.setdefault("albedo_openness", "off")      # saved before the solve weighed pixels by it
        values.setdefault("albedo_passes", 1)            # saved before the solves ran more than once
        values.setdefault("light_size", "off")           # saved before the light had a size
        values.setdefault("light_falloff", "off")        # saved before the light fell off with distance
        values.setdefault("grow_texture", False)         # saved before the finer solve grew the texture
        values.setdefault("final_rate_fraction", 1.0)    # saved before the learning rates fell
        values.setdefault("plateau_tolerance", 0.0)      # saved before the rates halved on a plateau
        values.setdefault("colour_model", "display")     # saved before the colour model was a choice: display
        values.setdefault("occlusion", "off")             # saved before the room light's occlusion
        values.setdefault("restart_lost_frames", "off")   # saved before lost frames were started again
        values.setdefault("light_search", "off")          # saved before the light was searched
        values.setdefault("align_downscale", 1)           # saved before the alignment rendered smaller
        values.setdefault("translation_smoothness", "metres")   # saved before the choice
        values.setdefault("anchor_size", "held")                # likewise
        values.setdefault("pose_smoothness", "velocity")        # saved before the choice
        # saved before the size was held by default: the size prior as it was then (weight 0 unless asked for)
        values.setdefault("size_anchor", "initial")
        values.setdefault("size_tolerance", SIZE_TOLERANCE)
        values.setdefault("size_measure", "hand")
        if "weights" in values and "size_prior" not in values["weights"]:
            values["weights"] = {**values["weights"], "size_prior": 0.0}
        if "weights" in values and "depth_prior" not in values["weights"]:   # saved before the depth prior existed
            values["weights"] = {**values["weights"], "depth_prior": 0.0}
        unknown = sorted(set(values) - {field.name for field in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"settings this version does not know: {', '.join(unknown)}")
        if "steps" in values:
            values["steps"] = tuple(values["steps"])
        return cls(**values)


PRESETS = {
    # a first look in under 2 minutes: 160 px, batches of 10 (each frame's pose visited about as often as in fast's
    # joint stage), a short alignment and joint stage, no appearance stage, and HARP's light alone (no environment
    # light, no specular lobe, a point light: none is fitted nor decided, so the albedo is solved once, in one pass);
    # on a 150-frame 448 px clip with 2 threads, 102 s: joint error 5% and L1 9% above fast's (docs/performance.md,
    # "A first avatar in two minutes")
    "preview": dict(resolution=160, texture_size=256, batch_size=10, steps=(20, 170, 0), align_steps=50,
                    environment="off", specular="off", light_size="off", albedo_passes=1),
    # 100 appearance steps, not 200: the albedo is solved from the frames after the stages, and from the joint stage's
    # end of 3 phone-like and 3 demo fits the second hundred moved held-out PSNR by -0.07 to +0.22 dB and new poses by
    # -0.03 to +0.03 (the seeds' spread 0.2-0.5 dB), for 45-52 s (docs/performance.md, "The appearance stage halved")
    "fast": dict(resolution=256, texture_size=256, batch_size=6, steps=(200, 300, 100), solve_resolution=1024),
    # fast's fit carried on to convergence: twice its steps after the alignment (as fast was until its appearance
    # stage was halved: 400 appearance steps), the joint and appearance stages' rates falling to a tenth (at constant
    # rates the poses wander once the fit has converged). Against fast, 3 seeds each (docs/performance.md, "`full`:
    # fast's fit carried to convergence"): held-out PSNR +0.22 dB on the phone-like clip and +0.28 on the demo,
    # fitted frames +0.4 / +0.7 dB, joints 8% lower on the phone-like clip (level on the demo), new poses +0.8 dB in
    # the overlap there (-0.3 on the demo, whose hand keeps MediaPipe's size, 2.5% small); 1.5-1.8x fast's time on
    # 30 frames
    "full": dict(resolution=256, texture_size=256, batch_size=6, steps=(400, 600, 400), final_rate_fraction=0.1,
                 solve_resolution=1024),
    # HARP's own schedule, to compare with the paper: 100 / 50 / 50 epochs over every frame, batches of ~18 frames
    # at 448 px; the `full` preset until the one above replaced it (no better than fast on the clips measured)
    "paper": dict(resolution=448, texture_size=512, batch_size=18, steps=(None, None, None), max_frames=100000,
                  displacement_grid="fine"),
}


# presets renamed: {old name: the name its settings have now} (a fit started under the old name resumes under the new)
RENAMED_PRESETS = {"full": "paper"}      # HARP's schedule, `full` until code 9cab746

# presets no longer offered, and why (a finished fit of one still loads: its checkpoint holds its settings)
RETIRED_PRESETS = {"balanced": "fast scored as well or better on every clip measured, and balanced's longer fit let "
                               "the hand's size drift (docs/performance.md)"}


def texture_size_for(working_size):
    """The largest texture a clip worked at `working_size` pixels (long side) can fill: the power
    of two at or above it. A finer texture has texels smaller than the pixels that see them; on
    the 256 px demo clip the paper's schedule's 512 texture was 38% less sharp than a 256 one, compared at 256
    (docs/fidelity.md)."""
    return max(64, 2 ** math.ceil(math.log2(max(1, working_size))))


def settings_for(preset, frame_count, image_size=None, **overrides):
    """FitSettings of a preset; the paper preset turns epochs into steps over the frames it fits
    (the clip's `frame_count`, at most max_frames). With `image_size` (the clip's long side,
    pixels), the preset's texture shrinks to what the working images can fill
    (texture_size_for); a texture_size given in `overrides` is kept as given."""
    if preset in RETIRED_PRESETS:
        raise ValueError(f"preset {preset!r} was retired: {RETIRED_PRESETS[preset]}; choose one of {list(PRESETS)}")
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {list(PRESETS)}")
    values = dict(PRESETS[preset])
    values.update({k: v for k, v in overrides.items() if v is not None and k != "steps"})
    if image_size is not None and overrides.get("texture_size") is None:
        working = min(values["resolution"], image_size)
        values["texture_size"] = min(values["texture_size"], texture_size_for(working))
    if overrides.get("texture_size") is not None and overrides.get("grow_texture") is None:
        values["grow_texture"] = False      # the size asked for is the size written
    if image_size is not None and values.get("solve_resolution"):
        # the frames the albedo solve reads are the clip's own at most; at the working size, no second pass
        finer = min(values["solve_resolution"], image_size)
        values["solve_resolution"] = finer if finer > min(values["resolution"], image_size) else None
    if preset == "paper":
        fitted = min(frame_count, values.get("max_frames", FitSettings.max_frames))
        per_epoch = max(1, -(-fitted // values["batch_size"]))
        values["steps"] = (100 * per_epoch, 50 * per_epoch, 50 * per_epoch)
    if overrides.get("steps") is not None:
        values["steps"] = overrides["steps"]
    return FitSettings(preset=preset, **values)
