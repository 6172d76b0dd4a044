"""The documentation: the tutorial runs, the docstrings' plain-text bars become text.

The HTML build itself (warnings as errors, math typeset by the shipped MathJax, no
CDN) is `make docs-check` (scripts/check_docs.py), which CI runs.
"""
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))


@pytest.mark.slow
def test_tutorial_runs_and_says_what_it_should(tmp_path):
    """examples/tutorial.py end to end (docs/tutorial.md shows it): the fit finds the
    rendered radius, the gradient points back towards it."""
    env = {**os.environ, "CORONA_CACHE_DIR": os.environ.get("CORONA_CACHE_DIR", str(tmp_path / "cache"))}
    r = subprocess.run([sys.executable, os.path.join(ROOT, "examples", "tutorial.py"), str(tmp_path / "out")],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    out = r.stdout
    radius = float(re.search(r"fitted radius ([0-9.]+) µm", out).group(1))
    assert abs(radius / 4.0 - 1) < 0.02, out
    grad = float(re.search(r"d loss / d radius at 4.4 µm = ([-+0-9.e]+)", out).group(1))
    assert grad > 0, out
    tc = float(re.search(r"T_c = \(1 - F_a\)\^2 = ([0-9.]+)", out).group(1))
    assert tc == pytest.approx(0.65 ** 2, abs=1e-4)
    assert (tmp_path / "out" / "render.exr").stat().st_size > 0


def _conf():
    import importlib.util
    spec = importlib.util.spec_from_file_location("corona_docs_conf", os.path.join(ROOT, "docs", "api", "conf.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bars_in_docstrings_are_escaped_outside_literals():
    """``F_a = n |A|`` in prose and in a list-table (the parameter tables of
    corona.parameters and the plugin) is text, not a substitution reference; inside
    inline literals, math and code blocks it stays as written."""
    pytest.importorskip("sphinx")       # conf.py needs Sphinx and its MathJax copy: the docs extra
    conf = _conf()
    lines = ["The area |A| of ``|x|``.", "", ".. list-table::", "   :header-rows: 1", "",
             "   * - F_a = n |A|, covered", "", ".. math::", "", "   |A| = 1", "", "Code::", "", "   a |b|"]
    conf._escape_substitutions(None, "module", "m", None, {}, lines)
    assert lines[0] == r"The area \|A\| of ``|x|``."
    assert lines[5] == r"   * - F_a = n \|A\|, covered"
    assert lines[9] == "   |A| = 1" and lines[13] == "   a |b|"


def test_docs_pages_are_listed():
    """Every page of the site is built: the tutorial and the corona.apps.post API page."""
    index = open(os.path.join(ROOT, "docs", "api", "index.md"), encoding="utf-8").read()
    assert "/tutorial" in index and "corona.apps.post" in index
    conf = open(os.path.join(ROOT, "docs", "api", "conf.py"), encoding="utf-8").read()
    assert '"tutorial.md"' in conf and 'mathjax_path = "mathjax/tex-chtml.js"' in conf


def _report():
    import importlib.util
    spec = importlib.util.spec_from_file_location("corona_bench_report", os.path.join(ROOT, "benchmarks", "report.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmarks_page_is_what_the_report_generates():
    """docs/benchmarks.md is generated from benchmarks/results/*.json (benchmarks/report.py) and
    written by nothing else: a results file added or changed without regenerating, or a hand edit
    of the page, fails here (regenerate: python benchmarks/report.py)."""
    report = _report()
    with open(os.path.join(ROOT, "docs", "benchmarks.md"), encoding="utf-8") as f:
        page = f.read()
    assert page == report.page(), "docs/benchmarks.md is stale: run python benchmarks/report.py"
    # one section per current benchmark with its command and machine; every other results file listed
    names = {os.path.splitext(n)[0] for n in os.listdir(report.RESULTS) if n.endswith(".json")}
    current = [b[0] for b in report.BENCHMARKS if b[0] in names]
    for name in current:
        body = page.split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]
        assert "\nCommand: `" in body and "\nMachine: " in body, name
    for name in names - set(current):
        assert f"| `{name}.json` |" in page, name
