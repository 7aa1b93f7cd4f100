#!/usr/bin/env bash
# GPU training figures (device machine): the full task with configs/train/gpu.toml.
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/train_gpu.sh [minutes] [extra mecanum-train flags...]
# Writes run directories under $OUT (metrics.jsonl, summary.json, checkpoints).
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp}"
MIN="${1:-4}"; shift || true
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 -c "import jax, flax, optax, orbax.checkpoint, brax, mujoco; print('jax', jax.__version__, jax.devices())"
python3 -m train.cli --config gpu --run-dir "$O/gpu" --max-minutes "$MIN" "$@" 2>&1 | grep -v -i warp | tail -25
python3 - "$O/gpu" <<'PY'
import json, sys
for line in open(sys.argv[1] + "/metrics.jsonl"):
    r = json.loads(line); t = r["train"]; e = r.get("eval", {})
    ev = e.get("randomized"); nom = e.get("nominal"); b = r.get("baseline")
    s = f"epoch {r['epoch']:3d} steps {r['env_steps']:>11,} wall {r['walltime']:6.1f}s sps {t.get('steps_per_s', 0):>10,.0f} reward {t['reward']:.3f}"
    if ev:
        s += f" | rand v {ev['rmse_lin']:.3f}/{b['randomized']['rmse_lin']:.3f} w {ev['rmse_wz']:.3f}/{b['randomized']['rmse_wz']:.3f}"
        s += f" | nom v {nom['rmse_lin']:.3f}/{b['nominal']['rmse_lin']:.3f} w {nom['rmse_wz']:.3f}/{b['nominal']['rmse_wz']:.3f}"
    print(s)
PY
