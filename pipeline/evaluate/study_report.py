"""What a study writes: study.json, study.md (its tables, in the study's order) and plots/
(the four refinement cases per motion as bars, each clip's refinement curves, the presets'
curves). matplotlib is imported only where the plots are drawn."""
from __future__ import annotations

import json
from pathlib import Path

from .plot import plot_curves, save_figure

STUDY_FILE, STUDY_JSON, PLOTS = "study.md", "study.json", "plots"
REFINEMENT_FIGURES = ("joint_mm", "vertex_mm", "joint_camera_mm", "vertex_camera_mm", "joint_end_over_min")


def write_outputs(out, study):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sections = study["sections"]
    plots = {}
    if "refinement" in sections:
        plots["refinement_bars"] = refinement_bars(sections["refinement"], out / PLOTS / "refinement.png")
        plots["refinement_curves"] = refinement_curves(sections["refinement"], out)
    if "runtime" in sections:
        runtime = sections["runtime"]
        folders = list(runtime["fits"].values())
        targets = {name: value for name, value in runtime["targets"].items()}
        plots["runtime"] = str(plot_curves(folders, out / PLOTS / f"runtime_{runtime['clip']}.png",
                                           figures=("l1_mean", "joint_mm", "psnr_mean", "vertex_mm"),
                                           labels=list(runtime["fits"]), targets=targets,
                                           title=f"error against fitting time: {runtime['clip']}"))
    if sections.get("stability", {}).get("fits"):
        stability = sections["stability"]
        path = stability_curves(stability, out / PLOTS / "stability.png")
        if path is not None:
            plots["stability"] = str(path)
            stability["plot"] = str(Path(path).relative_to(out))
    study["plots"] = {name: str(Path(path).relative_to(out)) if isinstance(path, (str, Path)) else
                      {k: str(Path(v).relative_to(out)) for k, v in path.items()} for name, path in plots.items()}
    (out / STUDY_JSON).write_text(json.dumps(study, indent=1))
    (out / STUDY_FILE).write_text(markdown(study))
    return out / STUDY_FILE


def _number(value, digits=2):
    return "–" if value is None else f"{value:.{digits}f}"


def markdown(study):
    lines = [f"# Study of {study['dataset']}", "",
             f"Preset `{study['preset']}`{' (quick: stages capped)' if study['quick'] else ''}; "
             f"{study['seconds'] / 60:.0f} min in all. Fit options: {study['fit_options'] or 'none'}.", ""]
    sections = study["sections"]
    if "refinement" in sections:
        lines += _refinement_tables(sections["refinement"])
    if "runtime" in sections:
        lines += _runtime_table(sections["runtime"])
    if "stability" in sections:
        lines += _stability_table(sections["stability"])
    for name, path in study.get("plots", {}).items():
        if isinstance(path, dict) or name == "stability":     # the sweep's curves stand in its section
            continue
        lines += [f"![{name}]({path})", ""]
    return "\n".join(lines) + "\n"


def _refinement_tables(section):
    seeds = section.get("seeds") or [0]
    seed_text = (f" Each fit ran with the fit seeds {', '.join(map(str, seeds))}, all from the same initial estimate: "
                 "a figure is the mean over the seeds (and the clips), and in brackets the lowest and highest of "
                 "its per-seed means (the seed spread)." if len(seeds) > 1 else f" Fit seed {seeds[0]}.")
    return ["## 1. Pose refinement", "",
            "Every fit starts from `gt-noise` (10 degrees on every joint, 1 cm on the wrist). Errors in mm on the "
            "fitted frames: joints (21 keypoints) and the model's vertices, Procrustes-aligned (PA) and in the "
            "camera frame (cam); \"end / lowest\": the joint error at the fit's end over the lowest its curve "
            f"reached.{seed_text}", "", "### Means", "", refinement_means_table(section), "### Per clip", "",
            refinement_per_clip_table(section)]


def refinement_means_table(section):
    """The markdown table of the refinement's means per motion and case (with the seed spread)."""
    lines = ["| motion | case | clips | joint PA | vertex PA | joint cam | vertex cam | joint PA end / lowest |",
             "|---|---|---|---|---|---|---|---|"]
    for motion, cases in section["means"].items():
        for case, figures in cases.items():
            lines.append(f"| {motion} | {case} | {figures['clips']} | "
                         + " | ".join(_with_spread(figures, name) for name in REFINEMENT_FIGURES) + " |")
    return "\n".join(lines) + "\n"


