"""The spread of the lattice lobe's sample weights (corona.mitsuba.sphere_lattice.LatticeSampler)
against uniform sampling of the sphere of directions: the relative standard deviation of
``mean_λ Z / pdf`` per sample (``Z = P S``, the uncapped lobe; four wavelengths a lane), 10⁶ samples,
1 µm spheres, crystallites of 20 spacings (the default).  The mean weights of both are ``∫ Z dΩ``
averaged over the lane's wavelengths and must agree within their errors.

Run ``python benchmarks/lattice_sampling.py``.
"""
from __future__ import annotations

import warnings

import numpy as np

import corona


def main(n=1_000_000):
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(corona.default_variant(prefer_gpu=False))
    corona.register()
    from corona.mitsuba.sphere_lattice import LatticeSampler
    import sys
    sys.path.insert(0, "tests")
    from bsdf_checks import interaction
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    print("| crystal | θi | mean weight (mixture) | (uniform) | rel. std (mixture) | (uniform) | variance ratio |")
    print("|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(1)
    for kind, a, jitter in (("hexagonal", 4.0, 0.0), ("square", 3.0, 0.15)):
        lat = corona.Lattice(kind, a, jitter=jitter)
        smp = LatticeSampler(bsdf.lobe, lat)
        for theta in (0.0, 30.0):
            th = np.radians(theta)
            si = interaction(n, (float(np.sin(th)), 0.0, float(np.cos(th))))
            u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
            wo, pdf = smp.sample(si, u[0], mi.Point2f(u[1], u[2]))
            Z = smp.lobe(si, wo)
            w_mix = np.asarray(dr.select(pdf > 0, sum(Z) / len(Z) / dr.maximum(pdf, 1e-30), 0.0), dtype=np.float64)
            wo_u = mi.warp.square_to_uniform_sphere(mi.Point2f(u[1], u[2]))
            Zu = smp.lobe(si, wo_u)
            w_uni = np.asarray(sum(Zu) / len(Zu), dtype=np.float64) * 4 * np.pi
            f = lambda w: (w.mean(), w.std() / w.mean())
            (m1, s1), (m2, s2) = f(w_mix), f(w_uni)
            print(f"| {kind} a={a:g} δ={jitter:g} | {theta:g}° | {m1:.4f} ± {m1 * s1 / np.sqrt(n):.4f} | "
                  f"{m2:.4f} ± {m2 * s2 / np.sqrt(n):.4f} | {s1:.2f} | {s2:.2f} | {(s2 * m2) ** 2 / (s1 * m1) ** 2:.0f} |",
                  flush=True)


if __name__ == "__main__":
    main()
