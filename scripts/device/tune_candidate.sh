#!/usr/bin/env bash
# Compare a candidate model with the shipped one on the tuning episodes
# (configs/eval/tuning.toml: the training distribution and the nominal robot on a seed no
# held-out evaluation uses). Run after ship_policy.sh, on the same warm machine.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/tune_candidate.sh [candidate, default /tmp/model/o_rectangle]
# Returns under $OUT: tune_candidate.json, tune_shipped.json, log.txt.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
CANDIDATE="${1:-/tmp/model/o_rectangle}"
{
for pair in "candidate:$CANDIDATE" "shipped:models/o_rectangle"; do
  name="${pair%%:*}"; model="${pair#*:}"
  echo "== $name ($model) on the tuning episodes"
  python3 -m train.evaluate "$model" --scenarios tuning --no-plots --out "/tmp/tune-$name" 2>&1 | tail -30
  cp "/tmp/tune-$name/report.json" "$O/tune_$name.json"
done
} 2>&1 | tee "$O/log.txt"
