"""A new Mie radius: a progress bar with a total while the exact rows build, and a coarse
preview (:meth:`corona.model.mie.material.SphereMaterial.preview`) to show meanwhile.

The preview is held against the exact table of the same layer: the lobes' shape
(energy-weighted L1 over the first rings, the first minimum's angle) and the forward
energy; a preview of a 10 % larger droplet misses the same bounds (negative control).
Its speed is a benchmark (benchmarks/first_render.py), not a test."""
from __future__ import annotations

import re

import numpy as np
import pytest

from corona.model.mie import layer
from corona.parameters import material_from_parameters

pytestmark = [pytest.mark.slow]

R = 2.0                 # µm: an exact table of a few seconds


def _lobe_distance(a, b, th):
    """Energy-weighted L1 distance of two lobes on a grid of polar angles ``th``, and their
    first minima's angles."""
    w = np.sin(th)
    l1 = float(np.sum(np.abs(a - b) * w) / np.sum(a * w))

    def first_minimum(f):
        i = np.flatnonzero((f[1:-1] < f[:-2]) & (f[1:-1] <= f[2:]))
        return th[i[0] + 1]
    return l1, first_minimum(a), first_minimum(b)


def test_preview_is_a_coarse_copy_of_the_exact_table(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))         # cold: the exact rows build here
    monkeypatch.setattr(layer.tabulated, "PROGRESS_DELAY", 0.0)
    m = material_from_parameters(shape="sphere", radius=R, area_fraction=0.1, process="poisson",
                                 size_spread=0.0)
    assert not m.rows_cached()
    p = m.preview()
    assert "preview" in repr(p) and "preview" not in repr(m)
    assert p.rows["x"].size == layer.PREVIEW_ROWS and p.rows["C_f"].size == 0
    assert not m.rows_cached()                     # the preview wrote nothing under the exact key
    capsys.readouterr()
    exact = m.rows                                 # the exact rows, with a progress bar
    err = capsys.readouterr().err
    assert m.rows_cached() and exact["x"].size > 4 * layer.PREVIEW_ROWS
    # the bar has a total (n/total), and it ends at the rows evaluated
    counts = [(int(a), int(b)) for a, b in re.findall(r"(\d+)/(\d+) \[", err)]
    assert counts, err[-500:]
    assert counts[-1][0] == counts[-1][1]
    # the preview against the exact table, 0.05° to 25° (five rings at 2 µm): the lobe averaged
    # over 420-680 nm (what a render's spectrum sees; a single wavelength's shallow minima move
    # with the resonances between the preview's rows)
    th = np.radians(np.linspace(0.05, 25.0, 600))
    d = np.stack([np.sin(th), 0 * th], -1)
    wrong = material_from_parameters(shape="sphere", radius=1.1 * R, area_fraction=0.1,
                                      process="poisson").preview()
    lams = np.arange(420.0, 681.0, 10.0)
    a = np.mean([m.lobe(d, lam) for lam in lams], axis=0)
    l1, t_exact, t_prev = _lobe_distance(a, np.mean([p.lobe(d, lam) for lam in lams], axis=0), th)
    assert l1 < 0.03 and abs(t_prev / t_exact - 1) < 0.01, (l1, t_exact, t_prev)   # 0.009, 0.5 %
    l1_bad, _, t_bad = _lobe_distance(a, np.mean([wrong.lobe(d, lam) for lam in lams], axis=0), th)
    assert l1_bad > 0.06 and abs(t_bad / t_exact - 1) > 0.03, (l1_bad, t_bad)      # control: 0.11, 4.7 %
    e, ep = m.energies(1.0, 550.0), p.energies(1.0, 550.0)
    assert ep["forward"] == pytest.approx(e["forward"], rel=0.05)
    assert ep["coherent"] == pytest.approx(e["coherent"], rel=0.03)


def test_preview_of_a_spread_and_a_hard_core_layer():
    """Every isotropic sphere layer has a preview: a size spread is left out (one-size rows of
    the mean droplet), a hard core's S(q) is kept; energies stay finite and below one."""
    m = material_from_parameters(shape="sphere", radius=6.0, size_spread=0.1, area_fraction=0.3,
                                 process="hard-disk")
    p = m.preview()
    assert p.rows["C_f"].size == 0 and p.sizes is m.sizes
    e = p.energies(1.0, 550.0)
    assert all(np.isfinite(float(v)) for v in e.values())
    assert 0.0 < float(e["coherent"]) + float(e["forward"]) * float(e["weight"]) < 1.0
    assert p.table_params() != m.table_params()        # never the exact table's cache key
