"""corona sweep and the Dask executor (corona.apps.sweep): the -D grammar, bad input,
a 2-worker local cluster against a serial run (renders, `corona validate`
cases, hard-disk table rows, RSA table chunks), skipping and --force.

Networking stays on 127.0.0.1.  One cluster serves the whole module."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import types

import numpy as np
import pytest
from click.testing import CliRunner

from corona._executor import Executor
from corona._validation import CoronaError
from corona.apps.cli import main
from corona.apps.sweep import parse_defines, point_name, run_sweep, sweep_points

from bsdf_checks import one_line_error as _one_line_error

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
SCENE = os.path.join(ROOT, "scenes", "sweep_radius.xml")
TINY = {"res": ["16"], "spp": ["4"]}


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker LocalCluster on 127.0.0.1 (one job per worker, 1 Dr.Jit thread each here)."""
    with Executor(workers=2) as ex:
        ex.start()
        yield ex


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _exr(path):
    import mitsuba as mi
    return np.array(mi.Bitmap(str(path)), dtype=np.float32)


# ----------------------------------------------------------------------
# the -D grammar
# ----------------------------------------------------------------------
def test_grid_is_the_cartesian_product_named_by_parameters():
    grid = parse_defines(["radius=2.5, 5,10", "area_fraction=0.1,0.3", "res=32"])
    assert grid == {"radius": ["2.5", "5", "10"], "area_fraction": ["0.1", "0.3"], "res": ["32"]}
    pts = sweep_points(grid)
    assert len(pts) == 6 and pts[0] == {"radius": "2.5", "area_fraction": "0.1", "res": "32"}
    assert pts[1]["area_fraction"] == "0.3" and pts[2]["radius"] == "5"     # last varies fastest
    assert len({tuple(p.values()) for p in pts}) == 6
    assert point_name("s", pts[0]) == "s_radius=2.5_area_fraction=0.1_res=32"
    assert point_name("s", {"f": "a/b c"}) == "s_f=a_b_c"          # no path separators


@pytest.mark.parametrize("bad,match", [
    (["radius"], "expected NAME=V1,V2"),
    (["=1,2"], "parameter name"),
    (["2x=1"], "parameter name"),
    (["radius="], "empty value"),
    (["radius=1,,2"], "empty value"),
    (["radius=1,2,1"], "'1' appears twice"),
    (["radius=1", "radius=2"], "given twice"),
])
def test_malformed_defines(bad, match):
    with pytest.raises(CoronaError, match=match):
        parse_defines(bad)


