"""The previous release's module names still import, as the moved modules themselves."""
import importlib
import subprocess
import sys
import warnings

import pytest

from corona import _moved


@pytest.mark.parametrize("old, new", sorted(_moved.MOVED.items()))
def test_old_name_is_the_moved_module(old, new):
    moved = importlib.import_module(new)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sys.modules.pop(old, None)
        alias = importlib.import_module(old)
    assert alias is moved                       # one module object: a monkeypatch is seen everywhere
    assert moved.__name__ == new and moved.__spec__.name == new
    assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught)


def test_old_submodule_names_resolve_to_the_same_objects():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import corona.shapes.base as old
    import corona.model.shapes.base as new
    assert old is new and old.Shape is new.Shape


def test_an_unknown_name_is_still_an_import_error():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("corona.no_such_module")


@pytest.mark.slow
def test_python_m_old_cli_name_runs_the_cli():
    r = subprocess.run([sys.executable, "-m", "corona.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "version" in r.stdout


@pytest.mark.parametrize("old", ["corona.mitsuba_bsdf", "corona.material", "corona.shapes"])
def test_every_old_name_has_moved_and_left_no_file(old):
    import corona
    from pathlib import Path
    root = Path(corona.__file__).parent
    assert not (root / (old.split(".", 1)[1] + ".py")).exists()
    assert _moved.new_name(old) == _moved.MOVED[old]


#: Public names that moved down the tiers in this release, by the module that still gives them.
MOVED_NAMES = {
    "corona.tables": ("corona.model.tabulated", [
        "CACHE_FILE", "D_MAX", "FORMAT_VERSION", "GRID2D_SIZE", "GridTable", "PROGRESS_DELAY", "RADIAL_DU",
        "RADIAL_MAX_SAMPLES", "RADIAL_MIN_UMAX", "ROW_TOLERANCE", "RadialTable", "TABLE_FILE", "WAVELENGTH_MAX",
        "WAVELENGTH_MIN", "bisect_rows", "cache_clear", "cache_dir", "cache_info", "cache_key", "cached",
        "code_key", "radial_cdfs", "radial_totals", "table_from_arrays", "u_max_for", "warp_for",
        "_checksum", "_warned_folders"]),
    "corona.tables.lobe": ("corona.model.render_lobe", [
        "CubicGrid", "EDGE_MAX", "RenderLobe", "SUPERSAMPLE", "TAYLOR_ORDER", "TAYLOR_U", "Term",
        "analytic_terms", "terms_amplitudes"]),
    "corona.apps.sweep": ("corona._executor", [
        "DASK_SCHEMES", "Executor", "Outcome", "TIMEOUT", "TIMEOUT_MAX", "WORKERS_PER_CORE", "default_workers",
        "_cpus", "_WORKER"]),
    "corona.apps.render": ("corona._validation", ["one_line_error"]),
}


@pytest.mark.parametrize("old", sorted(MOVED_NAMES))
def test_moved_names_are_the_same_objects_at_their_old_address(old):
    new, names = MOVED_NAMES[old]
    old_mod, new_mod = importlib.import_module(old), importlib.import_module(new)
    missing = [n for n in names if getattr(old_mod, n, None) is not getattr(new_mod, n)]
    assert not missing, f"{old} no longer gives {new}'s {missing}"


def test_the_renderers_rows_stay_in_the_tables_tier():
    import corona.tables.lobe as rows
    for name in ("region_points", "relative_error", "row_energy_changes", "row_slopes", "structure_rows"):
        assert getattr(rows, name).__module__ == "corona.tables.lobe", name
