#!/usr/bin/env bash
# run.sh's comparison tasks (tune, agree, fidelity, reference-table; run.sh's header
# describes them): sourced by run.sh, whose helpers (evaluate, throttle, gpus, quiet, $O) they use.
tune() {  # MODEL...; TUNE_JOBS=N: N evaluations at once (they share the GPU; compiling is most of each)
  local i=0 k name model ngpu names=() models=() shipped roller
  rm -rf /tmp/tune-reports; mkdir -p /tmp/tune-reports; ngpu=$(gpus)
  shipped=(models/o_rectangle); [ "${TUNE_SHIPPED:-1}" = 0 ] && shipped=()
  for model in "${@:-/tmp/model/o_rectangle}" "${shipped[@]}"; do
    i=$((i + 1)); name=$(basename "$(dirname "$model")")_$i
    [ "$model" = models/o_rectangle ] && name=shipped
    names+=("$name"); models+=("$model")
    CUDA_VISIBLE_DEVICES=$((i % ngpu)) evaluate "$model" tuning "/tmp/tune-$name" --no-plots \
      > "/tmp/tune-$name.log" 2>&1 &
    throttle "${TUNE_JOBS:-$ngpu}"
  done
  if [ -n "${TUNE_PROBE:-}" ]; then  # the shipped weights played with env fields changed
    names+=(probe); i=$((i + 1)); rm -rf /tmp/tune-probe
    # shellcheck disable=SC2086  # TUNE_PROBE is a list of FIELD=VALUE words
    CUDA_VISIBLE_DEVICES=$((i % ngpu)) evaluate models/o_rectangle tuning /tmp/tune-probe \
      --no-plots --play $TUNE_PROBE > /tmp/tune-probe.log 2>&1 &
  fi
  wait
  for k in "${!models[@]}"; do  # one that ran out of GPU memory beside the others: alone
    name=${names[$k]}
    if [ -f "/tmp/tune-$name/report.json" ] || ! grep -q RESOURCE_EXHAUSTED "/tmp/tune-$name.log"
    then continue; fi
    echo "tune: $name ran out of GPU memory beside the others; again, alone"
    evaluate "${models[$k]}" tuning "/tmp/tune-$name" --no-plots > "/tmp/tune-$name.log" 2>&1
  done
  roller=()  # TUNE_ROLLER=0: the fast model's tuning episodes alone
  if [ "${TUNE_ROLLER:-1}" = 1 ]; then  # the dashes in the reference roller model, each
    for k in "${!models[@]}"; do
      name=${names[$k]}; [ "$name" = probe ] && continue
      [ -f "/tmp/tune-$name/report.json" ] || continue  # its fast evaluation failed: unranked
      CUDA_VISIBLE_DEVICES=$((k % ngpu)) evaluate "${models[$k]}" dashes "/tmp/roller-$name" \
        --no-plots --fidelity reference --physics-impl jax > "/tmp/roller-$name.log" 2>&1 &
      throttle "${TUNE_JOBS:-$ngpu}"
    done
    if [ -n "${TUNE_PROBE:-}" ] && [ -f /tmp/tune-probe/report.json ]; then
      rm -rf /tmp/roller-probe
      # shellcheck disable=SC2086
      evaluate models/o_rectangle dashes /tmp/roller-probe --no-plots --fidelity reference \
        --physics-impl jax --play $TUNE_PROBE > /tmp/roller-probe.log 2>&1 &
    fi
    wait; roller=(--roller)
  fi
  for name in "${names[@]}"; do
    echo "== $name on the tuning episodes"; quiet < "/tmp/tune-$name.log" | tail -34
    cp "/tmp/tune-$name/report.json" "/tmp/tune-reports/tune_$name.json" 2>/dev/null \
      || { echo "tune: $name has no report: its evaluation failed (log above); not ranked"
           continue; }
    [ ${#roller[@]} = 0 ] && continue
    echo "== $name on the dashes, reference roller model"
    quiet < "/tmp/roller-$name.log" | tail -12
    cp "/tmp/roller-$name/report.json" "/tmp/tune-reports/roller_$name.json" 2>/dev/null || {
      echo "tune: $name has no roller report: its evaluation failed (log above); not ranked"
      rm -f "/tmp/tune-reports/tune_$name.json"; }
  done  # one file back however many candidates ($OUT takes 8): $O/tuning.json
  [ ${#roller[@]} = 0 ] || roller+=(/tmp/tune-reports/roller_*.json)
  python3 scripts/pick_candidate.py /tmp/tune-reports/tune_*.json "${roller[@]}" \
    --bundle "$O/tuning.json"
}

agree() {  # MODEL [SET SCENARIO [N]]: a scenario on this GPU and on this machine's CPU (JAX physics)
  local set=${2:-default} only=${3:-nominal} n=()
  [ -z "${4:-}" ] || n=(--episodes "$4")
  echo "== GPU/CPU agreement of the steady-state figures: $1, $set $only, JAX physics"
  evaluate "$1" "$set" /tmp/agree-gpu --only "$only" ${n[@]+"${n[@]}"} --physics-impl jax \
    --no-plots 2>&1 | quiet | tail -3
  JAX_PLATFORMS=cpu evaluate "$1" "$set" /tmp/agree-cpu --only "$only" ${n[@]+"${n[@]}"} \
    --physics-impl jax --no-plots 2>&1 | quiet | tail -3
  cp /tmp/agree-gpu/report.json "$O/agree_gpu.json"; cp /tmp/agree-cpu/report.json "$O/agree_cpu.json"
  python3 scripts/eval_agreement.py /tmp/agree-gpu/report.json /tmp/agree-cpu/report.json
}

fidelity() {  # [MODEL] [EPISODES]: both physics models on the same nominal and randomized
  # episodes (docs/evaluation.md, "The shipped policy in both models")
  local model=${1:-models/o_rectangle} n=${2:-8} f
  for f in reference fast; do
    echo "== $model in the $f model, $n episodes"
    evaluate "$model" default "/tmp/fid-$f-nominal" --only nominal --episodes "$n" \
      --fidelity "$f" --physics-impl jax --no-plots 2>&1 | quiet | tail -16
    evaluate "$model" randomized "/tmp/fid-$f-randomized" --episodes "$n" \
      --fidelity "$f" --physics-impl jax --no-plots 2>&1 | quiet | tail -16
    cp "/tmp/fid-$f-nominal/report.json" "$O/fidelity_${f}_nominal.json"
    cp "/tmp/fid-$f-randomized/report.json" "$O/fidelity_${f}_randomized.json"
  done
}

reference_table() {  # MODEL...: the evaluation table in the reference roller model
  local model name i=0 refs set n names=()
  for model in "$@"; do
    i=$((i + 1)); name=$(basename "$(dirname "$model")")
    [ "$model" = models/o_rectangle ] && name=shipped
    names+=("$name")
    refs=(--references analytic); [ $i = 1 ] && refs=()
    for set in default randomized; do
      n=(); [ $set = randomized ] && n=(--episodes "${FID_RANDOMIZED:-256}")
      evaluate "$model" $set "/tmp/ref-$name-$set" ${n[@]+"${n[@]}"} ${refs[@]+"${refs[@]}"} \
        --fidelity reference --physics-impl jax --no-plots > "/tmp/ref-$name-$set.log" 2>&1 &
      throttle "${FID_JOBS:-2}"
    done
  done
  wait
  for name in "${names[@]}"; do
    for set in default randomized; do
      echo "== $name, $set, reference model"; quiet < "/tmp/ref-$name-$set.log" | tail -30
      cp "/tmp/ref-$name-$set/report.json" "$O/reference_${name}_$set.json" \
        || echo "reference-table: $name $set has no report: its evaluation failed (log above)"
    done
  done
  local only=${FID_AGREE:-nominal}
  echo "== the GPU side of the agreement check in the reference model: $1, default $only, 8 episodes"
  evaluate "$1" default /tmp/ref-agree-gpu --only "$only" --episodes 8 \
    --fidelity reference --physics-impl jax --no-plots 2>&1 | quiet | tail -3
  cp /tmp/ref-agree-gpu/report.json "$O/reference_agree_gpu.json"
}
