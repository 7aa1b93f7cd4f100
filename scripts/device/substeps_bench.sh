#!/usr/bin/env bash
# What the physics step costs in PPO training throughput (device machine, carry .whl):
# the gpu config at the default 5 ms (4 substeps per 20 ms control step) against 6.67 ms (3)
# and 10 ms (2), all with 12 Newton iterations, and 5 ms / 6.67 ms with 65536 robots (one
# rollout of 20 steps per PPO iteration instead of two; the same samples per update).
# Fitting time per env step = a + b * substeps separates the physics from the rest.
# (4 ms: 0.60 M env steps/s, session 6.) One train.bench process per variant, so that a
# run cut short still leaves the variants it finished in $OUT.
# experiments/physics_step_candidates.py measures what each step does to tracking and stability.
#   bash scripts/device/substeps_bench.sh [EPOCHS]
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
O="${OUT:-/tmp}"; EPOCHS="${1:-1}"
{
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
date -u
T667="--env.physics-timestep 0.006666666666666667 --env.contact-timeconst 0.013333333333333334"
for v in "ts5" "ts5_64k --ppo.num-envs 65536" "ts6.67 $T667" "ts6.67_64k $T667 --ppo.num-envs 65536" \
         "ts10 --env.physics-timestep 0.01 --env.contact-timeconst 0.02"; do
  python3 -m train.bench --config gpu --epochs "$EPOCHS" --variant "$v" \
    --json-out "$O/substeps_${v%% *}.json" 2>&1 | grep -v -i warp | grep -E '│ ts' || echo "variant ${v%% *} failed"
done
} 2>&1 | tee "$O/log.txt"
