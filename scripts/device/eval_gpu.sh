#!/usr/bin/env bash
# Evaluation figures on the device machine: train the GPU config, then `mecanum-eval` the
# baseline alone and the trained checkpoint (all default scenarios, EGL video, export).
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh) and .gl
# (the EGL loader debs; see /work/.library/device/README.md).
#   bash scripts/device/eval_gpu.sh [training minutes]
# Returns under $OUT: report.json, report_baseline.json, plots.tgz, the video (gif),
# policy.npz, metrics.jsonl, summary.json, log.txt.
set -euo pipefail
if ls .gl/*.deb >/dev/null 2>&1; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 MUJOCO_GL=egl
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
MIN="${1:-4}"
{
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 -m train.cli --config gpu --run-dir /tmp/gpu --max-minutes "$MIN" \
  --run.max-checkpoints 1 --run.checkpoint-every 1000 2>&1 | grep -v -i warp | tail -22
echo "== baseline alone, all default scenarios (includes compilation)"
/usr/bin/time -f "wall %e s" python3 -m train.evaluate baseline --config gpu --no-plots \
  --out /tmp/eval-baseline 2>&1 | grep -v -i warp
echo "== trained policy vs baseline, all default scenarios, video (EGL) and export"
/usr/bin/time -f "wall %e s" python3 -m train.evaluate /tmp/gpu --out /tmp/eval --video \
  --video-format gif --fps 10 --export 2>&1 | grep -v -i warp
echo "== the same again, compilation cache warm, no plots or video"
/usr/bin/time -f "wall %e s" python3 -m train.evaluate /tmp/gpu --out /tmp/eval2 --no-plots \
  2>&1 | grep -v -i warp | grep -v "│"
} 2>&1 | tee "$O/log.txt"
cp /tmp/eval/report.json "$O/report.json"
cp /tmp/eval-baseline/report.json "$O/report_baseline.json"
(cd /tmp/eval && tar czf "$O/plots.tgz" ./*.png)
cp /tmp/eval/video_*.gif "$O/" || true
cp /tmp/eval/policy.npz "$O/"
cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/"
ls -la "$O"
