"""The runs a study is made of: sequence folders of its own for each initialisation, and fits
through `harp fit`'s own function (pipeline.fit.fit) with the anytime curve on, each skipped
when finished and resumed when stopped midway."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from ..fit import CHECKPOINT_FILE, fit
from ..formats import sequence_folder as seq
from ..formats.fit_report import REPORT_FILE, read_report
from ..formats.initial_estimate import FILE_NAME as INIT_FILE
from ..init import initialise_sequence
from ..init.initialisation import KEYPOINTS_FILE
from .curve import CurveRecorder

INIT_OUTPUTS = (INIT_FILE, KEYPOINTS_FILE)    # what `harp init` writes into a sequence folder


def linked_sequence(source, target):
    """A sequence folder at `target` that shares the frames, masks and ground truth of `source`
    (symbolic links; copies where links cannot be made) but has its own initial estimate."""
    source, target = Path(source).resolve(), Path(target)
    target.mkdir(parents=True, exist_ok=True)
    for entry in source.iterdir():
        link = target / entry.name
        if entry.name in INIT_OUTPUTS or link.exists() or link.is_symlink():
            continue
        try:
            link.symlink_to(entry, target_is_directory=entry.is_dir())
        except OSError:
            (shutil.copytree if entry.is_dir() else shutil.copy2)(entry, link)
    return target


def initialised(source, target, method, log, **options):
    """`target`: a linked copy of the sequence `source` with `harp init --init method` run on it
    (once: an existing init.npz is kept)."""
    target = linked_sequence(source, target)
    if not (target / INIT_FILE).is_file():
        initialise_sequence(target, method, log=log, warn=log, **options)
    return target


def finished_or_fitted(sequence, out, log, progress="none", **options):
    """The report of the fit of `sequence` into `out` with the curve recorded: read back if it
    has finished, resumed from its checkpoint if it stopped, else fitted."""
    out = Path(out)
    if (out / REPORT_FILE).is_file():
        return read_report(out)
    resume = (out / CHECKPOINT_FILE).is_file()
    log(f"{'resuming' if resume else 'fitting'} {out}")
    return fit(sequence, out, resume=resume, progress=progress, observers=[CurveRecorder(out)], **options)


def sequence_frame_count(folder):
    return seq.read_sequence_info(folder).frame_count


def read_json(path):
    return json.loads(Path(path).read_text())


def write_json(path, value):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(".tmp")
    temporary.write_text(json.dumps(value, indent=1))
    temporary.replace(path)
    return path
