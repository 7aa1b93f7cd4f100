#!/usr/bin/env bash
# The one runner for the GPU machine: set-up, then one task; everything lands in $OUT.
#
#   bash scripts/device/run.sh [--warp] TASK [ARGS...]
#
# Carry .whl (filled by ../shared/device/carry-wheels.sh, then scripts/device/extra-wheels.sh).
# --warp also rebuilds warp-lang under /tmp/site from the parts scripts/device/warp-parts.sh
# made (each part sent by an earlier call into /tmp/stash; carry .warp/manifest.txt too).
#
# Tasks (each writes $OUT/log.txt besides its own files):
#   bench ARGS...           mecanum-bench ARGS: kinematics or physics throughput
#   validate ARGS...        the physics validation table (python -m mecanum_jax.sim.validation)
#   train-bench ARGS...     PPO env steps/s of the gpu config, --variant 'name flags' side by side;
#                           the figures also as $OUT/train_bench.json (BENCH_TAG=T:
#                           train_bench_T.json, e.g. to bench two source trees in one call)
#   train MIN ARGS...       mecanum-train --config gpu for MIN minutes (+ mecanum-train flags)
#   ship MIN ARGS...        train, then package the policy as $OUT/model.tgz with provenance
#   seeds MIN 'K ...' ARGS  one run of MIN minutes training seeds K... side by side (vmapped),
#                           each packaged as /tmp/model_sK/o_rectangle and $OUT/model_sK.tgz
#   tune [MODEL...]         each MODEL (default /tmp/model/o_rectangle) and models/o_rectangle
#                           on the tuning episodes (configs/eval/tuning.toml, a seed of its own),
#                           TUNE_JOBS at a time (default: one per GPU, round robin; with
#                           twelve tuning scenarios 4 at once ran on one H200 in 124 s for 7
#                           models, another time one of 7 ran out of memory; with six, 3
#                           on one H100 ran out of memory, 2 fit; a model whose evaluation
#                           ran out of GPU memory runs again, alone); TUNE_SHIPPED=0 leaves
#                           models/o_rectangle out, e.g. for a screen whose recipe variant
#                           stands in for it; TUNE_PROBE='FIELD=VALUE ...' adds the shipped
#                           weights played so (mecanum-eval --play) as "probe"; then
#                           each (and the probe) also plays configs/eval/dashes.toml in the
#                           reference roller model (TUNE_ROLLER=0: not), whose losses count
#                           too; scripts/pick_candidate.py ranks
#                           them by its fixed rule and prints the chosen model's path last;
#                           every report comes back in $OUT/tuning.json (per-episode data
#                           left out but tuning_nominal's, which a CPU rerun checks with
#                           scripts/eval_agreement.py; full reports stay in /tmp/tune-reports)
#   eval [MODEL]            the evaluation table: MODEL (default models/o_rectangle) against the
#                           references on the default scenarios and 1024 randomized episodes
#                           (EVAL_SETS='default randomized starts': other sets of configs/eval
#                           too, each as $OUT/report_SET.json), then `agree MODEL`
#   agree [MODEL [SET SCENARIO [N]]]  SCENARIO of configs/eval/SET.toml (default: default
#                           nominal, its own episodes; N: that many) on the GPU and on the CPU
#                           of the same machine: do the steady-state figures agree to 1%?
#                           (scripts/eval_agreement.py; e.g. tuning tuning_nominal 64 checks a
#                           tuning table without playing held-out episodes)
#   repeat [MODEL [N]]      MODEL (default models/o_rectangle) on N (default 16) nominal and
#                           slippery episodes, JAX physics, in two processes as mecanum-eval
#                           runs (XLA's deterministic ops), then in two with XLA's default
#                           (--xla_gpu_exclude_nondeterministic_ops=false): how many per-episode
#                           figures part between the two of each, and the rollouts' seconds
#                           ($OUT/repeat_{det,xla}{1,2}.json)
#   fidelity [MODEL] [N]    MODEL (default models/o_rectangle) and the references on N (default
#                           8) nominal and N randomized episodes in the reference roller model,
#                           then in the fast one (JAX physics): $OUT/fidelity_{reference,fast}_*.json
#   reference-table MODEL...  every default scenario (their own episodes) and FID_RANDOMIZED
#                           (default 256) randomized episodes in the reference roller model,
#                           JAX physics, FID_JOBS models at a time (default 2): the first
#                           MODEL against every reference, the others against analytic only
#                           (e.g. a candidate's rows: scripts/eval_tables.py --also); then
#                           FID_AGREE (default nominal) 8 episodes of the first MODEL on the
#                           GPU ($OUT/reference_agree_gpu.json; the CPU side of the agreement
#                           check, about 10 minutes on 2 cores, is best run off the device:
#                           mecanum-eval MODEL --only nominal --episodes 8 --fidelity
#                           reference --physics-impl jax, then scripts/eval_agreement.py):
#                           $OUT/reference_NAME_{default,randomized}.json (NAME: the
#                           model's folder's folder, "shipped" for models/o_rectangle)
#   ab MIN 'name|flags'...  variants trained concurrently for MIN minutes, variant i on GPU i
#                           mod the GPUs (several share one where there are fewer GPUs), each
#                           packaged as /tmp/model_NAME/o_rectangle and $OUT/model_NAME.tgz
#                           (compare them next with: tune /tmp/model_NAME/o_rectangle ...); a
#                           variant of several --run.seeds K... as /tmp/model_NAME_sK/o_rectangle,
#                           all of them in $OUT/model_NAME.tgz (an archive over 15 MiB, as
#                           3 seeds' 19 MB are, comes back as model_NAME.tgz.partNN: at most 8
#                           files come back a call, so 2 such variants and their metrics)
#   multi-gpu EPOCHS [VARIANT...] [-- FLAGS...]  throughput over several GPUs: sh1gpu sh2gpu
#                           sh2gpu_64k mp2gpu (default), pmap2gpu, sh1gpu_64k, and split2gpu
#                           split2gpu_64k (each GPU its own rollout program), each with FLAGS
#                           too (e.g. -- --env.physics-impl warp, with --warp)
#   profile [--trace] ARGS...      where one epoch's time goes (python -m train.tools.profile, gpu
#                           config + ARGS): $OUT/profile.json; --trace also sends a
#                           jax.profiler trace of one epoch as $OUT/profile_trace.tgz.partNN
#   coldstart ARGS...       start to first evaluation (python -m train.tools.coldstart, gpu config +
#                           ARGS), twice: empty compilation cache, then warm;
#                           $OUT/coldstart_cold.json and coldstart_warm.json
#                           (COLDSTART_TAG=T: coldstart_T_cold.json ...; e.g. the same call
#                           with --compile-together off, then on; COLDSTART_TREE=DIR: the
#                           start from the sources in DIR, e.g. an earlier commit's
#                           `git archive`, to compare two versions on one machine;
#                           COLDSTART_PASSES='cold warm nobase warm2 nobase2': more warm
#                           starts, a "nobase" one without the stored baseline's figures)
#   scaling [N...] [FLAGS...]      PPO env steps/s of the gpu config at N robots (default 1024
#                           4096 16384 32768 65536; batch N/8: 2 unrolls per iteration as at
#                           32768), one process each: $OUT/scaling.json, $OUT/scaling.png
#
# COMMIT=HASH names the commit a packaged model's provenance records: the device's copy of
# .git can lag the working tree (on 2026-11-26 it gave an older HEAD, not the commit that
# trained the shipped policy), so pass COMMIT=$(git rev-parse --short HEAD).
#
# docs/benchmarks.md, docs/profiling.md and docs/training.md list the call behind each figure.
set -uo pipefail
WARP=0
if [ "${1:-}" = --warp ]; then WARP=1; shift; fi
TASK="${1:?usage: run.sh [--warp] TASK [ARGS...]}"; shift
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 \
  | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
