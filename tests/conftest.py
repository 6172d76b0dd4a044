"""Fixtures shared by the tests, and the check of each collected test's markers.

Markers (registered in pyproject.toml, ``[tool.pytest.ini_options]``), set by hand where the
test is defined (a decorator, or ``pytestmark`` where the whole file is slow):

``chi2``
    runs Mitsuba's chi-square test (:func:`bsdf_checks.run_chi2`);
``render``
    renders an image with Mitsuba (``mi.render``, ``corona render``, a sweep);
``browser``
    drives headless Chromium (the designer's page);
``reference``
    uses the reference tier (``corona.reference``) or an outside reference (miepython);
``slow``
    any of these, or starts Python processes, a Dask cluster or a render through the CLI,
    or is a property test (hypothesis: random materials, a table each), or takes more than
    about 3 s on two shared cores.
``mitsuba``
    runs Mitsuba in the tests' variant: uses the ``mi_variant`` fixture, lives in
    ``tests/plugin``, renders, or takes Dr.Jit derivatives (``scripts/device_check.sh`` runs
    these in ``cuda_ad_spectral`` on a GPU machine).

``make test-fast`` runs ``-m "not slow"``: the physics and the plugin's pointwise checks.
The collection checks the marks (:func:`pytest_collection_modifyitems`): a test whose code
names a chi-square run, a render, the reference tier, a process or cluster, or that takes a
costly fixture, and lacks the mark that says so, stops the session with one error listing
the test ids and the marks to add, so that a new slow test never slips into ``test-fast``.
"""
import os
import sys
import types

# scripts/ (gallery, demo) need a source checkout; the tests run from one
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "scripts"))

# the private table cache and `import corona` before drjit: ../conftest.py
import corona  # noqa: E402,F401
import pytest  # noqa: E402

CHI2_NAMES = {"chi2_test", "chi2_bsdf", "run_chi2", "ChiSquareTest"}
RENDER_NAMES = {"render", "render_linear", "render_point", "render_jobs", "run_sweep", "render_scene"}
REFERENCE_MODULES = ("corona.reference", "miepython")
#: names whose use makes a test slow by itself (processes, clusters, CLI renders)
SLOW_NAMES = {"subprocess", "Executor", "LocalCluster", "running"}
#: fixtures that cost seconds to set up (a cluster, rendered photographs, built layers)
SLOW_FIXTURES = {"cluster", "photographs", "fits", "layers", "driver", "browser",
                 "hd03", "short_run", "reverse", "forward", "dist"}
BROWSER_FILES = {"test_designer_browser.py"}
#: names whose use means Dr.Jit derivatives (a gradient test: ``mitsuba``)
GRADIENT_NAMES = {"backward", "forward", "enable_grad", "backward_from", "forward_to"}
#: a CLI test (CliRunner.invoke, subprocess.run) of one of these commands renders
CLI_RENDERS = {"str:render", "str:sweep"}


def _names(fn, module, depth: int = 2) -> set[str]:
    """Global and attribute names the code of ``fn`` uses, and those of the module-level
    functions of ``module`` it calls, ``depth`` levels down (short string constants as
    ``"str:<text>"``: the command a CLI test invokes)."""
    seen, out, todo = set(), set(), [(getattr(fn, "__code__", None), depth)]
    while todo:
        code, d = todo.pop()
        if code is None or code in seen:
            continue
        seen.add(code)
        out |= set(code.co_names)
        out |= {"str:" + c for c in code.co_consts if isinstance(c, str) and len(c) < 40}
        todo += [(c, d) for c in code.co_consts if isinstance(c, types.CodeType)]   # nested functions
        if d > 0:
            for name in code.co_names:
                g = getattr(module, name, None)
                if isinstance(g, types.FunctionType):
                    todo.append((g.__code__, d - 1))
    return out


def _uses_reference(names: set[str], module) -> bool:
    for name in names:
        g = getattr(module, name, None)
        mod = getattr(g, "__module__", None) or getattr(g, "__name__", None)
        if isinstance(mod, str) and mod.startswith(REFERENCE_MODULES):
            return True
    return "miepython" in names


def required_marks(item) -> set[str]:
    """The marks the code of ``item`` calls for (see the module docstring); empty for doctests."""
    fn = getattr(item, "function", None)
    module = getattr(item, "module", None)
    if fn is None or module is None:
        return set()
    names = _names(fn, module)
    need = set()
    if names & CHI2_NAMES:
        need.add("chi2")
    if names & RENDER_NAMES or ({"invoke", "run"} & names and CLI_RENDERS & names):
        need.add("render")
    if os.path.basename(str(item.fspath)) in BROWSER_FILES:
        need.add("browser")
    if _uses_reference(names, module):
        need.add("reference")
    if need or names & SLOW_NAMES or set(getattr(item, "fixturenames", ())) & SLOW_FIXTURES \
            or getattr(fn, "is_hypothesis_test", False):
        need.add("slow")
    return need


