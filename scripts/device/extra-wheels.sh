#!/usr/bin/env bash
# Add to .whl/ the project's own pure-Python needs that the GPU image lacks (after
# ../shared/device/carry-wheels.sh), pinned to the versions in .venv.
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
want=()
for p in tyro docstring-parser typeguard; do
  v=$(.venv/bin/python -c "import importlib.metadata as m; print(m.version('$p'))")
  want+=("$p==$v")
done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp --platform manylinux_2_28_x86_64 -d .whl "${want[@]}" 2>&1 | grep -v '^WARNING: Location' || true
ls .whl | grep -E "tyro|docstring|typeguard"
# PyOpenGL (3.2 MB) is for on-screen rendering, which no task of run.sh does; left out, the
# last Warp call's carry (the tree, about 32 MB, and .whl) stays under 64 MiB
rm -f .whl/pyopengl-*.whl
