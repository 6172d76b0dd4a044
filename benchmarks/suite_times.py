"""The test suite's wall time, cold (an empty tests' table cache) and warm (the same cache again).

    python benchmarks/suite_times.py [--full] [--runs cold,warm] [--cache DIR] [--note TEXT]

Runs ``pytest -n 2 -q -m "not slow" tests`` (what ``make test-fast`` runs; ``--full``: ``pytest -n 2
-q``, what ``make test`` runs) with ``CORONA_TEST_CACHE`` at ``DIR`` (default: a new temporary
folder): ``cold`` empties it first, ``warm`` reuses it.  Records each run's wall time, the CPU time
of pytest and its workers (``RUSAGE_CHILDREN``), the 1-minute load average before and after, and
pytest's summary line, into benchmarks/results/suite_times.json (runs of other kinds already there
are kept).  Not run by ``make bench`` (it is not a ``bench_*.py``): it takes minutes.  The goals
(issue 44): ``make test`` <= 12 min cold, <= 8 min warm; ``make test-fast`` <= 3 min cold, <= 60 s
warm, on two idle cores from a fresh clone.  On a shared machine read the CPU time and the load.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from common import RESULTS, machine  # noqa: E402

GOALS_S = {"test-fast cold": 180, "test-fast warm": 60, "test cold": 720, "test warm": 480}


def run(args: list[str], cache: str) -> dict:
    env = {**os.environ, "CORONA_TEST_CACHE": cache}
    env.pop("CORONA_CACHE_DIR", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    lines = [x for x in p.stdout.strip().splitlines() if x.strip()]
    return {"wall_s": round(wall, 1),
            "cpu_s": round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 1),
            "load_average_1min": [round(load0, 1), round(os.getloadavg()[0], 1)],
            "returncode": p.returncode, "summary": lines[-1] if lines else p.stderr[-300:]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="the whole suite (make test), not -m 'not slow'")
    ap.add_argument("--runs", default="cold,warm")
    ap.add_argument("--cache", default=None, help="the tests' cache root (default: a new temporary folder)")
    ap.add_argument("--note", default=None, help="machine_load note stored with the runs")
    args = ap.parse_args()
    cache = args.cache or tempfile.mkdtemp(prefix="corona-suite-times-")
    kind = "test" if args.full else "test-fast"
    cmd = [sys.executable, "-m", "pytest", "-n", "2", "-q", "-p", "no:cacheprovider"]
    cmd += [] if args.full else ["-m", "not slow", "tests"]
    path = os.path.join(RESULTS, "suite_times.json")
    data = json.load(open(path)) if os.path.exists(path) else {}
    data.setdefault("results", {})
    for which in args.runs.split(","):
        if which == "cold":
            shutil.rmtree(cache, ignore_errors=True)
        r = run(cmd, cache)
        r.update(command=" ".join(["python"] + cmd[1:]), goal_s=GOALS_S[f"{kind} {which}"])
        data["results"][f"{kind} {which}"] = r
        print(f"{kind} {which}: {r}", flush=True)
    data["machine"] = machine()
    if args.note:
        data["machine_load"] = args.note
    with open(path, "w") as f:
        json.dump(data, f, indent=1)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
