#!/usr/bin/env python
"""Benchmark and accuracy report of the hard-disk structure factor.

Writes ``benchmarks/results/hard_disk.json`` with

* ``lookup``: time of a cold table lookup for a material (load the npz,
  build the η interpolation, evaluate ``S`` on 2^18 points) and of a warm one;
* ``regenerate_row``: wall and CPU time to regenerate one table row
  (default η = 0.72, the most expensive row settings) with ``--jobs 2``, and
  its largest difference from the shipped row (the runs are seeded, so a
  regenerated row is identical);
* ``henderson``: per row, pressure ``Z``, contact value ``g(σ⁺)`` (from g(r)
  and from Z) and the table's ``S(0)`` against Henderson's equation of state;
* ``sum_rule``: ``∫ T_a T_s d²d`` against ``1 - F_a`` for circles;
* ``percus_yevick``: per row, the largest ``|S_table - S_PY|`` over
  ``qσ ∈ [0, 40]``, the first-peak heights, and the PY contact value;
* ``interpolation``: leave-one-row-out error of the η interpolation;
* ``tail``: error of the large-q tail model, tested on PY data;
* ``error_bars``: per row, the largest stored standard error of the smoothed
  row (issue 18: < 0.003 in the rows run with more chains);
* ``raw_vs_smoothed``: raw data minus the smoothed row around the first three
  peaks of every row η <= 0.69 (z-scores: the smoothing must not bias peaks);
* ``smoothing_bias``: the smoother on synthetic rows (Percus-Yevick at η + 0.01
  with the real rows' bins and errors): bias against noise per qσ band;
* ``metropolis``: the table against the independent Metropolis runs of
  ``tests/data/hard_disk_metropolis.json`` (scripts/check_hard_disk_table.py).

Usage: ``python benchmarks/bench_hard_disk.py [--eta 0.72] [--skip-regenerate]``
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import tempfile
import time

import numpy as np
from scipy import special

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from corona.model.processes import HardDisk  # noqa: E402
from corona.reference import hard_disk as hd  # noqa: E402
from corona.model.shapes import Circle  # noqa: E402


def _script():
    spec = importlib.util.spec_from_file_location(
        "make_hard_disk_table", os.path.join(ROOT, "scripts", "make_hard_disk_table.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _gl_panels(a, b, width, order=16):
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.arange(a, b + 0.5 * width, width)
    edges[-1] = b
    lo, hi = edges[:-1, None], edges[1:, None]
    return ((0.5 * (hi - lo) * x + 0.5 * (hi + lo)).ravel(), (0.5 * (hi - lo) * w).ravel())


def sum_rule(fa, radius=1.0):
    shape, proc = Circle(radius), HardDisk(fa)
    U = 20.0
    u, w = _gl_panels(0.0, U, 0.05)
    q = u / radius
    inner = np.sum(w * shape.form_factor_radial(q) * proc.structure_factor_radial(q, shape) * q)
    u2, w2 = _gl_panels(U, 3000.0, 0.5, 8)
    q2 = u2 / radius
    tail = np.sum(w2 * shape.form_factor_radial(q2) * (proc.structure_factor_radial(q2, shape) - 1) * q2)
    return float((inner + tail) / (2 * np.pi * radius) + special.j0(U) ** 2 + special.j1(U) ** 2)


def bench_lookup():
    hd.load_table.cache_clear()
    from corona.model.processes import hard_disk as lookup
    lookup.load_table.cache_clear()
    lookup._lookup_arrays.cache_clear()
    lookup._row.cache_clear()
    shape = Circle(0.5)
    q = np.linspace(0.0, 2000.0, 2**18)
    t0 = time.perf_counter()
    S = HardDisk(0.437).structure_factor_radial(q, shape)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    HardDisk(0.437).structure_factor_radial(q, shape)
    warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    HardDisk(0.551).structure_factor_radial(q, shape)
    new_eta = time.perf_counter() - t0
    assert np.all(np.isfinite(S))
    # the same in a fresh interpreter (nothing cached; imports not counted)
    import subprocess
    code = ("import time, numpy as np; from corona.model.processes import HardDisk; "
            "from corona.model.shapes import Circle; q = np.linspace(0.0, 2000.0, 2**18); "
            "t0 = time.perf_counter(); HardDisk(0.437).structure_factor_radial(q, Circle(0.5)); "
            "print(time.perf_counter() - t0)")
    fresh = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 check=True, cwd=ROOT).stdout.split()[-1])
    return dict(points=int(q.size), cold_seconds=cold, fresh_process_seconds=fresh,
                warm_seconds=warm,
                new_packing_fraction_seconds=new_eta, limit_seconds=0.2,
                ok=bool(max(cold, fresh) <= 0.2))


def bench_regenerate(eta, jobs=2):
    mk = _script()
    t = hd.load_table()
    i = int(np.flatnonzero(np.isclose(t["eta"], eta))[0])
    with tempfile.TemporaryDirectory() as tmp:
        c0 = os.times()
        t0 = time.perf_counter()
        raw = mk.simulate_row(float(t["eta"][i]), jobs, tmp, progress=False)
        row = mk.smooth_row(raw)
        wall = time.perf_counter() - t0
        c1 = os.times()
    cpu_children = (c1.children_user + c1.children_system) - (c0.children_user + c0.children_system)
    cpu_self = (c1.user + c1.system) - (c0.user + c0.system)
    diff = float(np.max(np.abs(row["S"] - t["S"][i])))
    load = os.getloadavg()
    return dict(eta=float(t["eta"][i]), jobs=jobs, settings=mk.row_settings(float(t["eta"][i])),
                wall_seconds=wall, cpu_seconds_chains=float(raw["cpu"]),
                cpu_seconds_process_tree=cpu_children + cpu_self,
                ideal_wall_on_2_free_cores=float(raw["cpu"]) / 2 + (wall - float(raw["wall"])),
                max_abs_diff_from_shipped_row=diff, load_average_1_5_15=list(load),
                cpu_count=os.cpu_count(), limit_seconds=60.0)


def bench_henderson():
    t = hd.load_table()
    rows = []
    for k, eta in enumerate(t["eta"]):
        if eta == 0:
            continue
        Zh = float(hd.henderson_compressibility_factor(eta))
        gh = float(hd.henderson_contact_value(eta))
        S0h = float(hd.henderson_structure_factor_zero(eta))
        Z = float(t["Z"][k])
        rows.append(dict(eta=float(eta), Z=Z, Z_err=float(t["Z_err"][k]), Z_henderson=Zh,
                         Z_rel_err=Z / Zh - 1,
                         contact_g=float(t["contact_value"][k]),
                         contact_g_err=float(t["contact_value_err"][k]),
                         contact_pressure=(Z - 1) / (2 * eta), contact_henderson=gh,
                         contact_g_rel_err=float(t["contact_value"][k]) / gh - 1,
                         S0_table=float(t["S"][k, 0]), S0_henderson=S0h,
                         S0_rel_err=float(t["S"][k, 0]) / S0h - 1,
                         psi6=float(t["psi6"][k]), min_distance=float(t["min_distance"][k]),
                         cpu_seconds=float(t["cpu_seconds"][k])))
    return rows


def bench_py():
    t = hd.load_table()
    out = []
    q = t["q_sigma"]
    for k, eta in enumerate(t["eta"]):
        if eta == 0:
            continue
        py = hd.structure_factor_py(q, eta)
        d = t["S"][k] - py
        j = int(np.argmax(np.abs(d)))
        out.append(dict(eta=float(eta), max_abs_err=float(np.abs(d[j])), at_q_sigma=float(q[j]),
                        rms_err=float(np.sqrt(np.mean(d**2))),
                        peak_table=float(t["S"][k].max()), peak_py=float(py.max()),
                        peak_q_table=float(q[np.argmax(t["S"][k])]), peak_q_py=float(q[np.argmax(py)]),
                        S0_py=float(py[0]), contact_py=hd.contact_value_percus_yevick(eta),
                        contact_simulation=float((t["Z"][k] - 1) / (2 * eta))))
    return out


def bench_interpolation():
    from scipy.interpolate import PchipInterpolator
    t = hd.load_table()
    eta, S = t["eta"], t["S"]
    out = []
    for k in range(1, len(eta) - 1):
        keep = np.arange(len(eta)) != k
        pred = PchipInterpolator(eta[keep], S[keep], axis=0)(eta[k])
        out.append(dict(eta=float(eta[k]), spacing_without_row=float(eta[k + 1] - eta[k - 1]),
                        max_abs_err=float(np.max(np.abs(pred - S[k])))))
    return out


def bench_tail():
    out = []
    for eta in (0.2, 0.5, 0.7):
        q = np.linspace(20, 42, 441)
        y = hd.structure_factor_py(q, eta) - 1
        A = -8 * eta * hd.contact_value_percus_yevick(eta)
        b1, b2 = hd.tail_basis(q)
        B = float(np.sum(b2 * (y - A * b1)) / np.sum(b2**2))
        qq = np.linspace(40, 300, 2601)
        c1, c2 = hd.tail_basis(qq)
        err = np.abs(1 + A * c1 + B * c2 - hd.structure_factor_py(qq, eta))
        out.append(dict(eta=eta, max_abs_err_40_300=float(err.max()),
                        max_abs_S_minus_1_at_40_45=float(np.abs(
                            hd.structure_factor_py(np.linspace(40, 45, 101), eta) - 1).max())))
    return out


def bench_error_bars():
    """Per row: the largest stored standard error of the smoothed row and where."""
    t = hd.load_table()
    if "S_err" not in t:
        return []
    return [dict(eta=float(e), max_err=float(t["S_err"][i].max()),
                 at_q_sigma=float(t["q_sigma"][np.argmax(t["S_err"][i])]),
                 median_err=float(np.median(t["S_err"][i])),
                 chains=int(json.loads(str(t["settings"][i])).get("n_chains", 0)))
            for i, e in enumerate(t["eta"]) if e > 0]


def bench_raw_vs_smoothed():
    """Raw binned data minus the smoothed row around the first three peaks (z-scores)."""
    t = hd.load_table()
    return [w for e in t["eta"] if 0 < e <= 0.69 + 1e-9 for w in hd.raw_minus_smoothed(float(e))]


def bench_smoothing_bias(n_resamples=8):
    """Bias of the smoother on synthetic rows: truth = Percus-Yevick at η + 0.01
    (more structure in the residual than the real rows), the real rows' bins
    and errors; max |mean(smoothed - truth)| and the noise, per band."""
    t = hd.load_table()
    out = []
    for eta in (0.3, 0.5, 0.65):
        i = int(np.flatnonzero(np.isclose(t["eta"], eta))[0])
        ok = np.isfinite(t["raw_S"][i])
        bias, sd = hd.smoothing_bias(t["raw_q"][i][ok], t["raw_S_err"][i][ok], eta,
                                     lambda q, e=eta: hd.structure_factor_percus_yevick(q, e + 0.01),
                                     n_resamples=n_resamples)
        q = hd.TABLE_Q_SIGMA
        for lo, hi in ((4.0, 8.0), (10.0, 14.0), (16.0, 20.0), (20.0, 40.0)):
            sel = (q >= lo) & (q < hi)
            out.append(dict(eta=eta, band=[lo, hi], max_abs_bias=float(np.abs(bias[sel]).max()),
                            max_noise=float(sd[sel].max()),
                            bias_standard_error=float(sd[sel].max() / np.sqrt(n_resamples))))
    return out


def bench_metropolis():
    """The table against the independent Metropolis runs of tests/data."""
    from corona.reference import hard_disk_metropolis as hm
    path = os.path.join(ROOT, "tests", "data", "hard_disk_metropolis.json")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        runs = json.load(f)["runs"]
    return [dict(c, metropolis_cpu_seconds=r["cpu_seconds"]) for r in runs for c in hm.compare_with_table(r)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eta", type=float, default=0.72, help="row to regenerate")
    ap.add_argument("--skip-regenerate", action="store_true")
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results", "hard_disk.json"))
    a = ap.parse_args(argv)
    res = dict(machine=dict(python=platform.python_version(), cpu_count=os.cpu_count(),
                            platform=platform.platform()),
               table_metadata=hd.load_table()["metadata"])
    res["lookup"] = bench_lookup()
    print("lookup", res["lookup"], flush=True)
    res["henderson"] = bench_henderson()
    res["sum_rule"] = [dict(area_fraction=fa, integral=v, expected=1 - fa, rel_err=v / (1 - fa) - 1)
                       for fa in (0.1, 0.3, 0.5, 0.65, 0.7, 0.72) for v in [sum_rule(fa)]]
    print("sum rule", [(r["area_fraction"], round(r["rel_err"], 5)) for r in res["sum_rule"]], flush=True)
    res["percus_yevick"] = bench_py()
    print("PY", [(r["eta"], round(r["max_abs_err"], 4)) for r in res["percus_yevick"]], flush=True)
    res["interpolation"] = bench_interpolation()
    res["tail"] = bench_tail()
    res["error_bars"] = bench_error_bars()
    res["raw_vs_smoothed"] = bench_raw_vs_smoothed()
    print("raw - smoothed at peaks: max |z|", max((abs(w["z"]) for w in res["raw_vs_smoothed"]), default=None))
    res["smoothing_bias"] = bench_smoothing_bias()
    print("smoothing bias", [(r["eta"], r["band"], round(r["max_abs_bias"], 4), round(r["max_noise"], 4))
                             for r in res["smoothing_bias"]], flush=True)
    res["metropolis"] = bench_metropolis()
    print("metropolis", [(r["eta"], r["window"], round(r["diff"], 4), round(r["z"], 2)) for r in res["metropolis"]])
    if not a.skip_regenerate:
        res["regenerate_row"] = bench_regenerate(a.eta)
        print("regenerate", res["regenerate_row"], flush=True)
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(res, f, indent=1)
    print("wrote", a.out)


if __name__ == "__main__":
    main()