def needs_mitsuba(item) -> bool:
    """Whether ``item`` runs Mitsuba in the tests' variant (the ``mitsuba`` marker, set here: it
    selects what scripts/device_check.sh runs on a GPU, it says nothing of a test's cost)."""
    fn = getattr(item, "function", None)
    module = getattr(item, "module", None)
    if fn is None or module is None:
        return False
    names = _names(fn, module)
    marks = {m.name for m in item.iter_markers()}
    return ("mi_variant" in getattr(item, "fixturenames", ()) or "render" in marks
            or bool(names & RENDER_NAMES) or bool(names & GRADIENT_NAMES)
            or os.path.basename(os.path.dirname(str(item.fspath))) == "plugin")


def pytest_collection_modifyitems(config, items):
    """Check every test's marks against its code (no mark is added here), and count the
    session's chi-square runs (the Sidak correction of :mod:`bsdf_checks`)."""
    import bsdf_checks
    n_chi2, missing = 0, []
    for item in items:
        marks = {m.name for m in item.iter_markers()}
        lacking = required_marks(item) - marks
        if "slow" not in marks and marks & {"chi2", "render", "browser", "reference"}:
            lacking.add("slow")
        if lacking:
            missing.append(f"  {item.nodeid}: add " + ", ".join(f"@pytest.mark.{m}" for m in sorted(lacking)))
        if "mitsuba" not in marks and needs_mitsuba(item):
            item.add_marker(pytest.mark.mitsuba)     # a selection (device_check.sh), not a cost
        if "chi2" in marks:
            n_chi2 += 1
    if missing:
        message = (f"{len(missing)} test(s) lack the marks their code calls for (chi-square runs, "
                   "renders, the reference tier, processes, clusters or costly fixtures are slow; "
                   "tests/conftest.py):\n" + "\n".join(missing)
                   + "\nMark each where it is defined (a decorator, or pytestmark for a whole file).")
        if not hasattr(config, "workerinput"):
            raise pytest.UsageError(message)
        # an xdist worker's UsageError reaches the terminal as a bare INTERNALERROR: there the
        # check is a test of its own that fails with the message, first in every selection
        items.insert(0, MarksCheck.from_parent(items[0].session, name="test_marks_match_the_code",
                                               message=message))
    bsdf_checks.CHI2_SESSION_COUNT = n_chi2


class MarksCheck(pytest.Item):
    """The failed marks check (:func:`pytest_collection_modifyitems`) under pytest-xdist."""

    def __init__(self, *, message: str, **kwargs):
        super().__init__(**kwargs)
        self.message = message

    def runtest(self):
        pytest.fail(self.message, pytrace=False)

    def reportinfo(self):
        return self.path, None, "tests/conftest.py: the marks of the collected tests"


@pytest.fixture(scope="session")
def mi_variant():
    """The default variant (llvm_ad_spectral here), with the plugin registered; the environment
    variable ``CORONA_TEST_VARIANT`` names another (``cuda_ad_spectral`` on a GPU machine:
    scripts/device_check.sh).  CI never sets it: no test depends on a GPU."""
    import mitsuba as mi
    variant = os.environ.get("CORONA_TEST_VARIANT") or corona.default_variant(prefer_gpu=False)
    if variant not in mi.variants():
        raise pytest.UsageError(f"CORONA_TEST_VARIANT={variant!r}: not a Mitsuba variant here "
                                f"(one of {', '.join(mi.variants())})")
    mi.set_variant(variant)
    corona.register()
    return variant


@pytest.fixture
def restored_registry():
    """The registry of families and the spec as they were before the test (a test may register
    families: corona.register_shape)."""
    from corona import parameters
    from corona.model import registry
    SPEC, DEFAULTS = parameters.SPEC, parameters.DEFAULTS
    saved = (dict(registry.SHAPE_FAMILIES), dict(registry.PROCESS_FAMILIES), dict(SPEC), dict(DEFAULTS),
             parameters.PARAMETERS, parameters.SHAPES, parameters.PROCESSES, parameters.MIXTURE_SHAPES,
             set(parameters._FAMILY_SCOPED))
    yield
    for table, old in ((registry.SHAPE_FAMILIES, saved[0]), (registry.PROCESS_FAMILIES, saved[1]),
                       (SPEC, saved[2]), (DEFAULTS, saved[3])):
        table.clear()
        table.update(old)
    (parameters.PARAMETERS, parameters.SHAPES, parameters.PROCESSES, parameters.MIXTURE_SHAPES) = saved[4:8]
    parameters._FAMILY_SCOPED.clear()
    parameters._FAMILY_SCOPED.update(saved[8])


@pytest.fixture(params=[False, True], ids=["in-place", "upload"])
def upload_branch(request, monkeypatch):
    """Both branches of the plugin where it depends on the Dr.Jit backend: LLVM's (tables
    written in place into host arrays, :func:`corona.mitsuba.common.host_buffer`) and CUDA's /
    the scalar variants' (filled in numpy, uploaded), the latter switched on by
    :data:`corona.mitsuba.common.UPLOAD_BRANCH` (environment: ``CORONA_UPLOAD_BRANCH=1``).
    On CUDA both params take the upload branch.  The value: whether the upload branch is forced."""
    from corona.mitsuba import common
    monkeypatch.setattr(common, "UPLOAD_BRANCH", bool(request.param))
    return bool(request.param)
