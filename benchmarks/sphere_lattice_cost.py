"""The cost of spheres on a lattice per BSDF sample against the number of Bragg orders the
per-lane cap holds (corona.mitsuba.sphere_lattice.LatticeCap: every order with
``|G| <= 2 k_max + RIM_REACH w``, about ``G_max² A_c / 4π`` for a cell of area ``A_c``): 1 µm
spheres on a hexagonal lattice, perfect and jittered, at area fractions that set the spacing; the
wall time of ``sample`` (four wavelengths a lane, its eval included) per lane over 16 384 lanes at
normal and 60° incidence, after a warm-up call (the kernel's compilation apart), the median of
three.  The largest count is the renderer's limit (:data:`corona.mitsuba.sphere_lattice.LATTICE_ORDERS_MAX`):
the slowest accepted lattice.  Writes ``benchmarks/results/sphere_lattice_cost.json``.

Run ``python benchmarks/sphere_lattice_cost.py``.
"""
from __future__ import annotations

import json
import os
import sys
import time
import warnings

import numpy as np

import corona


def main(n=16_384, out="benchmarks/results/sphere_lattice_cost.json"):
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(corona.default_variant(prefer_gpu=False))
    corona.register()
    from corona.mitsuba.sphere_lattice import LATTICE_ORDERS_MAX
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import machine
    from bsdf_checks import interaction
    # hexagonal cell area of 1 µm spheres at F_a: π / F_a; the limit's F_a: π G_max² / (4π N)
    g_max = 2.0 * 2.0 * np.pi / (corona.model.tabulated.WAVELENGTH_MIN * 1e-3)
    fa_limit = float(np.pi * g_max ** 2 / (4.0 * np.pi * LATTICE_ORDERS_MAX)) * 1.001
    rows = []
    rng = np.random.default_rng(1)
    for fa, jitter in ((0.5, 0.0), (0.2, 0.0), (0.05, 0.0), (0.02, 0.05), (fa_limit, 0.0), (fa_limit, 0.05)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "process": "lattice-hex",
                                 "area_fraction": float(fa), "jitter": jitter})
            load = time.perf_counter() - t0
        orders = bsdf.lobe.cap.count
        for theta in (0.0, 60.0):
            th = np.radians(theta)
            si = interaction(n, (float(np.sin(th)), 0.0, float(np.cos(th))))
            times = []
            for rep in range(4):
                u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
                t0 = time.perf_counter()
                bs, w = bsdf.sample(mi.BSDFContext(), si, u[0], mi.Point2f(u[1], u[2]))
                dr.eval(bs, w)
                dr.sync_thread()
                times.append(time.perf_counter() - t0)
            per = float(np.median(times[1:])) / n
            rows.append({"area_fraction": float(fa), "jitter_um": jitter, "orders": int(orders), "theta_deg": theta,
                         "load_s": round(load, 2), "sample_us_per_lane": round(per * 1e6, 2)})
            print(rows[-1], flush=True)
    result = {"what": "spheres (1 um) on a hexagonal lattice: sample() wall time per lane against the "
                      "Bragg orders the per-lane cap holds (4 wavelengths a lane, 16384 lanes, median of 3 "
                      "after a warm-up)",
              "limit_orders": int(LATTICE_ORDERS_MAX), "variant": mi.variant(),
              "machine": machine(), "rows": rows}
    with open(out, "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
