#!/usr/bin/env python
"""Speed of the brute-force reference against the model (issue 5, §4).

Writes ``benchmarks/results/wave.json`` with

* ``results.converge``: the brute force (``corona.reference.wave.brute_force``) of one
  lobe — circles of R = 2.5 µm on hard disks, F_a = 0.3, 2000 per screen,
  16 samples per radius, the comparison region of ``corona validate``
  (|u| ≤ 16, > 1 % of the peak) — with M = 1, 2, 4, … screens, each run from
  scratch (hard-disk simulation included); the time of the first M whose RMS
  error against the model is ≤ 2 %, and of the first M whose statistical
  error (split-half noise) alone is ≤ 2 %;
* ``results.model``: the model's lobe on the same grid points
  (``Material.lobe``, exact; cold = a fresh material, warm = median of 5) and
  the renderer's table route (``lobe_tabulated``; the table build counted in
  cold);
* ``ratio``: brute-force time to converge / model time (warm and cold);
* ``fft``: ``scipy.fft.rfft2`` (all cores) against ``numpy.fft.rfft2`` on the
  same grid (why scipy is used; pyFFTW is not installed and not needed);
* ``large_grid``: one 8192² ensemble (F_a = 0.1, 8200 scatterers): time per
  screen and peak memory.

Usage: ``python benchmarks/bench_wave.py [--max-m 128] [--skip-large]``
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "src"))

from common import write  # noqa: E402

from corona import CoronaWarning, Material  # noqa: E402
from corona.model import shapes
from corona.reference import wave  # noqa: E402
from corona.model.processes import HardDisk  # noqa: E402
from corona.reference.validate import U_COMPARE, compare  # noqa: E402

R = 2.5
LAM = 550.0


def _material():
    return Material(shapes.Circle(R), HardDisk(0.3))


def bench_converge(max_m: int):
    rows = []
    M = 1
    while M <= max_m:
        wave._HD_CACHE.clear()                       # count the simulation every time
        m = _material()
        t0 = time.perf_counter()
        bf = wave.brute_force(m, realisations=M, q_max=U_COMPARE / R * 1.02, seed=7, progress=False)
        t = time.perf_counter() - t0
        w = compare(m, bf, (LAM,))["wavelengths"][LAM]
        rows.append(dict(realisations=M, seconds=t, rms=w["rms"], noise=w["noise"], max=w["max"],
                         bins=w["bins"], positions_s=bf.seconds["positions"],
                         rasterise_s=bf.seconds["rasterise"], fft_s=bf.seconds["fft"],
                         grid=bf.grid.nx))
        print(f"M={M:4d} {t:7.2f} s  RMS {100 * w['rms']:.2f} %  noise {100 * w['noise']:.2f} %",
              flush=True)
        M *= 2
    return rows, bf


def cold_and_warm(make, evaluate):
    """Seconds of the first ``evaluate(make())`` (set-up included) and the median of 5 more."""
    t0 = time.perf_counter()
    m = make()
    evaluate(m)
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(5):
        t0 = time.perf_counter()
        evaluate(m)
        warm.append(time.perf_counter() - t0)
    return cold, statistics.median(warm)


def bench_model(bf):
    R_ = bf.length_scale
    ix = np.abs(bf.qx) * R_ <= U_COMPARE
    iy = np.abs(bf.qy) * R_ <= U_COMPARE
    QX, QY = np.meshgrid(bf.qx[ix], bf.qy[iy], indexing="xy")
    d = np.stack([QX, QY], -1) * (LAM * 1e-3 / (2 * np.pi))
    from corona.model.processes import hard_disk
    hard_disk._row.cache_clear()
    cold, warm = cold_and_warm(_material, lambda m: m.lobe(d, LAM))
    tab_cold, tab_warm = cold_and_warm(lambda: Material(shapes.Circle(R), HardDisk(0.3), use_cache=False),
                                       lambda m: m.lobe_tabulated(d, LAM))
    return dict(points=int(d.shape[0] * d.shape[1]), exact_cold_s=cold, exact_warm_s=warm,
                table_cold_s=tab_cold, table_warm_s=tab_warm)


def bench_fft(n):
    from scipy import fft as sp_fft
    a = np.random.default_rng(0).random((n, n))
    out = {}
    for name, f in [("scipy_all_cores", lambda: sp_fft.rfft2(a, workers=os.cpu_count())),
                    ("scipy_1_core", lambda: sp_fft.rfft2(a, workers=1)),
                    ("numpy", lambda: np.fft.rfft2(a))]:
        f()
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t0)
        out[name + "_s"] = statistics.median(ts)
    out["grid"] = n
    return out


def bench_large():
    m = Material(shapes.Circle(R), HardDisk(0.1))
    t0 = time.perf_counter()
    bf = wave.brute_force(m, realisations=2, n_scatterers=8200, q_max=U_COMPARE / R, seed=3,
                          progress=False)
    t = time.perf_counter() - t0
    w = compare(m, bf, (LAM,))["wavelengths"][LAM]
    return dict(grid=bf.grid.nx, realisations=2, seconds=t,
                per_screen_s=(bf.seconds["rasterise"] + bf.seconds["fft"]) / 2,
                simulation_s=bf.seconds["positions"], rms=w["rms"], noise=w["noise"],
                peak_rss_gib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--max-m", type=int, default=128)
    ap.add_argument("--skip-large", action="store_true")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore", CoronaWarning)
    rows, bf = bench_converge(a.max_m)
    model = bench_model(bf)
    print("model", model, flush=True)
    conv = next((r for r in rows if r["rms"] <= 0.02), None)
    quiet = next((r for r in rows if r["noise"] <= 0.02), None)
    results = {f"M={r['realisations']}": r for r in rows}
    results["model"] = model
    payload = {
        "goal": "brute-force time to converge one lobe to 2 % (RMS over the region above 1 % of "
                "the peak) vs the model's time for the same lobe on the same grid",
        "case": "circle R=2.5 µm, hard disks F_a=0.3, aperture, 550 nm, 2000 scatterers/screen, "
                "16 samples per radius",
        "results": results,
        "converged": None if conv is None else {
            "realisations": conv["realisations"], "seconds": conv["seconds"], "rms": conv["rms"],
            "ratio_to_model_warm": conv["seconds"] / model["exact_warm_s"],
            "ratio_to_model_cold": conv["seconds"] / model["exact_cold_s"],
            "ratio_to_table_warm": conv["seconds"] / model["table_warm_s"]},
        "noise_below_2pct": None if quiet is None else {
            "realisations": quiet["realisations"], "seconds": quiet["seconds"],
            "ratio_to_model_warm": quiet["seconds"] / model["exact_warm_s"]},
        "fft": bench_fft(bf.grid.nx),
    }
    print("converged", payload["converged"], flush=True)
    print("fft", payload["fft"], flush=True)
    if not a.skip_large:
        payload["large_grid"] = bench_large()
        print("large", payload["large_grid"], flush=True)
    write("wave", payload)


if __name__ == "__main__":
    main()
