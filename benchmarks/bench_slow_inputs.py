"""Table build times of the slowest valid inputs (issue 15, item 4).

Each case builds one material's lobe table from an empty cache, in its own
process (so a case that runs away is cut at ``--timeout`` and reported as
such).  The first group are the inputs the issue found slow; the second are
the worst cases at the documented maxima of :mod:`corona.parameters` (the
largest radius, spread, number of sides, rotated size, mask size).  Writes
benchmarks/results/slow_inputs.json.  Goal: every accepted input builds in
about a minute at most here, with a progress bar beyond 2 s.

    python benchmarks/bench_slow_inputs.py [--timeout 300] [--only NAME ...]
    python benchmarks/bench_slow_inputs.py --src OLD/src --out before   # another checkout
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import write  # noqa: E402

#: name -> material parameters ("@mask" is a 256 × 256 px opening written by this script)
CASES = {
    # --- the inputs issue 15 found slow (its figures: 75 s, > 4 min, 91 s, 49 s)
    "square random, spread 0.05": dict(shape="square", orientation="random", size_spread=0.05),
    "square random, spread 0.5": dict(shape="square", orientation="random", size_spread=0.5),
    "circle 20 µm, spread 0.5": dict(radius=20.0, size_spread=0.5),
    "polygon 50 sides": dict(shape="polygon", sides=50),
    # --- worst cases at the documented maxima
    "circle 1000 µm (max), spread 0.5 (max)": dict(radius=1000.0, size_spread=0.5),
    "circle 1000 µm, spread 0.5, schulz": dict(radius=1000.0, size_spread=0.5, size_distribution="schulz"),
    "square random, circumradius 25 µm (max)": dict(shape="square", orientation="random",
                                                    radius=25.0 / 2**0.5),
    "heptagon random, 25 µm (max)": dict(shape="polygon", sides=7, orientation="random", radius=25.0),
    "mask random, 25 µm (max)": dict(shape="mask", filename="@mask", pixel_size=0.199,
                                     orientation="random"),
    "square random, spread 0.5, largest 25 µm": dict(shape="square", orientation="random",
                                                     size_spread=0.5, radius=1.28),
    "hexagon spread 0.5 (2D table)": dict(shape="polygon", sides=6, size_spread=0.5),
    "heptagon spread 0.5 (2D table, at the work maximum)": dict(shape="polygon", sides=7, size_spread=0.5),
    "polygon 50 sides, spread 0.1 (2D table)": dict(shape="polygon", sides=50, size_spread=0.1),
    "ellipse aspect 5, spread 0.5 (2D table)": dict(shape="ellipse", aspect=5.0, size_spread=0.5,
                                                    process="poisson"),
    "mask 1024 px (max), fixed": dict(shape="mask", filename="@mask1024", pixel_size=0.01),
    # --- an isotropic shape on a lattice: a 2D table (found by the property test, 827 s before)
    "hexagon random, spread 0.5, on a lattice (2D table)": dict(
        shape="polygon", sides=6, orientation="random", size_spread=0.5, size_distribution="schulz",
        radius=0.001, process="lattice-square", jitter=2000.0),
}

CHILD = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
from corona.parameters import material_from_parameters
params = json.loads(sys.argv[1])
t0 = time.perf_counter()
m = material_from_parameters(**params)
m.table
print(json.dumps({"seconds": time.perf_counter() - t0, "samples": int(m.table.values.size),
                  "diffuse_transmittance": float(m.diffuse_transmittance())}))
"""


def _masks(folder: str) -> dict:
    """A 256 px and a 1024 px opening (a disk with a notch: no symmetry) as PNG files."""
    import imageio.v3 as iio
    import numpy as np
    out = {}
    for name, n in (("mask", 256), ("mask1024", 1024)):
        y, x = np.mgrid[:n, :n] - (n - 1) / 2
        img = (x * x + y * y <= (0.45 * n) ** 2) & ~((x > 0) & (np.abs(y) < 0.1 * n))
        out[name] = os.path.join(folder, f"{name}.png")
        iio.imwrite(out[name], (img * 255).astype(np.uint8))
    return out


def run_case(params: dict, timeout: float, src: str | None) -> dict:
    env = dict(os.environ, CORONA_CACHE_DIR=tempfile.mkdtemp(prefix="corona-bench-slow-"))
    if src:
        env["PYTHONPATH"] = src
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-c", CHILD, json.dumps(params)], env=env, capture_output=True,
                           text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"seconds": None, "timed_out_after_s": timeout}
    if p.returncode != 0:
        err = [ln for ln in p.stderr.strip().splitlines() if ln.strip()]
        return {"seconds": None, "error": err[-1] if err else f"exit {p.returncode}",
                "wall_s": time.perf_counter() - t0}
    return json.loads(p.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per case")
    ap.add_argument("--only", nargs="*", default=None, help="cases whose name contains one of these")
    ap.add_argument("--src", default=None, help="run against another source tree (its src/ folder)")
    ap.add_argument("--out", default="slow_inputs", help="results/NAME.json")
    args = ap.parse_args()
    masks = _masks(tempfile.mkdtemp(prefix="corona-bench-masks-"))
    results = {}
    for name, params in CASES.items():
        if args.only and not any(k in name for k in args.only):
            continue
        params = {k: (masks[v[1:]] if isinstance(v, str) and v.startswith("@") else v)
                  for k, v in params.items()}
        r = run_case(params, args.timeout, args.src)
        results[name] = {"params": {k: v for k, v in params.items() if k != "filename"}, **r}
        shown = (f"{r['seconds']:8.2f} s" if r.get("seconds") is not None else
                 f"> {args.timeout:.0f} s (cut)" if "timed_out_after_s" in r else f"error: {r['error']}")
        print(f"{name:45s} {shown}", flush=True)
    write(args.out, {"timeout_s": args.timeout, "results": results,
                     "goal": "every accepted input builds in about a minute at most, "
                             "a progress bar beyond 2 s (issue 15, item 4)"})


if __name__ == "__main__":
    main()
