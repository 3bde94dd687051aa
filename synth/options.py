"""Command-line arguments of synth/render.py and their checks (numpy only).

`parse_clip_args(argv)` returns ClipSettings or raises SynthError with a one-line message for
impossible settings; argparse itself prints the usage for unknown arguments (exit code 2).
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from . import SynthError
from .identity import FEATURES, NUM_BETAS
from .motions import MOTIONS

LIGHTING = ("ambient", "sun", "three", "room")
BACKGROUNDS = ("plain", "procedural")
MASK_ENGINES = ("workbench", "cycles")
PREVIEW = {"width": 64, "height": 64, "frames": 4, "samples": 4, "texture_size": 256}


@dataclasses.dataclass
class ClipSettings:
    out: Path
    overwrite: bool = False
    model_folder: Path | None = None
    mode: str = "arm"
    side: str = "right"
    motion: str = "flip"
    seconds: float = 5.0
    fps: float = 30.0
    frames: int | None = None
    seed: int = 0
    identity: int = 0
    skin_tone: float | None = None
    subsurface: float = 0.6         # the skin shader's Subsurface Weight (0: none)
    specular_level: float = 0.35    # its Specular IOR Level at IOR 1.4 (0: a matte, Lambertian-like skin)
    size: float | None = None
    betas: tuple | None = None
    features: tuple | None = None
    width: int = 448
    height: int = 448
    focal: float | None = None
    fov: float | None = None
    azimuth: float = 0.0
    elevation: float = 0.0
    distance: float | None = None   # None: fit the hand into the image
    lighting: str = "ambient"
    background: str = "plain"
    samples: int = 16
    denoise: bool = True
    texture_size: int = 512
    mask_engine: str = "workbench"
    save_vertices: bool = True
    verbose: bool = False
    threads: int = 0                # Cycles' CPU threads; 0: every core

    @property
    def frame_count(self) -> int:
        return self.frames if self.frames is not None else int(round(self.seconds * self.fps))

    def to_json(self) -> dict:
        entry = dataclasses.asdict(self)
        entry["out"] = str(self.out)
        entry["model_folder"] = None if self.model_folder is None else str(self.model_folder)
        return entry


def build_parser(prog="render.py"):
    parser = argparse.ArgumentParser(
        prog=prog, description="Render a synthetic hand clip with exact ground truth into a sequence folder.",
        epilog="Run as `python synth/render.py ARGS` (bpy module) or `blender -b -P synth/render.py -- ARGS`.")
    add = parser.add_argument
    add("--out", required=True, type=Path, help="output sequence folder (created; must be empty)")
    add("--overwrite", action="store_true", help="replace the files of an earlier clip in --out")
    add("--model-folder", type=Path, help="folder with hand_model_{hand,arm}.npz (default: the shipped model)")
    add("--mode", choices=("hand", "arm"), default="arm", help="hand only or hand + forearm (default arm)")
    add("--side", choices=("right", "left"), default="right")
    add("--motion", choices=MOTIONS, default="flip")
    add("--seconds", type=float, default=5.0, help="clip length (default 5)")
    add("--fps", type=float, default=30.0, help="frames per second (default 30)")
    add("--frames", type=int, help="number of frames (overrides --seconds)")
    add("--seed", type=int, default=0, help="seed of the random motion and background")
    add("--identity", type=int, default=0, help="seed of the person: shape, skin, features (default 0)")
    add("--skin-tone", type=float, help="0 very light .. 1 very dark (default: from --identity)")
    add("--subsurface", type=float, default=0.6,
        help="the skin's subsurface scattering weight, 0..1 (default 0.6; 0 with --specular-level 0: Lambertian skin)")
    add("--specular-level", type=float, default=0.35,
        help="the skin's Principled Specular IOR Level at IOR 1.4, 0..1 (default 0.35; 0: no sheen)")
    add("--size", type=float, help="hand size: the scale shape parameter, -3..3 (default: from --identity)")
    add("--betas", help=f"all {NUM_BETAS} shape parameters, comma-separated")
    add("--features", help=f"comma-separated subset of {','.join(FEATURES)}, or 'none' (default: from --identity)")
    add("--width", type=int, default=448)
    add("--height", type=int, default=448)
    add("--focal", type=float, help="focal length in pixels (default 2000 * width / 448)")
    add("--fov", type=float, help="horizontal field of view in degrees (instead of --focal)")
    add("--azimuth", type=float, default=0.0, help="degrees about the hand's long axis; 0 sees the back")
    add("--elevation", type=float, default=0.0, help="degrees towards the fingertips, -85..85")
    add("--distance", type=float, help="camera to hand pivot in metres (default: fit the hand)")
    add("--lighting", choices=LIGHTING, default="ambient")
    add("--background", choices=BACKGROUNDS, default="plain")
    add("--samples", type=int, default=16, help="Cycles samples per pixel (default 16, denoised)")
    add("--no-denoise", dest="denoise", action="store_false", help="switch OpenImageDenoise off")
    add("--texture-size", type=int, default=512, help="albedo texture size in texels (default 512)")
    add("--mask-engine", choices=MASK_ENGINES, default="workbench",
        help="workbench (needs OpenGL/EGL) or cycles (1 sample at pixel centres)")
    add("--no-vertices", dest="save_vertices", action="store_false", help="do not store posed vertices in gt.npz")
    add("--preview", action="store_true", help="4 frames, 64x64, 4 samples: a quick check")
    add("--verbose", action="store_true", help="show Blender's render output")
    add("--threads", type=int, default=0, help="CPU threads Cycles renders with (default 0: every core)")
    return parser


def blender_argv(argv):
    """The script's own arguments: those after '--' under Blender, else argv[1:]."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def parse_clip_args(args, prog="render.py") -> ClipSettings:
    namespace = build_parser(prog).parse_args([str(a) for a in args])
    values = vars(namespace)
    preview = values.pop("preview")
    betas = values.pop("betas")
    features = values.pop("features")
    settings = ClipSettings(**values)
    if betas is not None:
        try:
            settings.betas = tuple(float(b) for b in betas.split(","))
        except ValueError:
            raise SynthError(f"--betas must be {NUM_BETAS} comma-separated numbers, got {betas!r}") from None
    if features is not None:
        settings.features = () if features.strip() == "none" else tuple(f.strip() for f in features.split(","))
    if preview:
        for key, value in PREVIEW.items():
            setattr(settings, key, value)
    check_settings(settings)
    return settings


