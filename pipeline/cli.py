"""The `harp` command line."""
from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from .threads import available_cores, configure_threads


def _model_build(args):
    from .handmodel.build import build_models

    for path in build_models(args.out):
        print(f"wrote {path}")


def _model_preview(args):
    from .model_preview import write_preview

    print(f"wrote {write_preview(args.out, size=args.size, side=args.side, folder=args.model)}")


def _model_info(args):
    from .handmodel.measurements import anatomy_report

    print(anatomy_report(getattr(args, "model", None)))


def _budget(text):
    from .fit.budget import parse_budget

    try:
        return parse_budget(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _term_weights(pairs):
    """{term name: weight} of `--weight NAME=VALUE` arguments, over the registry's defaults (None
    when none is given); an unknown name or a bad value ends the command with one line."""
    if not pairs:
        return None
    from .fit.energy_terms import ENERGY_TERMS, default_weights

    weights = default_weights()
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in ENERGY_TERMS:
            raise SystemExit(f"harp fit: --weight {pair}: no energy term named {name!r}; the terms are "
                             f"{', '.join(ENERGY_TERMS)}")
        try:
            weights[name] = float(value)
        except ValueError:
            raise SystemExit(f"harp fit: --weight {pair}: the weight must be a number (NAME=VALUE)") from None
        if not weights[name] >= 0:
            raise SystemExit(f"harp fit: --weight {pair}: the weight must be 0 or more")
    return weights


def _stage_factors(items):
    """{term name: {stage name: factor}} of `--stage-factor NAME@STAGE=FACTOR` arguments (None when
    none is given); an unknown term or stage or a bad factor ends the command with one line."""
    if not items:
        return None
    from .fit.energy_terms import ENERGY_TERMS
    from .fit.schedule import StageKind

    stages = [kind.value for kind in StageKind]
    factors = {}
    for item in items:
        target, _, value = item.partition("=")
        name, _, stage = target.partition("@")
        if name not in ENERGY_TERMS:
            raise SystemExit(f"harp fit: --stage-factor {item}: no energy term named {name!r}; the terms are "
                             f"{', '.join(ENERGY_TERMS)}")
        if stage not in stages:
            raise SystemExit(f"harp fit: --stage-factor {item}: no stage named {stage!r} (NAME@STAGE=FACTOR); the "
                             f"stages are {', '.join(stages)}")
        try:
            factor = float(value)
        except ValueError:
            raise SystemExit(f"harp fit: --stage-factor {item}: the factor must be a number (NAME@STAGE=FACTOR)") \
                from None
        if not factor >= 0:
            raise SystemExit(f"harp fit: --stage-factor {item}: the factor must be 0 or more")
        factors.setdefault(name, {})[stage] = factor
    return factors


def _fit(args):
    configure_threads(args.threads)
    from .fit import fit
    from .fit.outputs import metrics_line
    from .fit.progress import duration_text

    weights = _term_weights(args.weight)
    stage_factors = _stage_factors(args.stage_factor)
    observers = []
    if args.curve:
        from .evaluate.curve import CurveRecorder

        observers.append(CurveRecorder(args.out))
    report = fit(args.sequence, args.out, preset=args.preset, resume=args.resume, progress=args.progress,
                 device=args.device, shadows=args.shadows, hold_out_every=args.hold_out_every,
                 known_appearance=args.known_appearance, observers=observers, max_steps=args.max_steps,
                 exposure=args.exposure, solve_albedo=args.solve_albedo, budget_seconds=args.budget,
                 validation_frames=args.validation_frames, workers=args.workers, environment=args.environment,
                 specular=args.specular, light_size=args.light_size, light_falloff=args.light_falloff,
                 colour_model=args.colour_model,
                 occlusion=args.occlusion,
                 restart_lost_frames=args.restart_lost_frames, albedo_facing=args.albedo_facing,
                 albedo_openness=args.albedo_openness, albedo_passes=args.albedo_passes, albedo_fill=args.albedo_fill,
                 light_search=args.light_search, solve_resolution=args.solve_resolution,
                 size_anchor=args.size_anchor, size_tolerance=args.size_tolerance, size_measure=args.size_measure,
                 anchor_size=args.anchor_size, pose_smoothness=args.pose_smoothness,
                 **({} if args.seed is None else {"seed": args.seed}),
                 **({} if weights is None else {"weights": weights}),
                 **({} if stage_factors is None else {"stage_factors": stage_factors}))
    wall = report.get("wall_seconds")
    took = f"{duration_text(wall)} ({report['total_seconds']:.0f} s in its stages)" if wall is not None else \
        f"{report['total_seconds']:.0f} s"
    print(f"wrote {args.out} in {took}: {metrics_line(report['metrics'])}")


def _plot(args):
    from .evaluate.plot import plot_curves

    print(f"wrote {plot_curves(args.fits, args.out, title=args.title)}")


def _blend(args):
    from .blender_scene import blend_avatar

    for path in blend_avatar(args.avatar, args.out, gltf=args.gltf, sequence=args.sequence, pack=args.pack,
                             smooth=args.smooth, fbx=args.fbx):
        print(f"wrote {path}")


def _addon_build(args):
    from .addon_build import build_addon

    print(f"wrote {build_addon(args.out)} (validated with Blender's blender_ext.py)")


def _seed_list(text):
    try:
        seeds = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds are whole numbers separated by commas, got {text!r}") from None
    if not seeds:
        raise argparse.ArgumentTypeError("give at least one seed")
    return seeds


def _study(args):
    if args.jobs < 1:
        raise ValueError(f"--jobs must be at least 1 (got {args.jobs})")
    configure_threads(args.threads)
    # with several jobs --threads is each job's; by default the cores are shared out between them
    threads_per_job = args.threads or max(1, available_cores() // args.jobs)
    from .evaluate.study import run_study

    study = run_study(args.dataset, args.out, clips=args.clips, quick=args.quick, preset=args.preset,
                      sections=tuple(args.sections.split(",")), progress=args.progress,
                      runtime_presets=tuple(args.runtime_presets.split(",")), runtime_frames=args.runtime_frames,
                      stability_scale=args.stability_scale,
                      stability_kinds=tuple(args.stability_kinds.split(",")) if args.stability_kinds else None,
                      seeds=args.seeds, jobs=args.jobs, threads=threads_per_job, executor=args.executor,
                      address=args.address)
    print(f"wrote {Path(args.out) / 'study.md'} ({study['seconds'] / 60:.0f} min)")


def _batch(args):
    if args.threads < 1 or (args.jobs is not None and args.jobs < 1):
        raise ValueError("--threads and --jobs must be at least 1")
    configure_threads(args.threads)
    from .batch import read_list, run_batch

    inputs = [(path, None) for path in args.inputs] + (read_list(args.list_file) if args.list_file else [])
    if not inputs:
        raise ValueError("give the clips: videos or sequence folders, or --list FILE")
    table = run_batch(inputs, args.out, resume=args.resume, executor=args.executor, jobs=args.jobs,
                      threads=args.threads, address=args.address, preset=args.preset,
                      hold_out_every=args.hold_out_every, init=args.init, seed=args.seed,
                      held_out_steps=args.held_out_steps, progress=args.progress)
    if any(row["status"] == "failed" for row in table):
        return 1


def _evaluate(args):
    from .evaluate import EVALUATION_FILE, evaluate_fit, summary_lines

    result = evaluate_fit(args.fit, args.sequence, held_out_steps=args.held_out_steps, device=args.device,
                          novel_poses=args.novel_poses or args.cycles, progress=args.progress, cycles=args.cycles)
    for line in summary_lines(result):
        print(line)
    print(f"wrote {Path(args.fit) / EVALUATION_FILE}")


def _import_video(args):
    from .sequence_import import import_video, parse_intrinsics

    import_video(args.video, args.masks, args.out, size=args.size, K=parse_intrinsics(args.K) if args.K else None,
                 fov_deg=args.fov, side=args.side, fps=args.fps, margin=args.margin, max_frames=args.max_frames,
                 overwrite=args.overwrite, warn=lambda message: print(message, file=sys.stderr), crop=args.crop,
                 window=args.window, workers=args.workers)


def _init(args):
    from .init import initialise_sequence

    method, *rest = args.init
    if len(rest) > 1:
        raise ValueError(f"--init takes a method and at most one FILE, got {' '.join(args.init)}")
    initialise_sequence(args.sequence, method, rest[0] if rest else None, mode=args.mode, seed=args.seed,
                        noise_degrees=args.noise_degrees, noise_translation_m=args.noise_translation,
                        warn=lambda message: print(message, file=sys.stderr), progress=args.progress,
                        landmark_offsets=args.landmark_offsets)


def _render(args):
    from .avatar_render import render_avatar

    light = [float(x) for x in args.light.split(",")] if args.light else None
    if light is not None and len(light) != 3:
        raise ValueError("--light takes x,y,z in metres (camera frame)")
    shadows = None if args.shadows == "fitted" else args.shadows == "on"
    print(f"wrote {render_avatar(args.avatar, args.out, args.pose, args.frame, args.azimuth, args.elevation, light, args.size, shadows)}")


def _demo(args):
    """The quick-start job: a synthetic clip, its initialisation, the fast fit and its figures."""
    configure_threads(args.threads)
    from .demo import run_demo

    run_demo(args.out, progress=args.progress)


# what each preset (fit/settings.PRESETS) costs and buys, as measured (docs/performance.md, "The 150-frame
# clip"); here, not in fit/, because importing the fit imports torch before configure_threads may set its
# threads' waiting; the add-on's panel (harp_addon/properties.py) says the same
PRESET_NOTES = {
    "preview": "a first look in under 2 min for a 150-frame 448 px clip on 2 CPU cores (160 px, a short fit, HARP's "
               "light alone): joint error 5%% and L1 9%% above fast's",
    "fast": "about 7 min for a 150-frame 448 px clip on 2 CPU cores, 8 on one",
    "full": "fast's fit carried to convergence, about 8-9 min for a 150-frame clip on 2 CPU cores (twice fast's on "
            "30 frames): held-out PSNR +0.4 dB against fast's on the phone-like clip and +0.3 on the demo, joint error "
            "11%% lower and the albedo sharper on the phone-like clip (3 seeds each); on the demo its hand ended 1-4%% "
            "small (new poses -0.5 dB)",
    "paper": "HARP's own schedule at 448 px, about 50 min for 150 frames, to compare with the paper: no better than "
             "fast on the clips measured",
}


def _preset_help():
    return "; ".join(f"{name}{' (default)' if name == 'fast' else ''}: {note}" for name, note in PRESET_NOTES.items()) \
        + " (docs/performance.md)"
PROGRESS_HELP = "bar (default): a progress bar; jsonl: JSON lines (for the Blender add-on); none"
THREADS_HELP = ("CPU threads (default: half the cores, waiting passively: a fit that shares the machine with "
                "Blender or another fit stays fast)")


def build_parser():
    parser = argparse.ArgumentParser(prog="harp", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    demo = commands.add_parser("demo", help="run the built-in example: render a synthetic clip, fit it, evaluate")
    demo.add_argument("--out", default="harp_demo", help="output folder (default: harp_demo)")
    demo.add_argument("--progress", choices=("bar", "jsonl", "none"), default="bar", help=PROGRESS_HELP)
    demo.add_argument("--threads", type=int, metavar="N", help=THREADS_HELP)
    demo.set_defaults(run=_demo)

    fit = commands.add_parser("fit", help="fit an avatar to a sequence folder that has an init.npz")
    fit.add_argument("sequence", help="sequence folder")
    fit.add_argument("--out", required=True, help="avatar folder to write")
    fit.add_argument("--preset", choices=tuple(PRESET_NOTES), default="fast", help=_preset_help())
    fit.add_argument("--shadows", choices=("auto", "on", "off"), default=None,
                     help="self-shadowing: auto (default) renders fitted frames with and without it half-way "
                          "through the fit and keeps whichever matches them better")
    fit.add_argument("--solve-albedo", action=argparse.BooleanOptionalAction, default=None,
                     help="solve the final albedo from the frames once geometry and light are final (default: on; "
                          "sharp detail such as tattoos, docs/fidelity.md)")
    fit.add_argument("--solve-resolution", type=int, default=None, metavar="PX",
                     help="the long side, pixels, of the frames the final albedo is solved from a second time, the "
                          "light held, into a texture grown to what they hold (a texel two pixels across): finer "
                          "than the working images, the texture takes what the footage shows of the skin (never "
                          "above the clip's own size; 0: the working frames alone; default: the preset's, the clip's "
                          "own up to 1024 px for fast and full: on a phone-like clip +0.4 dB held out at 448 px, and "
                          "at its own 873 px a 512 texture, held out +0.3 to +0.5 dB more and the albedo sharper, "
                          "docs/fidelity.md)")
    fit.add_argument("--exposure", choices=("auto", "on", "off"), default=None,
                     help="per-frame exposure and white-balance gains: auto (default) switches them on when the "
                          "footage's background brightness changes over the clip (a phone's automatic exposure)")
    fit.add_argument("--environment", choices=("auto", "on", "off"), default=None,
                     help="an environment light (a room's light from every side, spherical harmonics) beside the "
                          "point light: auto (default) keeps it where its colour changes with direction (a white "
                          "point light cannot explain that), on, or off (docs/fidelity.md)")
    fit.add_argument("--specular", choices=("auto", "on", "off"), default=None,
                     help="the skin's specular lobe (a fitted roughness and sheen, carried into Blender's Principled "
                          "BSDF): auto (default) keeps it where its highlights are at least 3%% of the colour they lie on, "
                          "on, or off (docs/fidelity.md)")
    fit.add_argument("--light-size", choices=("auto", "off"), default=None,
                     help="the light's size: auto (default) tries a point light and discs 6-19 degrees in radius "
                          "(a lamp's shade, a window) once the stages are done and keeps the one whose shadows "
                          "explain the frames best (soft shadows in every render and in Blender's sun); off keeps a "
                          "point light. Only a fit with self-shadowing has shadows to soften (docs/fidelity.md)")
    fit.add_argument("--light-falloff", choices=("on", "off"), default=None,
                     help="the light's inverse-square falloff: on lights the nearer parts of the hand more, as a lamp "
                          "or a window a metre away does; off (default) is as strong everywhere on the hand. The fit "
                          "does not search the light's distance yet: where its light stands too near, on costs "
                          "held-out PSNR (2 dB on the phone-like clip; docs/fidelity.md)")
    fit.add_argument("--colour-model", choices=("display", "linear"), default=None,
                     help="how the albedo and light make the frames' values: linear (default) decodes sRGB, shades "
                          "in linear light and encodes, as a camera and Blender do, so the bound avatar renders as "
                          "it was fitted; display shades the 8-bit values as they are, as fits before it did "
                          "(docs/fidelity.md)")
    fit.add_argument("--occlusion", choices=("on", "after", "off"),   # settings.OCCLUSION_CHOICES (no torch here)
                     default=None,
                     help="the room light (ambient and environment) held back where the hand itself is in its way, "
                          "between the fingers and in a closing palm: after (default: drawn from the albedo solve "
                          "on, the stages' steps without it; one measurement per frame), on (the stages' steps too: "
                          "4-6 measurements per frame, scored as after), or off (every point sees the whole room, "
                          "HARP's light). after against off, 3 seeds of two clips: held out +0.11-0.52 dB, new poses "
                          "+0.23-0.38 dB, the albedo nearer the truth (docs/fidelity.md)")
    fit.add_argument("--restart-lost-frames", choices=("on", "off"), default=None,
                     help="frames the alignment left off their silhouettes (a hand the detector turned over) started "
                          "again from their neighbours' poses: on, or off (default: on a phone-like clip it gained "
                          "0.4-1.3 dB on the frames but moved the hand's size; docs/fit.md)")
    fit.add_argument("--light-search", choices=("on", "off"), default=None,
                     help="before the light is fitted, its direction and the ambient ratio searched over the whole "
                          "sphere, each candidate scored by how well one colour per texel explains the frames: on "
                          "(default; on a phone-like clip's 3 seeds held out +1.05 dB and new poses +1.1 dB: "
                          "docs/fit.md), or off (the light starts in front of the hand, "
                          "above the camera)")
    fit.add_argument("--albedo-facing", choices=("on", "off"), default=None,
                     help="the final albedo solve weighs each pixel by how squarely it sees the skin, so a texel "
                          "seen head-on somewhere is not coloured by its grazing views: on, or off (default: on one "
                          "phone-like seed it lost 0.3 dB held out, the albedo no nearer the truth; docs/fidelity.md)")
    fit.add_argument("--albedo-openness", choices=("on", "off"), default=None,
                     help="the final albedo solve weighs each pixel by how much of the room its skin sees, so the "
                          "hollows of a fist, lit by the skin around them, leave their colour to the skin they "
                          "join: on (default), or off (docs/fidelity.md)")
    fit.add_argument("--albedo-passes", type=int, default=None, metavar="N",
                     help="passes of the albedo's solves and fill after the stages, each from the last one's albedo "
                          "and room light (default 2, preview 1; 2 against 1 on a phone-like clip's 3 seeds: new poses "
                          "+0.22-0.29 dB, the demo +0.05; about 40 s more on 24 frames, 34 s on 150 on one core: "
                          "docs/fidelity.md)")
    fit.add_argument("--albedo-fill", choices=("decided", "feathered", "edge"), default=None,   # settings.ALBEDO_FILL_CHOICES
                     help="what the fill keeps of the solved albedo: every texel the frames decide, as solved (decided, "
                          "default); each texel as far as pixels that see its skin squarely decide it, so a side the "
                          "clip only showed edge-on blends into the fill (feathered); or the skin seen only edge-on "
                          "blended within 4 mm of the fill (edge). On a real clip that never shows the palm both remove "
                          "a dark line along the hand's side; on the phone-like clip they cost new poses 0.5 dB "
                          "(feathered, one seed) and 0.13-0.20 dB (edge, 3 seeds; docs/real_footage.md)")
    fit.add_argument("--size-anchor", choices=("initial", "alignment"), default=None,
                     help="the size the size_prior term holds: the hand's where the alignment left it (alignment, "
                          "default; the term silent in the alignment), or the initial estimate's (initial; give it "
                          "--size-tolerance 0.03): one camera barely sees a hand's size, and the later stages drift "
                          "along it (docs/fidelity.md); --weight size_prior=0 lets it drift")
    fit.add_argument("--size-tolerance", type=float, default=None, metavar="FRACTION",
                     help="the size prior's free band around that size (default 0: held there)")
    fit.add_argument("--size-measure", choices=("hand", "palm", "scale"), default=None,
                     help="what the size prior measures: the shape's scale parameter alone (scale, default: every "
                          "proportion free), the spread of all 21 keypoints (hand), or of the wrist and knuckles "
                          "(palm: the fingers' lengths stay free; docs/fidelity.md)")
    fit.add_argument("--anchor-size", choices=("held", "free"), default=None,
                     help="what the keypoint anchor holds of the initial keypoints: their positions in metres, "
                          "their size included (held, default), or the pose and proportions alone, the fitted hand "
                          "brought to their size first (free: the size left to the silhouettes; docs/fidelity.md)")
    fit.add_argument("--pose-smoothness", choices=("acceleration", "adaptive", "velocity"), default=None,   # losses.POSE_SMOOTHNESS
                     help="what the temporal pose term holds of the joint rotations: their velocity where the "
                          "initial estimate, smoothed over time, holds a joint still and their acceleration where it "
                          "moves (adaptive, default), their velocity everywhere (velocity: a moving finger's swing "
                          "cut short) or their acceleration everywhere (acceleration: still fingers keep more of "
                          "the start's noise); docs/study.md, section 7")
    fit.add_argument("--weight", action="append", default=None, metavar="NAME=VALUE",
                     help="an energy term's weight (repeatable), e.g. size_prior=1 (the terms and their defaults: "
                          "pipeline/fit/energy_terms.py; 0 switches a term off)")
    fit.add_argument("--stage-factor", action="append", default=None, metavar="NAME@STAGE=FACTOR",
                     help="an energy term's weight in one kind of stage, times FACTOR (repeatable), e.g. "
                          "size_prior@align=0 (the stages: align, geometry, geometry+appearance, appearance, "
                          "held-out)")
    fit.add_argument("--resume", action="store_true", help="continue from the avatar folder's checkpoint")
    fit.add_argument("--progress", choices=("bar", "jsonl", "none"), default="bar", help=PROGRESS_HELP)
    fit.add_argument("--threads", type=int, metavar="N", help=THREADS_HELP)
    fit.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    fit.add_argument("--workers", type=int, default=1, metavar="N",
                     help="N processes share each batch's frames (CPU): on 2 cores, 2 make paper's steps 1.6-2.1x "
                          "faster, but fast's slower than --threads 2 (default 1; docs/performance.md)")
    fit.add_argument("--seed", type=int, default=None,
                     help="the fit's random seed (default 0): fit with several to see the spread of a figure")
    fit.add_argument("--hold-out-every", type=int, default=None, metavar="N",
                     help="leave every N-th frame out of the fit, for harp evaluate")
    fit.add_argument("--validation-frames", type=int, default=None, metavar="N",
                     help="keep N frames (at most one in ten) out of the fit and score them as it runs: the best "
                          "state is written, a stage that stops improving them ends (default 0: off; measured in "
                          "docs/fit.md)")
    fit.add_argument("--budget", type=_budget, default=None, metavar="TIME",
                     help="end within this time (e.g. 300, 90s, 10m, 1.5h): the stages' steps are cut where the "
                          "study's curves show they buy least (docs/fit.md)")
    fit.add_argument("--max-steps", type=int, default=None, metavar="N",
                     help="cap every stage at N steps: a quick look, not a finished avatar")
    fit.add_argument("--curve", action="store_true",
                     help="record the error against fitting time in AVATAR/curve.json (see harp plot)")
    fit.add_argument("--known-appearance", default=None, metavar="AVATAR",
                     help="take shape, displacements, textures and light from this finished fit of the same "
                          "hand, frozen, and fit only the per-frame poses (HARP-known)")
    fit.set_defaults(run=_fit)

    plot = commands.add_parser("plot", help="draw error against fitting time for fits recorded with --curve")
    plot.add_argument("fits", nargs="+", help="avatar folders with a curve.json")
    plot.add_argument("--out", default="curves.png", help="PNG to write (default: curves.png)")
    plot.add_argument("--title", default=None)
    plot.set_defaults(run=_plot)

    study = commands.add_parser("study", help="pose-refinement study, error against run time and stability "
                                              "sweep over a folder of synthetic clips")
    study.add_argument("dataset", help="folder of synthetic clips (as synth/dataset.py writes them)")
    study.add_argument("--out", required=True, help="study folder (rerun to resume: finished work is kept)")
    study.add_argument("--clips", default=None, metavar="PATTERNS",
                       help="comma-separated shell patterns of clip names, e.g. 'small-*,medium-light_*'")
    study.add_argument("--quick", action="store_true", help="a small version for CI: stages capped, short sweep")
    study.add_argument("--threads", type=int, metavar="N", help=THREADS_HELP)
    study.add_argument("--preset", choices=tuple(PRESET_NOTES), default="fast",
                       help="preset of the refinement fits (default: fast)")
    study.add_argument("--sections", default="refinement,runtime,stability",
                       help="which parts to run (default: refinement,runtime,stability)")
    study.add_argument("--runtime-presets", default="preview,fast,full,paper",
                       help="presets compared in the run-time section (default: preview,fast,full,paper)")
    study.add_argument("--runtime-frames", type=int, default=30, metavar="N",
                       help="frames of the clip every preset fits in the run-time section, spread evenly "
                            "(default: 30; 0: each preset's own number)")
    study.add_argument("--stability-scale", choices=("tiny", "fast"), default=None,
                       help="the stability sweep's clips and schedule: tiny (4 frames, 64 px, 10 steps per stage) "
                            "or fast (30 frames, 256 px, the fast preset's whole schedule, each fit's curve; hours "
                            "on one core, resumable); default: fast, with --quick tiny")
    study.add_argument("--stability-kinds", default=None, metavar="KINDS",
                       help="the sweep's cases of these kinds only, e.g. baseline,poses,shapes,framing,inputs "
                            "(default: all: baseline, poses, shapes, framing, inputs, rates, weights)")
    study.add_argument("--seeds", type=_seed_list, default=(0,), metavar="S,S,...",
                       help="fit seeds of the refinement fits, e.g. 0,1,2: the means come with their seed spread "
                            "(default: 0)")
    study.add_argument("--jobs", type=int, default=1, metavar="N",
                       help="fits run at once, each in a process of its own (default: 1; two fits of one thread "
                            "each share a 2-core machine at about the time of one)")
    study.add_argument("--progress", choices=("bar", "jsonl", "none"), default="none",
                       help="progress of each fit (default: none; the study logs each run)")
    study.add_argument("--executor", choices=("local", "ray"), default="local",
                       help="where the fits run: local (--jobs processes on this machine) or ray (a task per fit on "
                            "the Ray cluster at --address, or a local one; pip install .[cluster])")
    study.add_argument("--address", default=None, help="the Ray cluster's address (ray: default a local one)")
    study.set_defaults(run=_study)

    batch = commands.add_parser("batch", help="many clips (videos or sequence folders) through import, init, fit and "
                                              "evaluation, one table of their figures")
    batch.add_argument("inputs", nargs="*", help="videos (masks made from the footage) or sequence folders")
    batch.add_argument("--list", dest="list_file", default=None, metavar="FILE",
                       help="a file of inputs, one `INPUT [MASKS]` per line (# comments)")
    batch.add_argument("--out", required=True, help="batch folder: a folder per clip, batch.csv and batch.md")
    batch.add_argument("--resume", action="store_true", help="go on with the batch in --out where it stopped")
    batch.add_argument("--executor", choices=("local", "ray"), default="local",
                       help="local (default: clips at once on this machine) or ray (a task per clip; pip install "
                            ".[cluster])")
    batch.add_argument("--address", default=None, help="the Ray cluster's address (default: a local one)")
    batch.add_argument("--jobs", type=int, default=None, metavar="N",
                       help="local: clips at once (default: one per core, each single-threaded)")
    batch.add_argument("--threads", type=int, default=1, metavar="N", help="CPU threads of each clip (default 1)")
    batch.add_argument("--preset", choices=tuple(PRESET_NOTES), default="fast", help="the fits' preset (default: fast)")
    batch.add_argument("--hold-out-every", type=int, default=10, metavar="N",
                       help="leave every N-th frame out of each fit and score it (default 10)")
    batch.add_argument("--init", choices=("mediapipe", "gt-noise"), default="mediapipe",
                       help="the initial estimate (gt-noise: synthetic clips only)")
    batch.add_argument("--seed", type=int, default=None, help="the fits' random seed (default 0)")
    batch.add_argument("--held-out-steps", type=int, default=300, metavar="N",
                       help="the held-out frames' pose and light steps at most (default 300)")
    batch.add_argument("--progress", choices=("bar", "none"), default="bar", help="a bar over the clips, or log lines")
    batch.set_defaults(run=_batch)

    evaluate = commands.add_parser("evaluate", help="score a fit: held-out frames; albedo and poses against the truth")
    evaluate.add_argument("fit", help="avatar folder written by harp fit")
    evaluate.add_argument("sequence", help="the sequence folder it was fitted to")
    evaluate.add_argument("--held-out-steps", type=int, default=300, metavar="N",
                          help="at most N Adam steps of pose and light on the held-out frames, from their fitted "
                               "neighbours' poses until the loss stops falling (default 300); the figure from the "
                               "keypoints beside it takes 100")
    evaluate.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    evaluate.add_argument("--novel-poses", action="store_true",
                          help="synthetic clips: the avatar against the true hand (geometry, new poses, texture detail; "
                               "fidelity.json, fidelity.png)")
    evaluate.add_argument("--cycles", action="store_true",
                          help="with --novel-poses: also against Cycles renders of the true hand under the clip's light "
                               "(needs bpy; about 5 s per render, 14 renders)")
    evaluate.add_argument("--progress", choices=("bar", "jsonl", "none"), default="bar", help=PROGRESS_HELP)
    evaluate.set_defaults(run=_evaluate)

    render = commands.add_parser("render", help="render an avatar in a new pose, view and light")
    render.add_argument("avatar", help="avatar folder written by harp fit")
    render.add_argument("--out", default="avatar.png")
    render.add_argument("--pose", default="rest", help="a named pose: rest, fist, spread, thumbs_up, pinch, point")
    render.add_argument("--frame", type=int, default=None, help="use the fitted pose of this frame instead")
    render.add_argument("--azimuth", type=float, default=0.0, help="degrees about the vertical axis")
    render.add_argument("--elevation", type=float, default=0.0, help="degrees of tilt")
    render.add_argument("--light", default=None, help="x,y,z of the point light in the camera frame (m)")
    render.add_argument("--shadows", choices=("fitted", "on", "off"), default="fitted")
    render.add_argument("--size", type=int, default=512)
    render.set_defaults(run=_render)

    blend = commands.add_parser("blend", help="bind an avatar to a rig in a new Blender scene: .blend and glTF")
    blend.add_argument("avatar", help="avatar folder written by harp fit")
    blend.add_argument("--out", required=True, help=".blend file to write")
    blend.add_argument("--gltf", default=None, help="also export the hand (skin + motion) as this .glb")
    blend.add_argument("--fbx", default=None,
                       help="also export the hand (skin, embedded textures, motion baked at every frame) as this .fbx")
    blend.add_argument("--sequence", default=None,
                       help="the footage's sequence folder (default: the one the avatar was fitted to, if present)")
    blend.add_argument("--pack", action="store_true",
                       help="keep the albedo, normal map and footage frame inside the .blend (default: files beside "
                            "it, found relative to its folder)")
    blend.add_argument("--smooth", type=int, default=0, metavar="FRAMES",
                       help="smooth the keys over this many frames (odd, at least 5; default 0: as fitted). On "
                            "synthetic clips 7-9 frames took out 70-77%% of the jitter and brought the joints "
                            "closer to the truth (benchmarks/bench_smoothing.py)")
    blend.set_defaults(run=_blend)

    addon = commands.add_parser("addon", help="the Blender extension")
    addon_commands = addon.add_subparsers(dest="addon_command", required=True)
    addon_build = addon_commands.add_parser("build", help="build and validate the extension zip")
    addon_build.add_argument("--out", default="dist", help="folder for the zip (default: dist)")
    addon_build.set_defaults(run=_addon_build)

    model = commands.add_parser("model", help="the parametric hand model")
    model_commands = model.add_subparsers(dest="model_command", required=True)
    build = model_commands.add_parser("build", help="rebuild the model files from the anatomy")
    build.add_argument("--out", default=None, help="folder (default: the package's assets)")
    build.set_defaults(run=_model_build)
    preview = model_commands.add_parser("preview", help="write a PNG of the model in both modes")
    preview.add_argument("--out", default="hand_model.png")
    preview.add_argument("--size", type=int, default=300, help="pixels per view")
    preview.add_argument("--side", choices=("right", "left"), default="right")
    preview.add_argument("--model", default=None, help="folder of model files (default: shipped)")
    preview.set_defaults(run=_model_preview)
    info = model_commands.add_parser("info", help="print the model's measured anatomy")
    info.add_argument("--model", default=None, help="folder of model files (default: shipped)")
    info.set_defaults(run=_model_info)

    from .sequence_import import DEFAULT_SIZE as DEFAULT_IMPORT_SIZE   # numpy and OpenCV: a quarter of a second

    video = commands.add_parser("import-video", help="a sequence folder from a video (or images) and its masks")
    video.add_argument("video", help="video file or folder of images")
    video.add_argument("--masks", default=None,
                       help="mask video or folder of mask images (white = hand); default: made from the footage "
                            "(MediaPipe landmarks + GrabCut); given masks always win")
    video.add_argument("--out", required=True, help="sequence folder to write")
    video.add_argument("--size", type=int, default=DEFAULT_IMPORT_SIZE,
                       help=f"the largest square output size in pixels (default {DEFAULT_IMPORT_SIZE}; a smaller crop "
                            "keeps its own size, the hand's pixels in the footage)")
    camera = video.add_mutually_exclusive_group()
    camera.add_argument("--K", default=None, metavar="FX,FY,CX,CY", help="intrinsics of the video, pixels")
    camera.add_argument("--fov", type=float, default=None, metavar="DEG",
                        help="horizontal field of view of the video in degrees (default: a phone's main camera, "
                             "67 degrees across the longer side)")
    video.add_argument("--side", choices=("right", "left", "auto"), default="auto",
                       help="hand side (default: auto, from MediaPipe's handedness)")
    video.add_argument("--fps", type=float, default=None, help="frame rate (default: the video's, or 30)")
    video.add_argument("--margin", type=float, default=0.15,
                       help="room around the hand in the crop, as a fraction of the hand's box (default 0.15)")
    video.add_argument("--crop", choices=("auto", "frame", "clip"), default="auto",
                       help="frame: a window that follows the hand, so it is as large in every frame (each frame "
                            "gets its own principal point); clip: one window for the whole clip; auto (default): "
                            "follow the hand where that shows it at least 1.1x larger")
    video.add_argument("--window", choices=("hand", "mask"), default="hand",
                       help="what the crop holds: hand (default): the hand, found by MediaPipe's landmarks, so "
                            "that a forearm reaching to the frame's edge does not make it small (the crop cuts the "
                            "forearm); mask: the whole mask")
    video.add_argument("--max-frames", type=int, default=None, help="import only the first N frames")
    video.add_argument("--workers", type=int, default=None, metavar="N",
                       help="processes that make the masks from the footage at once (default: one per core; "
                            "each uses one core)")
    video.add_argument("--overwrite", action="store_true", help="replace the sequence in --out")
    video.set_defaults(run=_import_video)

    init = commands.add_parser("init", help="initial pose and shape of a sequence (writes init.npz)")
    init.add_argument("sequence", help="sequence folder")
    init.add_argument("--init", nargs="+", default=["mediapipe"], metavar="METHOD [FILE]",
                      help="mediapipe (default), keypoints FILE (.npy/.npz/.json, pixels), or gt-noise")
    init.add_argument("--mode", choices=("hand", "arm", "auto"), default="auto", help="template (default: from masks)")
    init.add_argument("--noise-degrees", type=float, default=10.0, help="gt-noise: rotation of every joint")
    init.add_argument("--noise-translation", type=float, default=0.01, help="gt-noise: wrist shift, metres")
    init.add_argument("--seed", type=int, default=0, help="gt-noise: random seed")
    init.add_argument("--progress", choices=("bar", "jsonl", "none"), default="bar", help=PROGRESS_HELP)
    init.add_argument("--landmark-offsets", action="store_true",
                      help="take the keypoints for MediaPipe's landmarks (as --init mediapipe and its keypoints.json "
                           "give) and compare them where they sit on the hand model, not as the model's keypoints "
                           "(measured in docs/initialisation.md: on a 1080p phone-like clip the avatar's surface error "
                           "halved; on the 256 px demo clip the joints lost 0.7 mm)")
    init.set_defaults(run=_init)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    _take_interrupts()
    try:
        code = args.run(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (OSError, ValueError) as error:
        print(f"harp: error: {error}", file=sys.stderr)
        return 1
    return code or 0


def _take_interrupts():
    """Ctrl-C (and the add-on's Cancel, which sends the same interrupt) stops every command, even
    one started by a process that ignores interrupts (a background job of a shell, some desktop
    launchers): their children inherit the ignoring, and Python then never raises
    KeyboardInterrupt."""
    import threading

    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


if __name__ == "__main__":
    sys.exit(main())
