"""The on-disk table cache under concurrency, truncation and format changes."""
import json
import multiprocessing as mp
import os

import numpy as np
import pytest

from corona import tables


def _build_in_process(args):
    cache, log = args
    os.environ["CORONA_CACHE_DIR"] = cache

    def build():
        import time
        with open(log, "a") as f:
            f.write("built\n")
        time.sleep(0.3)  # wide window for a race
        return {"values": np.linspace(0, 1, 100_000)}

    out = tables.cached({"concurrency": 1}, build)
    return float(out["values"].sum())


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
    tables.cached(params, lambda: {"values": np.ones(3)})
    path = tmp_path / (tables.cache_key(params) + ".npz")
    with np.load(path) as f:
        data = {k: f[k] for k in f.files}
    meta = json.loads(str(data["__meta__"]))
    meta["format"] = tables.FORMAT_VERSION - 1
    data["__meta__"] = np.array(json.dumps(meta))
    np.savez(path, **data)
    out = tables.cached(params, lambda: {"values": np.full(3, 7.0)})
    assert np.all(out["values"] == 7.0)


def test_corrupted_bytes_are_detected(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    params = {"corrupt-test": 1}
    tables.cached(params, lambda: {"values": np.arange(1000.0)})
    path = tmp_path / (tables.cache_key(params) + ".npz")
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # flip one byte inside the array data
    path.write_bytes(bytes(raw))
    out = tables.cached(params, lambda: {"values": np.zeros(1000)})
    assert np.all(out["values"] == 0.0)  # rebuilt, not the damaged bytes


def test_material_tables_come_back_from_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    import corona
    m1 = corona.Material(corona.Circle(1.0), corona.Poisson(0.2))
    v1 = m1.table.values
    assert tables.cache_info()["tables"] == 1
    m2 = corona.Material(corona.Circle(1.0), corona.Poisson(0.2))
    np.testing.assert_array_equal(m2.table.values, v1)
    m3 = corona.Material(corona.Circle(1.1), corona.Poisson(0.2))
    m3.table
    assert tables.cache_info()["tables"] == 2  # another radius, another key
