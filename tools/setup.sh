#!/usr/bin/env bash
# Create ./.venv and install the project into it (CPU build of torch).
#   bash tools/setup.sh          the `harp` command and its dependencies (bpy, Blender as a
#                                module, ~800 MB, renders the demo's synthetic clip)
#   bash tools/setup.sh --test   also pytest (and Ray, whose executor the tests run)
#   bash tools/setup.sh --cluster  also Ray, for `harp batch` / `harp study --executor ray`
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
wanted=()
for flag in "$@"; do
    case "$flag" in
        --test) wanted+=(test) ;;
        --cluster) wanted+=(cluster) ;;
        *) echo "setup.sh: unknown option $flag (use --test, --cluster)" >&2; exit 2 ;;
    esac
done
extras=""
if [ ${#wanted[@]} -gt 0 ]; then
    extras="[$(IFS=,; echo "${wanted[*]}")]"
fi
.venv/bin/python -m pip install --quiet -e ".${extras}"
# one working OpenCV: mediapipe pulls in the non-headless opencv-contrib-python (and other
# packages may pull opencv-python); both share the cv2 module with the headless build, so drop
# them and reinstall the headless build over whatever they left behind
removed=""
for package in opencv-python opencv-contrib-python; do
    if .venv/bin/python -m pip show "$package" >/dev/null 2>&1; then
        .venv/bin/python -m pip uninstall --quiet -y "$package"
        removed=yes
    fi
done
if [ -n "$removed" ]; then
    .venv/bin/python -m pip install --quiet --force-reinstall --no-deps opencv-contrib-python-headless==4.11.0.86
fi
.venv/bin/python -c "import cv2, torch, numpy, mediapipe; from mediapipe.python.solutions import hands; hands.Hands(static_image_mode=True).process(numpy.zeros((64, 64, 3), numpy.uint8)); print('environment ready: torch', torch.__version__, 'numpy', numpy.__version__, 'opencv', cv2.__version__, 'mediapipe', mediapipe.__version__)"
