"""Area-fraction rows of a textured layer: how many, how long to build, how exact.

A layer whose area fraction varies (a texture) is evaluated between two
tabulated rows of F_a by linear interpolation
(:meth:`corona.Material.area_fraction_rows`, rows bisected until the
interpolated lobe at every interval's midpoint is within 0.1 % of the exact
one wherever that exceeds 1e-3 of its peak).  For the whole F_a range of the
hard-disk and the RSA processes this records the row count, the build time
(cold cache), the builder's own midpoint figure (``row_error``) and an
independent check: at ``--samples`` random F_a in every interval, the
interpolated rows against the lobe table of a :class:`corona.Material`
built at that F_a (``Material.table``, its own code path), as

* ``max_relative_change``: the largest |interpolated - exact| / exact where
  exact > 1e-3 of its peak (the builder's criterion; goal of issue 12 < 0.5 %),
* ``max_change_of_peak``: the largest |interpolated - exact| anywhere, over
  the peak.

Writes benchmarks/results/rows.json.

    python benchmarks/bench_rows.py [--samples 2]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import corona  # noqa: E402,F401
from common import write  # noqa: E402

MATERIALS = {
    "droplets 5 µm / hard-disk": dict(radius=5.0, process="hard-disk", mode="particle"),
    "lycopodium 15 µm / rsa": dict(radius=15.0, process="rsa", mode="particle"),
}


def measure(params: dict, samples: int, rng) -> dict:
    from corona.model import tabulated
    from corona.parameters import material_from_parameters
    base = material_from_parameters(**params, area_fraction=0.3)
    tabulated.cache_clear()
    t0 = time.perf_counter()
    fas, tabs, row_error = base.area_fraction_rows()
    build = time.perf_counter() - t0
    vals = np.stack([t.values for t in tabs]).astype(np.float64)
    worst_rel, worst_peak, checked = 0.0, 0.0, 0
    for j in range(len(fas) - 1):
        for f in rng.uniform(fas[j], fas[j + 1], samples):
            if f <= 0.0:
                continue
            exact = material_from_parameters(**params, area_fraction=float(f)).table.values.astype(np.float64)
            t = (f - fas[j]) / (fas[j + 1] - fas[j])
            lerp = (1 - t) * vals[j] + t * vals[j + 1]
            sel = exact > 1e-3 * exact.max()
            worst_rel = max(worst_rel, float(np.max(np.abs(lerp[sel] - exact[sel]) / exact[sel])))
            worst_peak = max(worst_peak, float(np.max(np.abs(lerp - exact)) / exact.max()))
            checked += 1
    return {"area_fraction_range": f"{fas[0]:g} to {fas[-1]:g}", "rows": len(fas),
            "closest_rows": float(np.min(np.diff(fas))), "widest_rows": float(np.max(np.diff(fas))),
            "build_s": build, "row_error_midpoints": row_error, "checked_area_fractions": checked,
            "max_relative_change": worst_rel, "max_change_of_peak": worst_peak}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=2, help="random area fractions per interval")
    args = ap.parse_args()
    os.environ["CORONA_CACHE_DIR"] = tempfile.mkdtemp(prefix="corona-bench-")
    rng = np.random.default_rng(1)
    results = {}
    for name, params in MATERIALS.items():
        results[name] = r = measure(params, args.samples, rng)
        print(f"{name}: {r['rows']} rows over F_a {r['area_fraction_range']} (built in {r['build_s']:.2f} s), "
              f"midpoints {100 * r['row_error_midpoints']:.3f} %, at {r['checked_area_fractions']} random F_a: "
              f"max relative change {100 * r['max_relative_change']:.3f} %, "
              f"max change {100 * r['max_change_of_peak']:.4f} % of the peak", flush=True)
    write("rows", {"results": results, "samples_per_interval": args.samples,
                   "goal": "interpolating between F_a rows changes the lobe by < 0.5 % (issue 12)"})


if __name__ == "__main__":
    main()
