#!/usr/bin/env bash
# Multi-GPU training throughput (nvidia-h200-x2), one process per variant (a crash loses only
# that variant), cold compilation cache:
#   sh1gpu      run.parallel = "sharded" on 1 GPU (the reference, same machine, same run)
#   sh2gpu      sharded over both GPUs, same 32768 robots
#   sh2gpu_64k  sharded over both GPUs, 65536 robots
#   mp2gpu      two processes, one GPU each, joined through jax.distributed (--distributed)
#   pmap2gpu    Brax's pmap path on both GPUs (crashed XLA's compiler in sessions 3-8)
# NARROW=1 first reruns the narrow compiler-crash cases (scripts/device/diag_2gpu_narrow.py).
# Carry .whl (../shared/device/carry-wheels.sh + scripts/device/extra-wheels.sh).
#   bash scripts/device/train_bench_2gpu.sh [EPOCHS [VARIANT ...]]
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"; EPOCHS="${1:-2}"; shift || true
WANT="${*:-sh1gpu sh2gpu sh2gpu_64k mp2gpu pmap2gpu}"
declare -A SPEC=(
  [sh1gpu]="--run.parallel sharded --run.max-devices 1"
  [sh2gpu]="--run.parallel sharded"
  [sh2gpu_64k]="--run.parallel sharded --ppo.num-envs 65536 --ppo.batch-size 8192"
  [mp2gpu]="--run.parallel sharded"
  [pmap2gpu]="--run.parallel pmap"
)
bench() {  # NAME [extra args]: one variant, its table row and any crash line
  local name=$1; shift
  python3 -X faulthandler -m train.bench --config gpu --epochs "$EPOCHS" \
    --variant "$name ${SPEC[$name]}" --json-out "$O/gpu2_$name.json" "$@"
}
{
nvidia-smi --query-gpu=name --format=csv,noheader
[ "${NARROW:-0}" = 1 ] && python3 scripts/device/diag_2gpu_narrow.py
for v in $WANT; do
  t=$(date +%s)
  if [ "$v" = mp2gpu ]; then
    for i in 0 1; do
      JAX_COORDINATOR_ADDRESS=localhost:12355 JAX_NUM_PROCESSES=2 JAX_PROCESS_ID=$i \
        JAX_LOCAL_DEVICE_IDS=$i bench "$v" --distributed > "$O/mp2gpu_p$i.log" 2>&1 &
    done
    wait
    grep -hE "│ $v|Fatal|Error" "$O"/mp2gpu_p*.log | head -4
  else
    bench "$v" > "$O/$v.log" 2>&1
    grep -hE "│ $v|Fatal|Error" "$O/$v.log" | head -3
  fi
  echo "$v: $(( $(date +%s) - t )) s"
done
} 2>&1 | tee "$O/log.txt"
