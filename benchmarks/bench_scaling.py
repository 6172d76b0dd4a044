"""Scaling of the render cost: resolution × spp, and the number of distinct materials.

1. The street-light scene with the corona layer at several resolutions and
   sample counts: time per sample should be constant (linear scaling).
2. A screen tiled into 1, 2, 4, 8 panes, each a different corona material
   (radius 2–9 µm, hard disks): the cost of many distinct BSDFs (and tables)
   in one kernel.

Each configuration is rendered once to compile, then timed ``--repeats``
times (median).  Writes benchmarks/results/scaling.json.

    python benchmarks/bench_scaling.py [--repeats 3] [--variant V]
"""
from __future__ import annotations

import argparse
import gc
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def tiled_scene(n_materials: int, resolution: int) -> dict:
    """The street-light scene with its pane cut into ``n_materials`` vertical strips."""
    import mitsuba as mi

    from corona.apps.scenes import street_light_scene
    scene = street_light_scene(resolution=resolution, light_radius=0.5)
    pane = scene.pop("pane")
    T = mi.ScalarTransform4f
    width = 2.0 / n_materials          # the pane spans [-1, 1] in its local x
    for k in range(n_materials):
        x0 = -1.0 + (k + 0.5) * width
        scene[f"pane_{k}"] = {
            "type": "rectangle",
            "to_world": pane["to_world"] @ T().translate([x0, 0, 0]).scale([width / 2, 1, 1]),
            "bsdf": {"type": "corona", "radius": 2.0 + k, "area_fraction": 0.4,
                     "process": "hard-disk", "mode": "particle"},
        }
    return scene


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    args = ap.parse_args()

    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    from common import write
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant(args.variant)

    def timed(scene, spp):
        mi.render(scene, spp=spp, seed=0)          # compile
        dr.sync_thread()
        times = []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            dr.eval(mi.render(scene, spp=spp, seed=i + 1))
            dr.sync_thread()
            times.append(time.perf_counter() - t0)
        return statistics.median(times)

    results = {}
    bsdf = {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk", "mode": "particle"}
    for res in (64, 128, 256):
        scene = mi.load_dict(street_light_scene(resolution=res, bsdf=bsdf))
        for spp in (16, 64):
            t = timed(scene, spp)
            results[f"{res}x{res} / {spp} spp"] = {"samples": res * res * spp, "median_s": t,
                                                   "ns_per_sample": t / (res * res * spp) * 1e9}
            print(f"{res:4d}² {spp:3d} spp  {t:7.3f} s  {results[f'{res}x{res} / {spp} spp']['ns_per_sample']:6.1f} ns/sample",
                  flush=True)
        del scene
        gc.collect()
    for n in (1, 2, 4, 8):
        scene = mi.load_dict(tiled_scene(n, 256))
        t = timed(scene, 64)
        results[f"{n} material(s), 256² / 64 spp"] = {"samples": 256 * 256 * 64, "median_s": t,
                                                      "ns_per_sample": t / (256 * 256 * 64) * 1e9}
        print(f"{n} material(s)  {t:7.3f} s", flush=True)
        del scene
        gc.collect()
    write("scaling", {"repeats": args.repeats, "results": results,
                      "note": "linear scaling means constant ns per sample"})


if __name__ == "__main__":
    main()
