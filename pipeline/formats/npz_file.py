"""The .npz files of our formats: named arrays plus a JSON header (format name, version and
whatever else the format keeps there), written and read in one place (numpy and the standard
library only). Every problem reading one is a single line of the format's own error class."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

HEADER = "header"


def write_npz(path, header: dict, arrays: dict) -> Path:
    """Write `arrays` and the JSON `header` to `path` (compressed; the suffix is kept as given)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    encoded = np.frombuffer(json.dumps(header, sort_keys=True).encode(), np.uint8)
    with open(path, "wb") as handle:  # np.savez would append ".npz" to other suffixes
        np.savez_compressed(handle, **{HEADER: encoded}, **arrays)
    return path


def read_npz(path, format_name, version, error, required=(), optional=(), what="file"):
    """(header, {name: array}) of an .npz written by write_npz. `error` is the exception class
    raised, with one line, for a missing or damaged file, another format or version, or a
    missing required array; optional arrays that are absent are None."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as archive:
            header = json.loads(archive[HEADER].tobytes().decode()) if HEADER in archive.files else {}
            missing = [name for name in required if name not in archive.files]
            arrays = {name: archive[name] for name in required if name in archive.files}
            arrays.update({name: archive[name] if name in archive.files else None for name in optional})
    except Exception as error_:  # not a zip, truncated, bad JSON ...
        raise error(f"cannot read {what} {path}: {str(error_).splitlines()[0] if str(error_) else type(error_).__name__}") \
            from None
    if header.get("format") != format_name:
        raise error(f"{path} is not a {format_name} file")
    if header.get("version") != version:
        raise error(f"{path} has {format_name} version {header.get('version')}; this program reads version {version}")
    if missing:
        raise error(f"{path} lacks the array(s) {', '.join(missing)}")
    return header, arrays
