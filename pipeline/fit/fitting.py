"""`harp fit`: the stages of Adam over the avatar (appendix C.3, with our alignment first), with
checkpoints, resume, progress, observers (the anytime curve) and the scene adaptations (mode,
shadows, frames).

Only this module knows the order of stages; a stage's steps are stage_run.py's, the energy is
energy.py's, the problem (clip, avatar, fixed data) is built once in problem.py.
"""
from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
import time
from pathlib import Path

import numpy as np
import torch

from ..formats.environment_light import colour_strength, relative_strength
from ..formats.initial_estimate import read_initial_estimate
from ..formats.sequence_folder import validate_sequence_folder
from .albedo_solve import decided_texels, solve_avatar_albedo, texel_trust
from .avatar import APPEARANCE, SHAPE, SWITCHES
from .checkpoint import CHECKPOINT_FILE, CHECKPOINT_VERSION, Checkpoint, FitState, load_checkpoint, save_checkpoint
from .budget import BudgetKeeper
from .estimate import FitEstimate, active_stages, measure_step_costs
from .frames import held_out_frames, select_frames, validation_frames
from .light_probe import probe_frames, probe_l1
from .light_search import search_light
from .light_size import decide_light_size
from .lost_frames import LOST_IOU, anchor_restarted, frames_kept, frames_off_their_silhouettes, restart_lost_frames
from .outputs import write_outputs
from .problem import FitError, FitProblem, build_problem
from .progress import Progress, duration_text
from .schedule import SHADOWS_DECIDED_IN, StageKind, step_kind
from .settings import PRESETS, RENAMED_PRESETS, settings_for
from .specular_share import specular_share
from .stage_run import StageRun
from .texel_footprint import grow_texture
from .texture_fill import fill_avatar_albedo
from .validation import Validator, restore_best

# `shadows auto` renders light_probe.PROBE_FRAMES fitted frames with and without self-shadowing, each with its
# albedo solved from them, and keeps whichever matches them better. Where the point light carries most of the
# light (a fitted ambient ratio under SHADOW_DOMINANT_AMBIENT) shadows stay on unless the renders with them are further from the frames
# by more than SHADOW_TOLERANCE of the L1: on the phone-like clip's three fits (a window's soft light from one
# side, ambient 0.23) the L1 with shadows was 0.989 / 0.992 / 1.008 of that without, and the albedo solved with
# them 1.2-1.3 dB nearer the truth on each. Where the room's light dominates, a point light's shadows are a
# small share of the shading and cost a shadow map at every shaded step (+16-25% a step): they must bring
# the renders nearer by as much (the demo clip's uniform world, ambient 0.81: L1 and albedo alike either way)
# (docs/fidelity.md, "Shadows decided with the albedo solved")
SHADOW_TOLERANCE = 0.02
SHADOW_DOMINANT_AMBIENT = 0.5
# an `auto` environment light whose colour varies over the sphere by less than this share of the
# ambient (environment_light.colour_strength) is switched off. Exact clips over 3 seeds (docs/fidelity.md):
# 0.035 fitted on a room of 0.038, 0.002 on a clip without one; the demo 0.003, the MediaPipe sample video 0.013
ENVIRONMENT_THRESHOLD = 0.015
# and on fewer fitted frames than this it stays off, as the specular lobe does: a few views cannot tell a room's
# light (or a sheen) from the albedo (the add-on tests' 4-frame, 12-step fit of a clip under a white world found
# a "room" of colour strength 0.044)
ENVIRONMENT_MIN_FRAMES = 8
# an `auto` specular lobe whose highlight (specular_share.py: the 99th percentile of its share of each pixel's
# colour on the fitted frames) is below this is switched off; the same few-views rule as the environment's.
# Exact clips (tests/test_fit_specular.py's, 200 steps a stage): 0.134 fitted where the skin was drawn with an
# oily lobe (roughness 0.4, level 0.6), 0.015 with a faint satin one (0.6, 0.3; fitted PSNR on and off within
# 0.02 dB), 0.003 without one; a Cycles sun clip (level 0.24) 0.009, the MediaPipe sample video 0.004, the demo
# (a white world, no light to reflect) under 0.001 (docs/fidelity.md)
SPECULAR_THRESHOLD = 0.03
KNOWN_APPEARANCE = SHAPE + APPEARANCE   # what a fit with known appearance takes from another fit, frozen
# settings of what runs after the stages: a resumed fit may change them (they do not touch the checkpoint)
AFTER_THE_STAGES = ("solve_albedo", "solve_resolution", "light_size", "grow_texture")
# the key of FitState.albedo_solve that holds the figures of its finer pass (albedo alone, at solve_resolution)
FINER_SOLVE = "finer"
# FitSettings.albedo_fill "edge": how far from the fill texels seen mostly edge-on blend into it (metres
# on the rest surface), and the squarely-seen share of a texel's weight above which it is kept as solved
# (albedo_solve.texel_trust; "feathered" keeps its SQUARE_SHARE, 0.5). On the phone-like clip's 3 seeds a
# share of 0.1 cost new poses 0.13-0.20 dB against 0.5's 0.31-0.41, and still took the close-up's line
EDGE_BLEND_REACH = 0.004
EDGE_SQUARE_SHARE = 0.1
# a budgeted fit resumes with a new budget, or without one on the schedule it had (FitState.schedule)
BUDGET = ("budget_seconds",)
# the alignment's silhouette size: its poses come out the same at either (docs/performance.md), so a fit started
# before the setting, or under another, resumes with today's
ALIGNMENT_SIZE = ("align_downscale",)

