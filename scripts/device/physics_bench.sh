#!/usr/bin/env bash
# GPU run of the physics benchmark and of the kinematics forward map (device machine).
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL  # no rendering here; EGL libs are not carried
O="${OUT:-/tmp}"
python3 -m mecanum_jax.bench kinematics --ops forward inverse --sizes 1000 1000000 67108864 100000000 \
  --json-out "$O/gpu_kinematics_forward.json" | tail -12
python3 -m mecanum_jax.bench physics --fidelities fast --sizes 1 1024 16384 65536 131072 \
  --json-out "$O/gpu_physics_fast.json"
python3 -m mecanum_jax.bench physics --fidelities reference --sizes 1024 16384 \
  --json-out "$O/gpu_physics_reference.json"
python3 -m mecanum_jax.bench physics --fidelities fast --sizes 65536 --ls-iterations 2 \
  --json-out "$O/gpu_physics_fast_ls2.json"
