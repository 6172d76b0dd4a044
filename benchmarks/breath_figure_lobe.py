"""The lobe of a breath figure: three approximations of a polydisperse, correlated layer against
the exact far field of the simulated droplets themselves (issue 46, item 2).

For each time (10, 20, 40 s: the coalescence regime of the default run, water on a hemispherical
contact angle, corona.reference.breath_figure with its defaults) and each seed, one simulated
configuration (a 400 µm periodic box; droplets as opaque disks of their contact radius); on the box's
reciprocal lattice, ring averages in ``u = |q| R`` (R = ⟨a³⟩/⟨a²⟩, the area-weighted mean radius;
rings of 0.25 up to u = 14) of (corona.reference.breath_figure_optics):

* ``exact``: ``|Σ_j F_j e^{-i q·r_j}|² / N`` (the brute-force reference);
* ``decoupling``: ``⟨|F|²⟩ + |⟨F⟩|² (S - 1)``, S of all the centres;
* ``local_monodisperse`` (Pedersen 1994): ``⟨|F|² S_HD(2 a q; η)⟩``, η the coverage (≤ 0.72);
* ``partial``: partial structure factors of 12 size classes of equal covered area.

``summary`` holds these figures, each approximation's ingredients measured on the configuration
itself (its error is the approximation's alone).  ``model_summary`` holds the model's: each rule of
:meth:`corona.BreathFigure.intensity` with the shipped table (seeds 1 and 2; the partial structure
factors of its 12 classes) against configurations of seeds 7 and 8 (the table's statistics and its
classes count as well); ``lobe_energy_over_sum_rule``: each rule's lobe energy (the model's
``diffuse_transmittance``) over the sum rule ``F_a (1 - F_a)`` of non-overlapping droplets.

Errors: the RMS and the largest relative error over the rings where the exact lobe is above 1e-3
of its peak; and of the lobe's CIE 1931 X, Y, Z (equal-energy light, 380–780 nm, d = |(wo + wi).xy|
up to where u = 14 at 380 nm): RMS relative error over d where Y is above 1e-3 of its peak.

The fading phase (``fading``): configurations of the held-out seeds grown for
:data:`FADE_BREATH` s (between the table's evaporation starts) and evaporated at 0.1 µm/s until the
fractions :data:`FADE_FRACTIONS` of their water are gone (none of them a table row), against the
model ``BreathFigure(breath_time, dry_time=...)`` by each rule and against each approximation with
the configuration's own ingredients; ``fading_summary`` per dry time (with f = 0, the growing
layer, for reference), and ``ring``: the lobe's peak and energy-weighted mean scattering angle at
550 nm, exact and the model's.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/breath_figure_lobe.py [--seeds 2] [--fading-only]
(``--fading-only`` recomputes the fading rows and keeps the rest of the JSON as it is.)
Writes benchmarks/results/breath_figure_lobe.json.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import write  # noqa: E402

from corona.color import cie1931_xyz  # noqa: E402
from corona.reference.breath_figure import simulate_breath_figure  # noqa: E402
from corona.model.processes.breath_figure import BreathFigure, load_table  # noqa: E402
from corona.reference.breath_figure_optics import far_field_rings, ring_error  # noqa: E402

TIMES = (10.0, 20.0, 40.0)
BOX = 400.0
U_MAX = 14.0
APPROX = ("decoupling", "local_monodisperse", "partial")
#: Seeds of the held-out configurations (the shipped table is made with seeds 1 and 2).
HELD_OUT = (7, 8)
#: Size classes of the partial structure factors (the shipped table's number).
CLASSES = 12
#: The fading phase: growth time [s], fractions of the water evaporated, the evaporation rate [µm/s].
FADE_BREATH = 14.0
FADE_FRACTIONS = (0.3, 0.6, 0.85)
FADE_RATE = 0.1
RULES = {"decoupling": "decoupling", "local_monodisperse": "local-monodisperse", "partial": "partial"}


def fading_rows() -> tuple[list, dict]:
    """The fading phase against the model (module docstring)."""
    rows = []
    for seed in HELD_OUT:
        grown = simulate_breath_figure([FADE_BREATH], box=BOX, seed=seed)
        h0 = float(grown.total_volume[0]) / BOX ** 2
        taus = np.array(FADE_FRACTIONS) * h0 / FADE_RATE
        bf = simulate_breath_figure(np.concatenate([[FADE_BREATH], FADE_BREATH + taus]), box=BOX, seed=seed,
                                    dry_from=FADE_BREATH, evaporation_rate=FADE_RATE)
        for i, (f, tau) in enumerate(zip((0.0,) + FADE_FRACTIONS, np.concatenate([[0.0], taus]))):
            a, c = bf.radii[i], bf.centres[i]
            R = float(np.sum(a ** 3) / np.sum(a ** 2))
            t1 = time.perf_counter()
            r = far_field_rings(c, a, BOX, length=R, u_max=U_MAX, classes=CLASSES)
            n = a.size / BOX ** 2
            proc = BreathFigure(breath_time=FADE_BREATH, dry_time=float(tau), evaporation_rate=FADE_RATE)
            m = {"u": r["u"], "exact": r["exact"]}
            for key, rule in RULES.items():
                m[key] = proc.number_density * proc.intensity(r["u"] / R, rule) / n
            # the ring: the lobe's peak as a scattering angle at 550 nm, and its energy-weighted mean
            # angle (up to u = 14), of the exact far field and of the model's rule
            ring = {}
            for key in ("exact", BreathFigure.RULE):
                th = np.degrees(np.arcsin(np.clip(r["u"] / R * 0.55 / (2 * np.pi), 0, 1)))
                w = m[key] * r["u"]
                ring[key] = {"peak_deg_550nm": float(th[int(np.argmax(m[key]))]),
                             "mean_deg_550nm": float(np.sum(w * th) / np.sum(w))}
            rows.append(dict(seed=seed, breath_time_s=FADE_BREATH, evaporated=f, dry_time_s=float(tau),
                             drops=int(a.size), coverage=float(bf.coverage[i]), ring=ring,
                             table_coverage=proc.area_fraction(None), area_weighted_radius_um=R,
                             table_radius_um=proc.mean_radius, density=n, table_density=proc.number_density,
                             far_field_s=time.perf_counter() - t1,
                             own_rings=ring_errors(r), rings=ring_errors(m), xyz=xyz_errors(m, R, n)))
            print("fading", seed, f, round(tau, 2), {k: round(v["rms"], 4) for k, v in rows[-1]["rings"].items()},
                  flush=True)
    summary = {}
    for f in (0.0,) + FADE_FRACTIONS:
        at = [r for r in rows if r["evaporated"] == f]
        summary[f"{f:g}"] = {
            "ring": {key: {k: float(np.mean([r["ring"][key][k] for r in at]))
                           for k in ("peak_deg_550nm", "mean_deg_550nm")} for key in at[0]["ring"]},
            "dry_time_s": float(np.mean([r["dry_time_s"] for r in at])),
            "coverage": float(np.mean([r["coverage"] for r in at])),
            "table_coverage": float(at[0]["table_coverage"]),
            "radius_um": float(np.mean([r["area_weighted_radius_um"] for r in at])),
            "table_radius_um": float(at[0]["table_radius_um"]),
            **{k: {"ring_rms_mean": float(np.mean([r["rings"][k]["rms"] for r in at])),
                   "ring_max": float(np.max([r["rings"][k]["max"] for r in at])),
                   "own_ingredients_ring_rms_mean": float(np.mean([r["own_rings"][k]["rms"] for r in at])),
                   "xyz_rms_max": float(np.max([max(r["xyz"][k].values()) for r in at]))} for k in APPROX}}
    return rows, summary


def ring_errors(r: dict) -> dict:
    return {k: ring_error(r["exact"], r[k]) for k in APPROX}


def xyz_errors(r: dict, R: float, density: float) -> dict:
    lam = np.arange(380.0, 781.0, 5.0)                          # nm
    cmf = cie1931_xyz(lam)                                      # (n_lambda, 3)
    lam_um = lam * 1e-3
    d = np.linspace(0.0, U_MAX * lam_um[0] / (2 * np.pi * R), 400)[1:]
    u = 2 * np.pi * R * d[:, None] / lam_um[None, :]            # (n_d, n_lambda)

    def xyz(values):
        lobe = density * np.interp(u, r["u"], values) / lam_um[None, :] ** 2     # n I(q) / λ² [sr⁻¹]
        return lobe @ cmf * 5.0
    ref = xyz(r["exact"])
    sel = ref[:, 1] > 1e-3 * ref[:, 1].max()
    out = {}
    for k in APPROX:
        rel = xyz(r[k])[sel] / ref[sel] - 1.0
        out[k] = {c: float(np.sqrt(np.mean(rel[:, i] ** 2))) for i, c in enumerate("XYZ")}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--fading-only", action="store_true")
    args = ap.parse_args()
    far_field_rings(np.array([[1.0, 1.0]]), np.array([0.5]), 10.0, length=1.0, u_max=2.0)   # compile
    fade, fade_summary = fading_rows()
    fading = {"fading_setup": {"breath_time_s": FADE_BREATH, "evaporated_fractions": list(FADE_FRACTIONS),
                               "evaporation_rate_um_per_s": FADE_RATE, "seeds": list(HELD_OUT)},
              "fading": fade, "fading_summary": fade_summary, "fading_table": load_table()["metadata"]}
    if args.fading_only:
        import json
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "breath_figure_lobe.json")
        with open(path) as fh:
            old = json.load(fh)
        old.pop("machine", None)
        write("breath_figure_lobe", {**old, **fading})
        return
    t_table = time.perf_counter()
    BreathFigure(breath_time=20.0)                   # the shipped table, loaded once
    t_table = time.perf_counter() - t_table
    rows = []
    for seed in range(1, 1 + args.seeds):
        t0 = time.perf_counter()
        bf = simulate_breath_figure(TIMES, box=BOX, seed=seed)
        sim_s = time.perf_counter() - t0
        for i, t in enumerate(TIMES):
            a, c = bf.radii[i], bf.centres[i]
            R = float(np.sum(a ** 3) / np.sum(a ** 2))
            t1 = time.perf_counter()
            r = far_field_rings(c, a, BOX, length=R, u_max=U_MAX, classes=CLASSES)
            rows.append(dict(seed=seed, time_s=t, drops=int(a.size), coverage=float(bf.coverage[i]),
                             eta=r["eta"], area_weighted_radius_um=R, mean_radius_um=float(a.mean()),
                             simulation_s=sim_s, far_field_s=time.perf_counter() - t1,
                             rings=ring_errors(r), xyz=xyz_errors(r, R, a.size / BOX ** 2)))
            print({k: rows[-1][k] for k in ("seed", "time_s", "drops", "coverage", "far_field_s")},
                  {k: round(v["rms"], 4) for k, v in rows[-1]["rings"].items()}, flush=True)
    # the model: each rule from the shipped table (seeds 1, 2) against configurations of other seeds
    held = []
    rules = RULES
    for seed in HELD_OUT:
        bf = simulate_breath_figure(TIMES, box=BOX, seed=seed)
        for i, t in enumerate(TIMES):
            a, c = bf.radii[i], bf.centres[i]
            R = float(np.sum(a ** 3) / np.sum(a ** 2))
            r = far_field_rings(c, a, BOX, length=R, u_max=U_MAX)
            n = a.size / BOX ** 2
            proc = BreathFigure(breath_time=t)
            m = {"u": r["u"], "exact": r["exact"]}
            for key, rule in rules.items():      # per area, in the config's per-droplet units
                m[key] = proc.number_density * proc.intensity(r["u"] / R, rule) / n
            held.append(dict(seed=seed, time_s=t, drops=int(a.size), coverage=float(bf.coverage[i]),
                             table_coverage=proc.area_fraction(None), table_density=proc.number_density,
                             density=n, rings=ring_errors(m), xyz=xyz_errors(m, R, n)))
            print("held out", seed, t, {k: round(v["rms"], 4) for k, v in held[-1]["rings"].items()}, flush=True)
    # the lobe's energy against the sum rule of non-overlapping droplets, F_a (1 - F_a), per rule
    import corona
    energy = {}
    keep = BreathFigure.RULE
    try:
        for key, rule in rules.items():
            BreathFigure.RULE = rule
            energy[key] = {}
            for t in TIMES:
                m = corona.Material(corona.Circle(1.0), BreathFigure(breath_time=t), mode="particle",
                                    use_cache=False)
                fa = m.area_fraction
                energy[key][f"{t:g}s"] = float(m.diffuse_transmittance() / (fa * (1 - fa)))
    finally:
        BreathFigure.RULE = keep
    summary = {}
    for t in TIMES:
        at = [r for r in rows if r["time_s"] == t]
        summary[f"{t:g}s"] = {k: {"ring_rms_mean": float(np.mean([r["rings"][k]["rms"] for r in at])),
                                  "ring_max": float(np.max([r["rings"][k]["max"] for r in at])),
                                  "xyz_rms_max": float(np.max([max(r["xyz"][k].values()) for r in at]))}
                              for k in APPROX}
    model = {}
    for t in TIMES:
        at = [r for r in held if r["time_s"] == t]
        model[f"{t:g}s"] = {k: {"ring_rms_mean": float(np.mean([r["rings"][k]["rms"] for r in at])),
                                "ring_max": float(np.max([r["rings"][k]["max"] for r in at])),
                                "xyz_rms_max": float(np.max([max(r["xyz"][k].values()) for r in at]))}
                            for k in APPROX}
    best = {t: min(APPROX, key=lambda k: v[k]["ring_rms_mean"]) for t, v in summary.items()}
    best_model = {t: min(APPROX, key=lambda k: v[k]["ring_rms_mean"]) for t, v in model.items()}
    write("breath_figure_lobe", {
        "what": "breath-figure lobe: decoupling, local monodisperse and partial-structure-factor "
                "approximations against the exact far field of the simulated droplets (issue 46)",
        "command": "PYTHONPATH=src .venv/bin/python benchmarks/breath_figure_lobe.py --seeds "
                   f"{args.seeds}",
        "setup": {"box_um": BOX, "times_s": list(TIMES), "u_max": U_MAX, "ring_du": 0.25,
                  "size_classes": CLASSES, "length": "area-weighted mean contact radius <a^3>/<a^2>",
                  "droplet": "opaque disk of its contact radius (theta = 90 deg)",
                  "simulation": "corona.reference.breath_figure defaults (flux 0.1 um/s, "
                                "nucleation 0.05 /um^2/s, nuclei 0.25 um)"},
        "table": {**load_table()["metadata"], "load_s": t_table},
        "runs": rows, "summary": summary, "closest": best,
        "model_held_out": held, "model_summary": model, "model_closest": best_model,
        "model_rule": BreathFigure.RULE, "lobe_energy_over_sum_rule": energy, **fading})


if __name__ == "__main__":
    main()
