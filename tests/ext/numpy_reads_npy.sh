#!/usr/bin/env bash
# numpy opens what `cloudscape density` writes: shape, dtype, range, and the raw
# f32 file holds the same numbers (the overcast world: its stratocumulus has depth 10).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh
need_binary
need_python numpy
d=$(mktemp -d); trap 'rm -rf "$d"' EXIT
$bin density --world overcast --bbox 0,0,6400,3200 --t 500 --out "$d/a.npy"
$bin density --world overcast --bbox 0,0,6400,3200 --t 500 --format f32 --out "$d/a.f32"
$bin density --world overcast --bbox 0,0,6400,3200 --t 500 --field cld --out "$d/c.npy"
"$PY" - "$d" <<'PY'
import sys, numpy as np
d = sys.argv[1]
a = np.load(f"{d}/a.npy")
assert a.shape == (10, 32, 64), a.shape
assert a.dtype == np.float32, a.dtype
assert np.isfinite(a).all() and a.min() >= 0 and a.max() <= 1
raw = np.fromfile(f"{d}/a.f32", dtype="<f4").reshape(10, 32, 64)
assert (raw == a).all()
c = np.load(f"{d}/c.npy")
assert c.dtype == np.uint8 and c.shape == (10, 32, 64) and set(np.unique(c)) <= {0, 1}
print("numpy: 1 passed, 0 failed")
PY
