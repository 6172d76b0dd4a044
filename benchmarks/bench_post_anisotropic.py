"""corona post with anisotropic lobes: the issue-47 frame and the slowest accepted inputs.

Writes benchmarks/results/post_anisotropic.json.  Each case runs in a fresh process (its
peak resident memory is that process's): the 3840x2160 frame with a square (issue 47 item 6:
254 s and 5 GB before the kernel was read from a table of the lobe), and the two inputs at the
limit :data:`corona.apps.post.ANISOTROPIC_EVALUATIONS_MAX` (the slowest accepted: one by the
per-node path, a hexagon whose pixels are coarse against the lobe; one by the table path).
Wall and CPU seconds; the machine's load average is recorded (a shared machine inflates wall).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "src"))
sys.path.insert(0, os.path.dirname(__file__))

CASES = {
    "issue 47: square 5 um, 3840x2160, fov 60": (dict(shape="square", radius=5.0, area_fraction=0.3,
                                                     mode="particle"), 3840, 2160, 60.0),
    "slowest accepted, per-node path: hexagon 20 um, 2400x1350, fov 90": (
        dict(shape="polygon", sides=6, radius=20.0, area_fraction=0.3, mode="particle"), 2400, 1350, 90.0),
    "slowest accepted, table path: square 10 um, 3840x2160, fov 90": (
        dict(shape="square", radius=10.0, area_fraction=0.3, mode="particle"), 3840, 2160, 90.0),
    "refused: square 20 um, 3840x2160, fov 90": (
        dict(shape="square", radius=20.0, area_fraction=0.3, mode="particle"), 3840, 2160, 90.0),
}

_CHILD = r"""
import json, sys, time
import numpy as np
import corona, corona.apps.post as post
params, W, H, fov = json.loads(sys.argv[1])
m = post.layer(**params)
g = post._Grid(W, H, fov)
cost, how = post.anisotropic_cost(m, (post.WAVELENGTHS, post.channel_responses("srgb", 3)), g.nx, g.ny, g.step)
del g
rng = np.random.default_rng(0)
img = np.full((H, W, 3), 0.05, np.float32)
ys, xs = rng.integers(0, H, 3000), rng.integers(0, W, 3000)
img[ys, xs] = rng.uniform(10, 1000, (3000, 3)).astype(np.float32)
t0, c0 = time.perf_counter(), time.process_time()
try:
    out = post.apply(img, fov, m, progress=False)
    res = {"finite": bool(np.isfinite(out).all()), "refused": None}
except corona.CoronaError as err:
    res = {"refused": str(err)}
import resource
res.update(seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0, evaluations=cost, path=how,
           peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
print(json.dumps(res))
"""


def main(argv=None):
    from common import write
    import corona.apps.post as post
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--full", action="store_true", help="(accepted for run_all; same run)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "post_anisotropic.json"))
    a = ap.parse_args(argv)
    env = {**os.environ, "PYTHONPATH": os.path.join(os.path.dirname(__file__), os.pardir, "src")}
    results = {}
    for name, (params, W, H, fov) in CASES.items():
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-c", _CHILD, json.dumps([params, W, H, fov])],
                           capture_output=True, text=True, env=env)
        if r.returncode:
            raise SystemExit(r.stderr)
        res = json.loads(r.stdout.strip().splitlines()[-1])
        res.update(params=params, width=W, height=H, fov_deg=fov, process_wall_s=time.perf_counter() - t0,
                   load_average=os.getloadavg()[0])
        results[name] = res
        print(name, json.dumps(res), flush=True)
    write("post_anisotropic", {"benchmark": "post_anisotropic",
           "limit_evaluations": post.ANISOTROPIC_EVALUATIONS_MAX, "table_step_u": post.TABLE_STEP_U,
           "before": "issue 47: the 3840x2160 square took 254 s and 5 GB (float64 at every node x 24 wavelengths)",
           "results": results}, path=a.out)


if __name__ == "__main__":
    main()
