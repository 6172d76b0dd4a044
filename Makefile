# corona — two commands from a fresh clone:  make demo  /  make test
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
PYTEST_ARGS ?=
# make bench BENCH_ARGS=--full (bigger runs) or BENCH_ARGS="--only render sampling"
BENCH_ARGS ?=
DOCS_STAMP := $(VENV)/.docs-stamp
# make docs SPHINXOPTS=-W (warnings as errors) or SPHINXOPTS=-E (rebuild everything)
SPHINXOPTS ?=
# make gallery VARIANT=llvm_ad_rgb
VARIANT ?=

.PHONY: all demo test test-fast venv llvm chromium bench gallery docs docs-check dist wheel-check clean clean-cache designer

all: test

# The virtual environment, created and filled idempotently: the runtime plus
# the reference tier, the sweep executor (Dask), the designer and the test tools (a plain `pip install .` is the light runtime).
$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[reference,sweep,designer,test]'
	@touch $(STAMP)

venv: $(STAMP) llvm

# Dr.Jit's LLVM backend needs libLLVM >= 16; install Debian's libllvm19 if none.
llvm:
	@bash scripts/ensure_llvm.sh

# Debian's headless Chromium and chromedriver for the designer's browser test.
chromium:
	@bash scripts/ensure_chromium.sh

demo: venv
	$(PY) scripts/demo.py

# everything: the tests, the doctests, the chi-square runs, renders, the browser
test: venv chromium $(DOCS_STAMP)
	$(PY) -m pytest -n 2 -q $(PYTEST_ARGS)

# the physics and the plugin's pointwise checks (-m "not slow": no chi-square runs, renders,
# browser, reference simulations, processes or clusters; markers set where each test is defined,
# checked by tests/conftest.py). Both targets keep the tables in the tests' cache outside the
# clone, one folder per fingerprint of the table-building code (scripts/suite_cache.py; the root
# is $CORONA_TEST_CACHE or ~/.cache/corona-tests), so a second run reads them back
test-fast: venv
	$(PY) -m pytest -n 2 -q -m "not slow" tests $(PYTEST_ARGS)

# every scene of scenes/ at modest spp -> docs/gallery/*.png and docs/gallery.md
# (make gallery VARIANT=llvm_ad_rgb: another Mitsuba variant; default the fastest spectral one)
# (the panels render as the points of one sweep on a local Dask cluster: corona.apps.sweep)
gallery: venv
	$(PY) scripts/gallery.py $(if $(VARIANT),--variant $(VARIANT))
	$(PY) scripts/demo.py out/demo --update-docs $(if $(VARIANT),--variant $(VARIANT))

# the look-development page on http://127.0.0.1:8765/
designer: venv
	$(PY) -m corona.apps.cli designer

bench: venv
	$(PY) benchmarks/run_all.py $(BENCH_ARGS)

# the sdist and the wheel of the distribution corona-bsdf (import name corona) in dist/,
# their metadata checked (python -m build, twine check)
dist: venv
	rm -rf dist
	$(PY) -m build --outdir dist .
	$(PY) -m twine check --strict dist/*

# dist + the wheel installed into a fresh virtual environment, the teaser rendered from it
# in a temporary folder (not from the source tree); CI runs it
wheel-check: venv
	bash scripts/check_wheel.sh $(PY)

# the docs extra (Sphinx, MyST, a MathJax copy), added to the same .venv idempotently
$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install -q -e '.[test,docs]'
	@touch $(DOCS_STAMP)

# docs/physics.md, the tutorial + the API reference from the docstrings -> docs/_build/html
# (configuration in docs/api/conf.py; no network access during the build or when reading:
# the math is typeset by the MathJax copy in docs/_build/html/_static/mathjax)
docs: $(DOCS_STAMP)
	$(PY) -m sphinx -b html -q -c docs/api -d docs/_build/doctrees $(SPHINXOPTS) docs docs/_build/html
	@echo "docs: open docs/_build/html/index.html"

# the same with warnings as errors (a full build), then no CDN and the local MathJax
# checked on every page (scripts/check_docs.py); CI runs it
docs-check: $(DOCS_STAMP)
	$(PY) scripts/check_docs.py

# the user's table cache (corona tables clear) and every test cache (scripts/suite_cache.py)
clean-cache: venv
	$(PY) -m corona.apps.cli tables clear
	$(PY) scripts/suite_cache.py clear

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache .pytest-tables docs/_build
