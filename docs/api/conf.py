"""Sphinx configuration of the corona documentation (``make docs``).

Built with ``sphinx-build -c docs/api docs docs/_build/html``: the source
folder is ``docs/`` (so that ``docs/physics.md`` and the measured figures it
quotes are part of the site with their relative links intact) and this
folder holds the configuration and the API pages.  Neither the build nor
the reader needs a network: no intersphinx, and the math is typeset in the
browser by a copy of MathJax 3 shipped with the pages
(``_static/mathjax``, from the PyPI package ``sphinx-mathjax-offline`` of the
``docs`` extra: the TeX input, the CommonHTML output and its fonts, about 3 MB).
"""
from __future__ import annotations

import inspect
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
# the package is installed editable in .venv; this also works from a bare checkout
sys.path.insert(0, os.path.join(ROOT, "src"))


def _resolve_lazy_exports(package: str) -> None:
    """Names of ``package.__all__`` provided lazily by a module ``__getattr__``
    (``corona.HardDisk``) are not in ``dir(package)``, so autodoc would skip
    them; look each one up once so that it is an ordinary attribute."""
    import importlib
    try:
        module = importlib.import_module(package)
    except Exception:  # autodoc reports the import error on the page itself
        return
    for name in getattr(module, "__all__", ()):
        if name not in vars(module):
            try:
                setattr(module, name, getattr(module, name))
            except Exception:
                pass


_resolve_lazy_exports("corona")

# -- project -----------------------------------------------------------------
project = "corona"
author = "the corona authors"
copyright = "the corona authors"
import corona as _corona  # noqa: E402  (the version's one home: corona.__version__)
release = _corona.__version__
version = release

# -- general -----------------------------------------------------------------
extensions = [
    "myst_parser",            # Markdown (docs/physics.md, docs/validation/README.md, ...)
    "sphinx.ext.autodoc",     # API pages from the docstrings
    "sphinx.ext.napoleon",    # numpy-style docstrings
    "sphinx.ext.mathjax",     # $...$ in the Markdown pages (typeset in the browser by the local MathJax)
    "sphinx.ext.viewcode",    # [source] links
]

root_doc = "index"                 # docs/index.md: the landing page
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
# docs/ holds more than the site: only the pages below are built
include_patterns = ["index.md", "api/**", "install.md", "tutorial.md", "cli.md", "designer.md", "parameters.md",
                    "gallery.md", "physics.md", "layer.md", "tables.md", "mie.md", "volumes.md",
                    "combinations.md", "robustness.md", "validation/README.md", "benchmarks.md",
                    "contributing.md", "adding_a_scatterer.md"]
exclude_patterns = ["_build", "**/.ipynb_checkpoints"]

# MyST: $...$ / $$...$$ math as on GitHub, and GitHub-style anchors for headings
# (docs/physics.md#the-model works both on GitHub and in the built HTML)
myst_enable_extensions = ["dollarmath", "amsmath", "deflist"]
myst_heading_anchors = 4
myst_dmath_double_inline = True

# -- autodoc / napoleon --------------------------------------------------------
autodoc_default_options = {
    "members": True,
    # packages (corona.model.shapes, corona.model.processes, ...) re-export what their
    # submodules define; _only_own_members below keeps numpy & co. out
    "imported-members": True,
    "show-inheritance": True,
    "member-order": "bysource",
}
autodoc_typehints = "description"
autodoc_class_signature = "separated"
autodoc_preserve_defaults = True
autodoc_mock_imports: list[str] = []      # corona and its dependencies are imported for real
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True

# Docstrings use ``×``, ``…`` and Greek letters; keep Sphinx's quotes as written.
smartquotes = False

# docs/benchmarks.md (generated) shows truncated JSON; Pygments then falls back
# to relaxed highlighting, which is fine
suppress_warnings = ["misc.highlighting_failure"]

_documenting = {"module": ""}


def _note_module(app, what, name, obj, options, signature, return_annotation):
    """Remember which module autodoc is documenting (fires before its members)."""
    if what == "module":
        _documenting["module"] = name


def _only_own_members(app, what, name, obj, skip, options):
    """Of a module's classes and functions keep those defined in that module
    or below it (``corona.model.shapes`` keeps ``corona.model.shapes.analytic.Circle``,
    ``corona.model.material`` drops the ``Poisson`` it imports, every module drops
    numpy's and functools' helpers)."""
    if what != "module" or not (inspect.isclass(obj) or inspect.isroutine(obj)):
        return None
    module = getattr(obj, "__module__", None)
    current = _documenting["module"]
    if not isinstance(module, str) or not current:
        return None
    if module == current or module.startswith(current + "."):
        return None
    return True


# The docstrings write |A|, |q|, |Â|² in plain text, which reStructuredText
# reads as substitution references ("Undefined substitution referenced").
# Escape bare bars outside inline literals, roles, literal blocks and
# directives (math, code); line blocks and grid tables are left alone.
_PROTECTED = re.compile(r"(``.+?``|:[\w:.+-]+:`[^`]*`|`[^`]*`_{0,2})")


def _escape_bars(text: str) -> str:
    parts = _PROTECTED.split(text)
    for i in range(0, len(parts), 2):          # even indices: outside literals and roles
        parts[i] = re.sub(r"(?<!\\)\|", r"\\|", parts[i])
    return "".join(parts)