__all__ = ["fit", "FitJob", "FitError", "FitObserver", "CHECKPOINT_FILE"]


class FitObserver:
    """Watches a fit (e.g. the anytime curve, evaluate/curve.py): called at the start, after
    every step and at the end, with the problem and the state. The time it takes is not
    counted as fitting time (FitState.measure_seconds)."""

    def start(self, problem: FitProblem, state: FitState):
        pass

    def step(self, problem: FitProblem, state: FitState):
        pass

    def end(self, problem: FitProblem, state: FitState):
        pass


@dataclasses.dataclass(frozen=True)
class FitJob:
    """How a fit runs, beside what it fits (FitSettings): the preset the settings start from,
    whether it resumes, how it shows progress ("bar", "jsonl", "none"), where it runs, a cap on
    every stage's steps (a quick look), every N-th frame held out for evaluation (frames.py), and
    a finished fit whose shape, displacements, textures and light it takes, frozen, fitting only
    the per-frame poses (HARP-known)."""

    preset: str = "fast"
    resume: bool = False
    progress: str = "bar"
    device: str | None = None
    workers: int = 1              # processes that share each batch's frames (batch_workers.py; CPU only)
    max_steps: int | None = None
    hold_out_every: int | None = None
    known_appearance: str | Path | None = None

    @classmethod
    def split(cls, options: dict) -> tuple[dict, dict]:
        """(the job's options, the settings overrides) of fit()'s keyword options."""
        fields = {field.name for field in dataclasses.fields(cls)}
        return {k: v for k, v in options.items() if k in fields}, {k: v for k, v in options.items() if k not in fields}


def fit(sequence, out, job: FitJob | None = None, observers=(), **options):
    """Fit an avatar to a sequence folder with an init.npz; writes `out` and returns the report.
    `options` are FitJob fields (preset="preview", resume=True, ...) and FitSettings overrides
    (texture_size=512, shadows="off", ...) by name; they replace those of `job`. `observers`
    (FitObserver) watch the fit."""
    started = time.perf_counter()
    sequence, out = Path(sequence), Path(out)
    job_options, overrides = FitJob.split(options)
    job = dataclasses.replace(job or FitJob(), **job_options)
    setup = _set_up(sequence, job, overrides)
    with _batch_workers(setup.problem, setup.recipe, job.workers):
        return _run(setup, job, out, observers, started)


@dataclasses.dataclass
class FitSetup:
    """A fit's problem, the frames it leaves out (held out for evaluation, kept out for its own
    validation) and the arguments of problem.build_problem that made it (for batch workers)."""

    problem: FitProblem
    held_out: np.ndarray
    validation: np.ndarray
    recipe: dict


