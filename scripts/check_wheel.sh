#!/usr/bin/env bash
# Build the sdist and the wheel, check their metadata, install the wheel into a fresh
# virtual environment and render the teaser scene from it, in a temporary folder: the
# package must work without the source tree (its tables, the designer's static files).
#   bash scripts/check_wheel.sh [PYTHON]     (PYTHON: the build front end's interpreter; default .venv)
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${1:-.venv/bin/python}"
ROOT="$PWD"
rm -rf dist
"$PY" -m build --outdir dist . >/dev/null
"$PY" -m twine check --strict dist/*
WHEEL="$(ls dist/*.whl)"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
python3 -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q --upgrade pip
"$WORK/venv/bin/python" -m pip install -q "$WHEEL"
cp scenes/teaser.xml "$WORK/"
cd "$WORK"
export CORONA_CACHE_DIR="$WORK/cache"
# the package is imported from the fresh environment, never from the source tree
"$WORK/venv/bin/python" - "$ROOT" <<'PY'
import os, sys
import corona
root = os.path.realpath(sys.argv[1])
assert not os.path.realpath(corona.__file__).startswith(root), corona.__file__
print("wheel: corona", corona.__version__, "from", os.path.dirname(corona.__file__))
PY
"$WORK/venv/bin/corona" --version
"$WORK/venv/bin/corona" render teaser.xml -D res=48 -D spp=4 --out out
test -s out/teaser.exr && test -s out/teaser.png
"$WORK/venv/bin/corona" post out/teaser.exr --fov 24 -D radius=5 -D area_fraction=0.3 -D mode=particle \
    --out out/teaser_post.exr --no-progress
test -s out/teaser_post.exr
echo "wheel: installed $(basename "$WHEEL") into a fresh environment and rendered the teaser from it"
