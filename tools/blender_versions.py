"""The add-on's headless tests under each Blender the extension declares: every version's bpy
wheel in a virtual environment of its own (.venvs/bpy-VERSION), against one avatar fitted
beforehand with the project's .venv (tests/blender_fixture.py). They install the built
extension and bind and export through its buttons, check the depsgraph's exactness against the
fit, the textures that travel with the .blend, and Blender's view of the template mesh.

    .venv/bin/python tools/blender_versions.py              every version in VERSIONS
    .venv/bin/python tools/blender_versions.py 4.5.15       some
    .venv/bin/python tools/blender_versions.py lowest       blender_version_min of the manifest (CI)

An environment holds bpy, numpy and pytest only, no torch, like Blender itself: Python 3.11 up
to bpy 5.0, 3.13 from bpy 5.1 (it must be on the PATH as python3.11 / python3.13). numpy and
pytest are pinned as in pyproject.toml, except that bpy 5.1 and newer take the numpy they ask
for (they are built against numpy 2). The project is found through PYTHONPATH. Exit status 1 if
any version fails.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VERSIONS = ("4.2.0", "4.5.15", "5.0.1", "5.2.3")    # the lowest declared, the LTS releases, the project's, the newest
TESTS = ("tests/test_blender_addon.py", "tests/test_blender_textures.py", "tests/test_blender_mesh.py")
ENVIRONMENTS = ROOT / ".venvs"
READY = "harp-ready"     # written into an environment once everything is installed
# bpy 4.2 and 4.5, as modules, crash in the interpreter's teardown once their glTF add-on has run
# (a segmentation fault in 4.2.0 and 4.2.23, an abort in 4.5.15; not 5.0 or 5.2), after the tests
# have finished: pytest's status is handed back with os._exit, before that teardown
PYTEST = "import os, sys, pytest; status = pytest.main(sys.argv[1:]); sys.stdout.flush(); os._exit(int(status))"


def lowest_declared():
    """The extension's blender_version_min (blender_manifest.toml)."""
    return tomllib.loads((ROOT / "blender_manifest.toml").read_text())["blender_version_min"]


def python_for(version):
    """The Python that bpy `version` is built for."""
    major, minor = (int(part) for part in version.split(".")[:2])
    name = "python3.11" if (major, minor) < (5, 1) else "python3.13"
    found = shutil.which(name)
    if found is None:
        sys.exit(f"bpy {version} needs {name}, which is not on the PATH")
    return found


def pins(version):
    """pip requirements beside bpy: numpy (below bpy 5.1) and pytest, as pyproject.toml pins them."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pinned = {re.split(r"[=<>]", requirement)[0]: requirement.split("#")[0].strip()
              for requirement in project["dependencies"] + project["optional-dependencies"]["test"]}
    major, minor = (int(part) for part in version.split(".")[:2])
    return ([pinned["numpy"]] if (major, minor) < (5, 1) else []) + [pinned["pytest"]]


def environment(version) -> Path:
    """The environment's Python, made and installed on first use."""
    folder = ENVIRONMENTS / f"bpy-{version}"
    python = folder / "bin" / "python"
    if (folder / READY).is_file():
        return python
    shutil.rmtree(folder, ignore_errors=True)
    print(f"bpy {version}: making {folder.relative_to(ROOT)}", flush=True)
    subprocess.run([python_for(version), "-m", "venv", str(folder)], check=True)
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", f"bpy=={version}", *pins(version)], check=True)
    (folder / READY).write_text(version + "\n")
    return python


def run_tests(version, fixture) -> tuple[bool, str]:
    """(passed, pytest's closing line) of the tests in bpy `version`'s environment."""
    python = environment(version)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HARP_BLENDER_FIXTURE": str(fixture), "OMP_NUM_THREADS": "1"}
    print(f"bpy {version}: {' '.join(TESTS)}", flush=True)
    process = subprocess.Popen([str(python), "-c", PYTEST, "-q", "-p", "no:cacheprovider", *TESTS], cwd=ROOT,
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    last = ""
    for line in process.stdout:
        print(line, end="", flush=True)
        last = line.strip() or last
    return process.wait() == 0, last


def main(versions):
    sys.path.insert(0, str(ROOT / "tests"))
    from blender_fixture import SIDES, prepare

    results = {}
    with tempfile.TemporaryDirectory(prefix="harp-blender-") as fixture:
        print("fitting the avatar the tests bind (tests/blender_fixture.py)", flush=True)
        for side in SIDES:
            prepare(fixture, side)
        for version in versions:
            results[version] = run_tests(version, fixture)
    print("\nBlender versions:")
    for version, (passed, line) in results.items():
        print(f"  bpy {version}: {'ok' if passed else 'FAILED'} ({line.strip('= ')})")
    return 0 if all(passed for passed, _ in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main([lowest_declared() if name == "lowest" else name for name in sys.argv[1:] or VERSIONS]))
