#!/usr/bin/env bash
# Benchmark and check on a CUDA machine: the `fast` fit of one clip on the GPU (its wall time,
# report figures and the printed estimate), then the test suite's torch tests with CUDA as the
# default device (pipeline/fit/problem.default_device picks cuda when present).
#
#     bash benchmarks/cuda_check.sh SEQ OUT [PYTHON]
#
# SEQ: a sequence folder with init.npz (docs/fit.md); OUT: where the avatar, fit.log and
# tests.log go. PYTHON: an interpreter with torch (CUDA), numpy, scipy, opencv, tqdm, matplotlib
# and pytest (+ pytest-xdist, pytest-timeout); default python3. Tests that need bpy, mediapipe or
# pyfqmr fail or error where those are not installed: read tests.log's summary with that in mind.
# The figures in docs/performance.md ("On a GPU") come from this script.
set -u
sequence=${1:?usage: cuda_check.sh SEQ OUT [PYTHON]}
out=${2:?usage: cuda_check.sh SEQ OUT [PYTHON]}
python=${3:-python3}
export PYTHONUNBUFFERED=1
mkdir -p "$out"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
"$python" -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__)"

start=$(date +%s)
timeout 600 "$python" -m pipeline.cli fit "$sequence" --out "$out/avatar" --preset fast --device cuda \
    --progress none --curve > "$out/fit.log" 2>&1
echo "fit exit $? wall $(( $(date +%s) - start )) s (process start and CUDA's set-up included)" | tee -a "$out/fit.log"
tail -n 3 "$out/fit.log"

# one process per GPU share: 14 workers on one GPU made a few 200-step fixtures pass 120 s
OMP_NUM_THREADS=1 timeout 900 "$python" -m pytest -q -m "not blender" -n "${WORKERS:-6}" \
    -p no:cacheprovider --timeout 300 -rfE tests > "$out/tests.log" 2>&1
echo "tests exit $?" | tee -a "$out/tests.log"
tail -n 25 "$out/tests.log"
