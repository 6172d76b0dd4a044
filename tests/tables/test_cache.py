"""The on-disk table cache under concurrency, truncation and format changes."""
import json
import mmap
import multiprocessing as mp
import os

import numpy as np
import pytest

from corona._validation import CoronaError
from corona.model import tabulated


def _build_in_process(args):
    cache, log = args
    os.environ["CORONA_CACHE_DIR"] = cache

    def build():
        import time
        with open(log, "a") as f:
            f.write("built\n")
        time.sleep(0.3)  # wide window for a race
        return {"values": np.linspace(0, 1, 100_000)}

    out = tabulated.cached({"concurrency": 1}, build)
    return float(out["values"].sum())


@pytest.mark.slow
def test_many_processes_build_one_valid_file(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    log = tmp_path / "log"
    with mp.get_context("spawn").Pool(4) as pool:
        sums = pool.map(_build_in_process, [(str(cache), str(log))] * 8)
    assert len(set(sums)) == 1 and sums[0] == pytest.approx(50_000.0)
    assert log.read_text().count("built") == 1  # the lock serialised the builders
    files = [f for f in os.listdir(cache) if f.endswith(".npz")]
    assert len(files) == 1 and not any(f.startswith(".tmp-") for f in os.listdir(cache))


def test_older_format_is_rebuilt_not_misread(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    params = {"format-test": 1}
    tabulated.cached(params, lambda: {"values": np.ones(3)})
    path = tmp_path / (tabulated.cache_key(params) + ".npz")
    with np.load(path) as f:
        data = {k: f[k] for k in f.files}
    meta = json.loads(str(data["__meta__"]))
    meta["format"] = tabulated.FORMAT_VERSION - 1
    data["__meta__"] = np.array(json.dumps(meta))
    np.savez(path, **data)
    out = tabulated.cached(params, lambda: {"values": np.full(3, 7.0)})
    assert np.all(out["values"] == 7.0)


def test_corrupted_bytes_are_detected(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    params = {"corrupt-test": 1}
    tabulated.cached(params, lambda: {"values": np.arange(1000.0)})
    path = tmp_path / (tabulated.cache_key(params) + ".npz")
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # flip one byte inside the array data
    path.write_bytes(bytes(raw))
    out = tabulated.cached(params, lambda: {"values": np.zeros(1000)})
    assert np.all(out["values"] == 0.0)  # rebuilt, not the damaged bytes


def test_material_tables_come_back_from_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    import corona
    m1 = corona.Material(corona.Circle(1.0), corona.Poisson(0.2))
    v1 = m1.table.values
    assert tabulated.cache_info()["tables"] == 1
    m2 = corona.Material(corona.Circle(1.0), corona.Poisson(0.2))
    np.testing.assert_array_equal(m2.table.values, v1)
    m3 = corona.Material(corona.Circle(1.1), corona.Poisson(0.2))
    m3.table
    assert tabulated.cache_info()["tables"] == 2  # another radius, another key


# --------------------------------------------------------------------------
# interrupted writers
# --------------------------------------------------------------------------
_KILLED_WRITER = r"""
import io, os, sys, time
import numpy as np
from corona.model import tabulated
from corona._validation import CoronaError

signal, stage = sys.argv[1], sys.argv[2]
real_savez = np.savez

def half_savez(f, **arrays):
    # write half of the file, then hang: the parent kills us mid-write
    buf = io.BytesIO()
    real_savez(buf, **arrays)
    data = buf.getvalue()
    f.write(data[: len(data) // 2])
    f.flush()
    open(signal, "w").write("writing")
    time.sleep(600)

def slow_build():
    # hang while building (holding the lock)
    open(signal, "w").write("building")
    time.sleep(600)
    return {"values": np.arange(100_000.0)}

if stage == "write":
    np.savez = half_savez
    tabulated.cached({"killed-writer": 1}, lambda: {"values": np.arange(100_000.0)})
else:
    tabulated.cached({"killed-writer": 1}, slow_build)
"""


def _start_and_kill(tmp_path, stage):
    """Start a writer in another process and SIGKILL it at ``stage`` ('write' or 'build')."""
    import signal as sig
    import subprocess
    import sys
    import time
    signal_file = tmp_path / f"signal-{stage}"
    env = {**os.environ, "CORONA_CACHE_DIR": str(tmp_path)}
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(signal_file), stage], env=env)
    try:
        t0 = time.time()
        while not signal_file.exists():
            assert proc.poll() is None, "the writer exited early"
            assert time.time() - t0 < 120, "the writer never started"
            time.sleep(0.05)
    finally:
        proc.send_signal(sig.SIGKILL)
        proc.wait(30)
    assert proc.returncode == -sig.SIGKILL


def _cached_with_timeout(params, build, seconds=60):
    """``tabulated.cached`` in a thread: a lock left by a dead writer must not block."""
    import concurrent.futures
    with concurrent.futures.ThreadPoolExecutor(1) as ex:
        return ex.submit(tabulated.cached, params, build).result(timeout=seconds)


@pytest.mark.slow
def test_writer_killed_mid_write_leaves_no_table(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    _start_and_kill(tmp_path, "write")
    names = os.listdir(tmp_path)
    params = {"killed-writer": 1}
    final = tabulated.cache_key(params) + ".npz"
    assert final not in names                       # atomic: only the temporary file exists
    assert any(n.startswith(".tmp-") for n in names)
    assert tabulated.cache_info()["tables"] == 0       # the half-written temporary is not a table
    out = _cached_with_timeout(params, lambda: {"values": np.full(10, 3.0)})
    assert np.all(out["values"] == 3.0)             # rebuilt, not the half-written bytes
    assert tabulated.cache_info()["tables"] == 1
    assert not any(n.startswith(".tmp-") for n in os.listdir(tmp_path))   # the stale temporary is gone
    assert np.all(tabulated.cached(params, lambda: pytest.fail("rebuilt twice"))["values"] == 3.0)
    assert tabulated.cache_clear() == 1 and not [n for n in os.listdir(tmp_path) if n.endswith(".npz")]


def test_cache_clear_counts_tables_not_temporaries(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    tabulated.cached({"clear-test": 1}, lambda: {"values": np.ones(3)})
    (tmp_path / f".tmp-{'deadbeef' * 4}-x1y2.npz").write_bytes(b"half")   # a killed writer's
    assert tabulated.cache_info()["tables"] == 1
    assert tabulated.cache_clear() == 1 and os.listdir(tmp_path) == []


@pytest.mark.slow
def test_builder_killed_while_holding_the_lock(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    _start_and_kill(tmp_path, "build")
    out = _cached_with_timeout({"killed-writer": 1}, lambda: {"values": np.full(10, 5.0)})
    assert np.all(out["values"] == 5.0)


@pytest.mark.parametrize("mapped", [False, True], ids=["read", "mapped"])
@pytest.mark.parametrize("damage", ["empty", "truncated", "garbage", "no-meta", "wrong-key", "flipped"])
def test_damaged_file_is_rebuilt(tmp_path, monkeypatch, damage, mapped):
    """A truncated or otherwise damaged table (e.g. written by a non-atomic copy) is rebuilt,
    whether read or mapped from its file (a large table: ``MAP_BYTES``)."""
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(tabulated, "MAP_BYTES", 0 if mapped else 1 << 60)
    params = {"damage-test": 1}
    tabulated.cached(params, lambda: {"values": np.arange(5000.0)})
    path = tmp_path / (tabulated.cache_key(params) + ".npz")
    raw = path.read_bytes()
    if damage == "empty":
        path.write_bytes(b"")
    elif damage == "truncated":
        path.write_bytes(raw[: len(raw) - 100])
    elif damage == "garbage":
        path.write_bytes(os.urandom(len(raw)))
    elif damage == "no-meta":
        np.savez(path, values=np.arange(5000.0))
    elif damage == "flipped":                   # one byte inside the array data
        path.write_bytes(raw[:len(raw) // 2] + bytes([raw[len(raw) // 2] ^ 0xFF]) + raw[len(raw) // 2 + 1:])
    else:  # a valid table of another key copied over this one
        other = {"damage-test": 2}
        tabulated.cached(other, lambda: {"values": np.zeros(5000)})
        path.write_bytes((tmp_path / (tabulated.cache_key(other) + ".npz")).read_bytes())
    out = tabulated.cached(params, lambda: {"values": np.full(5000, 9.0)})
    assert np.all(out["values"] == 9.0)
    assert np.all(tabulated.cached(params, lambda: pytest.fail("rebuilt twice"))["values"] == 9.0)


def test_radial_cdfs_and_totals_are_radial_tables_row_by_row():
    """The batch CDFs equal RadialTable's bit for bit (negative values clipped), the totals to
    rounding; a row of zeros stays 0."""
    rng = np.random.default_rng(7)
    rows = rng.normal(1.0, 1.0, (9, 57))
    rows[3] = 0.0
    cdfs = tabulated.radial_cdfs(0.013, rows)
    totals = tabulated.radial_totals(0.013, rows)
    for row, cdf, total in zip(rows, cdfs, totals):
        ref = tabulated.RadialTable(0.013, row)
        assert np.array_equal(cdf, ref.cdf)
        assert total == pytest.approx(ref.total, rel=1e-13, abs=1e-300)
    assert totals[3] == 0.0 and np.all(cdfs[3] == 0.0)
    with pytest.raises(ValueError, match="rows"):
        tabulated.radial_cdfs(0.1, rows[0])
    # rows in several blocks (the last one partial): still RadialTable's bits, row by row
    many = rng.normal(1.0, 1.0, (1500, 57)) * np.exp(rng.uniform(-20.0, 5.0, (1500, 57)))
    assert many.size > 2 * tabulated.RADIAL_CDF_BLOCK
    for row, cdf in zip(many, tabulated.radial_cdfs(0.013, many)):
        assert np.array_equal(cdf, tabulated.RadialTable(0.013, row).cdf)


def test_code_key_follows_the_code():
    """code_key: the same for the same code, another for a changed constant or a changed
    nested function (the cache key of tables derived by that code)."""
    def f(x):
        return x + 1

    def g(x):
        return x + 2

    def outer_a(x):
        def inner(y):
            return y * 3
        return inner(x)

    def outer_b(x):
        def inner(y):
            return y * 4
        return inner(x)
    assert tabulated.code_key(f) == tabulated.code_key(f)
    assert tabulated.code_key(f) != tabulated.code_key(g)
    assert tabulated.code_key(outer_a) != tabulated.code_key(outer_b)
    assert tabulated.code_key(f, g) != tabulated.code_key(g, f)
    assert tabulated.code_key(tabulated.RadialTable.__post_init__) == tabulated.code_key(tabulated.RadialTable.__post_init__)


def test_checksum_is_that_of_the_bytes():
    """The checksum (no copy of the arrays) is sha256 over names, dtypes, shapes and the bytes,
    as written before: tables cached by an earlier release stay valid; any changed byte differs."""
    import hashlib
    arrays = {"a": np.arange(12.0).reshape(3, 4)[:, ::2], "b": np.zeros((0, 3)), "c": np.array(2.5),
              "d": np.array([True, False]), "e": np.arange(5, dtype=np.uint32)}
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        for part in (name.encode(), str(a.dtype).encode(), str(a.shape).encode(), a.tobytes()):
            h.update(part)
    assert tabulated._checksum(arrays) == h.hexdigest()
    changed = dict(arrays, e=np.array([0, 1, 2, 3, 5], dtype=np.uint32))
    assert tabulated._checksum(changed) != h.hexdigest()


def _background_build(cache, log):
    os.environ["CORONA_CACHE_DIR"] = cache

    def build():
        with open(log, "a") as f:
            f.write("built\n")
        return {"values": np.linspace(0, 1, 2_000_000)}

    out = tabulated.cached({"background": 1}, build, background=True)
    return float(out["values"].sum())


@pytest.mark.slow     # starts a pool of three Python processes
def test_background_write_is_waited_for_and_exact(tmp_path, monkeypatch):
    """``cached(..., background=True)``: the table is written by the writer thread while the caller
    goes on. A second call of the key in the same process, made at once, waits for the file (the
    key's lock) and reads it back without building; processes started while it is written do too
    (one build in all); the process's exit waits for the write; the file holds the table."""
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    made = []
    first = tabulated.cached({"bg": 1}, lambda: made.append(1) or {"values": np.arange(3_000_000.0)}, background=True)
    again = tabulated.cached({"bg": 1}, lambda: pytest.fail("built twice"), background=True)
    assert made == [1] and np.array_equal(first["values"], again["values"])
    tabulated.wait_for_writes()
    path = tmp_path / (tabulated.cache_key({"bg": 1}) + ".npz")
    assert tabulated._read(str(path), tabulated.cache_key({"bg": 1})) is not None
    # other processes against a background writer: one build, every process the same table
    cache, log = tmp_path / "procs", tmp_path / "log"
    cache.mkdir()
    pool = mp.get_context("spawn").Pool(3)
    sums = pool.starmap(_background_build, [(str(cache), str(log))] * 6)
    pool.close()
    pool.join()                          # the workers exit normally: their writer threads are joined
    assert len(set(sums)) == 1 and sums[0] == pytest.approx(1_000_000.0)
    assert log.read_text().count("built") == 1
    names = os.listdir(cache)
    assert len([n for n in names if n.endswith(".npz")]) == 1 and not any(n.startswith(".tmp-") for n in names)


def test_background_write_of_a_table_changed_meanwhile_is_not_served(tmp_path, monkeypatch):
    """The checksum is the built table's: a caller that (against the rule) writes into the arrays
    while the writer thread saves them leaves a file that fails its checksum, rebuilt when read,
    never served with the changed values under the old checksum. Negative control: unchanged, the
    file is read back."""
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    gate = __import__("threading").Event()
    real = tabulated._write_atomic

    def slow_write(*args, **kwargs):          # the write waits until the caller has changed the table
        gate.wait(10)
        return real(*args, **kwargs)
    monkeypatch.setattr(tabulated, "_write_atomic", slow_write)
    out = tabulated.cached({"bg-changed": 1}, lambda: {"values": np.zeros(1000)}, background=True)
    out["values"][:] = 5.0
    gate.set()
    tabulated.wait_for_writes()
    monkeypatch.setattr(tabulated, "_write_atomic", real)
    rebuilt = tabulated.cached({"bg-changed": 1}, lambda: {"values": np.full(1000, 2.0)})
    assert np.all(rebuilt["values"] == 2.0)
    # negative control: the same without the change is read back, not rebuilt
    gate.set()
    tabulated.cached({"bg-kept": 1}, lambda: {"values": np.ones(1000)}, background=True)
    tabulated.wait_for_writes()
    assert np.all(tabulated.cached({"bg-kept": 1}, lambda: pytest.fail("rebuilt"))["values"] == 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("empty", ["", "  "])
def test_an_empty_cache_variable_never_clears_the_user_cache(tmp_path, empty):
    """``CORONA_CACHE_DIR= corona tables clear`` cleared the user's real cache (an empty value
    was taken as unset): now one line, exit 2, and the user cache keeps its table.  Negative
    control: with the variable unset, the same command does clear that folder (the test's
    ``XDG_CACHE_HOME`` is where the default cache lives)."""
    import subprocess
    import sys
    user_cache = tmp_path / "xdg" / "corona"
    user_cache.mkdir(parents=True)
    table = user_cache / ("0" * 32 + ".npz")
    table.write_bytes(b"a table")
    env = {k: v for k, v in os.environ.items() if k != "CORONA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    cmd = [sys.executable, "-m", "corona.apps.cli", "tables", "clear"]
    r = subprocess.run(cmd, env={**env, "CORONA_CACHE_DIR": empty}, capture_output=True, text=True)
    assert r.returncode == 2 and "CORONA_CACHE_DIR" in r.stderr and "empty" in r.stderr, r.stderr
    assert r.stderr.strip().count("\n") == 0
    assert table.exists()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert r.returncode == 0 and "removed 1 table" in r.stdout, r.stderr
    assert not table.exists()


def test_an_empty_cache_variable_builds_in_memory_with_a_warning(monkeypatch):
    """Tables asked for with an empty ``CORONA_CACHE_DIR`` are built in memory (one warning naming
    the variable), never read from or written to the default cache."""
    monkeypatch.setenv("CORONA_CACHE_DIR", "")
    monkeypatch.setattr(tabulated, "_warned_folders", set())
    with pytest.raises(CoronaError, match="empty"):
        tabulated.cache_dir()
    with pytest.warns(RuntimeWarning, match="CORONA_CACHE_DIR='' is empty"):
        out = tabulated.cached({"empty-variable": 1}, lambda: {"values": np.arange(3.0)})
    assert out["values"].tolist() == [0.0, 1.0, 2.0]


def test_a_mapped_table_equals_the_written_one(tmp_path, monkeypatch):
    """A large table is mapped from its file (:func:`corona.model.tabulated._load_mapped`): the same
    arrays as ``np.load`` gives (dtypes, shapes, Fortran order, 0-d and empty arrays), writable,
    and a write to them changes neither the file nor a later read; a file replaced while mapped
    leaves the mapped arrays as they were."""
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(tabulated, "MAP_BYTES", 0)
    rng = np.random.default_rng(1)
    arrays = {"P": rng.random((37, 53)), "cdf": rng.random(1001).astype(np.float32),
              "guide": rng.integers(0, 2**32 - 1, 999, dtype=np.uint32), "G": np.array(17),
              "empty": np.zeros((0, 5)), "fortran": np.asfortranarray(rng.random((6, 7))),
              "s0": rng.random((3, 2)) + 1j * rng.random((3, 2))}
    params = {"mapped-test": 1}
    tabulated.cached(params, lambda: {k: v.copy() for k, v in arrays.items()})
    path = tmp_path / (tabulated.cache_key(params) + ".npz")
    with np.load(path) as f:
        assert sorted(f.files) == sorted([*arrays, "__meta__"])
    out = tabulated.cached(params, lambda: pytest.fail("a valid table rebuilt"))
    assert isinstance(out["P"].base, mmap.mmap)              # mapped, not read
    for k, v in arrays.items():
        assert out[k].dtype == v.dtype and out[k].shape == v.shape and np.array_equal(out[k], v), k
        assert out[k].flags.writeable
    out["P"][:] = -1.0
    again = tabulated.cached(params, lambda: pytest.fail("rebuilt after a write to a mapped array"))
    assert np.array_equal(again["P"], arrays["P"])
    tabulated._write_atomic(str(path), tabulated.cache_key(params), {"P": np.zeros((2, 2))})
    assert np.array_equal(again["P"], arrays["P"])         # the old file's pages
    assert np.array_equal(tabulated._read(str(path), tabulated.cache_key(params))["P"], np.zeros((2, 2)))
