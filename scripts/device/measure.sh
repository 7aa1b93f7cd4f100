#!/usr/bin/env bash
# run.sh's measurement tasks (multi-gpu, profile, coldstart, scaling; run.sh's header
# describes them): sourced by run.sh, whose helpers (train, quiet, $O) they use.
multi_gpu() {  # EPOCHS [VARIANT...] [-- FLAGS...]: one process per variant, so a crash loses only that one
  local epochs=$1; shift
  local names=() extra=""
  while [ $# -gt 0 ] && [ "$1" != -- ]; do names+=("$1"); shift; done
  [ "${1:-}" = -- ] && { shift; extra="$*"; }
  declare -A spec=(
    [sh1gpu]="--run.parallel sharded --run.max-devices 1"
    [sh2gpu]="--run.parallel sharded --run.max-devices 2"
    [sh2gpu_64k]="--run.parallel sharded --run.max-devices 2 --ppo.num-envs 65536 --ppo.batch-size 8192"
    [mp2gpu]="--run.parallel sharded"
    [pmap2gpu]="--run.parallel pmap"  # Brax's path: crashes XLA's compiler with MJX on GPUs
    [sh1gpu_64k]="--run.parallel sharded --run.max-devices 1 --ppo.num-envs 65536 --ppo.batch-size 8192"
    [split2gpu]="--run.parallel split --run.max-devices 2"  # rollouts per GPU (train/learner/split_epoch.py)
    [split2gpu_64k]="--run.parallel split --run.max-devices 2 --ppo.num-envs 65536 --ppo.batch-size 8192"
  )
  local v i
  [ ${#names[@]} -gt 0 ] || names=(sh1gpu sh2gpu sh2gpu_64k mp2gpu)
  for v in "${names[@]}"; do
    if [ "$v" = mp2gpu ]; then  # two processes, one GPU each, joined through jax.distributed
      for i in 0 1; do
        JAX_COORDINATOR_ADDRESS=localhost:12355 JAX_NUM_PROCESSES=2 JAX_PROCESS_ID=$i \
          JAX_LOCAL_DEVICE_IDS=$i python3 -m train.tools.bench --config gpu --epochs "$epochs" \
          --variant "$v ${spec[$v]} $extra" --json-out "$O/gpu2_$v.json" --distributed \
          > "$O/${v}_p$i.log" 2>&1 &
      done
      wait
      grep -hE "│ $v|Error" "$O/${v}"_p*.log | head -4
    else
      # shellcheck disable=SC2086
      python3 -m train.tools.bench --config gpu --epochs "$epochs" --variant "$v ${spec[$v]} $extra" \
        --json-out "$O/gpu2_$v.json" > "$O/$v.log" 2>&1
      grep -hE "│ $v|Error" "$O/$v.log" | head -3
    fi
  done
}

profile() {  # [--trace] [flags]: the epoch's parts (train/tools/profile.py)
  local trace=()
  if [ "${1:-}" = --trace ]; then shift; rm -rf /tmp/profile-trace; trace=(--trace-dir /tmp/profile-trace); fi
  python3 -m train.tools.profile --config gpu --json-out "$O/profile.json" ${trace[@]+"${trace[@]}"} "$@" 2>&1 | quiet | tail -45
  [ ${#trace[@]} -gt 0 ] || return 0
  tar czf /tmp/profile_trace.tgz -C /tmp profile-trace
  local size; size=$(stat -c %s /tmp/profile_trace.tgz)
  if [ "$size" -gt $((60 * 1024 * 1024)) ]; then  # $OUT takes 64 MiB in files of 16 MiB
    echo "trace: $size bytes, too large to send back; try --run.epoch-iterations 1"
  else
    mv /tmp/profile_trace.tgz "$O/" && send_back "$O/profile_trace.tgz"
  fi
}

coldstart() {  # [flags]: an empty compilation cache, then the same start with it warm
  # (COLDSTART_PASSES, default "cold warm"; a pass "nobaseN" is a warm start with the stored
  # baseline's figures removed first, train/loop/stored_baseline.py; warmN another warm one)
  local pass tree=${COLDSTART_TREE:-$PWD} mod=train.tools.coldstart
  [ -f "$tree/train/coldstart.py" ] && mod=train.coldstart  # a tree from before train/ had rooms
  rm -rf /tmp/coldstart-cache
  for pass in ${COLDSTART_PASSES:-cold warm}; do
    [[ $pass == nobase* ]] && rm -f /tmp/coldstart-cache/mecanum-programs/*.baseline
    echo "== $pass compilation cache ${COLDSTART_TAG:-} (sources: $tree)"
    (cd "$tree" && PYTHONPATH=/tmp/site:$tree python3 -m "$mod" --config gpu \
      --compilation-cache /tmp/coldstart-cache \
      --json-out "$O/coldstart_${COLDSTART_TAG:+${COLDSTART_TAG}_}$pass.json" "$@") 2>&1 \
      | quiet | tail -42
  done
}

scaling() {  # [N...] [flags]: one train.tools.bench process per robot count
  local sizes=() n
  while [ $# -gt 0 ] && [[ $1 =~ ^[0-9]+$ ]]; do sizes+=("$1"); shift; done
  [ ${#sizes[@]} -gt 0 ] || sizes=(1024 4096 16384 32768 65536)
  rm -rf /tmp/scaling; mkdir -p /tmp/scaling
  for n in "${sizes[@]}"; do
    python3 -m train.tools.bench --config gpu --epochs 2 --json-out "/tmp/scaling/e$n.json" \
      --variant "e$n --ppo.num-envs $n --ppo.batch-size $((n / 8)) $*" > "/tmp/scaling/e$n.log" 2>&1
    grep -hiE "│ e$n |error" "/tmp/scaling/e$n.log" | head -3
  done
  python3 scripts/plot_scaling.py /tmp/scaling/e*.json --out "$O/scaling.png" --json-out "$O/scaling.json"
}
