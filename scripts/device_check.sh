#!/usr/bin/env bash
# corona's checks on a GPU machine, as one prepared run of at most about 9.5 minutes: every test
# that runs Mitsuba in the tests' variant (marker `mitsuba`, set by tests/conftest.py: the
# plugin's tests, renders, derivatives; not the browser's) in cuda_ad_spectral, then the render
# benchmark in it.  Run from the repository's root on that machine, after scripts/device_bundle.sh
# packed .device/ here:
#
#   run(command="bash scripts/device_check.sh", carry=[".device"], timeout_s=590)
#
# Everything it learns lands in $OUT (the device tool brings that folder back): env.txt (GPU,
# versions, whether Dr.Jit's CUDA backend and the variant load), tests.log (pytest -v, one line
# a test, whole up to wherever the time ran out), device_check.json (scripts/device_summary.py:
# the machine and its date, the variant, passed, failed, the failing test ids), render.log and
# render_cuda.json (bench_render.py), summary.txt.  Copy the JSON back into the checkout with
#   cp <files_at>/device_check.json benchmarks/results/device_check.json
# (files_at: the folder the device tool names).  No test depends on this.
#
# Settings (environment): TESTS_S (default 420 s) and RENDER_S (default 120 s; 0: no benchmark)
# cap the two parts; WORKERS (default 8; 0: one process) pytest-xdist workers where installed;
# SELECT (default "mitsuba and not browser") the marker expression, K a -k expression, PATHS the
# test paths (default tests).  SITE=none takes the packages of the Python that runs it instead of
# .device/ (the CPU rehearsal, docs/testing.md):
#
#   SITE=none PY=.venv/bin/python CORONA_TEST_VARIANT=llvm_ad_spectral RENDER_S=0 WORKERS=0 \
#       PATHS=tests/plugin/test_trig.py OUT=/tmp/corona-rehearsal bash scripts/device_check.sh
set -uo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:-/tmp/corona-device}"
mkdir -p "$OUT"
PY="${PY:-python3}"
VARIANT="${CORONA_TEST_VARIANT:-cuda_ad_spectral}"
SITE="${SITE:-/tmp/corona-site}"
if [ "$SITE" = none ]; then
    export PYTHONPATH="$PWD/src"
else
    rm -rf "$SITE" && mkdir -p "$SITE"
    tar -C "$SITE" -xJf .device/site.tar.xz || { echo "no .device/site.tar.xz: run scripts/device_bundle.sh here first" | tee "$OUT/summary.txt"; exit 2; }
    export PYTHONPATH="$SITE/site:$PWD/src"
fi
export PYTHONUNBUFFERED=1 CORONA_CACHE_DIR="${CORONA_CACHE_DIR:-/tmp/corona-cache}" \
    CORONA_TEST_VARIANT="$VARIANT" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-2}"

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
GPU=$(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1)
DRIVER=$(nvidia-smi --query-gpu=driver_version --format=csv,noheader 2>/dev/null | head -1)
[ -n "$GPU" ] || GPU="none ($(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | cut -d: -f2 | sed 's/^ *//'), $(nproc) cores)"
VERSIONS=$("$PY" -c "import sys, drjit, mitsuba; print(f'python={sys.version.split()[0]} mitsuba={mitsuba.__version__} drjit={drjit.__version__}')" 2>/dev/null)

# the tests: one line a test (the log is whole up to the cap); xdist workers where installed
XDIST=()
if [ "${WORKERS:-8}" != 0 ] && "$PY" -c "import xdist" 2>/dev/null; then
    XDIST=(-n "${WORKERS:-8}")
fi
SELECT="${SELECT:-mitsuba and not browser}"
read -r -a TEST_PATHS <<< "${PATHS:-tests}"
KARGS=()
[ -n "${K:-}" ] && KARGS=(-k "$K")
T0=$(date +%s)
timeout "${TESTS_S:-420}" "$PY" -m pytest -v -ra -p no:cacheprovider -o console_output_style=classic \
    "${XDIST[@]}" -m "$SELECT" "${KARGS[@]}" "${TEST_PATHS[@]}" > "$OUT/tests.log" 2>&1
RC=$?
T1=$(date +%s)
echo "tests rc $RC (124: stopped at ${TESTS_S:-420} s) in $((T1 - T0)) s" >> "$OUT/summary.txt"
"$PY" scripts/device_summary.py "$OUT/tests.log" --variant "$VARIANT" --rc "$RC" --seconds "$((T1 - T0))" \
    --selection "${TEST_PATHS[*]} -m '$SELECT'${K:+ -k '$K'}" \
    --machine "gpu=$GPU" "driver=${DRIVER:-none}" $VERSIONS --out "$OUT/device_check.json" >> "$OUT/summary.txt" 2>&1

# the render benchmark: each layer over roughdielectric (the spheres over the circle), 512², two rounds
if [ "${RENDER_S:-120}" != 0 ]; then
    timeout "${RENDER_S:-120}" "$PY" benchmarks/bench_render.py --variant "$VARIANT" --res 512 --spp 64 \
        --rounds 2 --repeats 2 --bsdf-lanes 0 --name render_cuda \
        --bsdfs corona corona_textured corona-square corona-hexagon corona-square-spread corona-mie \
        corona-glass roughdielectric > "$OUT/render.log" 2>&1
    echo "render rc $? (124: stopped at ${RENDER_S:-120} s)" >> "$OUT/summary.txt"
    cp benchmarks/results/render_cuda.json "$OUT/" 2>/dev/null
    tail -20 "$OUT/render.log"
fi
cat "$OUT/summary.txt"
