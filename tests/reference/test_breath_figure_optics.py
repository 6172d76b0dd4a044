"""The far field of a breath figure (corona.reference.breath_figure_optics) against a direct numpy sum,
and its approximations' limits."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import j1

from corona.reference.breath_figure_optics import far_field_rings, partial_structure_rings, size_classes


def _direct(c, a, L, u_max, du):
    """|Σ_j F_j e^{-iq·r_j}|²/N and |Σ_j e^{-iq·r_j}|²/N on the half lattice, ring-averaged (numpy)."""
    dq = 2 * np.pi / L
    nmax = int(u_max / dq)
    m = np.arange(-nmax, nmax + 1)
    mm, nn = np.meshgrid(m, np.arange(nmax + 1))
    half = (nn > 0) | ((nn == 0) & (mm > 0))
    qx, qy = dq * mm[half], dq * nn[half]
    q = np.hypot(qx, qy)
    sel = q <= u_max
    qx, qy, q = qx[sel], qy[sel], q[sel]
    x = q[:, None] * a[None]
    F = np.pi * a ** 2 * 2 * j1(x) / x
    e = np.exp(-1j * (qx[:, None] * c[:, 0] + qy[:, None] * c[:, 1]))
    ring = (q / du).astype(int)
    cnt = np.bincount(ring)
    keep = cnt > 0
    I = np.bincount(ring, np.abs((F * e).sum(1)) ** 2 / len(a))[keep] / cnt[keep]
    S = np.bincount(ring, np.abs(e.sum(1)) ** 2 / len(a))[keep] / cnt[keep]
    return I, S


@pytest.mark.slow
@pytest.mark.reference
def test_far_field_is_the_direct_sum_and_partials_add_up():
    rng = np.random.default_rng(0)
    L, N = 50.0, 40
    c, a = rng.random((N, 2)) * L, rng.uniform(0.5, 2.0, N)
    r = far_field_rings(c, a, L, length=1.0, u_max=5.0, du=0.5, classes=3)
    I, S = _direct(c, a, L, 5.0, 0.5)
    np.testing.assert_allclose(r["exact"], I, rtol=2e-6)           # the kernel's J1 table: 1e-7
    np.testing.assert_allclose(r["S"], S, rtol=1e-10)
    # the lean kernel of the exact far field alone (the breath-figure lobe tests): the same values
    e = far_field_rings(c, a, L, length=1.0, u_max=5.0, du=0.5, exact_only=True)
    assert set(e) == {"u", "exact", "points", "coverage"}
    for k in ("u", "exact", "points"):
        np.testing.assert_array_equal(e[k], r[k], err_msg=k)
    # one class: the partial structure factors are the decoupling approximation
    r1 = far_field_rings(c, a, L, length=1.0, u_max=5.0, du=0.5, classes=1)
    np.testing.assert_allclose(r1["partial"], r1["decoupling"], rtol=1e-12)
    # ... which is not the exact far field of these sizes (negative control)
    assert np.max(np.abs(r1["decoupling"] / I - 1)) > 0.02
    # the partials of the classes sum to S
    cls = size_classes(a, 4)
    P = partial_structure_rings(c, cls, 4, L, length=1.0, u_max=5.0, du=0.5)
    np.testing.assert_allclose(P[np.isfinite(P[:, 0, 0])].sum(axis=(1, 2)), S, rtol=1e-10)


@pytest.mark.slow
@pytest.mark.reference
def test_size_classes_hold_equal_area():
    a = np.random.default_rng(2).lognormal(0.0, 0.8, 20000)
    cls = size_classes(a, 5)
    area = np.bincount(cls, a ** 2) / np.sum(a ** 2)
    np.testing.assert_allclose(area, 0.2, atol=0.01)
    assert np.all(np.diff([a[cls == k].mean() for k in range(5)]) > 0)


@pytest.mark.slow
@pytest.mark.reference
def test_fading_rows_hold_the_water_budget():
    """evaporation_rows (the table's fading phase) on a small box: the water left is exactly 1 - f of
    the start's (the simulator removes it at the prescribed rate), R = <a³>/<a²> is π W / (k F_a)
    (caps of one angle), the coverage and the number of droplets fall with f, and the partials add up
    to S.  The shipped table's rows obey the same budget."""
    from corona.model.processes.breath_figure import load_table
    from corona.reference.breath_figure import cap_volume_factor
    from corona.reference.breath_figure_optics import evaporation_rows
    t = load_table()
    k = cap_volume_factor(90.0)
    rows = evaporation_rows(t["x_edges"], t["class_edges"], starts=(5.0,), fractions=(0.3, 0.8), seeds=(3,),
                            box=100.0, progress=False)
    np.testing.assert_allclose(rows["dry_water_ratio"], [[0.7, 0.2]], rtol=1e-9)
    np.testing.assert_allclose(rows["dry_R"], np.pi * rows["dry_water"] / (k * rows["dry_coverage"]), rtol=1e-9)
    assert np.all(np.diff(rows["dry_coverage"][0]) < 0) and np.all(rows["dry_coverage_ratio"] < 1)
    assert np.all(np.diff(rows["dry_density"][0]) < 0) and np.all(rows["dry_density_ratio"] < 1)
    np.testing.assert_allclose(np.nansum(rows["dry_partial"], axis=(-1, -2)), np.nan_to_num(rows["dry_S"]),
                               rtol=1e-9, atol=1e-12)
    # the shipped fading rows
    np.testing.assert_allclose(t["dry_water_ratio"], np.broadcast_to(1 - t["dry_fractions"], t["dry_R"].shape),
                               rtol=1e-9)
    # (R, water and coverage are each averaged over the two seeds: the identity holds to their spread)
    np.testing.assert_allclose(t["dry_R"], np.pi * t["dry_water"] / (k * t["dry_coverage"]), rtol=0.01)
