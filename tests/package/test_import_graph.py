"""The import graph of src/corona: no cycles, no arrow up the tiers, and the runtime never
imports the reference tier.

The graph is read from the source with :mod:`ast` (nothing is imported), with every
``import`` statement counted wherever it sits: at module level, inside a function, under
``if TYPE_CHECKING``.  An import inside a function that closes a cycle is still a cycle: it
only moves the failure from import time to call time.
"""
from __future__ import annotations

import ast
import functools
import pathlib
import subprocess
import sys

import pytest

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
PACKAGE = "corona"

#: Cycles that another change removes; each entry is one pair whose mutual edges are ignored.
KNOWN_CYCLES: set = set()

#: Modules outside corona.reference allowed to import it, each with the reason.
REFERENCE_IMPORTERS = {
    # `corona validate` runs the brute-force comparison: the CLI subcommand imports
    # corona.reference.validate when it is invoked, never at `import corona.apps.cli`
    "corona.apps.cli": "the `corona validate` subcommand",
}


#: The tiers, low to high (docs/contributing.md, "The tiers and the import policy"): an import may only point to the
#: same tier or a lower one.  The shared infrastructure sits below the model (which holds the
#: tables and their cache: corona.model.tabulated, corona.model.rows); corona.parameters (the one
#: parameter spec, which builds materials and reads the tables' settings) above the model;
#: corona.reference beside the runtime, above the spec (it may use the model and the spec, never
#: the plugin or the applications, and nothing else imports it).
TIERS = (
    ("shared", ("corona._validation", "corona._environment", "corona._executor", "corona.color")),
    ("model", ("corona.model",)),
    ("spec", ("corona.parameters",)),
    ("reference", ("corona.reference",)),
    ("plugin", ("corona.mitsuba",)),
    ("applications", ("corona.apps",)),
)

#: Upward arrows allowed, (importer, imported) -> why.  An import inside a function counts
#: like one at the top of the module.
UPWARD_ALLOWED = {
    # `corona validate` runs the brute-force comparison: the CLI subcommand imports the
    # reference tier when it is invoked (the one door from the applications to it)
    ("corona.apps.cli", "corona.reference.validate"): "the `corona validate` subcommand",
}

#: The package root is the public face, above every tier, but every ``import corona.X`` runs it
#: first: at module level it may import only the shared infrastructure and the model; the
#: plugin and the applications only inside functions (``register``, the PEP 562 ``__getattr__``).
ROOT_EAGER_MAX = "model"


def _tier(module: str) -> str | None:
    for tier, prefixes in TIERS:
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return tier
    return None


_RANK = {tier: i for i, (tier, _) in enumerate(TIERS)}


def _module_name(path: pathlib.Path, src: pathlib.Path) -> str:
    rel = path.relative_to(src).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules(src: pathlib.Path) -> dict[str, pathlib.Path]:
    return {_module_name(p, src): p for p in sorted((src / PACKAGE).rglob("*.py"))}


def _imports(name: str, path: pathlib.Path, modules, eager_only: bool = False) -> set[str]:
    """corona modules that ``name`` imports (the named submodule if it is one, else its package).

    With ``eager_only`` only the imports that run when the module is imported (not those
    inside a function body)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    out = set()
    tree = ast.parse(path.read_text(), str(path))
    nodes = _eager_nodes(tree) if eager_only else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # `from pkg import sub` imports the submodule pkg.sub; `from pkg import name` the package
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:      # `import corona.model.shapes.base` -> that module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _eager_nodes(tree):
    """Every node outside function bodies (what runs at import time)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                stack.append(child)


@functools.lru_cache(maxsize=None)      # the source tree's graph parsed once per session, not per test
def _graph(src: pathlib.Path = SRC, eager_only: bool = False):
    modules = _modules(src)
    return {name: _imports(name, path, modules, eager_only) for name, path in modules.items()}


def _upward_arrows(graph, eager_root) -> list[str]:
    """Every import from a lower tier into a higher one (the root: see :data:`ROOT_EAGER_MAX`)."""
    bad = []
    for v, ws in sorted(graph.items()):
        for w in sorted(ws):
            tw = _tier(w)
            if v == PACKAGE:
                if tw is not None and w in eager_root and _RANK[tw] > _RANK[ROOT_EAGER_MAX]:
                    bad.append(f"{v} -> {w} (at import time)")
                continue
            tv = _tier(v)
            if tv is None or tw is None:
                continue   # the root face (any tier may use it) or a module in no tier (tested apart)
            if _RANK[tw] > _RANK[tv] and (v, w) not in UPWARD_ALLOWED:
                bad.append(f"{v} [{tv}] -> {w} [{tw}]")
            elif tw == "reference" and tv != "reference" and (v, w) not in UPWARD_ALLOWED:
                bad.append(f"{v} [{tv}] -> {w} [reference]")
    return bad


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _without_known(graph):
    return {v: {w for w in ws if frozenset({v, w}) not in KNOWN_CYCLES} for v, ws in graph.items()}


