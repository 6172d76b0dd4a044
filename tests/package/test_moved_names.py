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
