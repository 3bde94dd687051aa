"""Render one synthetic hand clip with exact ground truth into a sequence folder.

    python synth/render.py --out clips/flip --motion flip --lighting sun
    blender -b -P synth/render.py -- --out clips/flip --motion flip --lighting sun

Both run the same code with the same arguments and write the same ground truth. Arguments:
`python synth/render.py --help`; the output format: pipeline/formats/sequence_folder.py;
documentation: docs/synth.md.
"""
import os
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:  # Blender's Python and `python synth/render.py` both need this
    sys.path.insert(0, REPO_ROOT)


def main(argv=None):
    from synth import SynthError
    from synth.options import blender_argv, parse_clip_args

    args = blender_argv(sys.argv if argv is None else argv)
    try:
        settings = parse_clip_args(args)
        from synth.clip import log_to_stderr, render_clip

        summary = render_clip(settings, log=log_to_stderr if settings.verbose else (lambda message: None))
    except SynthError as error:
        print(f"render.py: error: {error}", file=sys.stderr)
        return 2
    print(f"wrote {summary['frames']} frames to {summary['out']} in {summary['seconds']:.1f} s "
          f"({summary['seconds_per_frame']:.2f} s per frame)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