O="${OUT:-/tmp/out}"; mkdir -p "$O"
quiet() { grep -v -E '^(Warp |Module |   )' ; }  # Warp's kernel-cache chatter

warp_install() {
  python3 - <<'PY'
import glob, io, lzma, os, tarfile
manifest = open(".warp/manifest.txt").read()
so_size, rest_size = map(int, manifest.split())
if os.path.exists("/tmp/site/warp/.manifest") and open("/tmp/site/warp/.manifest").read() == manifest:
    print("warp already under /tmp/site (an earlier call on this machine)")
    raise SystemExit(0)
blob = b"".join(open(p, "rb").read() for p in sorted(glob.glob("/tmp/stash/part-*")))
if len(blob) != so_size + rest_size:
    raise SystemExit(f"/tmp/stash holds {len(blob)} bytes of parts, expected "
                     f"{so_size + rest_size}: resend the parts")
with tarfile.open(fileobj=io.BytesIO(lzma.decompress(blob[so_size:]))) as tar:
    tar.extractall("/tmp/site", filter="data")
os.makedirs("/tmp/site/warp/bin", exist_ok=True)
with open("/tmp/site/warp/bin/warp.so", "wb") as f:
    f.write(lzma.decompress(blob[:so_size]))
with open("/tmp/site/warp/.manifest", "w") as f:
    f.write(manifest)
print("warp rebuilt under /tmp/site")
PY
}

