"""Sampling quality: MIS(cosine, light) vs MIS(T_a × T_s, light) (the talk's comparison).

Both strategies render the same scene file with the `path` integrator, which
combines BSDF sampling and emitter sampling by the power heuristic; only the
corona lobe's sampling differs (plugin parameter ``sampling = cosine | lobe``,
``-D sampling=...`` of the scenes).

Scenes (from ``scenes/``): the teaser (street lights of 0.14° through
condensation), lycopodium at 10× (a point-like lamp), and the sampling scene
(20 µm droplets before a lamp of 4.8° radius, wider than the lobe); and the
same droplets before a large lamp of 26.6° radius (``street_light_scene``).  With a
small light, emitter sampling alone evaluates the lobe almost exactly, so
both MIS combinations come out close; with a light wider than the lobe,
emitter sampling misses the lobe's peak and the BSDF strategy decides.

For each scene: a converged reference (lobe sampling, ``--ref-spp``, other
seeds); RMSE relative to the reference's mean, over the whole image and over
the halo (the lamps' own images left out, see ``halo_mask``), at equal spp
and at equal time (cosine rendered with the spp that costs the lobe render's time); and
the variance of single-sample lobe weights (one wavelength, normal
incidence).  Writes benchmarks/results/sampling.json.  Goal (issue 7):
>= 10x lower RMSE at equal time.

    python benchmarks/bench_sampling.py [--res 256] [--spp 64] [--ref-spp 4096]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
SCENE_DIR = os.path.join(HERE, "..", "scenes")

SCENES = {   # name: (scene file, extra -D parameters, the layer's parameters for the weights)
    "teaser": ("teaser.xml", {}, {"radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                                  "mode": "particle"}),
    "lycopodium 10x": ("lycopodium.xml", {"fov": "16"},
                       {"radius": 15.0, "size_spread": 0.05, "area_fraction": 0.35, "process": "rsa",
                        "mode": "particle"}),
    "wide lamp": ("sampling.xml", {}, {"radius": 20.0, "area_fraction": 0.4, "process": "hard-disk",
                                       "mode": "particle"}),
    # the same droplets before a lamp of 10 m radius at 20 m (26.6°, a bright diffuser or
    # overcast window filling much of the view): far wider than the lobe
    "large lamp": (None, {"light_radius": 10.0, "fov": 30.0},
                   {"radius": 20.0, "area_fraction": 0.4, "process": "hard-disk", "mode": "particle"}),
}


def relative_rmse(img, ref, mask=None):
    """RMSE over ``mask`` (default: all pixels), relative to the reference's mean there."""
    if mask is None:
        mask = np.ones(ref.shape[:2], bool)
    return float(np.sqrt(np.mean((img - ref)[mask] ** 2)) / max(float(np.mean(ref[mask])), 1e-30))


def halo_mask(ref) -> np.ndarray:
    """Pixels away from the lamps' own images (the corona around them).

    A lamp seen through the coherent (delta) component is orders of magnitude
    brighter than its halo and, when it is smaller than a pixel, its pixels'
    noise (does a sample hit the lamp or not?) swamps every other error while
    being the same for both strategies.  Pixels above half the maximum,
    grown by 2 pixels, are left out.
    """
    from scipy import ndimage
    lum = ref.mean(axis=-1)
    return ~ndimage.binary_dilation(lum > 0.5 * lum.max(), iterations=2)


