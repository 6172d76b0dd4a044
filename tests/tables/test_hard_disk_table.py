"""The hard-disk S(qσ) table: its own error bars, unbiased smoothing, and a
second, independent sampler.

* every row stores its standard error (``S_err``: parametric bootstrap of the
  smoothing); the rows the issue names (η = 0.3, 0.5, 0.65) are below 0.003
  everywhere;
* the smoothed rows do not flatten their peaks: around the first three peaks
  of every fluid row (η <= 0.69) the raw binned data minus the row average
  to within 3.5 standard errors (the old far-band smoother was 3.4 σ off at
  the third peak of η = 0.66 and 0.1);
* plain Metropolis Monte Carlo (local moves, disks grown from random points:
  no code or start shared with the event-chain runs of the table), stored in
  tests/data/hard_disk_metropolis.json by scripts/check_hard_disk_table.py,
  agrees with the table averaged over the same wave vectors within 3
  combined standard errors at η = 0.3, 0.5 and 0.65 around the peaks.
"""
import json
import os

import numpy as np
import pytest

from corona.model.processes.hard_disk import load_table
from corona.reference import hard_disk as hd
from corona.reference import hard_disk_metropolis as hm

#: the rows checked (η = 0.3, 0.5, 0.65), run with enough chains for error bars below 0.003
#: (scripts/make_hard_disk_table.py EXTRA_CHAINS; the others have 2–8 chains)
REGENERATED = (0.3, 0.5, 0.65)
DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data", "hard_disk_metropolis.json")


def test_rows_store_their_error_bars():
    t = load_table()
    err = t["S_err"]
    assert err.shape == t["S"].shape
    assert np.all(np.isfinite(err)) and np.all(err >= 0)
    assert np.all(err[t["eta"] == 0] == 0)
    for eta in REGENERATED:
        i = int(np.flatnonzero(np.isclose(t["eta"], eta))[0])
        assert err[i].max() < 0.003, (eta, float(err[i].max()))
        assert err[i].max() > 1e-4      # a real error bar, not a placeholder


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("eta", [float(e) for e in load_table()["eta"] if 0 < e <= 0.69 + 1e-9])
def test_smoothing_keeps_the_peaks(eta):
    for w in hd.raw_minus_smoothed(eta):
        assert abs(w["z"]) < 3.5, w


def _runs():
    with open(DATA) as f:
        return json.load(f)["runs"]


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("eta", [0.3, 0.5, 0.65])
def test_table_agrees_with_independent_metropolis(eta):
    run = next(r for r in _runs() if abs(r["eta"] - eta) < 1e-9)
    assert run["min_distance"] >= 1.0                       # no overlaps in the check itself
    # tight enough to see the reported discrepancies (0.004–0.009 at the
    # peaks; "3 %" = 0.09 at the first peak of 0.65) at >= 2–13 σ
    assert max(run["S_err"]) < 0.007
    for c in hm.compare_with_table(run):
        assert abs(c["z"]) < 3.0, c


@pytest.mark.slow
@pytest.mark.reference
def test_metropolis_agrees_with_an_exact_limit():
    """The checker on its own, where the answer is known: at η = 0.05 the
    Percus-Yevick S is exact to O(η²) (a few 1e-3)."""
    r = hm.metropolis_structure_factor(0.05, [(3.0, 5.0), (5.0, 8.0)], n_disks=300, n_sweeps=1500,
                                       n_equilibration=200, sample_every=10, n_chains=2, max_vectors=200,
                                       seed=1)
    for S, e, k in zip(r["S"], r["S_err"], r["k_vectors"]):
        py = float(np.mean(hd.structure_factor_percus_yevick(k, 0.05)))
        assert abs(S - py) < 4 * e + 0.004, (S, e, py)
