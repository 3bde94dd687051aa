"""`harp batch INPUT... --out DIR`: many clips through the whole job, one table of their figures.

Each input is a video (its masks made from the footage, or given beside it in a list file) or a
sequence folder (`harp import-video`'s or synth's output). Per clip, in DIR/NAME/: the input
(staged: a copy of the video or the sequence folder, so that the folder is all a worker needs),
`sequence/` (the import), the initial estimate (`harp init`), `avatar/` (`harp fit`, every
`hold_out_every`-th frame held out) and its evaluation (`harp evaluate`: the held-out frames under
both protocols; on synthetic clips the poses, the albedo and the avatar in new poses against the
truth), then `result.json`: its row of the table. Each step is skipped where its output is there
and a stopped fit resumes from its checkpoint, so a batch run again with `--resume` goes on where
it stopped, and a clip whose worker died goes on from what it left.

The clips run on an executor (executors.py): `local` (default: single-threaded clips, as many at
once as there are cores) or `ray`. A clip that fails is listed with its one-line reason; the
others finish. The table, DIR/batch.csv and DIR/batch.md, is written as clips finish and at the end.
"""
from __future__ import annotations

import csv
import json
import shutil
import time
from pathlib import Path

from .executors import Cell, CellFailure, default_jobs, run_cells
from .formats import sequence_folder as seq

RESULT_FILE, TABLE_CSV, TABLE_MD, PLAN_FILE = "result.json", "batch.csv", "batch.md", "batch.json"
ATTEMPTS_FILE, TIMES_FILE = "attempts.txt", "times.json"
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v")
COLUMNS = (  # (key, heading, digits)
    ("clip", "clip", None), ("status", "status", None), ("attempts", "attempts", 0), ("frames", "frames", 0),
    ("fitted_psnr", "fitted PSNR dB", 2), ("fitted_iou", "fitted IoU", 3),
    ("held_out_psnr", "held-out PSNR dB", 2), ("held_out_iou", "held-out IoU", 3), ("held_out_l1", "held-out L1", 4),
    ("held_out_keypoints_psnr", "held-out PSNR from keypoints dB", 2),
    ("joint_initial_mm", "joints at the start mm", 2), ("joint_mm", "joints mm", 2), ("surface_mm", "surface mm", 2),
    ("new_pose_psnr", "new poses PSNR dB", 2), ("sharpness", "albedo sharpness", 2),
    ("import_s", "import s", 0), ("init_s", "init s", 0), ("fit_s", "fit s", 0), ("evaluate_s", "evaluate s", 0),
    ("reason", "reason", None))


class BatchError(ValueError):
    """The batch cannot start (one-line message)."""


def read_list(path):
    """The inputs of a list file: one `INPUT [MASKS]` per line (paths relative to the file; # comments)."""
    path = Path(path)
    if not path.is_file():
        raise BatchError(f"list file not found: {path}")
    inputs = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if len(parts) > 2:
            raise BatchError(f"{path}:{number}: a line is INPUT [MASKS], got {len(parts)} items")
        inputs.append(tuple(str((path.parent / part).resolve()) if not Path(part).is_absolute() else part
                            for part in parts) + ((None,) if len(parts) == 1 else ()))
    if not inputs:
        raise BatchError(f"{path} lists no inputs")
    return inputs


def plan(inputs, out):
    """[(name, source, masks)]: each input checked and named after it (repeats numbered)."""
    planned, names = [], set()
    for source, masks in inputs:
        source = Path(source)
        if not source.exists():
            raise BatchError(f"input not found: {source}")
        if source.is_dir() and not (source / seq.SEQUENCE_FILE).is_file():
            raise BatchError(f"{source} is a folder but not a sequence folder (no {seq.SEQUENCE_FILE}); "
                             "give a video, or run harp import-video on it first")
        if source.is_file() and source.suffix.lower() not in VIDEO_SUFFIXES:
            raise BatchError(f"{source} is not a video ({', '.join(VIDEO_SUFFIXES)}) or a sequence folder")
        if masks is not None and not Path(masks).exists():
            raise BatchError(f"masks not found: {masks}")
        if masks is not None and source.is_dir():
            raise BatchError(f"{source}: a sequence folder has its masks already; masks are for videos")
        base = (source.stem if source.is_file() else source.name) or "clip"
        name, number = base, 2
        while name in names:
            name, number = f"{base}_{number}", number + 1
        names.add(name)
        planned.append((name, str(source), None if masks is None else str(masks)))
    return planned


