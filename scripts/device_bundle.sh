#!/usr/bin/env bash
# Packs, on this machine, what the GPU machine lacks for corona's CUDA checks
# (scripts/device_check.sh runs them there): that machine has Python 3.12 with numpy, scipy,
# numba, pytest and tqdm, no network, and takes at most 64 MiB of working tree a call.
#
#   bash scripts/device_bundle.sh      # writes .device/site.tar.xz (ignored by git)
#
# The wheels of mitsuba, drjit, miepython and platformdirs at the versions installed here
# (cp312, manylinux; PYVER=3.11 packs for a Python 3.11 instead), unpacked and without Mitsuba's variants that corona never uses
# (polarized, cuda_ad_mono: about 17 MB), then packed with xz.  Then, with the device tool:
#
#   run(command="bash scripts/device_check.sh", carry=[".device"], timeout_s=590)
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PY:-.venv/bin/python}"
PYVER="${PYVER:-3.12}"      # the GPU machine's Python
OUT=.device
rm -rf "$OUT"
mkdir -p "$OUT/whl" "$OUT/site"
version() { "$PY" -c "import importlib.metadata as m; print(m.version('$1'))"; }
for pkg in mitsuba drjit miepython platformdirs; do
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version "$PYVER" --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d "$OUT/whl" "$pkg==$(version "$pkg")"
done
for w in "$OUT"/whl/*.whl; do
    "$PY" -m zipfile -e "$w" "$OUT/site"
done
rm -f "$OUT"/site/mitsuba/*_polarized.cpython-*.so "$OUT"/site/mitsuba/cuda_ad_mono.cpython-*.so
tar -C "$OUT" -cJf "$OUT/site.tar.xz" site
rm -rf "$OUT/whl" "$OUT/site"
ls -l "$OUT/site.tar.xz"
