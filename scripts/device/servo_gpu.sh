#!/usr/bin/env bash
# Issue 4's servo fix on the device machine: the fast model's throughput with the chord
# servo against MJX's own (side by side, one process), then the GPU training config with
# the fixed physics, then `mecanum-eval` of that run against the baseline.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/servo_gpu.sh [training minutes]
# Returns under $OUT: physics_servos.json, metrics.jsonl, summary.json, report.json,
# plots.tgz, log.txt.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MIN="${1:-4}"
{
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
echo "== physics: chord servo vs MJX's servo"
python3 -m mecanum_jax.bench physics --fidelities fast --servos chord mjx \
  --sizes 16384 65536 131072 --json-out "$O/physics_servos.json" 2>&1 | grep -v -i warp | tail -12
echo "== training, gpu config, $MIN min"
python3 -m train.cli --config gpu --run-dir /tmp/gpu --max-minutes "$MIN" \
  --run.max-checkpoints 1 --run.checkpoint-every 1000 2>&1 | grep -v -i warp | tail -22
echo "== trained policy vs baseline, all default scenarios"
/usr/bin/time -f "wall %e s" python3 -m train.evaluate /tmp/gpu --out /tmp/eval 2>&1 | grep -v -i warp
} 2>&1 | tee "$O/log.txt"
cp /tmp/eval/report.json "$O/report.json" || true
(cd /tmp/eval && tar czf "$O/plots.tgz" ./*.png) || true
cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/" || true
