#!/usr/bin/env bash
# Train the shipped policy on one GPU and package it as models/<robot>/ (device machine).
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/ship_policy.sh [training minutes, default 8] [mecanum-train flags...]
# Returns under $OUT: model.tgz (the model directory), metrics.jsonl, summary.json, log.txt.
# Then: tar xzf model.tgz -C models/ and evaluate it with scripts/device/eval_policy.sh.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MIN="${1:-8}"; shift || true
COMMIT="${COMMIT:-$(git rev-parse --short HEAD 2>/dev/null || echo unknown)}"
DEVICE=$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1)
{
echo "device: $DEVICE; commit $COMMIT; $(date -u +%Y-%m-%dT%H:%M:%SZ)"
python3 -m train.cli --config gpu --run-dir /tmp/gpu --max-minutes "$MIN" \
  --run.max-checkpoints 1 --run.checkpoint-every 1000 "$@" 2>&1 | tail -22
python3 - "$MIN" "$COMMIT" "$DEVICE" "$*" <<'PY'
import json, sys
from train.evaluate import export_main
minutes, commit, device, extra = sys.argv[1:5]
s = json.load(open("/tmp/gpu/summary.json"))
command = f"mecanum-train --config gpu --max-minutes {minutes} {extra}".strip()
prov = [f"command={command}", f"commit={commit}", f"device={device}",
        f"session_wall_s={s['session_s']:.0f}", "script=scripts/device/ship_policy.sh"]
argv = ["/tmp/gpu", "/tmp/model/o_rectangle", "--model", "--provenance", *prov]
raise SystemExit(export_main(argv))
PY
} 2>&1 | tee "$O/log.txt"
tar czf "$O/model.tgz" -C /tmp/model o_rectangle
cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/"
ls -la "$O"
