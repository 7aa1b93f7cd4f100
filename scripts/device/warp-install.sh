#!/usr/bin/env bash
# On the GPU machine: install .whl into /tmp/site and rebuild warp-lang there from the
# parts that scripts/device/warp-parts.sh made and earlier calls left in /tmp/stash.
# Carry .whl and .warp/manifest.txt.
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists" || true
python3 - <<'PY'
import glob, io, lzma, os, tarfile
so_size, rest_size = map(int, open(".warp/manifest.txt").read().split())
blob = b"".join(open(p, "rb").read() for p in sorted(glob.glob("/tmp/stash/part-*")))
if len(blob) != so_size + rest_size:
    raise SystemExit(f"/tmp/stash holds {len(blob)} bytes of parts, expected {so_size + rest_size}: resend the parts")
with tarfile.open(fileobj=io.BytesIO(lzma.decompress(blob[so_size:]))) as tar:
    tar.extractall("/tmp/site", filter="data")
os.makedirs("/tmp/site/warp/bin", exist_ok=True)
with open("/tmp/site/warp/bin/warp.so", "wb") as f:
    f.write(lzma.decompress(blob[:so_size]))
print("warp rebuilt under /tmp/site")
PY