def run_batch(inputs, out, resume=False, executor="local", jobs=None, threads=1, address=None, preset="fast",
              hold_out_every=10, init="mediapipe", seed=None, held_out_steps=300, novel_poses="auto",
              progress="bar", log=print, **fit_options):
    """Every input through import, init, fit and evaluation into `out`; returns the table's rows
    (also batch.csv and batch.md). `inputs`: [(video or sequence folder, masks or None)]."""
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not resume:
        raise BatchError(f"{out} is not empty: add --resume to go on with the batch there, or choose another --out")
    clips = plan(inputs, out)
    out.mkdir(parents=True, exist_ok=True)
    options = dict(preset=preset, hold_out_every=hold_out_every, init=init, seed=seed, held_out_steps=held_out_steps,
                   novel_poses=novel_poses, fit_options=fit_options)
    (out / PLAN_FILE).write_text(json.dumps({"clips": clips, "options": options}, indent=1, default=str))
    cells = []
    for name, source, masks in clips:
        folder = out / name
        stage_input(source, masks, folder)
        cells.append(Cell(name, process_clip, {"folder": str(folder), "options": options}, ship=("folder",)))
    jobs = jobs or (default_jobs(threads) if executor == "local" else None)
    rows = {name: _read_row(out / name) for name, _, _ in clips}
    bar = _bar(progress, len(clips), sum(row is not None for row in rows.values()))

    def finished(name, row):
        rows[name] = row
        write_table(out, [rows[n] or _pending(n) for n, _, _ in clips])
        bar.update(1)
        bar.set_postfix_str(f"{name}: {row['status']}")

    todo = [cell for cell in cells if rows[cell.name] is None]
    started = time.perf_counter()
    try:
        run_cells(todo, jobs=jobs, threads=threads, log=log if progress != "bar" else bar.write,
                  logs=out / "logs", executor=executor, address=address, on_result=finished)
    except CellFailure as failure:
        for name, reason in failure.failures.items():
            rows[name] = {**_pending(name), "status": "failed", "reason": reason,
                          "attempts": _attempts(out / name)}
    finally:
        bar.close()
    table = [rows[name] for name, _, _ in clips]
    write_table(out, table)
    failed = sum(row["status"] == "failed" for row in table)
    log(f"{len(table) - failed} of {len(table)} clips done in {(time.perf_counter() - started) / 60:.1f} min"
        + (f"; {failed} failed (see {out / TABLE_MD})" if failed else "") + f"; table: {out / TABLE_CSV}")
    return table


def stage_input(source, masks, folder):
    """Put what the clip's job reads into its folder: the sequence folder copied, or the video
    (and its masks) under input/. Done once."""
    folder = Path(folder)
    source = Path(source)
    if source.is_dir():
        if not (folder / "sequence" / seq.SEQUENCE_FILE).is_file():
            shutil.copytree(source, folder / "sequence", symlinks=False, dirs_exist_ok=True)
        return
    staged = folder / "input"
    if not staged.is_dir():
        staged.mkdir(parents=True)
        shutil.copy2(source, staged / source.name)
        if masks is not None:
            target = staged / ("masks" + (Path(masks).suffix if Path(masks).is_file() else ""))
            (shutil.copy2 if Path(masks).is_file() else shutil.copytree)(masks, target)


def process_clip(folder, options, log):
    """One clip's job in its folder (the executor's cell): import, init, fit, evaluate, each
    skipped where done; returns its row (also result.json)."""
    folder = Path(folder)
    attempts = _attempts(folder) + 1
    (folder / ATTEMPTS_FILE).write_text(f"{attempts}\n")
    times_file = folder / TIMES_FILE
    times = json.loads(times_file.read_text()) if times_file.is_file() else {}
    sequence, avatar = folder / "sequence", folder / "avatar"

    def timed(step, work):
        start = time.perf_counter()
        work()
        times[step] = times.get(step, 0.0) + time.perf_counter() - start
        times_file.write_text(json.dumps(times))

    if not (sequence / seq.SEQUENCE_FILE).is_file():
        timed("import", lambda: _import(folder, sequence, log))
    from .formats.initial_estimate import FILE_NAME as INIT_FILE
    if not (sequence / INIT_FILE).is_file():
        timed("init", lambda: _initialise(sequence, options, log))
    from .formats.fit_report import REPORT_FILE
    if not (avatar / REPORT_FILE).is_file():
        timed("fit", lambda: _fit(sequence, avatar, options, log))
    from .evaluate import EVALUATION_FILE
    if not (avatar / EVALUATION_FILE).is_file():
        timed("evaluate", lambda: _evaluate(sequence, avatar, options, log))
    row = {**_figures(folder.name, sequence, avatar), "attempts": attempts,
           **{f"{step}_s": seconds for step, seconds in times.items()}}
    (folder / RESULT_FILE).write_text(json.dumps(row, indent=1))
    return row