def _run(setup: FitSetup, job, out, observers, started):
    """The stage loop of fit() over a problem set up."""
    problem, held_out, validation = setup.problem, setup.held_out, setup.validation
    settings = problem.settings
    out.mkdir(parents=True, exist_ok=True)
    validator = Validator(problem, validation) if len(validation) else None
    saver = _CheckpointSaver(out / CHECKPOINT_FILE, problem, validator)
    state, generator, optimiser_state = saver.resume() if job.resume else saver.fresh()
    measured_before = state.measure_seconds
    active = active_stages(problem, settings.schedule())
    costs = measure_step_costs(problem, state, active)     # the calibration step
    budget = None if settings.budget_seconds is None else \
        BudgetKeeper(settings.budget_seconds, settings.schedule(), active, started, state.fit_seconds,
                     state.measure_seconds)
    estimate = FitEstimate(problem, state, costs, active, budget, validator)
    clock = _FitClock(state)      # after the calibration: measuring the step costs is no stage's time
    if state.restarted:           # a resumed fit: the restarted frames' anchors where they were moved
        anchor_restarted(problem, state.restarted)
    with Progress(job.progress, estimate.steps_left) as reporter, _interrupt_flag() as interrupted:
        reporter.log(_opening_line(problem, job.preset, estimate))
        clock.observe(observers, "start", problem)
        for index in range(state.stage, len(state.schedule)):
            run = StageRun(problem, state.schedule[index], state, generator, optimiser_state)
            reporter.enter_stage(*_stage_number(state.schedule, index))
            if validator is not None and optimiser_state is None:   # a stage from its start
                validator.new_stage()
            if optimiser_state is None and run.stage.appearance:    # shaded: the room light's occlusion measured
                problem.avatar.measure_occlusion(exact=True)        # at its start (so a resumed fit does the same)
                if run.has_work and state.light_search is None and settings.light_search == "on" \
                        and "light_position" not in problem.frozen:
                    _search_light(problem, state, reporter)
            optimiser_state = None
            while run.has_work and not run.finished:
                if interrupted.is_set():
                    clock.charge()
                    saver.save(state, run, generator)
                    reporter.log(f"interrupted: saved {saver.path}; continue with --resume")
                    raise KeyboardInterrupt
                kind = step_kind(run.stage, run.shadows())
                result = run.step()
                clock.charge()
                reporter.update(run.stage.name, state.step, result.loss, *estimate.step(kind))
                run.stage = state.schedule[index]     # a budget may have re-planned its steps
                if result.event:
                    reporter.log(result.event)
                _decide_shadows(problem, run, reporter)
                if validator is not None and validator.due(run.stage, state.step):
                    _validate(validator, state, run, index, estimate, reporter)
                clock.observe(observers, "step", problem)
                saver.save_now_and_then(state, run, generator)
            clock.charge()
            if state.schedule[index].kind is StageKind.ALIGN and state.restarted is None \
                    and settings.restart_lost_frames == "on":
                _restart_lost_frames(problem, state, reporter)
            state.stage, state.step, state.order = index + 1, 0, []
            saver.save(state, None, generator)
        _after_the_stages(problem, state, reporter, lambda: saver.save(state, None, generator), validator)
        clock.observe(observers, "end", problem)
    return write_outputs(out, problem, state, held_out, estimate=estimate.report(), validation_frames=validation,
                         elapsed=lambda: time.perf_counter() - started - (state.measure_seconds - measured_before))


def _restart_lost_frames(problem, state, reporter):
    """After the alignment: the frames it left off their silhouettes started again from their
    neighbours (lost_frames.py), said in one line where there were any."""
    state.restarted = restart_lost_frames(problem)
    tried, restarted = state.restarted["tried"], state.restarted["frames"]
    if tried:
        gains = ", ".join(f"{frame} ({before:.2f} -> {after:.2f})" for frame, before, after in
                          zip(restarted, state.restarted["iou_before"], state.restarted["iou_after"]))
        reporter.log(f"frames the alignment left off their silhouettes (IoU under {LOST_IOU}): {tried}; "
                     + (f"started again from their neighbours' poses: {gains}" if restarted
                        else "their neighbours' poses cover them no better: kept"))


def _search_light(problem, state, reporter):
    """Before the first stage that fits the light: the light searched over the sphere
    (light_search.py), said in one line."""
    state.light_search = search_light(problem)
    if state.light_search:
        before, after = state.light_search["before"], state.light_search["after"]
        where = "kept" if not state.light_search["moved"] else \
            f"moved to {_position(after['position'])}, ambient {after['ambient']:.2f} (residual {after['residual']:.4f})"
        reporter.log(f"light search: {state.light_search['candidates']} lights scored by one colour per texel; "
                     f"the starting one at {_position(before['position'])}, ambient {before['ambient']:.2f} "
                     f"(residual {before['residual']:.4f}): {where}")


def _position(values):
    return "(" + ", ".join(f"{value:.2f}" for value in values) + ") m"


def _stage_number(schedule, index):
    """(number from 1, count) of stage `index` among the schedule's stages that have steps."""
    planned = [i for i, stage in enumerate(schedule) if stage.steps > 0]
    return sum(i <= index for i in planned) or 1, max(1, len(planned))


