#!/usr/bin/env bash
# GPU training-throughput benchmark (device machine), variants side by side in one process.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
python3 -m train.bench --config gpu --epochs 3 --json-out "$O/gpu_train_bench.json" \
  --variant base \
  --variant "tf32 --run.matmul-precision default" \
  --variant "envs16k --ppo.num-envs 16384 --ppo.batch-size 2048" \
  --variant "envs32k --ppo.num-envs 32768 --ppo.batch-size 4096" \
  --variant "seeds4x4k --run.seeds 0 1 2 3 --ppo.num-envs 4096 --ppo.batch-size 512" \
  "$@" 2>&1 | grep -v -i warp | grep -v '^\s*"' | tail -20
