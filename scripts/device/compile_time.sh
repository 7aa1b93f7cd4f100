#!/usr/bin/env bash
# Where the first epoch's time goes (device machine, carry .whl): JAX's compile log
# (tracing, lowering, XLA compilation) for the gpu config, once as is and once with XLA's
# GPU autotuning off, each in a fresh process (no persistent cache).
#   bash scripts/device/compile_time.sh
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists"
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 JAX_LOG_COMPILES=1; unset MUJOCO_GL
O="${OUT:-/tmp}"
for fl in "" "--xla_gpu_autotune_level=0"; do
  echo "== XLA_FLAGS=$fl"
  n="a$((${#fl} > 0))"
  XLA_FLAGS="$fl" python3 -m train.bench --config gpu --epochs 2 --variant "$n" \
    --json-out "$O/compile_${n#a}.json" 2>&1 | grep -v -i warp \
    | grep -E "│ a|Finished .* in [0-9.]+ sec" \
    | awk '{ if ($0 ~ /│/) print; else { for (i = 1; i <= NF; i++) if ($i == "in") t = $(i + 1); if (t + 0 > 0.5) print } }' \
    | cut -c1-220
done 2>&1 | tee "$O/log.txt"