def _import(folder, sequence, log):
    from .sequence_import import import_video

    inputs = sorted((folder / "input").iterdir())
    videos = [path for path in inputs if path.suffix.lower() in VIDEO_SUFFIXES]
    masks = next((path for path in inputs if path.name.startswith("masks")), None)
    import_video(videos[0], masks, sequence, overwrite=True, log=log, warn=log, workers=1)


def _initialise(sequence, options, log):
    from .init import initialise_sequence

    initialise_sequence(sequence, options["init"], log=log, warn=log)


def _fit(sequence, avatar, options, log):
    from .fit import CHECKPOINT_FILE, fit

    seed = {} if options["seed"] is None else {"seed": options["seed"]}
    resume = (avatar / CHECKPOINT_FILE).is_file()
    log(f"{'resuming the fit from its checkpoint' if resume else 'fitting'} in {avatar}")
    fit(sequence, avatar, preset=options["preset"], resume=resume, progress="none",
        hold_out_every=options["hold_out_every"], **seed, **options["fit_options"])


def _evaluate(sequence, avatar, options, log):
    from .evaluate import evaluate_fit

    synthetic = seq.read_sequence_info(sequence).ground_truth
    novel = synthetic if options["novel_poses"] == "auto" else bool(options["novel_poses"])
    evaluate_fit(avatar, sequence, held_out_steps=options["held_out_steps"], novel_poses=novel)


def _figures(name, sequence, avatar):
    """The clip's row: its figures from report.json and evaluation.json."""
    from .evaluate import EVALUATION_FILE
    from .formats.fit_report import read_report

    report = read_report(avatar)
    evaluation = json.loads((avatar / EVALUATION_FILE).read_text())
    fitted = evaluation["fit_frames"]
    row = {"clip": name, "status": "done", "frames": len(report.get("frames") or []),
           "fitted_psnr": fitted.get("psnr_mean"), "fitted_iou": fitted.get("silhouette_iou_mean")}
    for key, prefix in (("held_out", "held_out"), ("held_out_from_keypoints", "held_out_keypoints")):
        metrics = evaluation.get(key, {}).get("metrics", {})
        row[f"{prefix}_psnr"] = metrics.get("psnr_mean")
        if key == "held_out":
            row["held_out_iou"], row["held_out_l1"] = metrics.get("silhouette_iou_mean"), metrics.get("l1_mean")
    poses = evaluation.get("poses")
    if poses:
        row["joint_initial_mm"] = poses["initial"]["joints"]["procrustes_mm_mean"]
        row["joint_mm"] = poses["fit"]["joints"]["procrustes_mm_mean"]
    fidelity = evaluation.get("fidelity")
    if fidelity:
        row["surface_mm"] = fidelity["geometry"]["surface_mm_mean"]
        row["new_pose_psnr"] = fidelity["new_poses"]["psnr_overlap_mean"]
        row["sharpness"] = fidelity["texture"]["sharpness_ratio"]
    return row


def _attempts(folder):
    path = Path(folder) / ATTEMPTS_FILE
    return int(path.read_text()) if path.is_file() else 0


def _read_row(folder):
    path = Path(folder) / RESULT_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def _pending(name):
    return {"clip": name, "status": "pending"}


def write_table(out, rows):
    """batch.csv (every column) and batch.md (the columns any row fills)."""
    out = Path(out)
    with open(out / TABLE_CSV, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([key for key, _, _ in COLUMNS])
        for row in rows:
            writer.writerow(["" if row.get(key) is None else row[key] for key, _, _ in COLUMNS])
    shown = [(key, heading, digits) for key, heading, digits in COLUMNS
             if any(row.get(key) is not None for row in rows)]
    lines = ["| " + " | ".join(heading for _, heading, _ in shown) + " |", "|" + "---|" * len(shown)]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row.get(key), digits) for key, _, digits in shown) + " |")
    (out / TABLE_MD).write_text("\n".join(lines) + "\n")


def _cell(value, digits):
    if value is None:
        return ""
    if digits is None or not isinstance(value, (int, float)):
        return str(value)
    return f"{value:.{digits}f}"


class _NoBar:
    def update(self, count):
        pass

    def set_postfix_str(self, text):
        pass

    def write(self, text):
        print(text, flush=True)

    def close(self):
        pass


def _bar(progress, total, done):
    if progress != "bar":
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, initial=done, unit="clip", desc="harp batch")
