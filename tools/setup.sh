#!/usr/bin/env bash
# Create ./.venv and install the project into it (CPU build of torch).
#   bash tools/setup.sh          the `harp` command and its dependencies
#   bash tools/setup.sh --test   also pytest and bpy (Blender as a module, ~800 MB)
set -euo pipefail
cd "$(dirname "$0")/.."
python=${PYTHON:-python3.11}
command -v "$python" >/dev/null 2>&1 || python=python3
if [ ! -x .venv/bin/python ]; then
    "$python" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
# torch first and exactly pinned: this takes the CPU build instead of a multi-GB CUDA one
.venv/bin/python -m pip install --quiet torch==2.13.0
extras=""
if [ "${1:-}" = "--test" ]; then
    extras="[test,blender]"
fi
.venv/bin/python -m pip install --quiet -e ".${extras}"
# one working OpenCV: drop any non-headless build another package may have pulled in
if .venv/bin/python -m pip show opencv-python >/dev/null 2>&1; then
    .venv/bin/python -m pip uninstall --quiet -y opencv-python
    .venv/bin/python -m pip install --quiet --force-reinstall --no-deps opencv-contrib-python-headless==4.11.0.86
fi
.venv/bin/python -c "import cv2, torch, numpy; print('environment ready: torch', torch.__version__, 'numpy', numpy.__version__, 'opencv', cv2.__version__)"