def _validate(validator, state, run, index, estimate, reporter):
    """A validation check after the step just taken; a stage whose checks stopped gaining ends
    here (a new schedule with its steps so far)."""
    started = time.perf_counter()
    point = validator.check(state)
    estimate.checked(time.perf_counter() - started)
    reporter.log(f"validation ({len(validator.frames)} frames kept out) at {run.stage.name} step {state.step}: "
                 f"PSNR {point['psnr_mean']:.2f} dB, IoU {point['silhouette_iou_mean']:.3f}")
    if validator.stage_stalled() and not run.finished:
        reporter.log(f"validation: {run.stage.name} gained under the threshold in {validator.stalled_checks} checks "
                     f"in a row: the stage ends at step {state.step} of {run.stage.steps}")
        state.schedule = state.schedule.with_steps({run.stage.kind: state.step})
        run.stage = state.schedule[index]


def _after_the_stages(problem, state, reporter, save, validator=None):
    """The avatar back at its best validation check (when the last scored below it), the albedo
    solved from the frames (with the environment light, at the working size), the light's `auto`
    decisions, the albedo alone solved again from finer frames where `solve_resolution` asks for
    them (into a texture grown to what those frames hold, with `grow_texture`), then the unseen
    texels filled (each once: a resumed fit skips what has run). Frames the final surface leaves
    off their silhouettes are left out of the solves (_painting_frames)."""
    if validator is not None and state.albedo_solve is None and state.texture_fill is None:
        best = restore_best(validator, state)
        if best is not None:
            reporter.log(f"validation: the avatar of {best.stage} step {best.step} ({best.psnr:.2f} dB) is kept, "
                         f"better than the last check's {state.validation[-1]['psnr_mean']:.2f} dB")
            save()
    timed = _PartTimer(state.after_stages_seconds)
    solving = problem.settings.solve_albedo and not problem.known_appearance
    passes_left = solving and len(state.albedo_passes) < problem.settings.albedo_passes - 1
    # the albedo solve's openness weight and the fill's decided texels read it, where either is still to come
    weighing = solving and problem.settings.albedo_openness == "on" and (state.texture_fill is None or passes_left)
    problem.avatar.occlusion = problem.settings.occlusion_drawn   # `after` switches it on here
    with timed("occlusion"):   # at the final poses, in a resumed fit too
        problem.avatar.measure_occlusion(exact=True, when_off=weighing)
    painting = None
    if solving and (state.albedo_solve is None or state.texture_fill is None or passes_left):
        with timed("albedo_solve"):
            painting = _painting_frames(problem, state, reporter)
    if state.light_size is None and problem.settings.light_size == "auto" and solving:
        with timed("light_decisions"):
            _decide_light_size(problem, state, reporter, painting)
        save()
    if state.albedo_solve is None and solving:
        with timed("albedo_solve"):
            state.albedo_solve = solve_avatar_albedo(problem, state.shadows.on, frames=painting)
        reporter.log(f"albedo solved from the frames on the final geometry and light: "
                     f"{state.albedo_solve['solved_fraction']:.0%} of the texels "
                     f"(mean change {state.albedo_solve['mean_change']:.3f}{_pull_words(state.albedo_solve)})"
                     + (" with the environment light" if "environment_strength" in state.albedo_solve else ""))
        with timed("light_decisions"):
            _decide_light(problem, state, reporter, solved=problem, frames=painting)
        save()
    with timed("light_decisions"):
        _decide_light(problem, state, reporter, solved=None)     # without an albedo solve: as the stages left it
    seen = problem   # the frames the texture is solved from: at solve_resolution where it is finer
    if solving and state.texture_fill is None:
        with timed("albedo_solve"):
            seen = problem.at_resolution(problem.settings.solve_resolution)
        if seen is not problem and FINER_SOLVE not in state.albedo_solve:
            with timed("albedo_solve"):
                texture = grow_texture(seen) if problem.settings.grow_texture else None
                finer = solve_avatar_albedo(seen, state.shadows.on, solve_environment=False, frames=painting)
            state.albedo_solve = {**state.albedo_solve, FINER_SOLVE: {**finer, "texture": texture}}
            grown = "" if texture is None or texture["grown_from"] is None else \
                f", into a texture grown from {texture['grown_from']} to {texture['texture_size']} texels"
            reporter.log(f"albedo solved again from the frames at {max(seen.clip.height, seen.clip.width)} px, "
                         f"the light held{grown}: {finer['solved_fraction']:.0%} of the texels "
                         f"(mean change {finer['mean_change']:.3f}{_pull_words(finer)})")
            save()
    if state.texture_fill is None and not problem.known_appearance:
        with timed("texture_fill"):
            state.texture_fill = fill_albedo(problem, seen, frames=painting)
        reporter.log(f"albedo: {state.texture_fill['unseen_fraction']:.0%} of the texels not decided by the frames "
                     f"(never seen, or only at the silhouette), filled through the surface"
                     + (f", {state.texture_fill['blended_fraction']:.0%} seen only thinly or edge-on blended into it"
                        if state.texture_fill.get("blended_fraction") else "") + " "
                     f"(seam contrast {state.texture_fill['seam_contrast_before']:.3f} -> "
                     f"{state.texture_fill['seam_contrast_after']:.3f})")
        save()
    while solving and len(state.albedo_passes) < problem.settings.albedo_passes - 1:
        with timed("albedo_solve"):
            state.albedo_passes.append(solve_and_fill_again(problem, state.shadows.on, painting))
        again = state.albedo_passes[-1]
        reporter.log(f"albedo solved again (pass {len(state.albedo_passes) + 1} of {problem.settings.albedo_passes}), "
                     f"from the last pass's albedo and room light: mean change "
                     f"{(again[FINER_SOLVE] or again['working'])['mean_change']:.3f}")
        save()


