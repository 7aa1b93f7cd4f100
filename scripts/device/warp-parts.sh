#!/usr/bin/env bash
# Pack warp-lang (the wheel MJX's Warp backend needs, 149 MB) into parts that fit the GPU
# machine's 64 MiB carry, and print the device calls that send and rebuild it.
#
# Usage, from the project's root:   bash scripts/device/warp-parts.sh
#
# warp/bin/warp.so is recompressed with xz (about 78 MB), the rest of the wheel, less its
# examples and tests, goes into a tar.xz (about 21 MB); both are cut into .warp/part-* of
# at most 25 MiB: four parts (the tree, about 32 MB, and one part of 33 MiB came to more
# than the 64 MiB a call carries). Each device call carries one part and copies it to /tmp/stash (which
# survives while the machine stays warm: start each call within about 30 s of the last).
# The last call carries .whl too and runs scripts/device/run.sh --warp, which rebuilds
# warp under /tmp/site before its task, e.g. `run.sh --warp bench physics --impls jax warp`.
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
version=1.18.0 # the version mujoco-mjx's "warp" extra pins
mkdir -p .git/info .warp
grep -qx '/.warp/' .git/info/exclude 2>/dev/null || echo '/.warp/' >>.git/info/exclude
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp --platform manylinux_2_28_x86_64 -d "$work" "warp-lang==$version"
(cd "$work" && unzip -q warp_lang-*.whl -d wheel)
xz -9e -T0 -c "$work/wheel/warp/bin/warp.so" >"$work/warp.so.xz"
rm "$work/wheel/warp/bin/warp.so"
tar -C "$work/wheel" --exclude='warp/examples' --exclude='warp/tests' -cf - . |
  xz -9e -T0 >"$work/rest.tar.xz"
rm -f .warp/part-*
cat "$work/warp.so.xz" "$work/rest.tar.xz" | split -b 25M -d - .warp/part-
python3 - "$work" <<'EOF' >.warp/manifest.txt
import os, sys
work = sys.argv[1]
print(os.path.getsize(f"{work}/warp.so.xz"), os.path.getsize(f"{work}/rest.tar.xz"))
EOF
ls -l .warp
echo
echo "Device calls (each within ~30 s of the last):"
for p in .warp/part-*; do
  echo "  carry [\"$p\"]: mkdir -p /tmp/stash && cp $p /tmp/stash/"
done
echo "  carry [\".whl\", \".warp/manifest.txt\"]: bash scripts/device/run.sh --warp TASK ..."
