"""Render cost of corona vs Mitsuba's built-in roughdielectric / thindielectric.

One scene (a small bright emitter seen through a screen), 256², 64 spp,
`path` integrator, llvm_ad_spectral by default.  Each BSDF is rendered once
to JIT-compile (timed separately), then `--repeats` rounds that interleave
the BSDFs; medians and the ratios to roughdielectric are written to
benchmarks/results/render.json.

    python benchmarks/bench_render.py [--res 256] [--spp 64] [--repeats 5] [--variant V]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import corona  # noqa: E402  (sets up libLLVM first)
from common import write  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="render")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    from corona.render import setup_variant
    from corona.scenes import street_light_scene
    setup_variant(args.variant)

    bsdfs = {
        "corona": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                   "mode": "particle"},
        "roughdielectric": {"type": "roughdielectric", "alpha": 0.05, "int_ior": 1.5},
        "thindielectric": {"type": "thindielectric", "int_ior": 1.5},
    }
    scenes = {name: mi.load_dict(street_light_scene(resolution=args.res, bsdf=b))
              for name, b in bsdfs.items()}

    def timed(scene, seed):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=args.spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return time.perf_counter() - t0

    first = {name: timed(sc, 0) for name, sc in scenes.items()}  # includes JIT compilation
    times = {name: [] for name in scenes}
    for i in range(args.repeats):  # interleaved, so load changes hit every BSDF alike
        for name, sc in scenes.items():
            times[name].append(timed(sc, i + 1))
    results = {}
    for name in scenes:
        med = statistics.median(times[name])
        results[name] = {"first_render_s": first[name],
                         "jit_compile_s_estimate": max(0.0, first[name] - med),
                         "median_s": med, "times_s": times[name]}
        print(f"{name:16s} first {first[name]:7.3f} s   median {med:7.3f} s")
    ref = results["roughdielectric"]["median_s"]
    for name in results:
        results[name]["ratio_to_roughdielectric"] = results[name]["median_s"] / ref
    print(f"corona / roughdielectric = {results['corona']['ratio_to_roughdielectric']:.3f} (goal <= 1.3)")
    write(args.name, {"scene": "street_light_scene", "resolution": args.res, "spp": args.spp,
                      "integrator": "path", "repeats": args.repeats, "results": results,
                      "goal": "corona <= 1.3 x roughdielectric"})


if __name__ == "__main__":
    main()