def weight_variance(layer: dict, how: str, n: int = 200_000) -> tuple[float, float]:
    """Mean and variance of single-sample lobe weights (550 nm, normal incidence)."""
    import drjit as dr
    import mitsuba as mi
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(0, 0, 1)
    si.wavelengths = mi.Spectrum(550.0)
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission
    rng = np.random.default_rng(1)
    bsdf = mi.load_dict({"type": "corona", "sampling": how, **layer})
    w = np.array(bsdf.sample(ctx, si, mi.Float(rng.random(n)),
                             mi.Point2f(rng.random(n), rng.random(n)))[1])[0]
    return float(w.mean()), float(w.var())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    args = ap.parse_args()

    import corona  # noqa: F401  (sets up libLLVM first)
    import mitsuba as mi
    from common import write
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant(args.variant)

    def render(scene, spp, seed):
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)[..., :3]
        return img, time.perf_counter() - t0

    results = {}
    for name, (file, defines, layer) in SCENES.items():
        if file is not None:
            path = os.path.join(SCENE_DIR, file)
            scenes = {how: mi.load_file(path, res=str(args.res), sampling=how, **defines)
                      for how in ("lobe", "cosine")}
        else:   # corona.apps.scenes.street_light_scene with these keyword arguments
            scenes = {how: mi.load_dict(street_light_scene(
                resolution=args.res, bsdf={"type": "corona", "sampling": how, **layer}, **defines))
                for how in ("lobe", "cosine")}
        passes = max(1, args.ref_spp // 256)
        ref = sum(render(scenes["lobe"], args.ref_spp // passes, 1000 + i)[0]
                  for i in range(passes)) / passes
        regions = {"image": None, "halo": halo_mask(ref)}
        if regions["halo"].mean() < 0.01:   # the lamp fills the view: no halo to speak of
            del regions["halo"]
        out = {"halo_fraction_of_image": float(regions["halo"].mean()) if "halo" in regions else 0.0}
        for how, sc in scenes.items():
            render(sc, args.spp, 7)                       # JIT warm-up
            runs = [render(sc, args.spp, s) for s in range(args.repeats)]
            out[how] = {"spp": args.spp, "seconds": float(np.median([t for _, t in runs]))}
            for k, m in regions.items():
                out[how][f"rmse_{k}_equal_spp"] = float(np.mean([relative_rmse(i, ref, m) for i, _ in runs]))
            out[how]["weight_mean"], out[how]["weight_variance"] = weight_variance(layer, how)
        # equal time: cosine gets the spp that costs the lobe render's time
        spp_eq = max(1, int(round(args.spp * out["lobe"]["seconds"] / out["cosine"]["seconds"])))
        render(scenes["cosine"], spp_eq, 7)               # a new spp may compile anew
        runs = [render(scenes["cosine"], spp_eq, 10 + s)[0] for s in range(args.repeats)]
        out["cosine"]["spp_equal_time"] = spp_eq
        ratios = {"halo_fraction_of_image": out.pop("halo_fraction_of_image") if "halo" in regions else 0.0}
        for k, m in regions.items():
            out["cosine"][f"rmse_{k}_equal_time"] = float(np.mean([relative_rmse(i, ref, m) for i in runs]))
            out["lobe"][f"rmse_{k}_equal_time"] = out["lobe"][f"rmse_{k}_equal_spp"]
            for eq in ("spp", "time"):
                ratios[f"rmse_ratio_{k}_equal_{eq}"] = (out["cosine"][f"rmse_{k}_equal_{eq}"]
                                                        / out["lobe"][f"rmse_{k}_equal_{eq}"])
        ratios["weight_variance_ratio"] = out["cosine"]["weight_variance"] / out["lobe"]["weight_variance"]
        for how in ("lobe", "cosine"):
            results[f"{name} / {how}"] = {**out[how], **ratios}
        print(f"{name:15s} RMSE cosine/lobe at equal spp / equal time: whole image "
              f"{ratios['rmse_ratio_image_equal_spp']:.2f}x / {ratios['rmse_ratio_image_equal_time']:.2f}x, "
              + (f"halo {ratios['rmse_ratio_halo_equal_spp']:.2f}x / {ratios['rmse_ratio_halo_equal_time']:.2f}x; "
                 if "halo" in regions else "no halo region (the lamp fills the view); ")
              + "single-sample weight variance ratio "
              f"{ratios['weight_variance_ratio']:.3g}", flush=True)
    write("sampling", {"resolution": args.res, "spp": args.spp, "reference_spp": args.ref_spp,
                       "integrator": "path (MIS with emitter sampling)", "results": results,
                       "goal": ">= 10x lower RMSE at equal time with T_a x T_s sampling",
                       "note": "Both strategies draw the same random numbers, so where emitter sampling "
                               "carries all the weight (lights far smaller than the lobe: the power "
                               "heuristic gives BSDF samples ~ (p_bsdf/p_light)^2 ~ 0) the two images "
                               "are the same at equal spp and equal-time ratios only reflect timing "
                               "noise. BSDF sampling matters for lights wider than the lobe."})


if __name__ == "__main__":
    main()