train() {  # RUN_DIR MINUTES [flags]: the gpu config, one checkpoint kept
  local dir=$1 min=$2; shift 2
  python3 -m train.cli.train --config gpu --run-dir "$dir" --max-minutes "$min" \
    --run.max-checkpoints 1 --run.checkpoint-every 1000 "$@"
}

throttle() {  # N: wait until fewer than N background jobs run
  while [ "$(jobs -rp | wc -l)" -ge "$1" ]; do wait -n; done
}

evaluate() {  # MODEL SCENARIOS OUT_DIR [flags]
  local model=$1 set=$2 dir=$3; shift 3
  rm -rf "$dir"  # scratch of an earlier call on this warm machine
  /usr/bin/time -f "wall %e s" python3 -m train.cli.evaluate "$model" --scenarios "$set" --out "$dir" "$@"
}

repeat() {  # [MODEL [N]]: the same episodes twice, with mecanum-eval's deterministic ops and without
  local r x
  for r in det1 det2 xla1 xla2; do
    x="${XLA_FLAGS:-}"; case $r in xla*) x="$x --xla_gpu_exclude_nondeterministic_ops=false" ;; esac
    rm -rf "/tmp/repeat-$r"
    XLA_FLAGS="$x" python3 -m train.cli.evaluate "${1:-models/o_rectangle}" --only nominal slippery \
      --episodes "${2:-16}" --references feedback --physics-impl jax --no-plots \
      --out "/tmp/repeat-$r" 2>&1 | tail -1
    cp "/tmp/repeat-$r/report.json" "$O/repeat_$r.json"
  done
  python3 - "$O" <<'PY'
import json, sys
def load(n):
    return json.load(open(f"{sys.argv[1]}/repeat_{n}.json"))
for kind in ("det", "xla"):
    a, b = load(kind + "1"), load(kind + "2")
    parted = total = 0
    for name, sc in a["scenarios"].items():
        for who, figures in sc["per_episode"].items():
            for key, values in figures.items():
                other = b["scenarios"][name]["per_episode"][who][key]
                parted += sum(x != y for x, y in zip(values, other, strict=True))
                total += len(values)
    rollout = [r["timing"]["rollout_s"] for r in (a, b)]
    print(f"{kind}: {parted} of {total} per-episode figures part; rollouts {rollout} s")
PY
}

package() {  # RUN_DIR MODEL_DIR MINUTES "flags" [SEED]: the run's policy (of training seed
  # SEED, default the first) as a model, with provenance
  local commit device seed=${5:-}
  commit="${COMMIT:-$(git rev-parse --short HEAD 2>/dev/null || echo unknown)}"
  device=$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1)
  rm -rf "$2"
  python3 - "$1" "$2" "$3" "$4" "$commit" "$device" "$seed" <<'PY'