def test_no_import_cycles():
    cycles = _cycles(_without_known(_graph()))
    assert not cycles, "import cycles among corona modules: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_runtime_never_imports_the_reference_tier():
    bad = sorted(f"{v} -> {w}" for v, ws in _graph().items() for w in ws
                 if w.startswith("corona.reference") and not v.startswith("corona.reference")
                 and v not in REFERENCE_IMPORTERS)
    assert not bad, "the runtime imports corona.reference: " + ", ".join(bad)


def test_every_module_is_in_a_tier():
    lost = sorted(v for v in _graph() if v != PACKAGE and _tier(v) is None)
    assert not lost, "modules in no tier (add them to TIERS): " + ", ".join(lost)


def test_no_import_points_up_the_tiers():
    bad = _upward_arrows(_graph(), _graph(eager_only=True)[PACKAGE])
    assert not bad, "imports from a lower tier into a higher one: " + "; ".join(bad)


def test_allowed_upward_arrows_are_still_there():
    graph = _graph()
    for v, w in UPWARD_ALLOWED:
        assert w in graph[v], f"{v} no longer imports {w}: remove it from UPWARD_ALLOWED"


@pytest.mark.parametrize("source, bad", [
    # an upward arrow inside a function is still one
    ({"corona.model.m": "def f():\n    from corona.parameters import x", "corona.parameters": ""},
     ["corona.model.m [model] -> corona.parameters [spec]"]),
    ({"corona.parameters": "from corona.model import m", "corona.model.m": ""}, []),
    # the runtime reaching the reference tier, even from the tier that sits below it in rank
    ({"corona.mitsuba.b": "import corona.reference.r", "corona.reference.r": ""},
     ["corona.mitsuba.b [plugin] -> corona.reference.r [reference]"]),
    ({"corona.reference.r": "import corona.apps.a", "corona.apps.a": ""},
     ["corona.reference.r [reference] -> corona.apps.a [applications]"]),
    # the root: an application at import time is an arrow, inside a function it is not
    ({"corona": "from corona.apps.a import f", "corona.apps.a": ""}, ["corona -> corona.apps.a (at import time)"]),
    ({"corona": "def __getattr__(n):\n    from corona.apps.a import f", "corona.apps.a": ""}, []),
])
def test_the_checker_sees_upward_arrows(tmp_path, source, bad):
    """Negative control: each kind of upward arrow is found, a downward one is not."""
    (tmp_path / "corona").mkdir()
    (tmp_path / "corona" / "__init__.py").touch()
    for name, text in source.items():
        parts = name.split(".")
        path = tmp_path.joinpath(*parts[:-1], parts[-1] + ".py") if name != PACKAGE else \
            tmp_path / PACKAGE / "__init__.py"
        for i in range(2, len(parts)):
            tmp_path.joinpath(*parts[:i]).mkdir(exist_ok=True)
            tmp_path.joinpath(*parts[:i], "__init__.py").touch()
        path.write_text(text + "\n")
    found = _upward_arrows(_graph(tmp_path), _graph(tmp_path, eager_only=True)[PACKAGE])
    assert found == bad


def test_known_exceptions_are_still_needed():
    """Each whitelisted cycle and reference importer is still there (drop it when it is gone)."""
    graph = _graph()
    for pair in KNOWN_CYCLES:
        a, b = sorted(pair)
        assert b in graph[a] and a in graph[b], f"{a} <-> {b} is no longer a cycle: remove it from KNOWN_CYCLES"
    for v in REFERENCE_IMPORTERS:
        assert any(w.startswith("corona.reference") for w in graph[v]), \
            f"{v} no longer imports corona.reference: remove it from REFERENCE_IMPORTERS"


@pytest.mark.parametrize("source, cycle", [
    ({"corona.a": "from . import b", "corona.b": "def f():\n    from .a import x"}, ["corona.a", "corona.b"]),
    ({"corona.a": "import corona.b", "corona.b": "import numpy"}, None),
])
def test_the_checker_sees_function_level_cycles(tmp_path, source, cycle):
    """Negative control: a cycle closed by an import inside a function is found."""
    pkg = tmp_path / "corona"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name, text in source.items():
        (pkg / (name.split(".")[1] + ".py")).write_text(text + "\n")
    found = _cycles(_graph(tmp_path))
    assert found == ([cycle] if cycle else [])


@pytest.mark.slow
def test_importing_the_model_imports_no_higher_tier():
    """``import corona.model.material`` (which runs the package root) loads the model and the shared
    infrastructure only; the applications' names of the root come on first use (PEP 562)."""
    code = ("import sys, corona.model.material\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith(('corona.parameters',"
            " 'corona.mitsuba', 'corona.apps', 'corona.reference')))))\n"
            "import corona, corona.apps.fit, corona.apps.micrograph\n"
            "assert corona.fit_photograph is corona.apps.fit.fit_photograph\n"
            "assert corona.from_micrograph is corona.apps.micrograph.from_micrograph\n"
            "assert 'fit_photograph' in dir(corona)\n"
            "try:\n    corona.no_such_name\nexcept AttributeError as e:\n    print('AttributeError', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    first, second = out.stdout.splitlines()
    assert first == "", f"importing the model imported {first}"
    assert second.startswith("AttributeError") and "no_such_name" in second
