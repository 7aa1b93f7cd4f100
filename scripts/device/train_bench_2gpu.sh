#!/usr/bin/env bash
# Multi-GPU check (nvidia-h200-x2). First the narrow compiler-crash cases
# (scripts/device/diag_2gpu_narrow.py: pmap of any MJX step segfaults XLA on 2 GPUs with
# jax 0.11.2, sharded jit compiles), then training throughput, one process per variant (a
# crash loses only that variant): run.parallel = "sharded" on 1 and 2 GPUs, 2 GPUs with
# twice the robots, and the pmap path on 2 GPUs last (expected to crash).
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/train_bench_2gpu.sh [EPOCHS]
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"; EPOCHS="${1:-2}"
{
nvidia-smi --query-gpu=name --format=csv,noheader
python3 scripts/device/diag_2gpu_narrow.py
for v in "sh1gpu=run.parallel=sharded,run.max_devices=1" "sh2gpu=run.parallel=sharded" \
         "sh2gpu_64k=run.parallel=sharded,ppo.num_envs=65536,ppo.batch_size=8192" \
         "pmap2gpu=run.parallel=pmap"; do
  python3 -X faulthandler -m train.bench --config gpu --epochs "$EPOCHS" --variant "$v" \
    --json-out "$O/gpu2_${v%%=*}.json" 2>&1 | grep -E "│ (sh|pm)|Fatal|Error" | head -3
done
} 2>&1 | tee "$O/log.txt"
