#!/usr/bin/env bash
# One-time set-up on a fresh machine: system libraries for headless OpenGL, Python packages,
# and the `isa` wheel itself (built from this checkout by maturin). Safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."

# Rendering needs none of this (the Rust core rasterises); the optional pyrender backend, which
# the tests compare the core with, runs over EGL (Mesa llvmpipe); importing pyrender loads pyglet,
# which needs libGL and libXrender even off-screen. OSMesa as a fallback.
# The package list is isa.render.renderer.HEADLESS_GL_APT (read from the source: nothing is
# installed yet).
gl_pkgs=$(python3 -c "
import ast
tree = ast.parse(open('python/isa/render/renderer.py').read())
print(' '.join(next(ast.literal_eval(n.value) for n in tree.body
                    if isinstance(n, ast.Assign) and getattr(n.targets[0], 'id', '') == 'HEADLESS_GL_APT')))")
need_apt=()
for pkg in $gl_pkgs; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if [ ${#need_apt[@]} -gt 0 ]; then
  echo "[setup] apt-get install ${need_apt[*]}"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
# pyrender pins PyOpenGL==3.1.0, which lacks the OSMesa fallback: install it without its
# dependencies and list them here explicitly (see requirements/runtime.txt).
$PY -m pip install -q --disable-pip-version-check -r requirements/runtime.txt
$PY -m pip install -q --disable-pip-version-check --no-deps "pyrender==0.1.45"
if [ "${ISA_SETUP_DEV:-1}" = 1 ]; then
  $PY -m pip install -q --disable-pip-version-check -r requirements/dev.txt
fi
# The package itself: Rust core + PyO3 binding compiled by maturin (release profile). A build
# from before the abi3 module (python/isa/_core.cpython-*.so) would shadow the new _core.abi3.so.
rm -f python/isa/_core.cpython-*.so
$PY -m pip install -q --disable-pip-version-check --no-build-isolation --no-deps -e .
# An assignment, so that a package that does not import stops the script (set -e).
version=$($PY -c 'import isa; print("isa", isa.__version__)')
echo "[setup] done: $version"
