"""Fixtures shared by the tests, and the markers of each collected test.

Markers (registered in pyproject.toml, ``[tool.pytest.ini_options]``):

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
    or is a property test (hypothesis: random materials, a table each);
``mitsuba``
    runs Mitsuba in the tests' variant: uses the ``mi_variant`` fixture, lives in
    ``tests/plugin``, renders, or takes Dr.Jit derivatives (``scripts/device_check.sh`` runs
    these in ``cuda_ad_spectral`` on a GPU machine).

A test file may set them itself (``pytestmark``, decorators); for the others they are set
here from what the test's code names (the names its function and the module's functions
it calls use), so that a new chi-square or render test is marked without a list to keep.
``make test-fast`` runs ``-m "not slow"``: the physics and the plugin's pointwise checks.
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
#: tests measured above 3 s warm on two shared cores that the rules above miss (a fit, lobe
#: pictures, brute-force lattices, a lattice table, processes building one cache file)
SLOW_TESTS = {"test_fit_window_recovers_radius_area_fraction_and_bitmap", "test_lobe_picture",
              "test_lobe_picture_anisotropic", "test_lattice_table_keeps_each_bragg_peak_weight",
              "test_warped_table_covers_every_evaluated_direction", "test_many_processes_build_one_valid_file",
              "test_extinction_paradox", "test_lattice_matches_brute_force_jittered_lattice",
              # the sphere furnace's numpy sweep (252 incidences each), Percus-Yevick against a
              # simulation, a small `corona validate`, Mie tables between rows, large droplets,
              # RSA to jamming
              "test_furnace_sweep_numpy", "test_percus_yevick_against_simulation", "test_cli_validate",
              "test_table_between_nodes_and_rows_matches_mie", "test_large_droplets_coherent_is_one_minus_fa_squared",
              "test_rsa_saturates_at_jamming_limit",
              # 20 µm droplets with a size spread against brute-force Mie (6000 sizes)
              "test_large_droplet_spread_matches_brute_force_mie",
              # reverse and forward AD of a textured or anisotropic layer (a kernel compiled per
              # case: 1-17 s each on two idle cores)
              "test_derivatives_match_central_differences",
              # spheres on a lattice: an order near grazing exit integrated on a fine polar grid
              "test_grazing_order_energy_and_furnace"}
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


def pytest_collection_modifyitems(config, items):
    """Marks from the code (see the module docstring), and the session's chi-square count."""
    import bsdf_checks
    n_chi2 = 0
    for item in items:
        fn = getattr(item, "function", None)
        module = getattr(item, "module", None)
        if fn is None or module is None:
            continue
        names = _names(fn, module)
        marks = {m.name for m in item.iter_markers()}
        new = set()
        if names & CHI2_NAMES:
            new.add("chi2")
        if names & RENDER_NAMES or ({"invoke", "run"} & names and CLI_RENDERS & names):
            new.add("render")
        if os.path.basename(str(item.fspath)) in BROWSER_FILES:
            new.add("browser")
        if _uses_reference(names, module):
            new.add("reference")
        if "mi_variant" in getattr(item, "fixturenames", ()) or "render" in new | marks \
                or names & GRADIENT_NAMES or os.path.basename(os.path.dirname(str(item.fspath))) == "plugin":
            new.add("mitsuba")
        if (new | marks) & {"chi2", "render", "browser", "reference"} or names & SLOW_NAMES \
                or set(getattr(item, "fixturenames", ())) & SLOW_FIXTURES \
                or getattr(fn, "is_hypothesis_test", False) \
                or item.originalname in SLOW_TESTS:
            new.add("slow")
        for m in sorted(new - marks):
            item.add_marker(getattr(pytest.mark, m))
        if "chi2" in new | marks:
            n_chi2 += 1
    bsdf_checks.CHI2_SESSION_COUNT = n_chi2


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