def refinement_per_clip_table(section):
    """The markdown table of each clip's cases (over the seeds, with their spread)."""
    lines = ["| clip | case | joint PA | vertex PA | joint cam | vertex cam | joint PA end / lowest | fit s |",
             "|---|---|---|---|---|---|---|---|"]
    for row in section.get("per_clip") or section["rows"]:
        note = f" ({row['note']})" if row.get("note") else ""
        lines.append(f"| {row['clip']} | {row['case']}{note} | "
                     + " | ".join(_with_spread(row, name) for name in REFINEMENT_FIGURES)
                     + f" | {_number(row['fit_seconds'], 0)} |")
    return "\n".join(lines) + "\n"


def refinement_summary_table(section):
    """The README's table: the Procrustes-aligned joint error of each case per motion."""
    means = section["means"]
    motions = list(means)
    lines = ["| case | " + " | ".join(motions) + " |", "|---|" + "---|" * len(motions)]
    for case in section["cases"]:
        if any(case in means[motion] for motion in motions):
            lines.append(f"| {case} | " + " | ".join(_with_spread(means[motion][case], "joint_mm")
                                                     if case in means[motion] else "" for motion in motions) + " |")
    return "\n".join(lines) + "\n"


def _with_spread(figures, name):
    """"3.53 (3.41-3.66)": the mean and its per-seed lowest and highest, where there are several."""
    spread = figures.get(f"{name}_spread")
    value = _number(figures.get(name))
    return value if not spread else f"{value} ({spread[0]:.2f}-{spread[1]:.2f})"


def _runtime_table(section):
    targets = section["targets"]
    return ["## 2. Error against run time", "",
            f"Clip `{section['clip']}`{_frames(section.get('frames'))}. Targets: within {section['within']:.0%} of "
            f"the `{section['reference']}` preset's final figures: L1 {_number(targets.get('l1_mean'), 4)}, joint error "
            f"{_number(targets.get('joint_mm'))} mm. Seconds of fitting (measuring excluded) from which the figure stays "
            "within its target to the end.", "", runtime_table(section)]


def runtime_table(section):
    """The markdown table of the run-time section: each preset's time, final figures and times to the targets."""
    lines = ["| preset | fit s | final L1 | final joint PA mm | joint PA end / lowest | s to L1 target | "
             "s to joint target | s to both |", "|---|---|---|---|---|---|---|---|"]
    for row in section["table"]:
        lines.append(f"| {row['preset']} | {_number(row['fit_seconds'], 0)} | {_number(row['final_l1'], 4)} | "
                     f"{_number(row['final_joint_mm'])} | {_number(row.get('joint_end_over_min'))} | "
                     f"{_reached(row['seconds_to_l1'])} | {_reached(row['seconds_to_joint'])} | "
                     f"{_reached(row['seconds_to_both'])} |")
    return "\n".join(lines) + "\n"


def _frames(count):
    return f", {count} frames of it (spread evenly) for every preset" if count else ""


def _reached(seconds):
    return "not reached" if seconds is None else f"{seconds:.0f}"


