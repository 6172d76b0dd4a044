"""corona post on a 3840x2160 frame (radial lobe): wall time on the machine's cores.

Writes benchmarks/results/post.json.  The frame is a synthetic HDR plate (a dim
gradient and a few thousand small bright lights), the layer lycopodium-like
droplets (radius 5 µm, hard disks, F_a 0.3), fov 60°.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "src"))
import corona  # noqa: E402,F401
import corona.apps.post as post  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
from common import machine  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--width", type=int, default=3840)
    ap.add_argument("--height", type=int, default=2160)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--full", action="store_true", help="(accepted for run_all; same run)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "post.json"))
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    img = np.full((a.height, a.width, 3), 0.05, np.float32)
    img *= np.linspace(0.5, 1.5, a.width, dtype=np.float32)[None, :, None]
    ys, xs = rng.integers(0, a.height, 3000), rng.integers(0, a.width, 3000)
    img[ys, xs] = rng.uniform(10, 1000, (3000, 3)).astype(np.float32)
    params = dict(radius=5.0, area_fraction=0.3, mode="particle", process="hard-disk")
    m = post.layer(**params)
    m.lobe_dimensionless_radial(np.linspace(0, 1, 8))      # warm the material (its S table)
    times, cpu = [], []
    for _ in range(a.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = post.apply(img, 60.0, m, progress=False)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    res = {"machine": machine(), "goal": "a 3840x2160 frame in <= 10 s on 2 cores (radial lobe)",
           "benchmark": "post", "width": a.width, "height": a.height, "fov_deg": 60.0,
           "material": params, "cores": workers, "seconds": times, "best_s": min(times),
           "cpu_seconds": cpu, "best_cpu_s": min(cpu),
           "goal_s": 10.0, "finite": bool(np.isfinite(out).all()),
           "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w", encoding="utf-8") as f:
        json.dump(res, f, indent=1)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
