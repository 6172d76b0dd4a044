"""The previous release's names are gone in 0.2.0: one home per name, no alias finder.

The lists are written out here (not read from the package) so a name that comes back as an
alias fails this test.
"""
import importlib
import sys

import pytest

import corona

#: The module names of 0.1.0 that moved into the tier folders (CHANGELOG.md, 0.2.0, "Removed").
OLD_MODULES = [
    "corona.shapes", "corona.processes", "corona.mie", "corona.sphere_material", "corona.layer",
    "corona.material", "corona.substrate", "corona.render_lobe", "corona.mitsuba_common",
    "corona.mitsuba_bsdf", "corona.mitsuba_sphere", "corona.mitsuba_phase", "corona.lobe_kernels",
    "corona.volume", "corona.cli", "corona.render", "corona.sweep", "corona.fit", "corona.designer",
    "corona.pictures", "corona.post", "corona.scenes", "corona.micrograph",
    # the re-export package of corona.model.tabulated and its renderer's rows (now corona.model.rows)
    "corona.tables", "corona.tables.lobe",
]


@pytest.mark.parametrize("old", OLD_MODULES + ["corona.shapes.base", "corona.mie.theory"])
def test_old_module_name_is_gone(old):
    sys.modules.pop(old, None)
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


def test_the_sweep_no_longer_gives_the_executors_names():
    # corona.apps.sweep re-exported corona._executor's names; it keeps only those it uses
    from corona.apps import sweep
    gone = ["DASK_SCHEMES", "TIMEOUT", "TIMEOUT_MAX", "WORKERS_PER_CORE", "default_workers", "_cpus"]
    assert [n for n in gone if hasattr(sweep, n)] == []


def test_the_tables_and_rows_have_one_home():
    from corona.model import render_lobe, rows, tabulated
    for name in ("region_points", "relative_error", "row_energy_changes", "row_slopes", "structure_rows"):
        assert getattr(rows, name).__module__ == "corona.model.rows", name
    assert not hasattr(rows, "RenderLobe") and render_lobe.RenderLobe.__module__ == "corona.model.render_lobe"
    assert tabulated.RadialTable.__module__ == "corona.model.tabulated"


def test_no_alias_finder_on_the_meta_path():
    # 0.1.0 put a finder of old names on sys.meta_path at `import corona`
    assert not [f for f in sys.meta_path if type(f).__module__.startswith("corona")]


def test_the_version_is_0_2_0():
    assert corona.__version__ == "0.2.0"
