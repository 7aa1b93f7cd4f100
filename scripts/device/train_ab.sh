#!/usr/bin/env bash
# Training variants side by side on ONE GPU (device machine, carry .whl): every variant
# trains concurrently for the same wall time (so they share the GPU alike), then each is
# evaluated by mecanum-eval on the default scenarios, paired with the baseline.
#   bash scripts/device/train_ab.sh MINUTES 'name|mecanum-train flags' ['name|flags' ...]
# e.g. bash scripts/device/train_ab.sh 5 'a|' 'b|--ppo.learning-rate 3e-4'
# Writes $OUT/<name>_metrics.jsonl, $OUT/<name>_report.json and $OUT/log.txt.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache_$(date +%s)  # fresh: the training compiles cold, its evaluation reuses
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MIN="$1"; shift
{
nvidia-smi --query-gpu=name --format=csv,noheader
names=()
for spec in "$@"; do
  name="${spec%%|*}"; flags="${spec#*|}"; names+=("$name")
  echo "== variant $name: $flags"
  # shellcheck disable=SC2086
  python3 -m train.cli --config gpu --run-dir "/tmp/run_$name" --max-minutes "$MIN" \
    --run.max-checkpoints 1 --run.checkpoint-every 1000 $flags > "/tmp/train_$name.log" 2>&1 &
done
wait
for name in "${names[@]}"; do
  echo "== $name"; grep -v -i warp "/tmp/train_$name.log" | tail -6
  python3 -m train.evaluate "/tmp/run_$name" --no-plots --out "/tmp/eval_$name" > "/tmp/eval_$name.log" 2>&1 &
done
wait
for name in "${names[@]}"; do
  echo "== eval $name"; grep -v -i warp "/tmp/eval_$name.log" | tail -14
  cp "/tmp/eval_$name/report.json" "$O/${name}_report.json" || true
  cp "/tmp/run_$name/metrics.jsonl" "$O/${name}_metrics.jsonl" || true
  python3 - "/tmp/run_$name/metrics.jsonl" <<'PY'
import json, sys
for line in open(sys.argv[1]):
    r = json.loads(line); e = r.get("eval", {}); b = r.get("baseline")
    if e:
        ev, nom = e["randomized"], e["nominal"]
        print(f"epoch {r['epoch']:3d} steps {r['env_steps']:>11,} wall {r['walltime']:6.1f}s"
              f" | rand v {ev['rmse_lin']:.3f}/{b['randomized']['rmse_lin']:.3f}"
              f" w {ev['rmse_wz']:.3f}/{b['randomized']['rmse_wz']:.3f}"
              f" | nom v {nom['rmse_lin']:.3f}/{b['nominal']['rmse_lin']:.3f}"
              f" w {nom['rmse_wz']:.3f}/{b['nominal']['rmse_wz']:.3f}")
PY
done
} 2>&1 | tee "$O/log.txt"
