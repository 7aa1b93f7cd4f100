#!/usr/bin/env bash
# What limits the fast fidelity's physics throughput (device machine, carry .whl):
# MJX options side by side in one process (experiments/physics_speed_sweep.py), then the
# stock benchmark at the sizes around the best batch.
#   bash scripts/device/physics_sweep.sh
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 experiments/physics_speed_sweep.py --sizes 65536 \
  --variants default strip newton3 cg6 sparse elliptic nocontact noconstraint \
  --json-out "$O/physics_sweep_65536.json" 2>&1 | grep -v -i warp
python3 experiments/physics_speed_sweep.py --sizes 32768 131072 262144 --variants default strip \
  --json-out "$O/physics_sweep_sizes.json" 2>&1 | grep -v -i warp
