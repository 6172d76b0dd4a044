#!/usr/bin/env python
"""Check the shipped hard-disk S(qσ) table against a second, independent sampler.

Runs plain Metropolis Monte Carlo (:mod:`corona.reference.hard_disk_metropolis`:
local moves, disks grown from random points, N = 2000) at η = 0.3, 0.5 and
0.65 and stores, per ``|k|σ`` window around the peaks and troughs of S, the
mean S over the window's box wave vectors with its standard error, and those
wave vectors' ``|k|σ``, in ``tests/data/hard_disk_metropolis.json``.
``tests/tables/test_hard_disk_table.py`` compares the table, averaged over the same
wave vectors, within the combined error bars (issue 18).

    nice -n 19 python scripts/check_hard_disk_table.py [--eta 0.3 ...]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from corona.reference import hard_disk_metropolis as hm  # noqa: E402

OUT = os.path.join(ROOT, "tests", "data", "hard_disk_metropolis.json")
#: |k|σ windows per η: first peak, first trough, second peak, third peak
WINDOWS = {0.3: [(4.8, 6.2), (6.5, 8.5), (10.4, 12.2), (16.5, 18.5)],
           0.5: [(5.2, 6.4), (6.7, 7.4), (11.2, 12.6), (18.0, 19.7)],
           0.65: [(5.8, 6.7), (7.0, 8.0), (11.8, 13.0), (18.0, 19.7)]}
SETTINGS = {0.3: dict(n_sweeps=20000, n_equilibration=5000, sample_every=50, n_chains=2),
            0.5: dict(n_sweeps=20000, n_equilibration=5000, sample_every=50, n_chains=2),
            0.65: dict(n_sweeps=30000, n_equilibration=10000, sample_every=50, n_chains=2)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eta", type=float, action="append", help="only these rows (repeatable)")
    ap.add_argument("--out", default=OUT)
    a = ap.parse_args(argv)
    old = {}
    if os.path.exists(a.out):
        with open(a.out) as f:
            old = {r["eta"]: r for r in json.load(f)["runs"]}
    for eta in (a.eta or list(WINDOWS)):
        t0 = time.perf_counter()
        r = hm.metropolis_structure_factor(eta, WINDOWS[eta], n_disks=2000, seed=int(1000 * eta),
                                           **SETTINGS[eta])
        rec = dict(eta=eta, windows=WINDOWS[eta], S=r["S"].tolist(), S_err=r["S_err"].tolist(),
                   k_vectors=[np.round(k, 6).tolist() for k in r["k_vectors"]],
                   acceptance=r["acceptance"], min_distance=r["min_distance"],
                   grow_sweeps=r["grow_sweeps"], cpu_seconds=r["cpu_seconds"],
                   wall_seconds=time.perf_counter() - t0, settings=r["settings"])
        old[eta] = rec
        print(f"η={eta}: S={np.round(r['S'], 4).tolist()} ± {np.round(r['S_err'], 4).tolist()} "
              f"acc={r['acceptance']:.2f} d_min={r['min_distance']:.6f} cpu={r['cpu_seconds']:.0f}s",
              flush=True)
        os.makedirs(os.path.dirname(a.out), exist_ok=True)
        with open(a.out, "w") as f:
            json.dump({"generator": "scripts/check_hard_disk_table.py", "method": hm.__doc__.split("\n\n")[0],
                       "runs": [old[k] for k in sorted(old)]}, f)


if __name__ == "__main__":
    main()
