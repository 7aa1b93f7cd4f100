#!/usr/bin/env bash
# Multi-GPU check (nvidia-h200-x2): the pmap path on 2 GPUs against 1 GPU, same process.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
nvidia-smi --query-gpu=name --format=csv,noheader
python3 -m train.bench --config gpu --epochs 3 --json-out "$O/gpu2_train_bench.json" \
  --variant 1gpu=run.max_devices=1 \
  --variant 2gpu=run.max_devices=0 \
  --variant 2gpu_64k=ppo.num_envs=65536,ppo.batch_size=8192 \
  2>&1 | grep -v -i warp | grep -v '^\s*"' | tail -12
