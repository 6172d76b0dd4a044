"""The slowest accepted size spread of a fixed polygon (a 2D lobe table) and the issue-47 hexagon.

Writes benchmarks/results/spread_limit.json.  Each case builds its lobe table in a fresh process
with an empty cache (``parameters.SIZE_AVERAGE_WORK_MAX`` bounds the size average's terms): the
hexagon of spread 0.5 (issue 47 item 19: 134 s under load) and the nonagon of spread 0.5, the
largest accepted polygon at that spread.  Reported: wall and CPU seconds of the build (CPU summed
over the quadrature's threads), the terms, the 1-minute load average (a shared machine inflates
wall time, not CPU time).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, os.pardir, "src"))

CASES = {"issue 47: hexagon, spread 0.5": 6, "slowest accepted: nonagon, spread 0.5": 9}

_CHILD = r"""
import json, sys, time
import corona
from corona import parameters
from corona.parameters import material_from_parameters
m = material_from_parameters(shape="polygon", sides=int(sys.argv[1]), size_spread=0.5, radius=0.5)   # the issue-47 case (0.1.0 default radius)
t0, c0 = time.perf_counter(), time.process_time()
table = m.table
print(json.dumps({"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                  "terms": parameters._size_average_work(m.shape),
                  "limit": parameters.SIZE_AVERAGE_WORK_MAX,
                  "diffuse_transmittance": float(m.tabulated_transmittance)}))
"""


def main(argv=None):
    from common import write
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--full", action="store_true", help="(accepted for run_all; same run)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "spread_limit.json"))
    a = ap.parse_args(argv)
    results = {}
    for name, sides in CASES.items():
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "CORONA_CACHE_DIR": cache, "PYTHONPATH": os.path.join(HERE, os.pardir, "src")}
            r = subprocess.run([sys.executable, "-c", _CHILD, str(sides)], capture_output=True, text=True, env=env)
        if r.returncode:
            raise SystemExit(r.stderr)
        res = json.loads(r.stdout.strip().splitlines()[-1])
        res.update(sides=sides, size_spread=0.5, load_average=os.getloadavg()[0])
        results[name] = res
        print(name, json.dumps(res), flush=True)
    write("spread_limit", {"benchmark": "spread_limit",
           "before": "issue 47: the hexagon of spread 0.5 built in 134 s under load (one thread; limit 1.2e9 terms)",
           "results": results}, path=a.out)


if __name__ == "__main__":
    main()
