"""No private name crosses a package (the scipy / freud convention).

A name that starts with one ``_`` is used only inside its own package: the modules of the folder
that defines it.  A private *module* (``corona._executor``, ``corona._validation``, ...) may be
imported from anywhere in corona, but its own ``_private`` names stay with its siblings; a name
that another package needs gets a public spelling in its home.

The scan reads the source with :mod:`ast` (nothing is imported) and sees what an AST can see:
``from X import _y``, ``module._y`` / ``a.b.module._y`` and ``getattr(module, "_y")`` where the
module is a corona module bound by an import in the same file.  Attribute reads on objects
(``shape._x``) need types, which an AST has not.
"""
from __future__ import annotations

import ast
import pathlib
import textwrap

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
PACKAGE = "corona"


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _modules(root: pathlib.Path, package: str) -> dict:
    """Dotted module name -> file, for every module of ``package`` under ``root``."""
    out = {}
    for f in sorted((root / package).rglob("*.py")):
        parts = f.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _package_of(module: str, modules: dict) -> str:
    """The package (folder) a module belongs to: itself for a package's ``__init__``."""
    return module if modules[module].name == "__init__.py" else module.rpartition(".")[0]


def cross_package_private_names(root: pathlib.Path, package: str = PACKAGE) -> list:
    """Every use of a ``_private`` name of one package from a module of another, as
    ``"importer:line: what (home package)"``."""
    modules = _modules(root, package)
    hits = []
    for here, path in modules.items():
        here_pkg = _package_of(here, modules)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        aliases = {}                                   # local name -> dotted corona module

        def check(module: str, name: str, line: int, what: str) -> None:
            if not _private(name) or f"{module}.{name}" in modules:    # a (private) module is fine
                return
            home = _package_of(module, modules)
            if home != here_pkg:
                hits.append(f"{here}:{line}: {what} (home {home}, used from {here_pkg})")

        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.split(".")[0] == package:
                        if a.asname:
                            aliases[a.asname] = a.name
                        else:
                            aliases[package] = package
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:                          # relative: from the importer's package
                    anchor = here_pkg.split(".")
                    anchor = anchor[:len(anchor) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                if base.split(".")[0] != package or base not in modules:
                    continue
                for a in node.names:
                    if f"{base}.{a.name}" in modules:
                        aliases[a.asname or a.name] = f"{base}.{a.name}"
                    else:
                        check(base, a.name, node.lineno, f"from {base} import {a.name}")

        def resolve(expr) -> str | None:
            """The corona module an expression names, if it is a chain of module names."""
            if isinstance(expr, ast.Name):
                return aliases.get(expr.id)
            if isinstance(expr, ast.Attribute):
                parent = resolve(expr.value)
                if parent is not None and f"{parent}.{expr.attr}" in modules:
                    return f"{parent}.{expr.attr}"
            return None

        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _private(node.attr):
                module = resolve(node.value)
                if module is not None:
                    check(module, node.attr, node.lineno, f"{module}.{node.attr}")
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                  and node.func.id in ("getattr", "hasattr", "setattr") and len(node.args) >= 2
                  and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)):
                module = resolve(node.args[0])
                if module is not None:
                    check(module, node.args[1].value, node.lineno,
                          f"{node.func.id}({module}, {node.args[1].value!r})")
    return sorted(set(hits))


def test_no_private_name_crosses_a_package():
    hits = cross_package_private_names(SRC)
    assert not hits, ("private names used outside their package; give each a public spelling in "
                      "its home or move it where it is used:\n" + "\n".join(hits))


def test_the_scan_sees_every_kind_of_crossing(tmp_path):
    """Negative control: a synthetic package whose crossings the scan must list, one by one,
    beside uses that the rule allows (siblings, private modules, dunders, public names)."""
    files = {
        "pkg/__init__.py": "from pkg import _infra\n",
        "pkg/_infra.py": "_STATE = {}\nPUBLIC = 1\n",
        "pkg/a/__init__.py": "_A = 1\n",
        "pkg/a/m.py": "_x = 1\n_y = 2\n_z = 3\n_w = 4\n_g = 5\nok = 6\n",
        "pkg/a/sibling.py": "from pkg.a.m import _x\nfrom pkg.a import m\nm._y\nfrom pkg.a import _A\n",
        "pkg/b/__init__.py": "",
        "pkg/b/n.py": textwrap.dedent("""\
            from pkg.a.m import _x, ok
            import pkg.a.m as mm
            from pkg.a import m
            import pkg.a.m
            from pkg import _infra
            from pkg._infra import _STATE, PUBLIC
            from ..a import _A
            mm._y
            m._z
            pkg.a.m._w
            getattr(m, "_g")
            m.__name__
            _infra.PUBLIC
            """),
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    hits = cross_package_private_names(tmp_path, "pkg")
    found = {h.split(": ", 1)[1].split(" (")[0] for h in hits}
    assert found == {
        "from pkg.a.m import _x",
        "from pkg._infra import _STATE",
        "from pkg.a import _A",
        "pkg.a.m._y",
        "pkg.a.m._z",
        "pkg.a.m._w",
        "getattr(pkg.a.m, '_g')",
    }, hits
    assert all(h.startswith("pkg.b.n:") for h in hits), hits