import json, sys
from train.cli.export import export_main
run, model, minutes, extra, commit, device, seed = sys.argv[1:8]
s = json.load(open(f"{run}/summary.json"))
command = f"mecanum-train --config gpu --max-minutes {minutes} {extra}".strip()
prov = [f"command={command}", f"commit={commit}", f"device={device}",
        f"session_wall_s={s['session_s']:.0f}", "script=scripts/device/run.sh"]
args = [run, f"{model}/o_rectangle", "--model", "--provenance", *prov]
raise SystemExit(export_main(args + (["--seed", seed] if seed else [])))
PY
  [ -d "$2/o_rectangle" ] || { echo "package: no model was written for $1"; return 1; }
}

send_back() {  # FILE under $OUT: left whole, or cut into FILE.partNN of 15 MiB where it is
  # larger than a returned file may be (16 MiB; at most 8 files come back): `cat F.part* > F`
  local f=$1 size
  size=$(stat -c %s "$f") || return 1
  [ "$size" -gt $((15 * 1024 * 1024)) ] || return 0
  split -b 15M -d "$f" "$f.part" && rm "$f"
  echo "$(basename "$f"): $size bytes in $(basename "$f").part*: cat them into one"
}

ship() {  # MINUTES [flags]
  local min=$1; shift
  echo "device: $(nvidia-smi --query-gpu=name --format=csv,noheader | head -1); $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  rm -rf /tmp/gpu  # scratch of an earlier call on this warm machine
  train /tmp/gpu "$min" "$@" 2>&1 | quiet | tail -22
  package /tmp/gpu /tmp/model "$min" "$*" || return 1
  tar czf "$O/model.tgz" -C /tmp/model o_rectangle && send_back "$O/model.tgz"
  cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/"
}

seeds() {  # MINUTES SEEDS [flags]: one run training the seeds (e.g. "0 1 2") side by side,
  # each packaged as /tmp/model_sK/o_rectangle and $OUT/model_sK.tgz
  local min=$1 list=$2 k; shift 2
  echo "device: $(nvidia-smi --query-gpu=name --format=csv,noheader | head -1); $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  rm -rf /tmp/gpu
  # shellcheck disable=SC2086
  train /tmp/gpu "$min" --run.seeds $list "$@" 2>&1 | quiet | tail -22
  for k in $list; do
    package /tmp/gpu "/tmp/model_s$k" "$min" "--run.seeds $list $*" "$k" || return 1
    tar czf "$O/model_s$k.tgz" -C "/tmp/model_s$k" o_rectangle && send_back "$O/model_s$k.tgz"
  done
  cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/"
}

gpus() { nvidia-smi -L | wc -l; }

