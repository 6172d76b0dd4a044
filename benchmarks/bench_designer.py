"""Latency of `corona designer`: one slider step, end to end through the HTTP API.

For each material a "drag" of ``--steps`` slider steps (the radius grows by
1 % per step, so every step is a new material, as when a user drags the
radius knob) and, per step, the time of each view the page asks for,
through Starlette's TestClient (routing, parsing, the worker thread, PNG
encoding): GET /api/corona.png (256² picture), GET /api/profiles, and
GET /api/material (energy split and exports: needs the material's full
lobe table).  Writes benchmarks/results/designer.json.

Goal: every update <= 100 ms on 2 cores, radial and 2-D materials alike;
"update" = the picture and the profiles (what moves under the knob).  For
2-D materials a second drag asks for the half-size preview the page shows
while a slider moves (``preview=1``; the exact picture follows on release):
``drag_update_*``.  Both
wall-clock and CPU time (all threads of the process) are recorded: on a
shared, loaded machine the wall clock measures the neighbours too, while
the CPU time is what the update costs (numpy runs it on one core).  The
1-minute load average is recorded at the start and at the end of the run.

    python benchmarks/bench_designer.py [--steps 12] [--only NAME]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
os.environ.setdefault("CORONA_CACHE_DIR", tempfile.mkdtemp(prefix="corona-bench-"))

import corona  # noqa: E402,F401
from common import write  # noqa: E402

MATERIALS = {
    "fogged window (circle 5 µm, hard-disk)": "fogged window",
    "lycopodium 10× (circle 15 µm, 5 % spread, rsa)": "lycopodium 10×",
    "droplets 2 µm, poisson": ({"radius": 2.0, "area_fraction": 0.2, "process": "poisson"},
                               {"field": 20.0}),
    "hexagons 3 µm, random orientation": ({"shape": "polygon", "sides": 6, "radius": 3.0,
                                           "orientation": "random", "area_fraction": 0.3}, {}),
    "voile fabric (square lattice, 2-D)": "voile fabric",
    "ellipses 2 µm 2:1 at 25°, poisson (2-D, closed form)": (
        {"shape": "ellipse", "radius": 2.0, "aspect": 2.0, "angle": 25.0, "area_fraction": 0.2,
         "process": "poisson"}, {}),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--only", default="", help="run only the materials whose name contains this")
    args = ap.parse_args()
    from starlette.testclient import TestClient

    from corona.apps.designer import compute, create_app
    client = TestClient(create_app(timeout=120.0), base_url="http://127.0.0.1")
    load_start = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    # warm: imports, shipped tables, the first JIT of nothing (numpy only)
    client.get("/api/corona.png", params={"radius": 1.0})
    results = {}
    for name, spec in MATERIALS.items():
        if args.only not in name:
            continue
        if isinstance(spec, str):
            material, view = compute.PRESETS[spec]["material"], compute.PRESETS[spec]["view"]
        else:
            material, view = spec
        times = {"picture": [], "profiles": [], "material": []}
        cpu = {"picture": [], "profiles": [], "material": []}
        radial = None
        for step in range(args.steps):
            q = {**material, **view, "radius": round(material["radius"] * 1.01 ** (step + 1), 6)}
            for key, path in (("picture", "/api/corona.png"), ("profiles", "/api/profiles"),
                              ("material", "/api/material")):
                t0, c0 = time.perf_counter(), time.process_time()
                res = client.get(path, params=q if key != "material" else
                                 {k: v for k, v in q.items() if k in compute.DEFAULTS})
                times[key].append(time.perf_counter() - t0)
                cpu[key].append(time.process_time() - c0)
                if res.status_code != 200:
                    raise SystemExit(f"{name}: {path} answered {res.status_code}: {res.text}")
                if key == "material":
                    radial = res.json()["isotropic"]
        update = [a + b for a, b in zip(times["picture"], times["profiles"])]
        update_cpu = [a + b for a, b in zip(cpu["picture"], cpu["profiles"])]
        drag, drag_cpu = [], []
        if not radial:
            # a drag of 2-D materials: the half-size preview (preview=1) and the profiles, on
            # radii of their own (each a new material, as the exact pictures above)
            for step in range(args.steps):
                q = {**material, **view, "radius": round(material["radius"] * 0.99 ** (step + 1), 6),
                     "preview": 1}
                t0, c0 = time.perf_counter(), time.process_time()
                for path, params in (("/api/corona.png", q), ("/api/profiles",
                                                              {k: v for k, v in q.items() if k != "preview"})):
                    res = client.get(path, params=params)
                    if res.status_code != 200:
                        raise SystemExit(f"{name}: {path} answered {res.status_code}: {res.text}")
                drag.append(time.perf_counter() - t0)
                drag_cpu.append(time.process_time() - c0)
        results[name] = {
            "radial": radial,
            "picture_median_ms": 1e3 * statistics.median(times["picture"]),
            "profiles_median_ms": 1e3 * statistics.median(times["profiles"]),
            "update_median_ms": 1e3 * statistics.median(update),
            "update_max_ms": 1e3 * max(update),
            "update_cpu_median_ms": 1e3 * statistics.median(update_cpu),
            "picture_cpu_median_ms": 1e3 * statistics.median(cpu["picture"]),
            "energy_median_ms": 1e3 * statistics.median(times["material"]),
            "energy_cpu_median_ms": 1e3 * statistics.median(cpu["material"]),
            "energy_max_ms": 1e3 * max(times["material"]),
            "meets_100ms_wall": bool(statistics.median(update) <= 0.1),
            "meets_100ms_cpu": bool(statistics.median(update_cpu) <= 0.1),
        }
        if drag:
            results[name].update(drag_update_median_ms=1e3 * statistics.median(drag),
                                 drag_update_cpu_median_ms=1e3 * statistics.median(drag_cpu))
        r = results[name]
        print(f"{name:48s} {'radial' if radial else '2-D   '}  update {r['update_median_ms']:6.1f} ms "
              f"(cpu {r['update_cpu_median_ms']:6.1f}) "
              f"(picture {r['picture_median_ms']:5.1f}, profiles {r['profiles_median_ms']:5.1f}, "
              f"max {r['update_max_ms']:6.1f})  energy {r['energy_median_ms']:7.1f} ms"
              + (f"  drag (preview) {r['drag_update_median_ms']:6.1f} ms (cpu {r['drag_update_cpu_median_ms']:6.1f})"
                 if drag else ""), flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None   # at the end of the run
    print(f"load average (1 min): {load_start} at the start, {load} at the end", flush=True)
    if args.only:                     # a partial run: printed, not written
        return
    write("designer", {"steps": args.steps, "load_average_1min": load, "load_average_1min_start": load_start,
                       "results": results,
                       "goal": "every update (picture + profiles) <= 100 ms on 2 cores, radial and 2-D "
                               "(median over a drag of the radius slider; energy split reported apart)"})


if __name__ == "__main__":
    main()
