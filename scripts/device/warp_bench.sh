#!/usr/bin/env bash
# MJX's JAX and Warp implementations side by side on the GPU machine, after
# scripts/device/warp-parts.sh and its calls have rebuilt warp under /tmp/site.
#   bash scripts/device/warp_bench.sh physics   # physics steps/s and the validation table
#   bash scripts/device/warp_bench.sh train     # PPO env steps/s, then a 3-minute warp run
set -uo pipefail
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
quiet() { grep -v -E '^(Warp |Module |   )' ; }
case "${1:-physics}" in
  physics)
    python3 -m mecanum_jax.bench physics --fidelities fast --impls jax warp \
      --sizes 16384 65536 131072 --json-out "$O/physics_impls.json" 2>&1 | quiet | tail -12
    python3 -m mecanum_jax.validation --impl warp --out "$O/physics_validation_warp.md" 2>&1 | quiet | tail -40
    ;;
  train)
    python3 -m train.bench --config gpu --epochs 3 --json-out "$O/train_impls.json" \
      --variant "jax --env.physics-impl jax" --variant "warp --env.physics-impl warp" 2>&1 | quiet | tail -12
    timeout 300 python3 -m train.cli --config gpu --env.physics-impl warp --max-minutes 3 \
      --run-dir /tmp/warp_run 2>&1 | quiet | tail -30
    cp /tmp/warp_run/metrics.jsonl "$O/warp_run_metrics.jsonl"
    ;;
esac