@pytest.mark.slow
def test_import_corona_does_not_import_dask():
    code = ("import sys, corona, corona.apps.sweep, corona.apps.cli, corona.apps.render; "
            "print(any(m.split('.')[0] in ('distributed', 'dask') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ----------------------------------------------------------------------
# bad input on the command line: one line, exit 2, nothing rendered
# ----------------------------------------------------------------------
def _sweep_cli(*args):
    return CliRunner().invoke(main, ["sweep", SCENE, *args])


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("defines,words", [
    (["-D", "radius"], ["-D 'radius'", "NAME=V1,V2"]),
    (["-D", "radius=1,,2"], ["empty value"]),
    (["-D", "nosuch=1,2"], ["no parameter 'nosuch'", "radius"]),
    ([], ["-D NAME=V1,V2"]),
])
def test_cli_bad_defines(tmp_path, defines, words):
    r = _sweep_cli(*defines, "--out", str(tmp_path / "o"), "--workers", "0")
    _one_line_error(r, *words)
    assert not list(tmp_path.glob("o/*.exr"))


@pytest.mark.slow
@pytest.mark.render
def test_cli_output_folder_not_writable(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = _sweep_cli("-D", "radius=5", "--out", str(blocker / "sub"), "--workers", "0")
    _one_line_error(r, "--out", "not a writable folder")


@pytest.mark.slow
@pytest.mark.render
def test_cli_unreachable_scheduler(tmp_path):
    address = f"tcp://127.0.0.1:{_free_port()}"        # nothing listens there
    r = _sweep_cli("-D", "radius=2.5,5", "-D", "res=16", "--out", str(tmp_path / "o"),
                   "--scheduler", address, "--timeout", "2")
    _one_line_error(r, address, "no Dask scheduler reachable")
    assert not list((tmp_path / "o").glob("*.exr")) and not list((tmp_path / "o").glob("*.json"))
    r = _sweep_cli("-D", "radius=5", "--out", str(tmp_path / "o"), "--scheduler", "tcp://h:port")
    _one_line_error(r, "not a scheduler address")
    r = _sweep_cli("-D", "radius=5", "--workers", "2", "--scheduler", address)
    _one_line_error(r, "exclude each other")


@pytest.mark.slow
@pytest.mark.render
def test_scheduler_without_workers(tmp_path):
    from distributed import LocalCluster
    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=None) as empty:
        r = _sweep_cli("-D", "radius=5", "-D", "res=16", "--out", str(tmp_path / "o"),
                       "--scheduler", empty.scheduler_address, "--timeout", "1")
    _one_line_error(r, "has no workers", "dask worker")
    assert not list((tmp_path / "o").glob("*.exr"))


@pytest.mark.slow
@pytest.mark.render
def test_cli_sweep_on_an_existing_scheduler(tmp_path, cluster):
    """--scheduler: the fixture's cluster seen as a remote one (its workers get the thread plan)."""
    address = cluster.cluster.scheduler_address
    r = _sweep_cli("-D", "radius=5,10", "-D", "res=16", "-D", "spp=2", "--out", str(tmp_path / "o"),
                   "--scheduler", address, "--no-progress")
    assert r.exit_code == 0, r.output
    idx = json.loads((tmp_path / "o" / "sweep_radius_index.json").read_text())
    assert [p["status"] for p in idx["points"]] == ["rendered", "rendered"]
    assert idx["executor"].startswith(f"scheduler {address}: 2 worker(s)")
    assert (tmp_path / "o" / "sweep_radius_radius=10_res=16_spp=2.png").is_file()


# ----------------------------------------------------------------------
# a sweep: serial vs 2-worker cluster, failures, skipping, --force
# ----------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.render
def test_sweep_cluster_matches_serial_then_skips_and_forces(tmp_path, cluster, mi_variant):
    grid = {"radius": ["5", "-1", "2.5"], **TINY}       # radius=-1: a bad point among good ones
    serial = run_sweep(SCENE, grid, str(tmp_path / "serial"), executor=Executor(workers=0),
                       progress=False)
    dist = run_sweep(SCENE, grid, str(tmp_path / "dist"), executor=cluster, progress=False)
    for index in (serial, dist):
        st = [p["status"] for p in index["points"]]
        assert st == ["rendered", "failed", "rendered"]
        bad = index["points"][1]
        assert bad["parameters"]["radius"] == "-1" and "radius=-1" in bad["error"]
        assert os.path.getsize(index["sheet"]) > 1000
        assert json.load(open(index["index"]))["points"][1]["status"] == "failed"
    assert {p["drjit_threads"] for p in dist["points"] if p["status"] == "rendered"} == \
        {max(1, (len(os.sched_getaffinity(0))) // 2)}
    for p in (0, 2):
        name = serial["points"][p]["exr"]
        a, b = _exr(tmp_path / "serial" / name), _exr(tmp_path / "dist" / name)
        assert a.shape == (16, 16, 3) and a.max() > 0
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * a.max())
    # radius 2.5 vs 5: a different picture (the grid really reaches the scene)
    assert not np.allclose(_exr(tmp_path / "serial" / serial["points"][0]["exr"]),
                           _exr(tmp_path / "serial" / serial["points"][2]["exr"]))
    # re-run: the good points exist and are skipped, the failed one is tried again
    exr = tmp_path / "dist" / dist["points"][0]["exr"]
    before = exr.stat().st_mtime_ns
    again = run_sweep(SCENE, grid, str(tmp_path / "dist"), executor=cluster, progress=False)
    assert [p["status"] for p in again["points"]] == ["existing", "failed", "existing"]
    assert exr.stat().st_mtime_ns == before
    forced = run_sweep(SCENE, {"radius": ["5"], **TINY}, str(tmp_path / "dist"), executor=cluster,
                       progress=False, force=True)
    assert [p["status"] for p in forced["points"]] == ["rendered"]
    assert exr.stat().st_mtime_ns > before


@pytest.mark.slow
@pytest.mark.render
def test_cli_sweep_in_process_reports_the_failed_point(tmp_path):
    out = tmp_path / "o"
    r = _sweep_cli("-D", "radius=5,-1", "-D", "res=16", "-D", "spp=2", "--out", str(out),
                   "--workers", "0", "--no-progress")
    _one_line_error(r, "1 of 2 point(s) failed", "radius=-1")
    assert (out / "sweep_radius_radius=5_res=16_spp=2.exr").is_file()
    assert (out / "sweep_radius_sheet.png").is_file()
    idx = json.loads((out / "sweep_radius_index.json").read_text())
    assert [p["status"] for p in idx["points"]] == ["rendered", "failed"]


# ----------------------------------------------------------------------
# the reference tier through the same executor: identical to serial
# ----------------------------------------------------------------------
def _strip_times(obj):
    if isinstance(obj, dict):
        return {k: _strip_times(v) for k, v in obj.items()
                if k not in ("seconds", "brute_seconds", "date")}
    if isinstance(obj, list):
        return [_strip_times(v) for v in obj]
    return obj


@pytest.mark.slow
def test_validate_on_cluster_identical_to_serial(tmp_path, cluster):
    from corona.reference import validate as v
    kw = dict(cases=["circle-poisson-0.30-add"], realisations=2, n_scatterers=64, progress=False,
              echo=lambda s: None)
    a = v.run(str(tmp_path / "a"), executor=Executor(workers=0), **kw)
    b = v.run(str(tmp_path / "b"), executor=cluster, **kw)
    assert len(a["cases"]) == len(b["cases"]) == 1 and "skipped" not in a["cases"][0]
    # the model assumption of this case holds exactly: brute force within its noise
    w = a["cases"][0]["wavelengths"]["550.0"]
    assert w["rms"] < 3 * w["noise"] + 0.01
    ja = _strip_times(json.loads((tmp_path / "a" / "summary.json").read_text()))
    jb = _strip_times(json.loads((tmp_path / "b" / "summary.json").read_text()))
    assert ja == jb
    for c in a["cases"]:
        assert (tmp_path / "a" / c["figure"]).read_bytes() == (tmp_path / "b" / c["figure"]).read_bytes()


def _tiny_hard_disk_settings(eta):
    return dict(n_disks=64, n_sweeps=100, n_equilibration=50, sample_every=25, n_chains=2,
                q_sigma_max=42.0, bin_width=0.05, seed=11 + int(round(1000 * eta)))


@pytest.mark.slow
def test_hard_disk_rows_on_cluster_identical_to_serial(tmp_path, cluster):
    import make_hard_disk_table as T
    etas = [0.3, 0.5]
    a = T.simulate_rows(etas, str(tmp_path / "a"), Executor(workers=0), progress=False,
                        settings=_tiny_hard_disk_settings)
    b = T.simulate_rows(etas, str(tmp_path / "b"), cluster, progress=False,
                        settings=_tiny_hard_disk_settings)
    for ra, rb, eta in zip(a, b, etas):
        assert float(ra["eta"]) == eta and np.isfinite(ra["Z"]) and ra["Z"] > 1
        for k in ra:
            if k not in ("cpu", "wall"):
                np.testing.assert_array_equal(np.asarray(rb[k]), np.asarray(ra[k]), err_msg=k)
        with np.load(T.row_file(str(tmp_path / "b"), eta)) as z:     # stored by the client
            np.testing.assert_array_equal(z["S"], ra["S"])


@pytest.mark.slow
def test_rsa_chunks_on_cluster_identical_to_serial(cluster):
    import make_rsa_table as T
    args = types.SimpleNamespace(box=10.0, runs=4, chunk=2, kcut=4.5, dr=0.05, rmax=3.0, seed=5)
    a = T.simulate(args, Executor(workers=0), progress=False)
    b = T.simulate(args, cluster, progress=False)
    assert a["nsat"].shape == (4,) and np.all(a["nsat"] > 40)    # saturated: ~0.547 L²/(π/4) = 70
    for k in ("sk_sum", "sk_sq", "H", "ideal", "nsat"):
        np.testing.assert_array_equal(b[k], a[k], err_msg=k)
    # the chunks add up to one run after the other (the old serial loop)
    whole = T.simulate(types.SimpleNamespace(**{**vars(args), "chunk": 4}), Executor(workers=0),
                       progress=False)
    np.testing.assert_allclose(whole["sk_sum"], a["sk_sum"], rtol=1e-12)
    np.testing.assert_array_equal(whole["H"], a["H"])


# ----------------------------------------------------------------------
# hostile schedulers and sizes: one line, exit 2, within --timeout
# ----------------------------------------------------------------------
@pytest.fixture
def silent_listener():
    """tcp://127.0.0.1:PORT of a listener that accepts every connection and never answers."""
    import threading
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(16)
    held = []

    def accept():
        while True:
            try:
                held.append(srv.accept()[0])
            except OSError:
                return
    threading.Thread(target=accept, daemon=True).start()
    yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    srv.close()
    for c in held:
        c.close()


@pytest.mark.slow
@pytest.mark.render
def test_a_scheduler_that_accepts_and_never_answers(tmp_path, silent_listener):
    """Dask's Client waited without end (or a TimeoutError traceback from client.close())."""
    import time
    t0 = time.monotonic()
    r = _sweep_cli("-D", "radius=2.5,5", "-D", "res=16", "--out", str(tmp_path / "o"),
                   "--scheduler", silent_listener, "--timeout", "2")
    assert time.monotonic() - t0 < 2 + 3, time.monotonic() - t0
    _one_line_error(r, silent_listener, "did not answer as a Dask scheduler within 2 s")
    assert not list((tmp_path / "o").glob("*.exr"))


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("address", ["http://127.0.0.1:9", "https://example.com/dask", "ftp://h:1"])
def test_a_non_dask_scheduler_address_is_refused_at_once(tmp_path, address):
    import time
    t0 = time.monotonic()
    r = _sweep_cli("-D", "radius=5", "--out", str(tmp_path / "o"), "--scheduler", address, "--timeout", "30")
    assert time.monotonic() - t0 < 2.0
    _one_line_error(r, address, "not a Dask scheduler address", "tcp://")
    with pytest.raises(CoronaError, match="not a Dask scheduler address"):
        Executor(scheduler=address)


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "0", "-1", "1e308"])
def test_timeout_must_be_finite_and_positive(tmp_path, value):
    r = _sweep_cli("-D", "radius=5", "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9",
                   "--timeout", value)
    _one_line_error(r, "--timeout", "finite")
    with pytest.raises(CoronaError, match="timeout=.*finite"):
        Executor(scheduler="tcp://127.0.0.1:9", timeout=float(value))


@pytest.mark.slow
@pytest.mark.render
def test_many_local_workers_are_capped_at_the_points_and_cores(tmp_path, monkeypatch):
    """--workers 1000 on a two-point sweep started 1000 processes on 2 cores (a hang): the local
    cluster gets at most one worker per point and WORKERS_PER_CORE per core, said in one line."""
    import distributed

    from corona import _executor
    asked = {}

    class Recorder:
        def __init__(self, n_workers, **kwargs):
            asked["n"] = n_workers
            raise CoronaError("stop here: the size is what this test checks")
    monkeypatch.setattr(distributed, "LocalCluster", Recorder)
    logged = []
    with pytest.raises(CoronaError, match="stop here"):
        Executor(workers=1000, log=logged.append).start(n_tasks=2)
    assert asked["n"] == 2 and any("capped to 2" in s for s in logged), (asked, logged)
    with pytest.raises(CoronaError, match="stop here"):
        Executor(workers=1000).start(n_tasks=10**6)
    assert asked["n"] == _executor.WORKERS_PER_CORE * _executor._cpus()
    r = _sweep_cli("-D", "radius=2.5,5", "--out", str(tmp_path / "o"), "--workers", "1000")
    _one_line_error(r, "stop here")
    assert asked["n"] == 2