ab() {  # MINUTES 'name|flags'...: trained side by side, variant i on GPU i mod the GPUs
  local min=$1; shift
  local spec name i=0 n
  n=$(gpus)
  local evals=$((2048 / (($# + n - 1) / n)))  # the periodic evaluations share a GPU's memory
  for spec in "$@"; do
    name="${spec%%|*}"
    rm -rf "/tmp/run_$name"
    echo "== variant $name on GPU $((i % n)): ${spec#*|}"
    # shellcheck disable=SC2086
    CUDA_VISIBLE_DEVICES=$((i % n)) train "/tmp/run_$name" "$min" --run.num-eval-envs "$evals" \
      ${spec#*|} > "/tmp/train_$name.log" 2>&1 &
    i=$((i + 1))
  done
  wait
  for spec in "$@"; do
    name="${spec%%|*}"; echo "== $name"; quiet < "/tmp/train_$name.log" | tail -8
    ab_package "$min" "$spec" > "/tmp/package_$name.log" 2>&1 &
  done
  wait
  for spec in "$@"; do cat "/tmp/package_${spec%%|*}.log"; done
}

ab_package() {  # MINUTES 'name|flags': a variant's policy (each of its seeds) packaged
  local min=$1 spec=$2 name seeds k
  name="${spec%%|*}"
  {
    seeds=$(python3 -c "import json, sys; print(*json.load(open(sys.argv[1]))['run']['seeds'])" \
      "/tmp/run_$name/config.json" 2>/dev/null)
    if [ "$(wc -w <<< "$seeds")" -gt 1 ]; then  # every seed: /tmp/model_NAME_sK/o_rectangle
      for k in $seeds; do
        package "/tmp/run_$name" "/tmp/model_${name}_s$k" "$min" "${spec#*|}" "$k"
      done
      (cd /tmp && tar czf "$O/model_$name.tgz" "model_${name}"_s*/o_rectangle)
    else
      package "/tmp/run_$name" "/tmp/model_$name" "$min" "${spec#*|}" \
        && tar czf "$O/model_$name.tgz" -C "/tmp/model_$name" o_rectangle
    fi
    send_back "$O/model_$name.tgz"  # (3 seeds: about 19 MB)
    cp "/tmp/run_$name/metrics.jsonl" "$O/${name}_metrics.jsonl" || true
  }
}

# the comparison tasks: tune, agree, fidelity, reference-table
# shellcheck source=scripts/device/compare.sh
source scripts/device/compare.sh

# the measurement tasks: multi-gpu, profile, coldstart, scaling
# shellcheck source=scripts/device/measure.sh
source scripts/device/measure.sh

{
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
date -u +%Y-%m-%dT%H:%M:%SZ
if [ "$WARP" = 1 ]; then warp_install || exit 3; fi
case "$TASK" in
  bench) python3 -m mecanum_jax.bench "$@" 2>&1 | quiet ;;
  validate) python3 -m mecanum_jax.sim.validation "$@" 2>&1 | quiet | tail -40 ;;
  train-bench)
    python3 -m train.tools.bench --config gpu --epochs 3 \
      --json-out "$O/train_bench${BENCH_TAG:+_$BENCH_TAG}.json" "$@" 2>&1 | quiet | tail -14 ;;
  train)
    min=$1; shift
    rm -rf /tmp/gpu
    train /tmp/gpu "$min" "$@" 2>&1 | quiet | tail -30
    cp /tmp/gpu/metrics.jsonl /tmp/gpu/summary.json "$O/" ;;
  ship) ship "$@" ;;
  seeds) seeds "$@" ;;
  fidelity) fidelity "$@" ;;
  reference-table) reference_table "$@" ;;
  tune) tune "$@" ;;
  eval)
    for set in ${EVAL_SETS:-default randomized}; do
      echo "== ${1:-models/o_rectangle}, scenarios: $set"
      evaluate "${1:-models/o_rectangle}" "$set" "/tmp/eval-$set" 2>&1 | quiet
      cp "/tmp/eval-$set/report.json" "$O/report_$set.json"
    done
    # shellcheck disable=SC2046  # the sets' plot globs, expanded in /tmp
    (cd /tmp && tar czf "$O/plots.tgz" $(for set in ${EVAL_SETS:-default randomized}; do
      echo "eval-$set/*.png"; done))
    [ "${AGREE:-1}" = 1 ] && agree "${1:-models/o_rectangle}" ;;  # AGREE=0: skip the check
  agree) agree "${1:-models/o_rectangle}" "${@:2}" ;;
  repeat) repeat "$@" ;;
  ab) ab "$@" ;;
  multi-gpu) multi_gpu "$@" ;;
  profile) profile "$@" ;;
  coldstart) coldstart "$@" ;;
  scaling) scaling "$@" ;;
  *) echo "run.sh: unknown task '$TASK' (see the header of scripts/device/run.sh)"; exit 2 ;;
esac
} 2>&1 | tee "$O/log.txt"
status=${PIPESTATUS[0]}
ls -la "$O"
case $status in 2 | 3) exit "$status" ;; esac  # its own refusals: unknown task, no Warp
