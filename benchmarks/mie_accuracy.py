"""Accuracy of the renderer's Mie sphere lobes against Mie theory at the same (x, m).

For a dilute Poisson layer at normal incidence, the tabulated forward and backward lobes
(``SphereMaterial._lobes``, which the plugin evaluates identically) are compared with
``corona.model.mie.theory.amplitudes`` evaluated directly (independent of the table builder), on a fine
grid of the scattering angle:

* energy-weighted RMS: ``sqrt(Σ w (P_tab/P_mie - 1)²)``, weights ``w ∝ P_mie dΩ``;
* scale: ``∫ P_tab dΩ / ∫ P_mie dΩ - 1`` over the lobe;
* rings: the relative shift of the first three minima and maxima of the forward lobe (each
  against the table's extremum of the same kind nearest it).

Run ``python benchmarks/mie_accuracy.py [RADII [WAVELENGTHS]]`` (comma-separated; prints a markdown
table and rewrites benchmarks/results/mie_accuracy.json after each radius).
"""
from __future__ import annotations

import sys
import time

import numpy as np

import corona
from corona.model.mie import theory as mie


def _extrema(theta, p, n=3):
    d = np.diff(p)
    mins = np.where((d[:-1] < 0) & (d[1:] >= 0))[0] + 1
    maxs = np.where((d[:-1] > 0) & (d[1:] <= 0))[0] + 1
    return theta[mins[:n]], theta[maxs[:n]]


def _refine(theta, p, idx):
    """Parabolic refinement of a discrete extremum."""
    out = []
    for i in idx:
        y0, y1, y2 = p[i - 1], p[i], p[i + 1]
        den = y0 - 2 * y1 + y2
        off = 0.5 * (y0 - y2) / den if den != 0 else 0.0
        out.append(theta[i] + off * (theta[1] - theta[0]))
    return np.array(out)


def lobe_errors(material, wavelength: float) -> dict:
    """Errors of the tabulated lobes of ``material`` at ``wavelength`` [nm] (normal incidence)."""
    sph = material.sphere
    x = 2 * np.pi * sph.radius / (wavelength * 1e-3)
    out = {}
    for which in ("f", "b"):
        n = int(min(200000, max(20000, 400 * x)))
        th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)         # angle from the lobe's axis
        ang = th if which == "f" else np.pi - th               # scattering angle
        wi = np.array([0.0, 0.0, 1.0])
        wo = np.stack([np.sin(ang), 0 * ang, -np.cos(ang)], -1)
        Zf, Zb, fwd = material._lobes(wi, wo, wavelength)
        tab = np.where(fwd, Zf, Zb)
        Zf, Zb, fwd = material._lobes(wi, wo, wavelength, exact=True)
        ref = np.where(fwd, Zf, Zb)
        w = ref * np.sin(th)
        w = w / w.sum()
        ok = ref > 0
        rel = np.where(ok, tab / np.where(ok, ref, 1) - 1, 0)
        out[which + "_rms"] = float(np.sqrt(np.sum(w * rel**2)))
        out[which + "_scale"] = float(np.sum(tab * np.sin(th)) / np.sum(ref * np.sin(th)) - 1)
        if which == "f":
            d = np.diff(ref)
            mins = (np.where((d[:-1] < 0) & (d[1:] >= 0))[0] + 1)[:3]
            maxs = (np.where((d[:-1] > 0) & (d[1:] <= 0))[0] + 1)[:3]
            dt = np.diff(tab)
            tab_ext = {1: np.where((dt[:-1] < 0) & (dt[1:] >= 0))[0] + 1,
                       -1: np.where((dt[:-1] > 0) & (dt[1:] <= 0))[0] + 1}
            shifts = []
            for idx, sign in ((mins, 1), (maxs, -1)):
                for i in idx:        # the table's extremum of the same kind nearest the reference's
                    cand = tab_ext[sign]
                    if not cand.size:
                        shifts.append(float("inf"))
                        continue
                    k = int(cand[np.argmin(np.abs(cand - i))])
                    t_ref = _refine(th, ref, [i])[0]
                    t_tab = _refine(th, tab, [k])[0]
                    shifts.append(abs(t_tab / t_ref - 1))
            out["rings"] = float(max(shifts)) if shifts else float("nan")
    return out


def main(radii=(0.5, 2.0, 5.0, 8.0, 10.0, 20.0, 25.0), wavelengths=(361.3, 452.7, 551.9, 648.2, 829.1),
         iors=(None, 1.5), results=None, done=None):
    """Print the table; append one dict per (radius, ior, λ) to ``results`` if given and call
    ``done()`` after each radius (the results so far survive an interrupted run)."""
    print("| radius µm | ior | build s | λ nm | fwd RMS % | fwd scale % | rings % | back RMS % | back scale % |")
    print("|---|---|---|---|---|---|---|---|---|")
    for ior in iors:
        for r in radii:
            mat = corona.Material(corona.Sphere(r, ior=ior), corona.Poisson(area_fraction=0.01), use_cache=False)
            t0, c0 = time.perf_counter(), time.process_time()
            _ = mat.rows
            _ = mat._derived
            build, build_cpu = time.perf_counter() - t0, time.process_time() - c0
            for lam in wavelengths:
                e = lobe_errors(mat, lam)
                if results is not None:
                    results.append({"radius": r, "ior": "water" if ior is None else ior, "wavelength": lam,
                                    "build_s": build, "build_cpu_s": build_cpu,
                                    "rows": int(mat.rows["P_f"].shape[0]),
                                    "chord_nodes": int(mat.rows["P_f"].shape[1]), **e})
                print(f"| {r:g} | {'water' if ior is None else ior} | {build:.2f} | {lam:g} | "
                      f"{100 * e['f_rms']:.2f} | {100 * e['f_scale']:+.2f} | {100 * e['rings']:.3f} | "
                      f"{100 * e['b_rms']:.2f} | {100 * e['b_scale']:+.2f} |", flush=True)
            if done is not None:
                done()


if __name__ == "__main__":
    sys.path.insert(0, __import__("os").path.dirname(__file__))
    from common import write
    out: list = []
    main(*[tuple(float(v) for v in a.split(",")) for a in sys.argv[1:3]], results=out,
         done=lambda: write("mie_accuracy", {"results": out, "goal": {"rms": 0.01, "scale": 0.005, "rings": 0.002}}))
