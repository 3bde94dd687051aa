"""Render the standard evaluation set: several identities (varying in size and skin tone), each
with the `flip` and `fingers` motions, seen from several viewpoints under the three lighting
presets. One sequence folder per clip plus `dataset.json` (the plan and the render times).

    python synth/dataset.py --out data/synth_eval            # the standard set (24 clips)
    python synth/dataset.py --out data/synth_eval --full     # every view under every preset (72)
    python synth/dataset.py --out DIR --list                 # print the plan only
    blender -b -P synth/dataset.py -- --out DIR

By default each identity-motion pair is seen from the three viewpoints, the lighting presets
rotating over them (a Latin square: every identity, motion and viewpoint meets every preset).
Finished clips (with their sequence.json) are skipped, so an interrupted run resumes.
"""
import argparse
import json
import os
import sys
import time

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    sys.path.insert(0, REPO_ROOT)

from synth import SynthError  # noqa: E402
from synth.options import LIGHTING, blender_argv, parse_clip_args  # noqa: E402

STUDY_LIGHTING = ("ambient", "sun", "three")   # the set's presets (room came later: see --lighting)

# name: (identity seed, size = scale shape parameter, skin tone 0..1, features)
IDENTITIES = {
    "small-verylight": (101, -1.5, 0.05, "freckles"),
    "medium-light": (102, 0.0, 0.3, "none"),
    "large-medium": (103, 1.5, 0.6, "tattoo,scars"),
    "medium-verydark": (104, 0.5, 0.95, "polish"),
}
VIEWS = {"front": (0.0, 0.0), "thumbside": (35.0, 15.0), "pinkyside": (-30.0, -10.0)}  # azimuth, elevation
MOTIONS = ("flip", "fingers")


def plan(identities, motions, views, lighting, full=False):
    """List of (clip name, render.py arguments)."""
    clips = []
    for i, identity in enumerate(identities):
        seed, size, tone, features = IDENTITIES[identity]
        for m, motion in enumerate(motions):
            for v, view in enumerate(views):
                presets = lighting if full else [lighting[(i + m + v) % len(lighting)]]
                for preset in presets:
                    azimuth, elevation = VIEWS[view]
                    args = ["--identity", seed, "--size", size, "--skin-tone", tone, "--features", features,
                            "--motion", motion, "--azimuth", azimuth, "--elevation", elevation,
                            "--lighting", preset, "--seed", i * 100 + m * 10 + v]
                    clips.append((f"{identity}_{motion}_{view}_{preset}", [str(a) for a in args]))
    return clips


def build_parser():
    parser = argparse.ArgumentParser(prog="dataset.py", description="Render the standard synthetic evaluation set.")
    add = parser.add_argument
    add("--out", required=True, help="dataset folder (one sequence folder per clip)")
    add("--identities", default=",".join(IDENTITIES), help=f"comma-separated subset of {','.join(IDENTITIES)}")
    add("--motions", default=",".join(MOTIONS), help="comma-separated subset of flip,fingers,random")
    add("--views", default=",".join(VIEWS), help=f"comma-separated subset of {','.join(VIEWS)}")
    add("--lighting", default=",".join(STUDY_LIGHTING), help=f"comma-separated subset of {','.join(LIGHTING)}")
    add("--full", action="store_true", help="every viewpoint under every lighting preset")
    add("--list", action="store_true", help="print the clips and exit")
    add("--overwrite", action="store_true", help="render finished clips again")
    add("--preview", action="store_true", help="tiny clips (4 frames, 64x64) to check the set up")
    add("--clip-args", default="", help="extra render.py arguments for every clip, e.g. '--seconds 3 --samples 32'")
    add("--jobs", type=int, default=1, help="clips rendered at once, each in a process of its own with its share of "
                                            "the cores (default 1: one at a time on every core)")
    add("--executor", choices=("local", "ray"), default="local",
        help="local (--jobs processes here) or ray (a task per clip on the Ray cluster at --address; "
             "pip install .[cluster]); the dataset folder must be one every node sees")
    add("--address", default=None, help="the Ray cluster's address (default: a local one)")
    return parser