_LITERAL_DIRECTIVES = {"math", "code", "code-block", "sourcecode", "literalinclude", "doctest",
                       "testcode", "testoutput", "highlight", "raw", "parsed-literal"}


def _escape_substitutions(app, what, name, obj, options, lines):
    block_indent = None                        # indentation of the line that opened a block
    for k, line in enumerate(lines):
        stripped = line.strip()
        indent = len(line) - len(line.lstrip())
        if block_indent is not None:
            if not stripped or indent > block_indent:
                continue                       # inside a literal block or directive
            block_indent = None
        if stripped.startswith(("|", "+-", "+=")) or "|" not in line:
            pass
        else:
            lines[k] = _escape_bars(line)
        directive = re.match(r"\.\. ([\w:-]+)::", stripped)
        if directive:
            # math, code and the like hold no reStructuredText; the content of other
            # directives (list-table, note, ...) is parsed and needs the escapes
            if directive.group(1) in _LITERAL_DIRECTIVES:
                block_indent = indent
        elif stripped.endswith("::"):
            block_indent = indent                  # a literal block follows


def _napoleon_except_attributes(app, what, name, obj, options, lines):
    """Napoleon for everything but attributes, data and properties: it reads a
    first line ``text: more text`` of those as ``type: description``, and
    corona's one-line attribute docstrings are prose ("Weight of the delta
    transmission: ``F_a²`` ...")."""
    if what in ("attribute", "data", "property"):
        return
    from sphinx.ext.napoleon import _process_docstring
    _process_docstring(app, what, name, obj, options, lines)


def _allow_reexports() -> None:
    """A class re-exported by two pages (``corona.Circle`` on the top-level
    page, ``corona.model.shapes.Circle`` on its package's page) is documented twice
    with the same ``:canonical:`` name (``corona.model.shapes.analytic.Circle``);
    Sphinx then warns "duplicate object description" for two *aliases*.
    Keep the first alias quietly; real duplicates still warn."""
    from sphinx.domains.python import PythonDomain
    note_object = PythonDomain.note_object
    if getattr(note_object, "_corona_allows_reexports", False):
        return

    def _note_object(self, name, objtype, node_id, aliased=False, location=None):
        other = self.objects.get(name)
        if other is not None and other.aliased and aliased:
            return
        return note_object(self, name, objtype, node_id, aliased=aliased, location=location)

    _note_object._corona_allows_reexports = True
    PythonDomain.note_object = _note_object


def setup(app):
    _allow_reexports()
    app.connect("autodoc-process-signature", _note_module)
    app.connect("autodoc-skip-member", _only_own_members)
    app.connect("autodoc-process-docstring", _escape_substitutions, priority=400)
    # replace napoleon's docstring hook by the one that leaves attributes alone
    # (if a future Sphinx hides its listeners, napoleon simply stays as it is)
    replaced = False
    for listener in list(getattr(app.events, "listeners", {}).get("autodoc-process-docstring", [])):
        if getattr(listener.handler, "__module__", "") == "sphinx.ext.napoleon":
            app.disconnect(listener.id)
            replaced = True
    if replaced:
        app.connect("autodoc-process-docstring", _napoleon_except_attributes)
    app.connect("build-finished", _copy_mathjax)


# -- math: a local MathJax, never a CDN ------------------------------------------
def _mathjax_source() -> str:
    """The MathJax 3 distribution inside the ``sphinx-mathjax-offline`` package."""
    import importlib.util
    spec = importlib.util.find_spec("sphinx-mathjax-offline")
    folder = (os.path.join(os.path.dirname(spec.origin), "static", "mathjax")
              if spec is not None and spec.origin else "")
    if not os.path.isfile(os.path.join(folder, "tex-chtml.js")):
        raise RuntimeError("the docs need a local MathJax: pip install 'corona-bsdf[docs]' "
                           "(the package sphinx-mathjax-offline); make docs installs it")
    return folder


#: What the pages load: the combined TeX -> CommonHTML component, the TeX extensions it
#: loads on demand (\boldsymbol, ...), its fonts, the menu and the assistive MathML.
_MATHJAX_PARTS = ("tex-chtml.js", "input/tex/extensions", "output/chtml/fonts/woff-v2", "ui", "a11y",
                  "adaptors")
_MATHJAX = _mathjax_source()
mathjax_path = "mathjax/tex-chtml.js"         # relative: served from _static/


def _copy_mathjax(app, exception):
    import shutil
    if exception is not None or app.builder.format != "html":
        return
    target = os.path.join(app.outdir, "_static", "mathjax")
    for part in _MATHJAX_PARTS:
        src, dst = os.path.join(_MATHJAX, part), os.path.join(target, part)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        if os.path.isdir(src):
            shutil.copytree(src, dst, dirs_exist_ok=True)
        else:
            shutil.copy2(src, dst)


# -- HTML ---------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"corona {release}"
html_static_path: list[str] = []
html_theme_options = {
    "description": "A wave-optics BSDF for correlated scatterers (Mitsuba 3 plugin)",
    "page_width": "1100px",
    "sidebar_width": "240px",
}