def fill_trust(problem, frames=None):
    """(T, T): how far the fill keeps each texel of the avatar's albedo as solved, as FitSettings.albedo_fill
    asks: albedo_solve.texel_trust ("feathered"; "edge" at EDGE_SQUARE_SHARE) or the texels the frames decide
    ("decided")."""
    if problem.settings.albedo_fill == "decided":
        return decided_texels(problem, frames=frames)
    if problem.settings.albedo_fill == "edge":
        return texel_trust(problem, frames=frames, square_share=EDGE_SQUARE_SHARE)
    return texel_trust(problem, frames=frames)


def fill_albedo(problem, seen, frames=None) -> dict:
    """Fill the avatar's albedo as FitSettings.albedo_fill asks, the trust measured on the frames
    `seen` (the problem at the resolution the albedo was last solved from); "edge" blends only within
    EDGE_BLEND_REACH of the fill (texture_fill.trusted_away_from_fill)."""
    reach = EDGE_BLEND_REACH if problem.settings.albedo_fill == "edge" else None
    return fill_avatar_albedo(problem.avatar, fill_trust(seen, frames=frames), blend_reach=reach)


def solve_and_fill_again(problem, shadows, frames=None) -> dict:
    """One more pass of the albedo's solves and fill on the final geometry and light, each starting
    from the avatar's albedo and room light as the last pass left them (FitSettings.albedo_passes):
    the albedo and room light from the working frames, the albedo alone from the frames at
    solve_resolution where they are finer, then the undecided texels filled. The solves pull
    towards the albedo they start from and alternate the albedo with the room light a few rounds,
    and on real frames one pass from the stages' albedo stops short of where further passes go
    (docs/fidelity.md, "A second albedo pass"). Returns each part's figures and the pass's seconds."""
    started = time.perf_counter()
    working = solve_avatar_albedo(problem, shadows, frames=frames)
    seen = problem.at_resolution(problem.settings.solve_resolution)
    finer = None if seen is problem else solve_avatar_albedo(seen, shadows, solve_environment=False, frames=frames)
    fill = fill_albedo(problem, seen, frames=frames)
    return {"working": working, FINER_SOLVE: finer, "fill": fill, "seconds": time.perf_counter() - started}


def _set_up(sequence, job: FitJob, overrides) -> FitSetup:
    """The FitSetup of a fit's job and settings overrides; bad input is one FitError line."""
    info = validate_sequence_folder(sequence)
    initial = read_initial_estimate(sequence)
    settings = settings_for(job.preset, initial.frame_count, image_size=max(info.width, info.height), **overrides)
    if job.max_steps is not None:  # a quick look (and tests): every stage capped
        most = job.max_steps
        settings = dataclasses.replace(settings, steps=tuple(min(s, most) for s in settings.steps),
                                       align_steps=min(settings.align_steps, most))
    held_out = held_out_frames(initial.frame_count, job.hold_out_every)
    validation = validation_frames(initial.frame_count, settings.validation_frames, exclude=held_out)
    known_appearance, device = job.known_appearance, job.device
    frames = select_frames(initial.frame_count, settings.max_frames, exclude=np.concatenate([held_out, validation]))
    shared = {}
    if known_appearance is not None:
        if not (Path(known_appearance) / CHECKPOINT_FILE).is_file():
            raise FitError(f"known appearance: {known_appearance} is not a fit folder (no {CHECKPOINT_FILE})")
        known = load_checkpoint(Path(known_appearance) / CHECKPOINT_FILE, device)
        if not known.state.finished:
            raise FitError(f"the fit in {known_appearance} has not finished: resume it first")
        shared = {name: known.avatar[name] for name in KNOWN_APPEARANCE + SWITCHES}
        # its light comes with its shadows and environment decisions
        settings = dataclasses.replace(settings, shadows="on" if known.state.shadows.on else "off",
                                       environment="on" if bool(known.avatar["environment_on"]) else "off",
                                       specular="on" if bool(known.avatar["specular_on"]) else "off",
                                       displacement_grid=known.settings.displacement_grid)   # its displacements' grid
    recipe = dict(sequence=sequence, settings=settings, frames=frames, device=device, shared=shared,
                  frozen=tuple(shared))
    return FitSetup(build_problem(**recipe), held_out, validation, recipe)


