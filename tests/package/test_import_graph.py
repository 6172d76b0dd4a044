"""The import graph of src/corona: no cycles, and the runtime never imports the reference tier.

The graph is read from the source with :mod:`ast` (nothing is imported), with every
``import`` statement counted wherever it sits: at module level, inside a function, under
``if TYPE_CHECKING``.  An import inside a function that closes a cycle is still a cycle: it
only moves the failure from import time to call time.
"""
from __future__ import annotations

import ast
import pathlib

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


def _module_name(path: pathlib.Path, src: pathlib.Path) -> str:
    rel = path.relative_to(src).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules(src: pathlib.Path) -> dict[str, pathlib.Path]:
    return {_module_name(p, src): p for p in sorted((src / PACKAGE).rglob("*.py"))}


def _imports(name: str, path: pathlib.Path, modules) -> set[str]:
    """corona modules that ``name`` imports (the named submodule if it is one, else its package)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
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


def _graph(src: pathlib.Path = SRC):
    modules = _modules(src)
    return {name: _imports(name, path, modules) for name, path in modules.items()}


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
