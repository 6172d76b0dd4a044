#!/usr/bin/env bash
# corona's checks on a GPU machine, as one prepared run of at most about 9.5 minutes: the
# plugin's tests in cuda_ad_spectral, then the render benchmark in it.  Run from the
# repository's root on that machine, after scripts/device_bundle.sh packed .device/ here:
#
#   run(command="bash scripts/device_check.sh", carry=[".device"], timeout_s=590)
#
# Everything it learns lands in $OUT (the device tool brings that folder back): env.txt (GPU,
# versions, whether Dr.Jit's CUDA backend and the variant load), plugin_tests.log (pytest -v,
# one line a test, complete up to wherever the time ran out), render.log and render_cuda.json
# (bench_render.py: each layer over roughdielectric, and Mie over the circle), summary.txt.
# Time caps: TESTS_S (default 330 s) and RENDER_S (default 200 s).  No test depends on this.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:-/tmp/corona-device}"
mkdir -p "$OUT"
PY="${PY:-python3}"
VARIANT="${CORONA_TEST_VARIANT:-cuda_ad_spectral}"
SITE="${SITE:-/tmp/corona-site}"
rm -rf "$SITE" && mkdir -p "$SITE"
tar -C "$SITE" -xJf .device/site.tar.xz || { echo "no .device/site.tar.xz: run scripts/device_bundle.sh here first" | tee "$OUT/summary.txt"; exit 2; }
export PYTHONPATH="$SITE/site:$PWD/src" PYTHONUNBUFFERED=1 CORONA_CACHE_DIR=/tmp/corona-cache \
    CORONA_TEST_VARIANT="$VARIANT" OPENBLAS_NUM_THREADS=4

{
    date -u
    nvidia-smi 2>&1 | head -15
    "$PY" --version
    "$PY" -c "import corona, drjit as dr, mitsuba as mi
print('mitsuba', mi.__version__, 'drjit', dr.__version__, 'corona', corona.__version__)
print('CUDA backend:', dr.has_backend(dr.JitBackend.CUDA))
mi.set_variant('$VARIANT'); corona.register(); print('variant', mi.variant(), 'loads')"
} > "$OUT/env.txt" 2>&1
echo "env rc $?" > "$OUT/summary.txt"
cat "$OUT/env.txt"

# the plugin's tests: the layers' own first, then the rest (one line a test: the log is whole up to the cap)
timeout "${TESTS_S:-330}" "$PY" -m pytest -v -p no:cacheprovider -o console_output_style=classic \
    tests/plugin/test_plugin.py tests/plugin/test_plugin_sphere.py tests/plugin/test_plugin_materials.py \
    tests/plugin/test_plugin_textures.py tests/plugin/test_combinations.py tests/plugin/test_properties.py \
    tests/plugin/test_sphere_layer.py tests/plugin/test_sphere_kernel_layout.py tests/plugin/test_gradients.py \
    tests/plugin/test_sphere_gradients.py tests/plugin/test_volume.py > "$OUT/plugin_tests.log" 2>&1
echo "plugin tests rc $? (124: stopped at ${TESTS_S:-330} s)" >> "$OUT/summary.txt"
grep -cE " PASSED" "$OUT/plugin_tests.log" | sed 's/^/passed /' >> "$OUT/summary.txt"
grep -E " (FAILED|ERROR)" "$OUT/plugin_tests.log" | head -50 >> "$OUT/summary.txt"

# the render benchmark: each layer over roughdielectric (the spheres over the circle), 512², two rounds
timeout "${RENDER_S:-200}" "$PY" benchmarks/bench_render.py --variant "$VARIANT" --res 512 --spp 64 \
    --rounds 2 --repeats 2 --bsdf-lanes 0 --name render_cuda \
    --bsdfs corona corona_textured corona-square corona-hexagon corona-square-spread corona-mie \
    corona-glass roughdielectric > "$OUT/render.log" 2>&1
echo "render rc $? (124: stopped at ${RENDER_S:-200} s)" >> "$OUT/summary.txt"
cp benchmarks/results/render_cuda.json "$OUT/" 2>/dev/null
cat "$OUT/summary.txt"
tail -20 "$OUT/render.log"