def _opening_line(problem, preset, estimate):
    settings, initial = problem.settings, problem.initial
    known = ", appearance known (frozen)" if problem.known_appearance else ""
    return (f"fitting {len(problem.frames)} frames ({initial.mode} mode, {initial.side} hand) with preset {preset}"
            f"{known} (images {max(problem.clip.images.shape[1:3])} px, texture {settings.texture_size} px), "
            f"perceptual term {problem.perceptual_name}, exposure gains {problem.exposure_note}"
            + (f"; {problem.mask_cut_frames} masks end mid-forearm (a sleeve?): the silhouette beyond that line is "
               "not compared" if problem.mask_cut_frames else "")
            + f"; expected time {duration_text(estimate.expected_seconds)} on {problem.device} "
            + (f"(step costs measured in {estimate.costs.calibration_seconds:.0f} s)" if estimate.costs.calibrated
               else "(a small fit: step costs not measured)")
            + (_short_budget_note(estimate.budget, preset) if estimate.budget is not None and estimate.budget.too_short
               else ""))


def _short_budget_note(budget, preset):
    names = list(PRESETS)       # lightest first
    before = names[:names.index(preset)][::-1] if preset in names else []
    lighter = ", ".join(before[:-1]) + f" or {before[-1]}" if len(before) > 1 else "".join(before)
    return (f"; the budget leaves the stages {duration_text(max(0.0, budget.stage_seconds))} of the "
            f"{duration_text(budget.needed_seconds)} that preset {preset} needs at the least on this clip, so every "
            "stage is cut short" + (f": preset {lighter} would use the time better" if lighter
                                    else ": a longer budget or fewer frames would help"))


def _decide_shadows(problem, run, reporter):
    """Self-shadowing pays off where the scene's light casts shadows: `auto` decides half-way
    through the joint stage by rendering up to light_probe.PROBE_FRAMES fitted frames with and without
    it, each with the albedo solved from those frames for it (the light held; probe_l1): the
    avatar has been fitted without shadows so far, and its albedo has taken in every shadow the
    frames show alike, which a render with shadows would then darken twice. Shadows are kept
    unless they take the renders further from the frames (L1 in the masks) by more than
    SHADOW_TOLERANCE where the point light carries most of the light: where the frames cannot
    tell (a shadow that falls on the same skin in every frame that shows it explains them as well
    as a darker albedo does), its own shadows are kept, since a shadow taken into the albedo is
    wrong in every new pose. Under a dominant room light they must bring the renders nearer by
    as much to pay for their cost."""
    decision = run.state.shadows
    if decision.decided or run.stage.kind is not SHADOWS_DECIDED_IN or run.state.step < run.stage.steps // 2:
        return
    probe = probe_frames(len(problem.frames))
    with torch.no_grad():
        without, with_shadows = (probe_l1(problem, shadows, probe) for shadows in (False, True))
    decision.ambient_at_decision = problem.avatar.ambient.item()
    lean = SHADOW_TOLERANCE if decision.ambient_at_decision < SHADOW_DOMINANT_AMBIENT else -SHADOW_TOLERANCE
    decision.on, decision.decided = bool(with_shadows < without * (1 + lean)), True
    decision.l1_without, decision.l1_with = without, with_shadows
    reporter.log(f"shadows auto: L1 in the masks of {len(probe)} fitted frames {without:.4f} without self-shadowing, "
                 f"{with_shadows:.4f} with -> {'on' if decision.on else 'off'} (fitted ambient ratio "
                 f"{decision.ambient_at_decision:.2f})")


def _decide_light(problem, state, reporter, solved, frames=None):
    """The `auto` environment light and specular lobe, each decided once after the stages (after
    the albedo solve, when `solved` is the problem it read: it solves the environment with the albedo
    and takes the lobe's sheen off the frames); the albedo is solved again from `solved` (its
    `frames`), once, without what they switch off."""
    switched_off = _decide_environment(problem, state, reporter)
    switched_off = _decide_specular(problem, state, reporter) or switched_off
    if switched_off and solved is not None:
        state.albedo_solve = solve_avatar_albedo(solved, state.shadows.on, frames=frames)


