"""Sampling quality: MIS(cosine, light) vs MIS(T_a × T_s, light) (the talk's comparison).

Both strategies render the same scene with the `path` integrator, which
combines BSDF sampling and emitter sampling by the power heuristic; only the
corona lobe's sampling differs (plugin parameter ``sampling = cosine | lobe``).
Scenes: the teaser (a small street light), lycopodium (a point-like light)
and a wide lamp (a light wider than the lobe's core).  With a small light,
emitter sampling alone evaluates the lobe almost exactly, so the two MIS
combinations come out nearly equal; with a wide light, emitter sampling
misses the lobe's peak and the BSDF strategy decides the noise.  RMSE (relative
to the reference's mean) is measured over the whole image and over the corona
region alone (pixels not seeing the light directly).

For each scene: a converged reference (lobe sampling, ``--ref-spp``, other
seeds); RMSE of each strategy at equal spp; time per render; RMSE at equal
time (cosine rendered with the spp that takes the lobe render's time); and
the variance of single-sample lobe weights (one wavelength, normal
incidence).  Writes benchmarks/results/sampling.json.  Goal (issue 7):
>= 10x lower RMSE at equal time.

    python benchmarks/bench_sampling.py [--res 128] [--spp 16] [--ref-spp 2048]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

SCENES = {
    # the teaser: condensation (5 µm droplets, hard disks, particle mode) before a
    # street light of 5 cm radius at 20 m (0.14°): emitter sampling alone is nearly exact
    "teaser": dict(bsdf={"radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                         "mode": "particle"}, light_radius=0.05, fov=30.0),
    # lycopodium spores (15 µm radius, sequential adsorption) on a slide before a
    # point-like light (1 cm at 20 m)
    "lycopodium": dict(bsdf={"radius": 15.0, "area_fraction": 0.4, "process": "rsa",
                             "mode": "particle"}, light_radius=0.01, fov=12.0),
    # the same droplets before a wide lamp (3 m radius at 20 m, 8.5°), wider than the
    # lobe's core: here emitter sampling misses the lobe's peak and BSDF sampling matters
    "wide lamp": dict(bsdf={"radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                            "mode": "particle"}, light_radius=3.0, fov=40.0),
}
LIGHT_DISTANCE = 20.0   # m (street_light_scene's default)


def rmse(img, ref, mask):
    """RMSE over the masked pixels relative to the reference's mean there."""
    return float(np.sqrt(np.mean((img - ref)[mask] ** 2)) / max(np.mean(ref[mask]), 1e-30))


def corona_region(res: int, fov_deg: float, light_radius: float) -> np.ndarray:
    """Pixels that do not see the light directly (3 pixels of margin).

    Pixels on the light's own image are lit through the coherent (delta)
    component, whose noise (choice of component) is the same for both
    strategies; the corona around it is what lobe sampling changes.
    """
    x = (np.arange(res) + 0.5) / res * 2 - 1
    X, Y = np.meshgrid(x, x)
    ang = np.degrees(np.arctan(np.tan(np.radians(fov_deg / 2)) * np.hypot(X, Y)))
    return ang > np.degrees(np.arctan(light_radius / LIGHT_DISTANCE)) + 3 * fov_deg / res


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    args = ap.parse_args()

    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    from common import write
    from corona.render import setup_variant
    from corona.scenes import street_light_scene
    setup_variant(args.variant)

    def render(scene, spp, seed):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=seed)
        arr = np.array(img, dtype=np.float64)[..., :3]
        return arr, time.perf_counter() - t0

    results = {}
    for name, cfg in SCENES.items():
        scenes = {how: mi.load_dict(street_light_scene(
            resolution=args.res, fov=cfg["fov"], light_radius=cfg["light_radius"],
            bsdf={"type": "corona", "sampling": how, **cfg["bsdf"]})) for how in ("lobe", "cosine")}
        # converged reference in passes (lobe sampling, other seeds)
        passes = max(1, args.ref_spp // 256)
        ref = sum(render(scenes["lobe"], args.ref_spp // passes, 1000 + i)[0] for i in range(passes)) / passes
        mask = corona_region(args.res, cfg["fov"], cfg["light_radius"])
        regions = {"image": np.ones_like(mask), "corona": mask}
        out = {}
        for how, sc in scenes.items():
            render(sc, args.spp, 7)                       # JIT warm-up
            times, errs = [], {k: [] for k in regions}
            for seed in range(3):
                img, t = render(sc, args.spp, seed)
                times.append(t)
                for k, m in regions.items():
                    errs[k].append(rmse(img, ref, m))
            out[how] = {"spp": args.spp, "seconds": float(np.median(times))}
            for k in regions:
                out[how][f"rmse_{k}_equal_spp"] = float(np.mean(errs[k]))
        # equal time: give cosine the spp that costs the lobe render's time
        spp_eq = max(1, int(round(args.spp * out["lobe"]["seconds"] / out["cosine"]["seconds"])))
        imgs = [render(scenes["cosine"], spp_eq, 10 + s)[0] for s in range(3)]
        out["cosine"]["spp_equal_time"] = spp_eq
        for k, m in regions.items():
            out["cosine"][f"rmse_{k}_equal_time"] = float(np.mean([rmse(i, ref, m) for i in imgs]))
            out["lobe"][f"rmse_{k}_equal_time"] = out["lobe"][f"rmse_{k}_equal_spp"]
            for eq in ("spp", "time"):
                out[f"ratio_{k}_equal_{eq}"] = (out["cosine"][f"rmse_{k}_equal_{eq}"]
                                                / out["lobe"][f"rmse_{k}_equal_{eq}"])

        # single-sample weights of the lobe component at normal incidence, one wavelength
        n = 200_000
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(0, 0, 1)
        si.wavelengths = mi.Spectrum(550.0)
        ctx = mi.BSDFContext()
        ctx.type_mask = mi.BSDFFlags.GlossyTransmission
        rng = np.random.default_rng(1)
        s1, s2 = mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
        for how in ("lobe", "cosine"):
            bsdf = mi.load_dict({"type": "corona", "sampling": how, **cfg["bsdf"]})
            w = np.array(bsdf.sample(ctx, si, s1, s2)[1])[0]
            out[how]["weight_mean"] = float(w.mean())
            out[how]["weight_variance"] = float(w.var())
        results[name] = out
        print(f"{name:11s} RMSE cosine/lobe at equal time: whole image {out['ratio_image_equal_time']:.2f}x, "
              f"corona region {out['ratio_corona_equal_time']:.2f}x; single-sample weight variance "
              f"lobe {out['lobe']['weight_variance']:.3g}, cosine {out['cosine']['weight_variance']:.3g}",
              flush=True)
    flat = {}
    for name, out in results.items():
        for how in ("lobe", "cosine"):
            flat[f"{name} / {how}"] = {**out[how], **{k: v for k, v in out.items() if k.startswith("ratio")}}
    write("sampling", {"resolution": args.res, "spp": args.spp, "reference_spp": args.ref_spp,
                       "integrator": "path (MIS with emitter sampling)", "results": flat,
                       "goal": ">= 10x lower RMSE at equal time with T_a x T_s sampling"})


if __name__ == "__main__":
    main()
