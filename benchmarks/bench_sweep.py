"""`corona sweep` on a 2-worker local Dask cluster against the same sweep in one process.

Eight points of a small scene (scenes/sweep_radius.xml, radius 1.5 ... 12 µm,
``--res`` pixels, ``--spp`` samples) rendered by the real command,
``corona sweep ... --workers 0`` (one process, Dr.Jit on all cores) and
``corona sweep ... --workers 2`` (two worker processes, one render each at a
time, Dr.Jit's thread count set to cores // 2 in each), each in a fresh
process and output folder, ``--rounds`` rounds alternating the order.  The
Dr.Jit kernel cache is warmed once first, so neither side pays more JIT
compilation than the other (each worker process still traces and loads its
kernels).

Reported: the command's wall time (process start to exit), the sweep's own
wall (first job to last, from the index), the cluster's start-up, and the
scheduling overhead per point: the round trip of an empty task through the
executor's map (``--noop`` tasks on a 2-worker cluster: submit, run,
result, progress bar) against the same in one process.

On a 2-core machine Dr.Jit already uses both cores in one process, so the
local speed-up is expected near 1x; what the numbers bound is the price of
going through Dask, which is what buys scaling out to more machines.

    python benchmarks/bench_sweep.py [--res 128] [--spp 64] [--rounds 2] [--noop 64]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "scenes", "sweep_radius.xml")
RADII = "1.5,2,3,4,5,6,8,12"


def sweep_command(out: str, workers: int, res: int, spp: int) -> dict:
    cmd = [sys.executable, "-m", "corona.apps.cli", "sweep", SCENE, "-D", f"radius={RADII}",
           "-D", f"res={res}", "-D", f"spp={spp}", "--out", out, "--workers", str(workers),
           "--no-progress"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    with open(os.path.join(out, "sweep_radius_index.json")) as f:
        index = json.load(f)
    pts = index["points"]
    assert all(p["status"] == "rendered" for p in pts), pts
    return {"command_s": wall, "sweep_s": index["wall_seconds"],
            "startup_s": index["executor_startup_seconds"],
            "render_sum_s": sum(p["seconds"] for p in pts),
            "drjit_threads": sorted({p["drjit_threads"] for p in pts})}


def noop_overhead(n: int) -> dict:
    """Seconds per empty task through Executor.map, on 2 local workers and in this process."""
    from corona._executor import Executor
    out = {}
    for name, workers in (("cluster_2_workers", 2), ("in_process", 0)):
        with Executor(workers=workers) as ex:
            ex.start()
            ex.map(os.getpid, [()] * 4, progress=False)           # warm the connections
            t0 = time.perf_counter()
            res = ex.map(os.getpid, [()] * n, progress=False)
            dt = time.perf_counter() - t0
            assert all(o.ok for o in res)
            out[name] = {"tasks": n, "seconds_per_task": dt / n,
                         "startup_s": ex.startup_seconds,
                         "distinct_worker_pids": len({o.value for o in res})}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--noop", type=int, default=64, help="empty tasks for the overhead")
    args = ap.parse_args()
    from common import write

    from corona.apps.render import setup_variant
    setup_variant()            # the variant the workers pick too (recorded with the machine)
    with tempfile.TemporaryDirectory() as tmp:
        sweep_command(os.path.join(tmp, "warm"), 0, args.res, 4)      # the kernel cache
        runs = {"serial_1_process": [], "cluster_2_workers": []}
        for r in range(args.rounds):
            order = [("serial_1_process", 0), ("cluster_2_workers", 2)]
            for name, workers in (order if r % 2 == 0 else order[::-1]):
                res = sweep_command(os.path.join(tmp, f"{name}-{r}"), workers, args.res, args.spp)
                runs[name].append(res)
                print(f"round {r + 1}/{args.rounds} {name:18s} command {res['command_s']:6.2f} s, "
                      f"sweep {res['sweep_s']:6.2f} s (start-up {res['startup_s']:.2f} s), "
                      f"renders {res['render_sum_s']:.2f} s", flush=True)
    results = {}
    for name, rs in runs.items():
        results[name] = {k: statistics.median(r[k] for r in rs)
                         for k in ("command_s", "sweep_s", "startup_s", "render_sum_s")}
        results[name]["drjit_threads_per_render"] = rs[0]["drjit_threads"][0]
        results[name]["points"] = 8
    s, c = results["serial_1_process"], results["cluster_2_workers"]
    c["speedup_command"] = s["command_s"] / c["command_s"]
    c["speedup_sweep_after_startup"] = s["sweep_s"] / max(c["sweep_s"] - c["startup_s"], 1e-9)
    overhead = noop_overhead(args.noop)
    per = overhead["cluster_2_workers"]["seconds_per_task"]
    print(f"speed-up (whole command) {c['speedup_command']:.2f}x, (sweep after cluster start) "
          f"{c['speedup_sweep_after_startup']:.2f}x; cluster start-up {c['startup_s']:.2f} s; "
          f"scheduling overhead {1e3 * per:.1f} ms per point "
          f"(in process {1e3 * overhead['in_process']['seconds_per_task']:.2f} ms)")
    write("sweep", {"scene": "scenes/sweep_radius.xml", "radius": RADII, "resolution": args.res,
                    "spp": args.spp, "rounds": args.rounds, "results": results,
                    "scheduling_overhead": overhead,
                    "goal": "report: the same command scales out; on 2 cores the local speed-up "
                            "may be ~1x (Dr.Jit already uses both cores in one process)"})


if __name__ == "__main__":
    main()
