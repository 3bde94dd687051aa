"""Benchmark: how much light the skin sends back into the hand's hollows, on a finished fit.

    .venv/bin/python benchmarks/bench_occlusion_bounce.py FIT SEQ WORK [--scales 0,0.5,1,2] [--threads 2]
        [--directions 64] [--resolution 128] [--fit-options JSON]

The room light's occlusion (render/occlusion.py) takes from each point the light the hand hides
from it and gives back a `bounce`: the skin's mean albedo under its mean shading, seen along every
blocked direction (bounce_radiance). For each scale s of that bounce, the fit's work after the
stages is done again on its final state (bench_albedo_pose_polish.polished, no polishing steps)
and the held-out frames are scored on the result (`evaluate_fit`, both protocols), the bounce
scaled by s in both: the frames the albedo solve reads, the held-out renders. Scale 1 is the fit as
it stands; a peak elsewhere says the hollows are lit more (or less) than the model draws them.
`--directions` and `--resolution` measure the occlusion itself finer (or coarser) than the fit does
(render/occlusion.py's DIRECTIONS of its quadrature, RESOLUTION of its depth maps), in the replay
and the held-out frames alike. Each case's avatar goes to WORK/bounce_S (with _dD_rR where those
differ from the fit's; kept: a finished case is read back, not redone); one JSON line per scale.
The figures of docs/real_footage.md ("The held-out drop of 2026-12-07 traced") come from this script.
"""
from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import torch  # noqa: E402

import pipeline.fit.avatar as fit_avatar  # noqa: E402
import pipeline.render.occlusion as occlusion  # noqa: E402
from bench_albedo_pose_polish import polished, write_replayed  # noqa: E402
from pipeline.evaluate import evaluate_fit  # noqa: E402

EVALUATION_FILE = "evaluation.json"
DONE_FILE = "bench_occlusion_bounce.json"    # one scale's replay seconds, written once it is scored


@contextlib.contextmanager
def occlusion_as(scale, directions=occlusion.DIRECTIONS, resolution=occlusion.RESOLUTION):
    """Inside the block the fit's avatar (fit/avatar.py, which the replay and the held-out evaluation
    shade with) draws the skin's bounce scaled by `scale`, and every measurement of the occlusion
    (render/occlusion.lost_light) takes `directions` and a depth map `resolution` by default."""
    measure = inspect.unwrap(occlusion.lost_light)       # under its no_grad wrapper
    bounce, defaults = fit_avatar.bounce_radiance, measure.__defaults__
    fit_avatar.bounce_radiance = lambda *args, **kwargs: bounce(*args, **kwargs) * scale
    measure.__defaults__ = (None, directions, resolution, None)     # focus, directions, resolution, occluders
    try:
        yield
    finally:
        fit_avatar.bounce_radiance, measure.__defaults__ = bounce, defaults


def replayed_and_scored(fit, sequence, out, scale, directions, resolution, fit_options=None) -> dict:
    """The fit's work after the stages replayed with the occlusion as `occlusion_as` draws it, written
    to `out` (albedo.png and the checkpoint that `evaluate_fit` reads), its held-out frames scored
    with the same."""
    with occlusion_as(scale, directions, resolution):
        avatar, seconds, _, _ = polished(fit, sequence, 0, fit_options=fit_options)
        write_replayed(avatar, fit, out, checkpoint=True)
        evaluate_fit(out, sequence)
    return {"replay_seconds": round(seconds, 1)}


def figures(out, scale) -> dict:
    """One scale's line: the held-out frames' PSNR / IoU / L1 under both protocols."""
    evaluation = json.loads((out / EVALUATION_FILE).read_text())
    line = {"bounce_scale": scale}
    for protocol in ("held_out", "held_out_from_keypoints"):
        metrics = evaluation.get(protocol, {}).get("metrics", {})
        for name in ("psnr_mean", "silhouette_iou_mean", "l1_mean"):
            if name in metrics:
                line[f"{protocol}_{name}"] = round(float(metrics[name]), 4)
    return line


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("work", type=Path, help="each scale's avatar goes to WORK/bounce_S")
    parser.add_argument("--scales", default="0,0.5,1,2", help="comma-separated bounce scales")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--directions", type=int, default=occlusion.DIRECTIONS,
                        help=f"the occlusion's directions over the sphere (the fit's: {occlusion.DIRECTIONS})")
    parser.add_argument("--resolution", type=int, default=occlusion.RESOLUTION,
                        help=f"its depth maps' texels across the hand (the fit's: {occlusion.RESOLUTION})")
    parser.add_argument("--fit-options", type=json.loads, default=None,
                        help="FitSettings fields that replace the checkpoint's for the replay, as JSON")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    report = args.fit / "report.json"
    if not report.is_file():
        parser.error(f"{args.fit} is not a finished fit's folder (no report.json)")
    if not json.loads(report.read_text()).get("held_out_frames"):
        parser.error(f"{args.fit} holds no frames out (fit it with --hold-out-every N): nothing to score")
    for scale in (float(value) for value in args.scales.split(",")):
        finer = (args.directions, args.resolution) != (occlusion.DIRECTIONS, occlusion.RESOLUTION)
        out = args.work / (f"bounce_{scale:g}" + (f"_d{args.directions}_r{args.resolution}" if finer else ""))
        if not (out / DONE_FILE).is_file():
            replay = replayed_and_scored(args.fit, args.sequence, out, scale, args.directions, args.resolution,
                                         args.fit_options)
            (out / DONE_FILE).write_text(json.dumps({"directions": args.directions, "resolution": args.resolution,
                                                     **replay}))
        print(json.dumps({**figures(out, scale), **json.loads((out / DONE_FILE).read_text())}), flush=True)


if __name__ == "__main__":
    main()
