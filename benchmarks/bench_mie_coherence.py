"""What the sphere layer's render costs when its lanes read fewer of its rows (timing only).

The sphere layer (``bench_render.py``'s ``corona-mie``: water, 5 µm, hard disks at 0.4) reads, at
each of a lane's four wavelengths, the rows of its table around that wavelength's size parameter
x = 2π r/λ (thousands of rows in x, tens of MB a lobe).  Random wavelengths spread a render's reads
over all of them.  Here the same scene renders with the wavelengths the layer sees replaced, in
variants that give wrong images and right costs:

* ``as is``: the lane's own four wavelengths (what a render does);
* ``hero``: the lane's first wavelength at all four (each lane one row of x, the lanes' rows random);
* ``N wavelengths``: each wavelength rounded to the nearest of N evenly spaced over 360–830 nm (the
  render reads only the rows of N size parameters);
* ``550 nm``: all four at 550 nm (every lane the same row);
* ``plain rows``: the lane's own wavelengths, the lobes' rows held plain (four scalar gathers a row's
  Catmull–Rom taps, a quarter of the memory) instead of packed (one ``Vector4f`` a row's interval:
  ``corona.mitsuba.sphere.LOBE_PACKING_BYTES`` set to 0 while the scene loads); the same image.

Each variant's render over the opaque circle layer (``corona``) on the same scene, in one process,
its renders interleaved round by round (the medians over the rounds; JIT untimed: a warm-up render
each first).  Only the wavelengths the sphere layer reads change: the rest of the path (the
sensor's spectrum, the light) is as in the render.

    python benchmarks/bench_mie_coherence.py [--res 256] [--spp 64] [--rounds 5] [--levels 8 64 512]

Writes benchmarks/results/mie_coherence.json.  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import types

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

LAMBDA_RANGE = (360.0, 830.0)


def _replaced(bsdf, mode, levels=None):
    """Make the sphere BSDF ``bsdf`` read its rows at other wavelengths (see the module docstring)."""
    import mitsuba as mi
    import drjit as dr
    own = bsdf._wavelengths
    lo, hi = LAMBDA_RANGE
    step = None if levels is None else (hi - lo) / levels

    def wavelengths(self, lams_in):
        lams, m = own(lams_in)
        if mode == "550":
            lams = [mi.Float(550.0) + 0.0 * lam for lam in lams]
        elif mode == "hero":
            lams = [lams[0] + 0.0 * lam for lam in lams]
        elif mode == "levels":
            lams = [lo + (dr.floor((dr.clip(lam, lo, hi - 1e-3) - lo) / step) + 0.5) * step for lam in lams]
        return lams, m
    bsdf._wavelengths = types.MethodType(wavelengths, bsdf)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--levels", type=int, nargs="*", default=[8, 64, 512],
                    help="numbers of distinct wavelengths of the rounded variants")
    ap.add_argument("--name", default="mie_coherence")
    args = ap.parse_args()

    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    from bench_render import BSDFS
    from common import write
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant("llvm_ad_spectral")

    variants = {"circle": ("corona", None, None), "as is": ("corona-mie", None, None),
                "hero": ("corona-mie", "hero", None)}
    variants.update({f"{n} wavelengths": ("corona-mie", "levels", n) for n in args.levels})
    variants["550 nm"] = ("corona-mie", "550", None)
    variants["plain rows"] = ("corona-mie", "plain", None)
    scenes = {}
    import corona.mitsuba.sphere as sphere_module
    for name, (key, mode, levels) in variants.items():
        packing = sphere_module.LOBE_PACKING_BYTES
        if mode == "plain":
            sphere_module.LOBE_PACKING_BYTES = 0
        try:
            scene = mi.load_dict(street_light_scene(resolution=args.res, bsdf=BSDFS[key]))
        finally:
            sphere_module.LOBE_PACKING_BYTES = packing
        if mode == "plain":
            found = [s.bsdf() for s in scene.shapes() if hasattr(s.bsdf(), "chords")]
            assert found and all(isinstance(b.chords, sphere_module.PlainChordRows) for b in found), \
                "the rows are still packed"
        elif mode is not None:
            found = [s.bsdf() for s in scene.shapes() if hasattr(s.bsdf(), "_wavelengths")]
            assert found, "no sphere layer in the scene"
            for bsdf in found:
                _replaced(bsdf, mode, levels)
        scenes[name] = scene

    def timed(scene, seed):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=args.spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return time.perf_counter() - t0

    for scene in scenes.values():       # JIT compile and first loads out of the clock
        timed(scene, 0)
    times = {name: [] for name in scenes}
    load0 = os.getloadavg()[0]
    for r in range(args.rounds):
        for name, scene in scenes.items():
            times[name].append(timed(scene, r + 1))
    circle = statistics.median(times["circle"])
    results = {}
    for name, ts in times.items():
        results[name] = {"median_s": statistics.median(ts), "min_s": min(ts), "times_s": ts,
                         "over_circle": statistics.median(ts) / circle,
                         "over_circle_minima": min(ts) / min(times["circle"]),
                         "rounds_over_circle": [t / c for t, c in zip(ts, times["circle"])]}
        print(f"{name:18s} median {results[name]['median_s']:.3f} s  / circle {results[name]['over_circle']:.3f}"
              f"  (minima {results[name]['over_circle_minima']:.3f})", flush=True)
    write(args.name, {"resolution": args.res, "spp": args.spp, "rounds": args.rounds, "bsdf": BSDFS["corona-mie"],
                      "results": results, "load_average_1min": [load0, os.getloadavg()[0]],
                      "goal": "corona-mie / corona <= 1.2 (bench_render.py); the variants are timing only"})


if __name__ == "__main__":
    main()
