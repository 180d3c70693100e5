#!/usr/bin/env bash
# The wheel as a user gets it: build it from this checkout (maturin, into a temporary folder),
# install it into a fresh virtual environment outside the tree (with numpy and Pillow only, for
# the end-to-end below), and run the `isa` command pip installed: --help, then train -> predict
# on a synthetic plate whose pose is known. Prints the wheel's name (abi3: one wheel for
# CPython 3.10+) and ends with "wheel check: 1 passed, 0 failed".
#   bash scripts/wheel_check.sh     # PYTHON=/path/to/python3.13: the venv (not the build) on another one
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m maturin build --release --quiet --out "$work/dist" >/dev/null
wheel=$(ls "$work"/dist/isa-*.whl)
echo "built $(basename "$wheel")"
$PY -m venv "$work/venv"
"$work/venv/bin/pip" install -q --disable-pip-version-check "numpy>=1.26,<3" "Pillow>=10,<13"
"$work/venv/bin/pip" install -q --disable-pip-version-check --no-deps "$wheel"
"$work/venv/bin/isa" --help >/dev/null
cd "$work"   # nothing of the checkout on the path: the installed package only
"$work/venv/bin/python" - <<'PY'
import json, os, subprocess, sys
import numpy as np
from PIL import Image
import isa
from isa import _core

assert "venv" in isa.__file__, isa.__file__
K = (200.0, 200.0, 63.5, 47.5)

def plate(c, w=128, h=96, cx=63.5, cy=47.5):
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    x, y = (u - cx) * c[2] / 200.0 - c[0], (v - cy) * c[2] / 200.0 - c[1]
    inside = (abs(x) < 0.2) & (abs(y) < 0.2)
    z = np.where(inside, c[2], 0.0) - np.where(inside & (x < 0) & (y < 0), 0.1, 0.0)
    return np.round(z * 1000).astype(np.uint16)

images, offsets = [], []
centres = [(0.0, 0.0, 1.5), (0.05, -0.03, 1.4), (-0.04, 0.02, 1.6)]
for c in centres:
    images.append(plate(c))
parts = _core.sample_parts(images, stride=2)
for i, u, v in parts:
    z = images[i][v, u] / 1000.0
    p = np.array([(u - K[2]) * z / K[0], (v - K[3]) * z / K[1], z])
    offsets.append(np.array(centres[i]) - p)
offsets = np.asarray(offsets, np.float32)
rotations = np.tile(np.array([1, 0, 0, 0], np.float32), (len(parts), 1))
_core.TrainSet(images, parts, offsets, rotations).write("plate.isat")
exe = os.path.join(os.path.dirname(sys.executable), "isa")  # the command pip installed
run = lambda *a: subprocess.run([exe, *a], capture_output=True, text=True)
r = run("train", "plate.isat", "-o", "plate.isa", "--quality", "Q1", "--n-trees", "3", "--max-depth", "14", "-q")
assert r.returncode == 0, r.stderr
Image.fromarray(plate((0.0, 0.0, 1.5))).save("frame.png")
r = run("predict", "plate.isa", "frame.png", "-k", *map(str, K), "--stride", "2")
assert r.returncode == 0, r.stderr
t = json.loads(r.stdout)["images"][0]["hypotheses"][0]["t"]
assert np.linalg.norm(np.array(t) - centres[0]) < 0.03, t
assert run("inspect", "missing.isa").returncode == 3
print(f"isa {isa.__version__} from {isa.__file__}, python {sys.version.split()[0]}: predicted t = {np.round(t, 3).tolist()}")
PY
echo "wheel check: 1 passed, 0 failed"
