#!/usr/bin/env bash
# GPU run of the kinematics benchmark, on the device machine (see docs/benchmarks.md).
# Carry .whl (from ../shared/device/carry-wheels.sh); results land in $OUT.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false MUJOCO_GL=egl PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import jax; print('jax', jax.__version__, jax.devices())"
python3 -m mecanum_jax.bench kinematics \
  --sizes 1000 10000 100000 1000000 10000000 67108864 100000000 134217728 \
  --repeats 7 --json-out "${OUT:-/tmp}/gpu_kinematics.json" | tee "${OUT:-/tmp}/gpu_kinematics.txt"