def _stability_table(section):
    description = section.get("description") or (f"Exact 64 px clips, 4 frames, {section['steps_per_stage']} "
                                                  "steps per stage, from `gt-noise`")
    lines = ["## 3. Stability sweep", "",
             f"{description[0].upper()}{description[1:]}. Every entry finite: "
             f"{'yes' if section['all_finite'] else 'NO'}. Ratios are to the unperturbed fit's; a case whose input "
             "is not degraded should end within 20% of its joint error.", ""]
    if section.get("plot"):
        lines += [f"![joint error against fitting time, per kind of case]({section['plot']})", ""]
    lines += ["| kind | case | degraded input | finished | rollbacks | non-finite events | joint PA mm (initial) | "
              "x unperturbed | L1 | x unperturbed | fit s |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in section["rows"]:
        finished = "yes" if row["finished"] else f"no: {row['error']}"
        within = row.get("within_baseline")
        flag = "" if within is None or within else " (over 20%)"
        lines.append(f"| {row['kind']} | {row['case']} | {'yes' if row.get('degraded') else 'no'} | {finished} | "
                     f"{row['rollbacks']} | {row['non_finite']} | {_number(row['joint_mm'])} "
                     f"({_number(row['initial_joint_mm'])}) | {_number(row.get('joint_ratio'))}{flag} | "
                     f"{_number(row.get('l1_mean'), 4)} | {_number(row.get('l1_ratio'))} | "
                     f"{_number(row.get('fit_seconds'), 0)} |")
    return lines + [""]


def stability_curves(section, path):
    """Joint error against fitting time of the sweep's fits, one panel per kind of case, the
    unperturbed fit in black in each; None when no fit recorded its curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .curve import read_curve

    fits = section.get("fits") or {}
    if not fits:
        return None
    kinds = {}
    for row in section["rows"]:
        if row["case"] in fits and row["kind"] != "baseline":
            kinds.setdefault(row["kind"], []).append(row["case"])
    baseline = next((row["case"] for row in section["rows"] if row["kind"] == "baseline" and row["case"] in fits),
                    None)
    columns = min(3, max(1, len(kinds)))
    rows = -(-max(1, len(kinds)) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.6 * columns, 3.4 * rows), squeeze=False)

    def draw(axis, case, **style):
        points = [p for p in read_curve(fits[case])["points"] if p.get("joint_mm") is not None and p["fit_seconds"] > 0]
        axis.plot([p["fit_seconds"] for p in points], [p["joint_mm"] for p in points], label=case, **style)

    for axis, (kind, cases) in zip(axes.flat, kinds.items()):
        if baseline is not None:
            draw(axis, baseline, color="black", linewidth=2)
        for number, case in enumerate(cases):
            draw(axis, case, color=f"C{number % 10}", linewidth=0.8 if len(cases) > 10 else 1.3)
        axis.set_xscale("log")
        axis.set_title(kind)
        axis.set_xlabel("fitting time (s)")
        axis.set_ylabel("joint error, PA (mm)")
        if len(cases) <= 10:
            axis.legend(fontsize=6)
    for axis in list(axes.flat)[len(kinds):]:
        axis.axis("off")
    figure.suptitle("stability sweep: joint error against fitting time")
    return save_figure(figure, path)


def refinement_bars(section, path):
    """A bar chart: mean Procrustes-aligned joint error of each case, per motion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    means = section["means"]
    motions = list(means)
    cases = [case for case in section["cases"] if any(case in means[m] for m in motions)]
    figure, axis = plt.subplots(figsize=(1.6 + 1.4 * len(motions) * len(cases) / 3, 3.6))
    width = 0.8 / len(cases)
    for k, case in enumerate(cases):
        present = [(i, means[m][case]["joint_mm"]) for i, m in enumerate(motions)
                   if means[m].get(case, {}).get("joint_mm") is not None]
        bars = axis.bar([i + k * width for i, _ in present], [value for _, value in present], width, label=case,
                        color=f"C{k}")
        axis.bar_label(bars, fmt="%.1f", fontsize=7)
    axis.set_xticks([i + width * (len(cases) - 1) / 2 for i in range(len(motions))], motions)
    axis.set_ylabel("joint error, Procrustes-aligned (mm)")
    axis.set_title("pose refinement: mean over clips")
    axis.legend(fontsize=7)
    return save_figure(figure, path)


def refinement_curves(section, out):
    """Per clip: the curves of its HARP-sil, HARP-full and HARP-known fits of the first seed."""
    seed = (section.get("seeds") or [0])[0]
    paths = {}
    for clip in sorted({row["clip"] for row in section["rows"]}):
        fits = out / "fits" / clip / f"seed{seed}"
        folders = [(name, fits / name) for name in ("sil", "full", "known")]
        folders = [(name, folder) for name, folder in folders if (folder / "curve.json").is_file()]
        if folders:
            paths[clip] = plot_curves([folder for _, folder in folders], out / PLOTS / f"refinement_{clip}.png",
                                      labels=[f"HARP-{name}" for name, _ in folders], title=f"{clip}, seed {seed}")
    return paths
