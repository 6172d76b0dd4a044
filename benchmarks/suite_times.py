"""The test suite's wall time and item counts, cold (an empty tests' table cache) and warm (the same cache again).

    python benchmarks/suite_times.py [-m EXPR | --full] [-n WORKERS] [--runs cold,warm] [--cache DIR]
                                     [--label TEXT] [--note TEXT] [--log DIR] [--pytest-args ARGS]

Runs ``pytest -n WORKERS -q -p no:cacheprovider -m EXPR tests`` (default ``-n 2 -m "not slow"``:
what ``make test-fast`` runs; ``--full``: ``pytest -n 2 -q``, what ``make test`` runs) with
``CORONA_TEST_CACHE`` at ``DIR`` (default: a new temporary folder): ``cold`` empties it first,
``warm`` reuses it.  Before the runs one collection (``--collect-only``, with this file as a pytest
plugin: :func:`pytest_collection_finish`) counts the items the expression selects and the items of
each marker (``slow``, ``chi2``, ``render``, ...) in the whole suite.  Records each run's wall time,
the CPU time of pytest and its workers (``RUSAGE_CHILDREN``), the load averages (1, 5, 15 min) before
and after and pytest's summary line, with the counts and the machine (common.write), into
benchmarks/results/suite_times.json; runs of other labels already there are kept.  Not run by
``make bench`` (it is not a ``bench_*.py``): it takes minutes.  The goals (issue 44): ``make test``
<= 12 min cold, <= 8 min warm; ``make test-fast`` <= 3 min cold, <= 60 s warm, on two idle cores
from a fresh clone.  On a shared machine read the CPU time and the load.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from common import RESULTS, write  # noqa: E402

GOALS_S = {"test-fast cold": 180, "test-fast warm": 60, "test cold": 720, "test warm": 480}
#: the markers whose items the collection counts (tests/conftest.py says what each means)
MARKERS = ("slow", "chi2", "render", "browser", "reference", "mitsuba")
#: the environment variable naming the file the collection plugin writes its counts to
COUNTS_ENV = "CORONA_SUITE_TIMES_COUNTS"


def pytest_collection_finish(session):
    """(pytest plugin, ``-p suite_times``) The counts of the collected items, into ``$COUNTS_ENV``:
    ``selected`` (what ``-m`` kept) and, per marker of :data:`MARKERS`, the items that carry it
    (over the selection)."""
    path = os.environ.get(COUNTS_ENV)
    if not path:
        return
    items = session.items
    counts = {"selected": len(items)}
    for name in MARKERS:
        counts[name] = sum(1 for it in items if it.get_closest_marker(name) is not None)
    with open(path, "w") as f:
        json.dump(counts, f)


def _env(cache: str) -> dict:
    env = {**os.environ, "CORONA_TEST_CACHE": cache,
           "PYTHONPATH": os.pathsep.join([os.path.join(ROOT, "src"), HERE]
                                         + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    env.pop("CORONA_CACHE_DIR", None)       # the root conftest.py sets its own (the fingerprint folder)
    return env


def count_items(marker: str | None, cache: str) -> dict:
    """One ``--collect-only`` run: the items selected by ``marker`` and, over the whole suite, per marker."""
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key, expr in (("suite", None), ("selection", marker)):
            if key == "selection" and marker is None:
                break
            path = os.path.join(tmp, f"{key}.json")
            cmd = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                   "-p", "suite_times"] + (["-m", expr, "tests"] if expr else [])
            p = subprocess.run(cmd, cwd=ROOT, env={**_env(cache), COUNTS_ENV: path},
                               capture_output=True, text=True)
            if p.returncode != 0 or not os.path.exists(path):
                raise SystemExit(f"collection failed ({' '.join(cmd[1:])}):\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
            with open(path) as f:
                out[key] = json.load(f)
    return out


def run(args: list[str], cache: str, log: str | None = None) -> dict:
    """One pytest run: wall and CPU time, the load before and after; ``log``: a file for pytest's output."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    p = subprocess.run(args, cwd=ROOT, env=_env(cache), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    load1 = os.getloadavg()
    if log:
        with open(log, "w") as f:
            f.write(p.stdout + p.stderr)
    lines = [x for x in p.stdout.strip().splitlines() if x.strip()]
    summary = lines[-1] if lines else p.stderr[-300:]
    passed = re.search(r"(\d+) passed", summary)
    return {"wall_s": round(wall, 1),
            "cpu_s": round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 1),
            "load_average_1min": [round(load0[0], 1), round(load1[0], 1)],
            "load_average_1_5_15min": {"start": [round(x, 1) for x in load0], "end": [round(x, 1) for x in load1]},
            "returncode": p.returncode, "passed": int(passed.group(1)) if passed else 0, "summary": summary}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-m", dest="marker", default="not slow", help="the marker expression (default: 'not slow')")
    ap.add_argument("--full", action="store_true", help="the whole suite (make test): no -m, no 'tests' path")
    ap.add_argument("-n", dest="workers", type=int, default=2, help="pytest-xdist workers (default 2, as make)")
    ap.add_argument("--runs", default="cold,warm")
    ap.add_argument("--cache", default=None, help="the tests' cache root (default: a new temporary folder)")
    ap.add_argument("--label", default=None, help="the result's name prefix (default: test-fast / test)")
    ap.add_argument("--note", default=None, help="a note stored with these runs (the machine's load, ...)")
    ap.add_argument("--log", default=None, help="a folder for each run's pytest output (<label> <run>.txt)")
    ap.add_argument("--pytest-args", default="", help="more pytest arguments, e.g. '--durations=0' (split on spaces)")
    args = ap.parse_args()
    cache = args.cache or tempfile.mkdtemp(prefix="corona-suite-times-")
    marker = None if args.full else args.marker
    kind = "test" if args.full else ("test-fast" if marker == "not slow" else f"-m {marker}")
    label = args.label or kind
    cmd = [sys.executable, "-m", "pytest", "-n", str(args.workers), "-q", "-p", "no:cacheprovider"]
    cmd += [] if marker is None else ["-m", marker, "tests"]
    cmd += args.pytest_args.split()
    path = os.path.join(RESULTS, "suite_times.json")
    data = {}
    if os.path.exists(path):
        with open(path) as f:
            data = json.load(f)
    data.pop("machine", None)
    data.setdefault("results", {})
    counts = count_items(marker, cache)
    data["items"] = counts["suite"]
    for which in args.runs.split(","):
        if which == "cold":
            shutil.rmtree(cache, ignore_errors=True)
        log = None
        if args.log:
            os.makedirs(args.log, exist_ok=True)
            log = os.path.join(args.log, f"{label} {which}.txt".replace(" ", "_"))
        r = run(cmd, cache, log)
        r.update(command=" ".join(["python"] + cmd[1:]), marker=marker or "", workers=args.workers,
                 items=counts.get("selection", counts["suite"])["selected"])
        if f"{kind} {which}" in GOALS_S and args.workers == 2:
            r["goal_s"] = GOALS_S[f"{kind} {which}"]
        if args.note:
            r["note"] = args.note
        data["results"][f"{label} {which}"] = r
        print(f"{label} {which}: {r}", flush=True)
    write("suite_times", data, path)


if __name__ == "__main__":
    main()
