"""Benchmark: how far the fitted hand's size explains its new-pose score, over evaluated fits.

    .venv/bin/python benchmarks/size_against_new_poses.py [LABEL=]AVATAR... [--picture PNG]

Each AVATAR is a fit evaluated with `harp evaluate AVATAR SEQ --novel-poses` on a synthetic clip
(its evaluation.json). AVATARs given as LABEL=AVATAR are grouped under LABEL (default: one group).
Prints one JSON line per fit (the size, the truth's over the fit's, `geometry.apart_from_size`; the
new-pose PSNR in the overlap, as it is and at the truth's size; the fitted shape wearing the true
albedo; the surface; held-out and fitted PSNR; the fitted frames' joint error after Procrustes) and,
per group, the means; with --picture, the new-pose PSNR against the size, each group in its own
colour, the avatar at the truth's size beside it (hollow).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def figures(avatar: Path) -> dict:
    """The figures of one evaluated fit (its evaluation.json)."""
    evaluation = json.loads((avatar / "evaluation.json").read_text())
    fidelity = evaluation["fidelity"]
    new_poses = fidelity["new_poses"]
    return {"fit": str(avatar),
            "scale": fidelity["geometry"]["apart_from_size"]["scale"],
            "new_poses": new_poses["psnr_overlap_mean"],
            "new_poses_at_true_size": new_poses["at_true_size"]["psnr_overlap_mean"],
            "fitted_shape_true_albedo": new_poses["fitted_shape_alone"]["psnr_overlap_mean"],
            "surface_mm": fidelity["geometry"]["surface_mm_mean"],
            "held_out_psnr": evaluation["held_out"]["metrics"]["psnr_mean"],
            "fitted_psnr": evaluation["fit_frames"]["psnr_mean"],
            "joints_mm": evaluation["poses"]["fit"]["joints"]["procrustes_mm_mean"]}


def plot(groups: dict, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    figure, axes = pyplot.subplots(figsize=(6.4, 4.2), dpi=120)
    for index, (label, rows) in enumerate(groups.items()):
        colour = f"C{index % 10}"      # matplotlib's colour cycle: every group drawn, however many
        sizes = [100 * (row["scale"] - 1) for row in rows]
        axes.scatter(sizes, [row["new_poses"] for row in rows], color=colour, label=label)
        axes.scatter(sizes, [row["new_poses_at_true_size"] for row in rows], facecolors="none", edgecolors=colour)
    axes.set_xlabel("the fit's size short of the truth's (%)")
    axes.set_ylabel("new poses, overlap PSNR (dB)")
    axes.set_title("filled: the avatar; hollow: the same at the truth's size", fontsize=9)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("avatars", nargs="+", help="AVATAR or LABEL=AVATAR")
    parser.add_argument("--picture", type=Path)
    args = parser.parse_args()
    groups: dict[str, list] = {}
    for given in args.avatars:
        label, _, folder = given.rpartition("=")
        row = figures(Path(folder))
        groups.setdefault(label or "fits", []).append(row)
        print(json.dumps({"group": label or "fits", **{k: round(v, 4) if isinstance(v, float) else v
                                                        for k, v in row.items()}}))
    for label, rows in groups.items():
        means = {key: round(sum(row[key] for row in rows) / len(rows), 4) for key in rows[0] if key != "fit"}
        print(json.dumps({"group": label, "fits": len(rows), "mean": means}))
    if args.picture:
        plot(groups, args.picture)


if __name__ == "__main__":
    main()
