"""The tests' table cache (scripts/suite_cache.py, set up by ../../conftest.py): kept between runs
outside the clone, one folder per fingerprint of the table-building code.  A table read back from
it equals the one the code builds now, bit for bit, and a change of that code is a new folder."""
import os
import shutil

import numpy as np
import platformdirs
import pytest

import corona
import suite_cache
from corona.model import tabulated
from corona.model.rows import structure_rows


def _hit(monkeypatch, make, get) -> dict:
    """``get(make(True))`` once (built or read), then again from a new object: the second must be
    read from the cache folder, no builder called (``tabulated.cached`` spied on)."""
    get(make(True))
    tabulated.wait_for_writes()
    built = []
    real = tabulated.cached

    def spy(params, build, **kw):
        def counted():
            built.append(params)
            return build()
        return real(params, counted, **kw)
    monkeypatch.setattr(tabulated, "cached", spy)
    out = get(make(True))
    monkeypatch.undo()
    assert built == [], "the second read built a table: not a cache hit"
    return out


def _assert_bitwise(hit: dict, fresh: dict) -> None:
    assert sorted(hit) == sorted(fresh)
    for name in fresh:
        a, b = np.asarray(hit[name]), np.asarray(fresh[name])
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert a.tobytes() == b.tobytes(), f"{name}: the cached table differs from a fresh build"


def _material_arrays(m):
    return dict(m._arrays)