def _subset(text, allowed, what):
    items = [item.strip() for item in text.split(",") if item.strip()]
    unknown = [item for item in items if item not in allowed]
    if unknown or not items:
        raise SynthError(f"unknown {what} {unknown[0] if unknown else text!r}; choose from {', '.join(allowed)}")
    return items


def main(argv=None):
    args = build_parser().parse_args(blender_argv(sys.argv if argv is None else argv))
    try:
        clips = plan(_subset(args.identities, IDENTITIES, "identity"),
                     _subset(args.motions, ("flip", "fingers", "random"), "motion"),
                     _subset(args.views, VIEWS, "view"), _subset(args.lighting, LIGHTING, "lighting preset"),
                     args.full)
        extra = args.clip_args.split() + (["--preview"] if args.preview else [])
        settings = [parse_clip_args(["--out", os.path.join(args.out, name), "--overwrite", *clip, *extra])
                    for name, clip in clips]
    except SynthError as error:
        print(f"dataset.py: error: {error}", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"dataset.py: error: --jobs must be at least 1, got {args.jobs}", file=sys.stderr)
        return 2
    if args.list:
        for (name, clip), s in zip(clips, settings):
            print(f"{name}: {s.frame_count} frames, {' '.join(clip)}")
        return 0
    index_path = os.path.join(args.out, "dataset.json")
    index = {"clips": {}}
    if os.path.isfile(index_path):
        with open(index_path) as handle:
            index = json.load(handle)

    def record(name, clip, summary):
        index["clips"][name] = {"args": clip + extra, "frames": summary["frames"],
                                "seconds": round(summary["seconds"], 1)}
        os.makedirs(args.out, exist_ok=True)
        with open(index_path, "w") as handle:
            json.dump(index, handle, indent=1)

    started = time.perf_counter()
    todo = []
    for number, ((name, clip), s) in enumerate(zip(clips, settings)):
        if os.path.isfile(os.path.join(s.out, "sequence.json")) and not args.overwrite:
            print(f"[{number + 1}/{len(clips)}] {name}: done already", flush=True)
        else:
            todo.append((number, name, clip, s))
    if args.jobs > 1 or args.executor == "ray":
        code = _render_spread(todo, extra, args, record)
        if code:
            return code
    else:
        from synth.clip import render_clip

        for number, name, clip, s in todo:
            try:
                summary = render_clip(s, log=lambda message: None)
            except SynthError as error:
                print(f"dataset.py: error in {name}: {error}", file=sys.stderr)
                return 2
            record(name, clip, summary)
            print(f"[{number + 1}/{len(clips)}] {name}: {summary['frames']} frames in {summary['seconds']:.0f} s",
                  flush=True)
    print(f"rendered {len(clips)} clips into {args.out} in {time.perf_counter() - started:.0f} s")
    return 0


def _render_spread(todo, extra, args, record):
    """The clips to render as cells of an executor (pipeline/executors.py), each with its share
    of the cores unless --clip-args sets Cycles' --threads; 0, or 2 where a clip failed."""
    from pipeline.executors import Cell, CellFailure, ExecutorError, run_cells
    from pipeline.threads import available_cores
    from synth.clip import render_clip_from_args

    threads = [] if "--threads" in extra else ["--threads", str(max(1, available_cores() // max(1, args.jobs)))]
    cells = [Cell(name, render_clip_from_args,
                  {"args": ["--out", os.path.join(args.out, name), "--overwrite", *clip, *extra, *threads]})
             for _, name, clip, _ in todo]
    arguments = {name: clip for _, name, clip, _ in todo}

    def finished(name, summary):
        record(name, arguments[name], summary)
        print(f"{name}: {summary['frames']} frames in {summary['seconds']:.0f} s", flush=True)

    try:
        run_cells(cells, jobs=args.jobs, threads=1, executor=args.executor, address=args.address, ship="never",
                  log=lambda message: print(message, flush=True), logs=os.path.join(args.out, "logs"),
                  on_result=finished)
    except ExecutorError as error:
        print(f"dataset.py: error: {error}", file=sys.stderr)
        return 2
    except CellFailure as failure:
        for name, reason in failure.failures.items():
            print(f"dataset.py: error in {name}: {reason}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
