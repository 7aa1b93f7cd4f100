#!/usr/bin/env bash
# The evaluation table of docs/evaluation.md (device machine): a model directory against
# the three reference controllers on every default scenario and on 1024 held-out episodes
# of the training distribution (configs/eval/randomized.toml), all on the same episodes.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/eval_policy.sh [model directory, default models/o_rectangle]
# Returns under $OUT: report_default.json, report_randomized.json, plots.tgz, log.txt.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MODEL="${1:-models/o_rectangle}"
{
nvidia-smi --query-gpu=name --format=csv,noheader; date -u +%Y-%m-%dT%H:%M:%SZ
for set in default randomized; do
  echo "== $MODEL, scenarios: $set"
  /usr/bin/time -f "wall %e s" python3 -m train.evaluate "$MODEL" --scenarios "$set" \
    --out "/tmp/eval-$set" 2>&1
done
} 2>&1 | tee "$O/log.txt"
for set in default randomized; do cp "/tmp/eval-$set/report.json" "$O/report_$set.json"; done
(cd /tmp && tar czf "$O/plots.tgz" eval-default/*.png eval-randomized/*.png)
ls -la "$O"
