#!/usr/bin/env bash
# What 12 Newton iterations (instead of 4 or 8) cost and buy, side by side (device machine, carry
# .whl): physics steps/s of the fast model, PPO training steps/s, and how many randomized
# baseline episodes tip over (experiments/runaway_episodes.py) at 4, 8 and 12 iterations.
# Session 6 ran it with 8 as the default (its log: docs/bench/session6_2026-11-22/).
#   bash scripts/device/iterations_bench.sh
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
{
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
date -u
echo "== physics steps/s, batch 65536 (strip = the default model, 12 iterations)"
python3 experiments/physics_speed_sweep.py --sizes 65536 --variants strip newton8 newton4 \
  --json-out "$O/iterations_physics.json" 2>&1 | grep -v -i warp
echo "== PPO training steps/s (gpu config)"
python3 -m train.bench --config gpu --epochs 2 --json-out "$O/iterations_train.json" \
  --variant it12 --variant "it8 --env.solver-iterations 8" --variant "it4 --env.solver-iterations 4" \
  2>&1 | grep -v -i warp | grep -v '^\s*"' | tail -12
echo "== tipped robots, 4096 randomized baseline episodes x 10 s"
for it in 12 8 4; do
  python3 experiments/runaway_episodes.py --episodes 4096 --chunk 4096 --worst 5 \
    --opt iterations=$it 2>&1 | grep -v -i warp
done
} 2>&1 | tee "$O/log.txt"
