"""Table build and cache-load times for each kind of material.

For each material: the time to build its lobe table from scratch (form
factor × structure factor from the shipped data, no simulation), the time to
load it back from the on-disk cache, and its size.  Writes
benchmarks/results/tables.json.  Goal (issue 3): any structure-factor table
for a material from the shipped data in <= 0.2 s.

    python benchmarks/bench_tables.py [--repeats 5]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import corona  # noqa: E402,F401
from common import write  # noqa: E402

MATERIALS = {
    "circle / poisson": dict(radius=0.5, process="poisson"),
    "circle / hard-disk": dict(radius=0.5, process="hard-disk", area_fraction=0.5),
    "droplets 5 µm / hard-disk": dict(radius=5.0, process="hard-disk", area_fraction=0.4),
    "lycopodium 15 µm / rsa": dict(radius=15.0, process="rsa", area_fraction=0.4),
    "square / lattice-square (2D)": dict(shape="square", radius=0.5, process="lattice-square",
                                         area_fraction=0.3, jitter=0.05),
    "hexagon random / hard-disk": dict(shape="polygon", sides=6, radius=0.5, orientation="random",
                                       process="hard-disk", area_fraction=0.3),
    "ellipse (2D) / hard-disk": dict(shape="ellipse", radius=0.5, aspect=1.5, process="hard-disk",
                                     area_fraction=0.3),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from corona import tables
    from corona.parameters import material_from_parameters
    os.environ["CORONA_CACHE_DIR"] = tempfile.mkdtemp(prefix="corona-bench-")
    material_from_parameters(**MATERIALS["circle / hard-disk"]).table  # warm imports / data load
    tables.cache_clear()
    results = {}
    for name, params in MATERIALS.items():
        build, load = [], []
        for _ in range(args.repeats):
            tables.cache_clear()
            m = material_from_parameters(**params)
            t0 = time.perf_counter()
            t = m.table
            build.append(time.perf_counter() - t0)
            m2 = material_from_parameters(**params)
            t0 = time.perf_counter()
            m2.table
            load.append(time.perf_counter() - t0)
        results[name] = {"kind": "radial" if m.isotropic else "2d",
                         "samples": int(t.values.size), "bytes": int(t.values.nbytes),
                         "build_median_s": statistics.median(build),
                         "load_median_s": statistics.median(load)}
        print(f"{name:32s} {results[name]['kind']:6s} {t.values.size:8d} samples  "
              f"build {results[name]['build_median_s'] * 1e3:8.1f} ms  "
              f"load {results[name]['load_median_s'] * 1e3:6.1f} ms")
    write("tables", {"repeats": args.repeats, "results": results,
                     "goal": "structure-factor table of a material from shipped data <= 0.2 s"})


if __name__ == "__main__":
    main()
