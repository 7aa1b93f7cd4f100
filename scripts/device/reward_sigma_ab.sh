#!/usr/bin/env bash
# A/B on the device machine: the GPU config as is, against sigma_ang = 0.25 (the angular
# tracking kernel as tight as the linear one, as in MuJoCo Playground's joystick tasks),
# each trained for the same wall time, then both evaluated by mecanum-eval on the
# default scenarios (paired with the baseline). Carry .whl.
#   bash scripts/device/reward_sigma_ab.sh [minutes per run]
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MIN="${1:-3}"
{
nvidia-smi --query-gpu=name --format=csv,noheader
for v in a b; do
  extra=(); [ "$v" = b ] && extra=(--env.reward.sigma-ang 0.25)
  echo "== variant $v ${extra[*]:-}"
  if [ ! -f /tmp/run_$v/summary.json ]; then  # a warm machine may have it already
    python3 -m train.cli --config gpu --run-dir /tmp/run_$v --max-minutes "$MIN" \
      --run.max-checkpoints 1 --run.checkpoint-every 1000 "${extra[@]}" 2>&1 | grep -v -i warp | tail -9
  fi
  rm -rf /tmp/eval_$v
  python3 -m train.evaluate /tmp/run_$v --no-plots --out /tmp/eval_$v 2>&1 | grep -v -i warp | tail -22
  cp /tmp/eval_$v/report.json "$O/report_$v.json"; cp /tmp/run_$v/metrics.jsonl "$O/metrics_$v.jsonl"
done
} 2>&1 | tee "$O/log.txt"
