"""`harp plot AVATAR... --out PNG`: error against seconds of fitting for one or several fits,
from their anytime curves (curve.json), on a log time axis. matplotlib is imported here only.

One panel per figure that the fits recorded (formats/fit_curve.FIGURES: image errors always,
pose and albedo errors on synthetic clips); the first point of each curve (the initial
estimate, at 0 s) is drawn at the left edge as a hollow marker. The fit's validation checks (on
the frames it kept out) are drawn dashed beside its training curve where they hold the figure.
"""
from __future__ import annotations

import math
from pathlib import Path

from ..formats.fit_curve import FIGURES, read_curve

DEFAULT_FIGURES = ("l1_mean", "psnr_mean", "silhouette_iou_mean", "joint_mm", "vertex_mm", "albedo_mae")


def curve_label(folder, curve):
    return f"{Path(folder).name} ({curve.get('preset', '?')})"


def plot_curves(folders, out, figures=DEFAULT_FIGURES, labels=None, title=None, targets=None, finals=()):
    """Draw the curves of the fits in `folders` into the PNG `out`; returns its path.
    `labels` name the fits (default: folder and preset); `targets` ({figure: value}) draws a
    dashed horizontal line per panel (e.g. the level a preset must reach); `finals` draws fits
    known only by their end, one star each: [(label, fit seconds, {figure: value})]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = [read_curve(folder) for folder in folders]
    labels = labels or [curve_label(folder, curve) for folder, curve in zip(folders, curves)]
    shown = [name for name in figures
             if any(point.get(name) is not None for curve in curves for point in curve["points"])
             or any(values.get(name) is not None for _, _, values in finals)]
    if not shown:
        raise ValueError("the curves hold none of the figures " + ", ".join(figures))
    columns = min(3, len(shown))
    rows = math.ceil(len(shown) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.6 * columns, 3.4 * rows), squeeze=False)
    earliest = min((p["fit_seconds"] for c in curves for p in c["points"] if p["fit_seconds"] > 0), default=1.0)
    left = earliest / 2
    for axis, name in zip(axes.flat, shown):
        label, lower_is_better = FIGURES[name]
        for curve, text in zip(curves, labels):
            points = [p for p in curve["points"] if p.get(name) is not None]
            if not points:
                continue
            times = [max(p["fit_seconds"], left) for p in points]
            values = [p[name] for p in points]
            line, = axis.plot(times, values, marker=".", markersize=4, label=text)
            if points[0]["fit_seconds"] <= 0:
                axis.plot([left], [values[0]], marker="o", fillstyle="none", color=line.get_color())
            checks = [p for p in curve.get("validation", []) if p.get(name) is not None]
            if checks:
                axis.plot([max(p["fit_seconds"], left) for p in checks], [p[name] for p in checks], marker="x",
                          markersize=4, linestyle="--", color=line.get_color(), label=f"{text}, validation frames")
        for text, seconds, values in finals:
            if values.get(name) is not None:
                axis.plot([seconds], [values[name]], marker="*", markersize=10, linestyle="none", label=text)
        if targets and name in targets:
            axis.axhline(targets[name], color="grey", linestyle="--", linewidth=0.8)
        axis.set_xscale("log")
        axis.set_xlabel("seconds of fitting")
        axis.set_title(label + (" (lower is better)" if lower_is_better else ""), fontsize=9)
        axis.grid(True, which="both", alpha=0.3)
    for axis in list(axes.flat)[len(shown):]:
        axis.set_visible(False)
    axes.flat[0].legend(fontsize=8)
    if title:
        figure.suptitle(title)
    return save_figure(figure, out)


def save_figure(figure, path):
    """Lay out, write as PNG (making its folder) and close a matplotlib figure; returns the path."""
    import matplotlib.pyplot as plt

    figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
