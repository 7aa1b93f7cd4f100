#!/usr/bin/env bash
# The start after an edit of the sources, before and after a change. For each of two
# revisions (git worktrees, each round with a compilation cache of its own): a cold start
# of the tiny config, a comment appended to train/cli/evaluate.py (a new source hash, the
# same programs), then two starts. ROUNDS rounds (default 2), the revisions' order
# alternating; prints each start's process wall time (python -m train.tools.coldstart).
#
#   bash scripts/bench_edit_start.sh REV_BEFORE REV_AFTER [ROUNDS]
set -euo pipefail
[ $# -ge 2 ] || { sed -n '2,8p' "$0"; exit 2; }
root=$(git rev-parse --show-toplevel)
py="$root/.venv/bin/python"
before=$(git rev-parse --short "$1") after=$(git rev-parse --short "$2") rounds=${3:-2}
work=$(mktemp -d)
cleanup() {
  for r in a b; do git -C "$root" worktree remove --force "$work/$r" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT
git -C "$root" worktree add -q --detach "$work/a" "$before"
git -C "$root" worktree add -q --detach "$work/b" "$after"
printf '%-6s %-12s %-10s %s\n' round revision start wall_s
for round in $(seq "$rounds"); do
  order="a b"; [ $((round % 2)) = 0 ] && order="b a"
  for r in $order; do
    rev=$before; [ "$r" = b ] && rev=$after
    for start in cold edited-1 edited-2; do
      [ "$start" = edited-1 ] && echo "# an edit" >> "$work/$r/train/cli/evaluate.py"
      t0=$(date +%s.%N)
      (cd "$work/$r" && "$py" -m train.tools.coldstart --config tiny \
        --compilation-cache "$work/cache-$r-$round" --json-out "$work/out.json" > "$work/log" 2>&1)
      t1=$(date +%s.%N)
      printf '%-6s %-12s %-10s %s\n' "$round" "$rev" "$start" "$("$py" -c "print(f'{$t1 - $t0:.1f}')")"
    done
    git -C "$work/$r" checkout -q -- train/cli/evaluate.py
  done
done
