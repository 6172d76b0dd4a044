"""CPU time of a size distribution's Mie rows (``build_mie_rows``), a base revision against this checkout.

Each case builds in a fresh process (imports warmed by a small build first, nothing read from the
table cache), the base revision's tree and this checkout's alternating round by round, so that both
see the same load.  Reported: the CPU seconds of the build (``time.process_time``, the whole process:
run it with ``OPENBLAS_NUM_THREADS=1``), the 1-minute load average at each run.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_spread_build.py --base 8b775ce [--rounds 3]
        [--cases water:20:0.1,1.5:20:0.1] [--name spread_build_ab]

writes benchmarks/results/<name>.json.  Nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

ONE = r"""
import json, os, sys, time
import corona
from corona.model.mie import layer
ior, radius, spread = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
ior = None if ior == "water" else float(ior)
layer.build_mie_rows(corona.Sphere(1.0), sizes=corona.SizeDistribution(corona.Sphere(1.0), 0.1))
sizes = corona.SizeDistribution(corona.Sphere(radius, ior=ior), spread)
c0 = time.process_time()
layer.build_mie_rows(sizes.shape, sizes=sizes)
print(json.dumps({"cpu_s": time.process_time() - c0, "load_average_1min": os.getloadavg()[0]}))
"""


def one(src: str, case: str) -> dict:
    env = dict(os.environ, PYTHONPATH=src, TQDM_DISABLE="1")
    out = subprocess.run([sys.executable, "-c", ONE, *case.split(":")], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="a git revision to compare with this checkout")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cases", default="water:20:0.1,1.5:20:0.1", help="ior:radius_um:spread, comma-separated")
    ap.add_argument("--name", default="spread_build_ab")
    args = ap.parse_args()
    from common import write
    runs = {}
    with tempfile.TemporaryDirectory() as base:
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.base, "src"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", base], input=archive, check=True)
        trees = ((f"base {args.base}", os.path.join(base, "src")), ("this checkout", os.path.join(ROOT, "src")))
        for r in range(args.rounds):
            for case in args.cases.split(","):
                for tree, src in trees:
                    res = one(src, case)
                    runs.setdefault(case, {}).setdefault(tree, []).append(res)
                    print(f"round {r + 1} {case:16s} {tree:16s} CPU {res['cpu_s']:.2f} s  "
                          f"load {res['load_average_1min']:.1f}", flush=True)
    summary = {case: {tree: {"min_cpu_s": min(x["cpu_s"] for x in v),
                             "median_cpu_s": statistics.median(x["cpu_s"] for x in v)}
                      for tree, v in per.items()} for case, per in runs.items()}
    print(json.dumps(summary, indent=1))
    write(args.name, {"base": args.base, "rounds": args.rounds, "summary": summary, "runs": runs})


if __name__ == "__main__":
    main()