def check_settings(s: ClipSettings) -> None:
    """Raise SynthError (one line) for settings that cannot be rendered."""
    def fail(message):
        raise SynthError(message)

    if not (16 <= s.width <= 8192 and 16 <= s.height <= 8192):
        fail(f"image size {s.width}x{s.height} is out of range (16..8192 pixels per side)")
    if not 0 < s.fps <= 1000:
        fail(f"--fps must be in (0, 1000], got {s.fps}")
    if s.frames is None and not s.seconds > 0:
        fail(f"--seconds must be positive, got {s.seconds}")
    if s.frames is not None and s.frames < 1:
        fail(f"--frames must be at least 1, got {s.frames}")
    if s.frame_count < 1:
        fail(f"{s.seconds} s at {s.fps} fps is less than one frame")
    if s.frame_count > 100000:
        fail(f"{s.frame_count} frames is too many (at most 100000)")
    if s.focal is not None and s.fov is not None:
        fail("give either --focal or --fov, not both")
    if s.focal is not None and not s.focal > 0:
        fail(f"--focal must be positive, got {s.focal}")
    if s.fov is not None and not 0 < s.fov < 170:
        fail(f"--fov must be between 0 and 170 degrees, got {s.fov}")
    if not -85 <= s.elevation <= 85:
        fail(f"--elevation must be within -85..85 degrees, got {s.elevation}")
    if s.distance is not None and not 0.1 <= s.distance <= 100:
        fail(f"--distance must be within 0.1..100 m, got {s.distance}")
    if s.skin_tone is not None and not 0 <= s.skin_tone <= 1:
        fail(f"--skin-tone must be within 0..1, got {s.skin_tone}")
    if not 0 <= s.subsurface <= 1:
        fail(f"--subsurface must be within 0..1, got {s.subsurface}")
    if not 0 <= s.specular_level <= 1:
        fail(f"--specular-level must be within 0..1, got {s.specular_level}")
    if s.size is not None and not -3 <= s.size <= 3:
        fail(f"--size must be within -3..3 (the model's tested shape range), got {s.size}")
    if s.betas is not None:
        if len(s.betas) != NUM_BETAS:
            fail(f"--betas needs {NUM_BETAS} values, got {len(s.betas)}")
        if any(not -3 <= b <= 3 for b in s.betas):
            fail("--betas must lie within -3..3 (the model's tested shape range)")
    if s.features is not None:
        unknown = [f for f in s.features if f not in FEATURES]
        if unknown:
            fail(f"unknown feature {unknown[0]!r}; choose from {', '.join(FEATURES)} or 'none'")
    if not 1 <= s.samples <= 65536:
        fail(f"--samples must be within 1..65536, got {s.samples}")
    if not 0 <= s.threads <= 1024:
        fail(f"--threads must be within 0..1024 (0: every core), got {s.threads}")
    if s.texture_size not in (64, 128, 256, 512, 1024, 2048, 4096):
        fail(f"--texture-size must be a power of two from 64 to 4096, got {s.texture_size}")
    if s.out.exists() and not s.out.is_dir():
        fail(f"--out {s.out} exists and is not a folder")
    if s.out.is_dir() and any(s.out.iterdir()) and not s.overwrite:
        fail(f"output folder {s.out} is not empty (use --overwrite to replace its clip)")
