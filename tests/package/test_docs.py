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


def _toctree_entries(page: str) -> list[str]:
    text = open(os.path.join(ROOT, "docs", page), encoding="utf-8").read()
    entries = []
    for block in re.findall(r"```\{toctree\}\n(.*?)```", text, re.S):
        entries += [line.strip() for line in block.splitlines() if line.strip() and not line.startswith(":")]
    return entries


def test_docs_open_on_the_index_and_list_every_page():
    """The site opens on docs/index.md (not a redirect to the API page), its table of
    contents reaches every page the build includes (the gallery, the command line, the
    parameters, the contributors' page, the tutorial, the API pages), and each exists."""
    conf = open(os.path.join(ROOT, "docs", "api", "conf.py"), encoding="utf-8").read()
    assert re.search(r'^root_doc = "index"', conf, re.M)
    assert "_redirect_root" not in conf and 'mathjax_path = "mathjax/tex-chtml.js"' in conf
    included = re.search(r"include_patterns = \[(.*?)\]", conf, re.S).group(1)
    pages = {p[:-3] for p in re.findall(r'"([^"*]+\.md)"', included)}
    listed = set(_toctree_entries("index.md")) | {"index"}
    listed |= {"api/" + e for e in _toctree_entries(os.path.join("api", "index.md"))}
    for page in ("gallery", "cli", "designer", "parameters", "install", "contributing", "tutorial", "physics"):
        assert page in pages and page in listed, page
    assert pages <= listed, pages - listed
    assert "api/corona.apps.post" in listed
    for page in listed:
        assert os.path.exists(os.path.join(ROOT, "docs", page + ".md")) or \
            os.path.exists(os.path.join(ROOT, "docs", page + ".rst")), page


def _tutorial_sections() -> list[str]:
    """examples/tutorial.py cut at its ``# --- `` lines: the code after the docstring,
    then each section without its marker line."""
    import ast
    source = open(os.path.join(ROOT, "examples", "tutorial.py"), encoding="utf-8").read()
    lines = source.splitlines()[ast.parse(source).body[0].end_lineno:]
    chunks = [[]]
    for line in lines:
        if line.startswith("# --- "):
            chunks.append([])
        else:
            chunks[-1].append(line)
    return ["\n".join(c).strip("\n") for c in chunks]


def test_tutorial_page_shows_the_script_as_it_is():
    """docs/tutorial.md shows its code as plain Markdown blocks (readable on a forge, no
    ``{literalinclude}``), and those blocks are examples/tutorial.py, section by section,
    in order: the script that test_tutorial_runs_and_says_what_it_should runs."""
    page = open(os.path.join(ROOT, "docs", "tutorial.md"), encoding="utf-8").read()
    assert "literalinclude" not in page
    blocks = [b.strip("\n") for b in re.findall(r"^```python\n(.*?)^```$", page, re.S | re.M)]
    sections = _tutorial_sections()
    assert len(sections) == 7, "examples/tutorial.py: a preamble and six '# --- ' sections"
    assert blocks == sections, "docs/tutorial.md's code blocks differ from examples/tutorial.py's sections"


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
