"""Build time of the ``corona_mie`` volume tables of the scenes' droplet populations.

Each build runs in a fresh process (``MieVolume(...)._build()``, no cache), timed by the
process's CPU time (every thread: BLAS may use two) and the wall clock.  With
``--compare-src DIR`` (another checkout's ``src``) the two sources alternate round by round,
so each round's ratio is measured under the same load; the median of the per-round ratios is
reported.  Writes benchmarks/results/volume_table.json (not with ``--compare-src``: printed).

    python benchmarks/bench_volume_table.py [--rounds 3] [--compare-src /path/to/other/src]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

#: The populations of scenes/glory_cloud_deck.xml, streetlight_fog.xml, moon_altocumulus.xml.
POPULATIONS = {
    "glory_cloud_deck (10 µm, gamma 0.01)": dict(radius=10.0, distribution="gamma", variance=0.01),
    "streetlight_fog (5 µm, gamma 0.02)": dict(radius=5.0, distribution="gamma", variance=0.02),
    "moon_altocumulus (5 µm, gamma 0.01)": dict(radius=5.0, distribution="gamma", variance=0.01),
}


def one(kwargs: dict, save: str | None = None) -> dict:
    import time

    import numpy as np

    import corona  # noqa: F401
    from corona.model.mie.volume import MieVolume
    v = MieVolume(**kwargs, use_cache=False)
    v.grid()
    t0, c0 = time.perf_counter(), time.process_time()
    table = v._build()
    if save:
        np.savez(save, **table)
    return {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
            "rows": int(v.grid()[0].size), "sizes": int(v.radii.size), "angles": 2 * v.grid()[2] + 1}


def run(src: str, kwargs: dict, save: str | None = None) -> dict:
    env = {**os.environ, "PYTHONPATH": src, "PYTHONDONTWRITEBYTECODE": "1"}
    cmd = [sys.executable, os.path.abspath(__file__), "--one", json.dumps(kwargs)]
    if save:
        cmd += ["--save", save]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True, cwd=HERE)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--compare-src", default=None, help="another checkout's src folder (the 'before')")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--save", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(json.loads(args.one), args.save)), flush=True)
        return
    import tempfile

    import numpy as np
    tmp = tempfile.mkdtemp(prefix="corona-bench-volume-")
    src = os.path.join(ROOT, "src")
    load0 = os.getloadavg()[0]
    results = {}
    for name, kwargs in POPULATIONS.items():
        this, other = [], []
        for k in range(args.rounds):
            this.append(run(src, kwargs, os.path.join(tmp, "this.npz") if k == 0 else None))
            if args.compare_src:
                other.append(run(args.compare_src, kwargs, os.path.join(tmp, "other.npz") if k == 0 else None))
        r = {"cpu_median_s": statistics.median(x["cpu_s"] for x in this),
             "wall_median_s": statistics.median(x["wall_s"] for x in this),
             "rows": this[0]["rows"], "sizes": this[0]["sizes"], "angles": this[0]["angles"]}
        line = f"{name:40s} {r['cpu_median_s']:6.2f} s CPU  {r['wall_median_s']:6.2f} s wall"
        if other:
            ratios = [o["cpu_s"] / t["cpu_s"] for o, t in zip(other, this)]
            r.update(before_cpu_median_s=statistics.median(x["cpu_s"] for x in other),
                     speedup_cpu_median=statistics.median(ratios))
            a, b = np.load(os.path.join(tmp, "this.npz")), np.load(os.path.join(tmp, "other.npz"))
            r["max_relative_difference"] = {
                key: float(np.max(np.abs(a[key] - b[key]) / np.maximum(np.abs(b[key]), 1e-300)))
                for key in ("p", "c_ext", "c_sca", "g")}
            line += (f"   before {r['before_cpu_median_s']:6.2f} s CPU  speed-up {r['speedup_cpu_median']:.2f}× "
                     f"(rounds {', '.join(f'{x:.2f}' for x in ratios)}); max relative difference "
                     + ", ".join(f"{k} {v:.1e}" for k, v in r["max_relative_difference"].items()))
        results[name] = r
        print(line, flush=True)
    load = [load0, os.getloadavg()[0]]
    print(f"load average (1 min): {load[0]:.1f} at the start, {load[1]:.1f} at the end", flush=True)
    if args.compare_src:
        return
    from common import write
    write("volume_table", {"rounds": args.rounds, "results": results, "load_average_1min": load,
                           "goal": "each scene's tables cold <= 2 s (the volume table is all of it)"})


if __name__ == "__main__":
    main()
