"""A ``breath_time`` texture in the Mitsuba plugin against the exact model at each time (issue 46, item 3).

The plugin carries a texture of the breath figure's age as rows over the coverage (it grows with
time), each the material at one time with its radial table resampled to a length ``L ∝ R(t)``,
Hermite-interpolated in F_a between rows; each lane's F_a and R linear in log t
(:meth:`corona.mitsuba.bsdf.CoronaBSDFMixin._time_rows`).  For a texture spanning the whole table
(5–80 s, the whole span the plugin accepts at contact angle 90°) and one of 10–20 s, the
plugin's ``eval`` along a cut through the lobe (normal incidence, four wavelengths) at times on and
between the rows is compared with ``Material(process="breath-figure", breath_time=t)``'s exact lobe:

* ``rms_rel``: RMS relative error over the rings ``u = q R`` in [0.3, 12] where the lobe is above
  1 % of its peak; ``max_over_peak``: the largest error over the lane's peak;

for ``TIME_SUBDIVIDE`` = 1, 2 and 4 (the default) rows per interval of the table's times.
``self_similar``: the design it replaced, for comparison: one lobe at the range's geometric-mean
time scaled to ``R(t)`` (Family & Meakin's self-similarity) and F_a fixed, the same error measure
(numpy, the model's lobes).

Usage: PYTHONPATH=src .venv/bin/python benchmarks/breath_time_texture.py
Writes benchmarks/results/breath_time_texture.json.
"""
from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, os.pardir, "tests"))
from common import write  # noqa: E402

LAMS = (450.0, 550.0, 650.0, 750.0)
RANGES = ((5.0, 80.0), (10.0, 20.0))


def _cut(R, n=300):
    u = np.linspace(0.3, 12.0, n)
    d = u / R * (min(LAMS) * 1e-3) / (2 * np.pi)
    wo = np.column_stack([d, 0 * d, -np.sqrt(1 - d * d)])
    return np.array([0.0, 0.0, 1.0]), wo


def _errors(val, ref):
    keep = ref > 0.01 * ref.max(axis=1, keepdims=True)
    rel = ((val - ref) / ref)[keep]
    return {"rms_rel": float(np.sqrt(np.mean(rel ** 2))),
            "max_over_peak": float(np.max(np.abs(val - ref) / ref.max(axis=1, keepdims=True)))}


def main():
    import mitsuba as mi
    mi.set_variant("llvm_ad_spectral")
    import corona
    from corona.mitsuba import bsdf as plugin
    from corona.parameters import material_from_parameters
    from bsdf_checks import bitmap_texture, plugin_eval, transmitted_lobe
    corona.register()
    warnings.simplefilter("ignore")
    out = {"lams_nm": list(LAMS), "ranges": []}
    models = {}

    def model(t):
        if t not in models:
            models[t] = material_from_parameters(process="breath-figure", breath_time=float(t))
        return models[t]
    for lo, hi in RANGES:
        times = np.exp(np.linspace(np.log(lo), np.log(hi), 15))
        entry = {"range_s": [lo, hi], "times_s": times.tolist(), "subdivide": {}}
        for sub in (1, 2, 4):
            plugin.TIME_SUBDIVIDE = sub
            tex = bitmap_texture(times[None, :].astype(np.float32))
            t0 = time.perf_counter()
            bsdf = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": tex})
            load_s = time.perf_counter() - t0
            errs = []
            for i, t in enumerate(times):
                m = model(float(np.float32(t)))
                wi, wo = _cut(m.process.mean_radius)
                val, _ = plugin_eval(bsdf, wi, wo, LAMS, uv=((i + 0.5) / times.size, 0.5))
                ref = np.stack([transmitted_lobe(m)(wi, wo, lam) for lam in LAMS])
                errs.append(_errors(val, ref))
            entry["subdivide"][str(sub)] = {
                "rows": int(len(bsdf.time_rows)), "load_s": load_s,
                "rms_rel": [e["rms_rel"] for e in errs], "max_over_peak": [e["max_over_peak"] for e in errs],
                "worst_rms_rel": max(e["rms_rel"] for e in errs),
                "worst_max_over_peak": max(e["max_over_peak"] for e in errs)}
            print(lo, hi, sub, entry["subdivide"][str(sub)]["rows"],
                  entry["subdivide"][str(sub)]["worst_rms_rel"], entry["subdivide"][str(sub)]["worst_max_over_peak"])
        plugin.TIME_SUBDIVIDE = 4
        # the self-similar design: the lobe at the geometric-mean time, scaled to R(t), F_a fixed
        ref_m = model(float(np.float32(np.sqrt(lo * hi))))
        rr = ref_m.process.mean_radius
        ss = []
        for t in times:
            m = model(float(np.float32(t)))
            s = m.process.mean_radius / rr
            wi, wo = _cut(m.process.mean_radius)
            d = wo[:, :2] + wi[:2]
            ref = np.stack([m.lobe(d, lam) for lam in LAMS])
            val = np.stack([s * s * ref_m.lobe(d * s, lam) for lam in LAMS])
            ss.append(_errors(val, ref))
        entry["self_similar"] = {"rms_rel": [e["rms_rel"] for e in ss],
                                 "worst_rms_rel": max(e["rms_rel"] for e in ss)}
        print("self-similar", entry["self_similar"]["worst_rms_rel"])
        out["ranges"].append(entry)
    write("breath_time_texture", out)


if __name__ == "__main__":
    main()
