"""A fitted avatar in new poses, from the back and from the palm, under its fitted light: one
picture (a row per view, a column per pose), as `harp render` draws each. Several avatars (the
same hand fitted two ways, say) give a block of rows each, each tile named by its avatar's --labels.

    .venv/bin/python tools/picture_new_poses.py AVATAR [AVATAR ...] OUT.png [--poses fist,spread,thumbs_up,pinch]
        [--size 256] [--views palm,back] [--labels "before,after"]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.avatar_render import render_avatar  # noqa: E402

VIEWS = (("palm", 20.0), ("back", 200.0))     # azimuths (degrees): the palm faces the camera at 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("avatars", nargs="+", help="avatar folders, then the picture to write")
    parser.add_argument("--poses", default="fist,spread,thumbs_up,pinch")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--views", default=",".join(name for name, _ in VIEWS))
    parser.add_argument("--labels", default=None, help="comma-separated, one per avatar (default: none)")
    args = parser.parse_args(argv)
    if len(args.avatars) < 2:
        parser.error("give at least one avatar folder and the picture to write")
    *avatars, args.out = args.avatars
    labels = args.labels.split(",") if args.labels else [""] * len(avatars)
    if len(labels) != len(avatars):
        parser.error(f"--labels names {len(labels)} avatars, {len(avatars)} given")
    views = [(name, azimuth) for name, azimuth in VIEWS if name in args.views.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for number, (avatar, label) in enumerate(zip(avatars, labels)):
            for view, azimuth in views:
                tiles = []
                for pose in args.poses.split(","):
                    path = render_avatar(avatar, Path(scratch) / f"{number}_{view}_{pose}.png", pose, None, azimuth,
                                         10.0, None, args.size, None)
                    tile = cv2.imread(str(path))
                    name = f"{label}: {pose}, {view}" if label else f"{pose}, {view}"
                    cv2.putText(tile, name, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
                    tiles.append(tile)
                rows.append(np.concatenate(tiles, axis=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), np.concatenate(rows, axis=0)):
        raise SystemExit(f"could not write {args.out}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