CASES = {
    # a shape's radial rows: the circle's lobe table over hard-disk centres
    "circle radial": (lambda c: corona.Material(corona.Circle(2.0), corona.HardDisk(0.3), use_cache=c),
                      _material_arrays),
    # the hard-disk S(q) rows in area fraction (what an anisotropic shape's F_a texture reads)
    "hard-disk S rows": (lambda c: corona.Material(corona.Square(1.5), corona.HardDisk(0.3), use_cache=c),
                         lambda m: dict(zip(("area_fraction", "s_minus_one", "s_du", "error"),
                                            structure_rows(m, 0.1, 0.3)))),
    # a lattice's 2-D table
    "lattice grid": (lambda c: corona.Material(corona.Square(2.0), corona.Lattice("square", 8.0), use_cache=c),
                     _material_arrays),
    # the Mie rows of a small sphere
    "mie rows": (lambda c: corona.Material(corona.Sphere(0.5), corona.Poisson(0.05), use_cache=c),
                 lambda m: dict(m.rows)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_cache_hit_equals_fresh_build(case, monkeypatch):
    make, get = CASES[case]
    hit = _hit(monkeypatch, make, get)
    fresh = get(make(False))
    _assert_bitwise(hit, fresh)


def test_session_cache_is_the_fingerprint_folder_outside_the_user_cache():
    folder = os.environ["CORONA_CACHE_DIR"]
    assert tabulated.cache_dir() == folder
    assert os.path.basename(folder) == suite_cache.fingerprint()
    assert os.path.dirname(folder) == suite_cache.root()
    user = os.path.realpath(platformdirs.user_cache_dir("corona"))
    real = os.path.realpath(folder)
    assert not (real == user or real.startswith(user + os.sep)), "tests write to the user's cache"
    if not os.environ.get("CORONA_TEST_CACHE"):         # (the default root; a chosen one is the user's call)
        checkout = os.path.realpath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
        assert not real.startswith(checkout + os.sep), "the tests' cache is inside the clone"


def test_fingerprint_changes_with_the_table_building_code(tmp_path):
    src = tmp_path / "corona"
    shutil.copytree(suite_cache.SRC, src, ignore=shutil.ignore_patterns("__pycache__"))
    v = "python x; numpy=1"
    base = suite_cache.fingerprint(str(src), v)
    assert base == suite_cache.fingerprint(str(src), v)                   # deterministic
    assert base == suite_cache.fingerprint(suite_cache.SRC, v)              # the path is not part of it
    # an edit of a table builder (a constant of the Mie rows), a data file, a new module: new folders
    layer = src / "model" / "mie" / "layer.py"
    text = layer.read_text()
    layer.write_text(text.replace("ROW_DX_MIN = 0.005", "ROW_DX_MIN = 0.006", 1))
    assert layer.read_text() != text
    changed = suite_cache.fingerprint(str(src), v)
    assert changed != base
    layer.write_text(text)
    assert suite_cache.fingerprint(str(src), v) == base
    (src / "model" / "processes" / "new_process.py").write_text("X = 1\n")
    assert suite_cache.fingerprint(str(src), v) != base
    (src / "model" / "processes" / "new_process.py").unlink()
    data = src / "data" / "hard_disk_structure_factor.npz"
    data.write_bytes(data.read_bytes() + b"\0")
    assert suite_cache.fingerprint(str(src), v) != base
    shutil.copy(os.path.join(suite_cache.SRC, "data", "hard_disk_structure_factor.npz"), data)
    # another version of a numeric library: a new folder
    assert suite_cache.fingerprint(str(src), "python x; numpy=2") != base
    # the applications build no table: their edits keep the folder
    (src / "apps" / "cli.py").write_text("# edited\n")
    assert suite_cache.fingerprint(str(src), v) == base


def test_prune_and_clear_touch_only_the_test_cache_root(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_TEST_CACHE", str(tmp_path / "root"))
    old = tmp_path / "root" / ("0" * 24)
    old.mkdir(parents=True)
    (old / suite_cache.STAMP).write_text("0\n")
    os.utime(old / suite_cache.STAMP, (0, 0))
    new = suite_cache.folder(suite_cache.SRC)
    assert suite_cache.prune() == [str(old)]
    assert not old.exists() and os.path.isdir(new)
    assert suite_cache.clear() == str(tmp_path / "root")
    assert not (tmp_path / "root").exists() and tmp_path.exists()


def test_prune_keeps_the_most_recently_used_folders_by_count(tmp_path, monkeypatch):
    """Beyond the ``KEEP_COUNT`` newest folders the least recently used go, however young, except
    one used within ``BUSY_HOURS`` (a run may be writing to it); ``numba`` and unstamped folders stay."""
    monkeypatch.setenv("CORONA_TEST_CACHE", str(tmp_path / "root"))
    now = suite_cache.time.time()
    hours = {f"{i:024x}": 3.0 + i for i in range(suite_cache.KEEP_COUNT + 3)}   # 3 h, 4 h, ... old
    busy = "b" * 24                                       # used 10 minutes ago
    for name, age in {**hours, busy: 1 / 6}.items():
        path = tmp_path / "root" / name
        path.mkdir(parents=True)
        (path / suite_cache.STAMP).write_text("x\n")
        os.utime(path / suite_cache.STAMP, (now - age * 3600, now - age * 3600))
    (tmp_path / "root" / "numba").mkdir()
    (tmp_path / "root" / "c").mkdir()                      # no stamp: not a fingerprint folder of ours
    gone = sorted(os.path.basename(p) for p in suite_cache.prune())
    # the busy folder is the newest, so it takes one of the KEEP_COUNT places; the oldest of the rest go
    kept = [busy] + sorted(hours, key=hours.get)[:suite_cache.KEEP_COUNT - 1]
    assert gone == sorted(set(hours) - set(kept))
    assert sorted(os.listdir(tmp_path / "root")) == sorted(kept + ["numba", "c"])
    # a busy folder beyond the count stays: all are made busy, none goes
    for name in kept[1:]:
        os.utime(tmp_path / "root" / name / suite_cache.STAMP, (now, now))
    young = tmp_path / "root" / ("d" * 24)
    young.mkdir()
    (young / suite_cache.STAMP).write_text("x\n")
    os.utime(young / suite_cache.STAMP, (now - 600, now - 600))
    assert suite_cache.prune() == []
    assert suite_cache.prune(keep_count=2, busy_hours=0.0) != []           # the count alone would cut
