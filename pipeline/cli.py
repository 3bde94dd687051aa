"""The `harp` command line."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


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


def _fit(args):
    from .fit.fitting import fit

    report = fit(args.sequence, args.out, preset=args.preset, resume=args.resume, progress=args.progress,
                 device=args.device, shadows=args.shadows)
    scores = report["metrics"]
    print(f"wrote {args.out}: silhouette IoU min {scores['silhouette_iou_min']:.3f}, "
          f"PSNR in the mask {scores['psnr_mean']:.1f} dB, {report['total_seconds']:.0f} s")


def _demo(args):
    """The quick-start job: build the hand model from scratch and picture it."""
    out = Path(args.out)
    _model_build(argparse.Namespace(out=out / "model"))
    _model_preview(argparse.Namespace(out=out / "hand_model.png", size=300, side="right", model=out / "model"))
    _model_info(argparse.Namespace(model=out / "model"))


def build_parser():
    parser = argparse.ArgumentParser(prog="harp", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    demo = commands.add_parser("demo", help="run the built-in example")
    demo.add_argument("--out", default="harp_demo", help="output folder (default: harp_demo)")
    demo.set_defaults(run=_demo)

    fit = commands.add_parser("fit", help="fit an avatar to a sequence folder that has an init.npz")
    fit.add_argument("sequence", help="sequence folder")
    fit.add_argument("--out", required=True, help="avatar folder to write")
    fit.add_argument("--preset", choices=("fast", "balanced", "full"), default="fast")
    fit.add_argument("--shadows", choices=("auto", "on", "off"), default="auto")
    fit.add_argument("--resume", action="store_true", help="continue from the avatar folder's checkpoint")
    fit.add_argument("--progress", choices=("bar", "jsonl", "none"), default="bar")
    fit.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    fit.set_defaults(run=_fit)

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
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (OSError, ValueError) as error:
        print(f"harp: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
