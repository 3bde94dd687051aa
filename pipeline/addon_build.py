"""`harp addon build`: the Blender extension zip, made with Blender's own `blender_ext.py build`
(from the bpy wheel) and checked with its `validate`.

The zip holds harp_addon/ at its root, the manifest (blender_manifest.toml), and in vendor/ the
numpy-only formats of pipeline/formats/ (the add-on's one source of every format, copied at
build time, never committed twice) and engine.json, which records this Python as the default
fitting engine.
"""
from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = "blender_manifest.toml"
IGNORED = shutil.ignore_patterns("__pycache__", "*.pyc", "vendor")


class AddonBuildError(ValueError):
    """The extension cannot be built (one-line message)."""


def blender_ext_tool() -> Path:
    """blender_ext.py inside the installed bpy wheel."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise AddonBuildError("the bpy module is not installed (bash tools/setup.sh installs it)")
    found = sorted(Path(spec.submodule_search_locations[0]).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise AddonBuildError("blender_ext.py is not inside the installed bpy module")
    return found[-1]


def _run(arguments):
    result = subprocess.run([sys.executable, str(blender_ext_tool()), *arguments], capture_output=True, text=True)
    if result.returncode != 0:
        lines = (result.stdout + result.stderr).strip().splitlines()
        raise AddonBuildError(f"blender_ext.py {arguments[0]}: {lines[-1] if lines else result.returncode}")
    return result.stdout


def stage(target, engine_python=None) -> Path:
    """Lay out the extension's source in `target`: the add-on, the manifest, the vendored formats."""
    target = Path(target)
    shutil.copytree(ROOT / "harp_addon", target, ignore=IGNORED, dirs_exist_ok=True)
    shutil.copy2(ROOT / MANIFEST, target / MANIFEST)
    vendor = target / "vendor"
    shutil.copytree(ROOT / "pipeline" / "formats", vendor / "formats", ignore=IGNORED)
    (vendor / "__init__.py").write_text('"""Copied from the project at build time (harp addon build)."""\n')
    (vendor / "engine.json").write_text(json.dumps({"python": str(engine_python or sys.executable)}) + "\n")
    return target


def build_addon(out, engine_python=None) -> Path:
    """Build and validate the extension zip into the folder `out`; returns its path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as temporary:
        source = stage(Path(temporary) / "harp_avatar", engine_python)
        _run(["build", "--source-dir", str(source), "--output-dir", str(out)])
    built = sorted(out.glob("harp_avatar-*.zip"), key=lambda path: path.stat().st_mtime)
    if not built:
        raise AddonBuildError(f"blender_ext.py build wrote no zip into {out}")
    _run(["validate", str(built[-1])])
    return built[-1]