def _decide_light_size(problem, state, reporter, painting):
    """`auto` light size (light_size.py), decided once before the albedo solve, on the probe frames
    among those the solve reads."""
    probe = probe_frames(len(problem.frames), kept=painting)
    state.light_size = decide_light_size(problem, state.shadows.on, probe)
    if not state.light_size["candidates"]:
        reporter.log("light size auto: no self-shadowing, so no shadows to soften -> a point light")
        return
    scores = ", ".join(f"{float(d):g} deg {l1:.4f}" for d, l1 in state.light_size["candidates"].items())
    reporter.log(f"light size auto: L1 in the masks of {len(probe)} fitted frames, the light's angular radius: "
                 f"{scores} -> {state.light_size['degrees']:g} deg")


def _pull_words(figures):
    """', neighbour pull P' for an albedo solve's figures (solve_avatar_albedo) that have one."""
    pull = figures.get("neighbour_pull")
    return "" if pull is None else f", neighbour pull {pull:.1e}"


def _painting_frames(problem, state, reporter):
    """Indices of the fitted frames the albedo solves and the fill's decided texels read: every one
    but those the final surface leaves off their silhouettes (lost_frames.py: a hand turned over
    or left beside its mask paints its colours onto the wrong texels), found once (a resumed fit
    reads them from the state) and said in one line; None: every frame."""
    if state.solve_left_out is None:
        state.solve_left_out = frames_off_their_silhouettes(problem)
        if state.solve_left_out["frames"]:
            listed = ", ".join(f"{frame} ({iou:.2f})" for frame, iou in
                               zip(state.solve_left_out["frames"], state.solve_left_out["ious"]))
            reporter.log(f"albedo solve: frames the fit left off their silhouettes (IoU under {LOST_IOU}) "
                         f"left out: {listed}")
    return frames_kept(state.solve_left_out, len(problem.frames))


def _decide_environment(problem, state, reporter) -> bool:
    """`auto` environment light: kept where its colour varies with direction by at least
    ENVIRONMENT_THRESHOLD of the ambient (a white point light and an ambient ratio cannot explain
    that; its colourless part they largely can) over at least ENVIRONMENT_MIN_FRAMES fitted
    frames, else switched off (True)."""
    if state.environment is not None or problem.settings.environment != "auto":
        return False
    avatar = problem.avatar
    coefficients, ambient = avatar.environment.detach().cpu().numpy(), avatar.ambient.item()
    colour, strength = colour_strength(coefficients, ambient), relative_strength(coefficients, ambient)
    on = colour >= ENVIRONMENT_THRESHOLD and _enough_views(problem)
    state.environment = {"on": on, "colour_strength": colour, "relative_strength": strength}
    reporter.log(f"environment light auto: its colour varies by {100 * colour:.1f}% of the ambient over the sphere "
                 f"(all of it {100 * strength:.1f}%) -> {'on' if on else 'off'}{_views_note(problem)}")
    if not on:
        avatar.switch_environment(False)
    return not on


def _decide_specular(problem, state, reporter) -> bool:
    """`auto` specular lobe: kept where it carries at least SPECULAR_THRESHOLD of the colour where
    it shines (specular_share.py) on at least ENVIRONMENT_MIN_FRAMES fitted frames, else switched
    off (True)."""
    if state.specular is not None or problem.settings.specular != "auto":
        return False
    avatar = problem.avatar
    share = specular_share(problem, state.shadows.on)
    roughness, level = avatar.roughness.item(), avatar.specular_level.item()
    on = share["highlight"] >= SPECULAR_THRESHOLD and _enough_views(problem)
    state.specular = {"on": on, "share": share["mean"], "highlight": share["highlight"], "roughness": roughness,
                      "level": level}
    reporter.log(f"specular lobe auto: roughness {roughness:.2f}, level {level:.2f}: {100 * share['highlight']:.1f}% "
                 f"of the colour where it shines, {100 * share['mean']:.1f}% of all -> {'on' if on else 'off'}"
                 f"{_views_note(problem)}")
    if not on:
        avatar.switch_specular(False)
    return not on


def _enough_views(problem) -> bool:
    """Whether the fit has frames enough to tell a light's or a lobe's effect from the albedo."""
    return len(problem.frames) >= ENVIRONMENT_MIN_FRAMES


def _views_note(problem) -> str:
    return "" if _enough_views(problem) else f" (fewer than {ENVIRONMENT_MIN_FRAMES} frames fitted: too few views)"


