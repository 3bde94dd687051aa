"""The fitting engine: the Python (with torch and the harp-avatar package) that runs `harp`
commands for the add-on in a worker process. Blender's own Python has no torch and never needs
it: the add-on only starts that Python and reads the folders it writes.

Where the engine is found, in order: the add-on preference; $HARP_PYTHON; the Python that
built the extension (recorded in the extension as engine.json: the project's .venv); the
Python of a `harp` command on the PATH.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

ENGINE_HINT_FILE = Path(__file__).resolve().parent / "vendor" / "engine.json"
CHECK_SECONDS = 120
CHECK_SCRIPT = (
    "import json, torch, pipeline.cli; "
    "device = 'cuda (' + torch.cuda.get_device_name(0) + ')' if torch.cuda.is_available() else 'cpu'; "
    "print(json.dumps({'torch': torch.__version__, 'device': device, 'threads': torch.get_num_threads()}))")


@dataclasses.dataclass
class EngineStatus:
    ok: bool
    message: str                 # one line for the interface
    torch: str | None = None
    device: str | None = None


def default_engine_python():
    """The engine's Python as far as it can be found without the user, or None."""
    candidates = [os.environ.get("HARP_PYTHON")]
    if ENGINE_HINT_FILE.is_file():
        try:
            candidates.append(json.loads(ENGINE_HINT_FILE.read_text()).get("python"))
        except (OSError, json.JSONDecodeError):
            pass
    harp = shutil.which("harp")
    if harp:
        candidates.append(_shebang_python(harp))
    return next((c for c in candidates if c and Path(c).is_file()), None)


def _shebang_python(script):
    try:
        with open(script, "rb") as handle:
            first = handle.readline().decode(errors="replace").strip()
    except OSError:
        return None
    return first[2:].strip().split()[0] if first.startswith("#!") and first[2:].strip() else None


def check_engine(python, timeout=CHECK_SECONDS) -> EngineStatus:
    """Start the engine's Python once and report its torch version and device, or what is wrong
    with it, in one line."""
    if not python:
        return EngineStatus(False, "no engine Python set: choose the Python of the harp-avatar install "
                                   "(its .venv/bin/python) in the add-on's preferences")
    if not Path(python).is_file():
        return EngineStatus(False, f"no Python at {python}")
    try:
        result = subprocess.run([str(python), "-c", CHECK_SCRIPT], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return EngineStatus(False, f"{python} did not answer within {timeout} s")
    except OSError as error:
        return EngineStatus(False, f"cannot start {python}: {error.strerror or error}")
    if result.returncode != 0:
        lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
        reason = lines[-1] if lines else f"exit status {result.returncode}"
        return EngineStatus(False, f"{python} cannot run the fitting engine: {reason}")
    try:
        facts = json.loads(result.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        return EngineStatus(False, f"{python} gave an unexpected answer: {result.stdout.strip()[:200]}")
    return EngineStatus(True, f"engine ready: torch {facts['torch']} on {facts['device']}", facts["torch"],
                        facts["device"])


def harp_command(python, *arguments):
    """The command line of `harp ARGUMENTS` run by the engine's Python."""
    return [str(python), "-m", "pipeline.cli", *[str(a) for a in arguments]]