class _CheckpointSaver:
    """Writes the fit's checkpoint (at stage ends, every settings.checkpoint_seconds, on
    Ctrl-C) and reads it back for --resume."""

    def __init__(self, path, problem, validator=None):
        self.path, self.problem, self.validator, self.last_save = Path(path), problem, validator, time.time()

    def fresh(self):
        settings = self.problem.settings
        return FitState.fresh(settings.schedule(), settings.shadows), torch.Generator().manual_seed(settings.seed), None

    def resume(self):
        if not self.path.is_file():
            raise FitError(f"nothing to resume: no {self.path}")
        saved = load_checkpoint(self.path, self.problem.device)
        if saved.version != CHECKPOINT_VERSION:
            raise FitError(f"{self.path} was written by an older harp version (checkpoint {saved.version}): "
                           "fit again without --resume")
        settings, tolerated = self.problem.settings, AFTER_THE_STAGES + BUDGET + ALIGNMENT_SIZE
        saved_values = dict(vars(saved.settings))
        renamed = RENAMED_PRESETS.get(saved_values["preset"])
        if renamed == settings.preset:      # started under the preset's old name
            saved_values["preset"] = renamed
        changed = sorted(k for k, v in saved_values.items() if vars(settings).get(k) != v and k not in tolerated)
        if changed:
            hint = (f" (it started as preset {saved_values['preset']}, which is now called {renamed}: resume with "
                     f"--preset {renamed})" if renamed and renamed != settings.preset else "")
            raise FitError(f"{self.path} was written with other settings ({', '.join(changed)}): "
                           f"resume with the options the fit started with{hint}")
        self.problem.avatar.resize_textures(int(saved.avatar["albedo"].shape[-1]))   # grown after the stages
        self.problem.avatar.load_state_dict(saved.avatar)
        if self.validator is not None:
            self.validator.resume(saved.state, saved.best_avatar)
        generator = torch.Generator()
        generator.set_state(saved.generator.cpu())
        return saved.state, generator, saved.optimiser

    def save(self, state, run, generator):
        optimiser = None if run is None else run.optimiser.state_dict()
        best = None if self.validator is None or self.validator.best is None else self.validator.best.avatar
        save_checkpoint(self.path, Checkpoint(self.problem.settings, state, self.problem.avatar.state_dict(),
                                              optimiser, generator.get_state(), best))
        self.last_save = time.time()

    def save_now_and_then(self, state, run, generator):
        if time.time() - self.last_save > self.problem.settings.checkpoint_seconds:
            self.save(state, run, generator)


class _PartTimer:
    """`with timer(part):` adds the block's wall seconds to `seconds[part]` (FitState.after_stages_seconds:
    what the estimate's after-stages figure is checked against)."""

    def __init__(self, seconds: dict):
        self.seconds = seconds

    @contextlib.contextmanager
    def __call__(self, part):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[part] = self.seconds.get(part, 0.0) + time.perf_counter() - start


class _FitClock:
    """Charges wall time to the stage under way (FitState.stage_seconds), and the time
    observers take to FitState.measure_seconds instead."""

    def __init__(self, state):
        self.state, self.last = state, time.perf_counter()

    def _lap(self):
        now = time.perf_counter()
        lap, self.last = now - self.last, now
        return lap

    def charge(self):
        """Time since the last call was fitting: it goes to the stage under way."""
        lap = self._lap()
        if self.state.stage < len(self.state.stage_seconds):
            self.state.stage_seconds[self.state.stage] += lap

    def observe(self, observers, event, problem):
        if observers:
            if event == "start":
                self._lap()      # nothing has been fitted yet: the first point is at fit time 0
            else:
                self.charge()
            for observer in observers:
                getattr(observer, event)(problem, self.state)
            self.state.measure_seconds += self._lap()


@contextlib.contextmanager
def _batch_workers(problem, recipe, workers):
    """`workers` - 1 batch worker processes over the problem for the block (batch_workers.py;
    on the CPU only: a GPU takes a batch whole)."""
    if workers <= 1 or problem.device.type != "cpu":
        yield
        return
    from .batch_workers import BatchWorkers

    problem.workers = BatchWorkers(problem, {**recipe, "settings": problem.settings}, workers - 1)
    try:
        yield
    finally:
        problem.workers.close()
        problem.workers = None


@contextlib.contextmanager
def _interrupt_flag():
    """An Event set by Ctrl-C (SIGINT; on Windows also Ctrl-Break, which the Blender add-on sends
    to cancel) for the block, so the loop can save and stop cleanly; outside the main thread
    (where signals cannot be caught) it is never set."""
    flag = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return
    signals = [signal.SIGINT] + ([signal.SIGBREAK] if hasattr(signal, "SIGBREAK") else [])
    previous = {number: signal.signal(number, lambda *_: flag.set()) for number in signals}
    try:
        yield flag
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
