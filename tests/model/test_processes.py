"""Point processes other than the hard-disk fluid: RSA, lattices, measured
point sets, micrographs."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from corona import CoronaError
from corona.model import processes as P
from corona.model.processes import Lattice, PointSet, SequentialAdsorption, rsa_structure_factor
from corona.model.processes.rsa import _RSA_TABLE_PATH
from corona.reference.rsa import rsa_configuration
from corona.model.shapes import Circle


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def box_sk(points, Lx, Ly, kmax_index):
    """|Σ e^{-ik·s}|²/N on the box wave vectors of a periodic box (all m, n)."""
    m = np.arange(-kmax_index, kmax_index + 1)
    mm, nn = np.meshgrid(m, m, indexing="ij")
    k = np.stack([2 * np.pi * mm.ravel() / Lx, 2 * np.pi * nn.ravel() / Ly], -1)
    F = np.exp(-1j * (points @ k.T)).sum(axis=0)
    return k, np.abs(F) ** 2 / len(points)


def min_periodic_distance(points, L):
    tree = cKDTree(points, boxsize=L)
    d, _ = tree.query(points, k=2)
    return d[:, 1].min()


# ---------------------------------------------------------------------------
# random sequential adsorption
# ---------------------------------------------------------------------------
@pytest.mark.slow
def test_rsa_saturates_at_jamming_limit():
    L = 40.0
    cov = []
    for seed in range(8):
        pos = rsa_configuration(L, seed=seed)
        cov.append(len(pos) * np.pi / 4 / L**2)
        assert min_periodic_distance(np.mod(pos, L), L) >= 1.0 - 1e-9
        # saturated: no random probe point is farther than σ from every centre
        probe = np.random.default_rng(seed).random((20000, 2)) * L
        d, _ = cKDTree(np.mod(pos, L), boxsize=L).query(probe)
        assert d.max() < 1.0
    # Zhang & Torquato (2013): 0.547069; per-run spread at L = 40σ is ≈ 0.004
    assert abs(np.mean(cov) - P.RSA_SATURATION) < 0.01 * P.RSA_SATURATION
    assert abs(np.mean(cov) - P.RSA_SATURATION) < 0.004


def test_rsa_partial_configuration():
    pos = rsa_configuration(30.0, 0.3, sigma=2.0, seed=5)
    L = 30.0
    assert len(pos) == round(0.3 * L**2 / (np.pi * 4.0 / 4))
    assert min_periodic_distance(pos, L) >= 2.0 - 1e-9
    assert pos.min() >= 0 and pos.max() < L


def test_rsa_table_saturation_and_coverage():
    with np.load(_RSA_TABLE_PATH) as z:
        cov, cov_err = z["saturation_coverage"]
        s0 = z["S0"]
    assert abs(cov - P.RSA_SATURATION) < 3 * cov_err + 1e-4
    # S(0) at saturation ≈ 0.059 (Torquato, Uche & Stillinger 2006; Zhang & Torquato 2013)
    assert 0.054 < s0[-1] < 0.062
    assert abs(rsa_structure_factor(0.0, P.RSA_JAMMING_LIMIT) - s0[-1]) < 0.003


@pytest.mark.parametrize("eta", [0.01, 0.02, 0.03, 0.05])
def test_rsa_low_density_expansion(eta):
    """S(0) = 1 - 4η + (2/3)(16 - 3 b3) η² + O(η³) with b3 = 4(4/3 - √3/π):
    the first-order RSA pair correlation is g = 1 + (2/3) n A_ov(r) for r > σ
    (kinetic expansion, Widom 1966), two thirds of the equilibrium value."""
    b3 = 4 * (4 / 3 - np.sqrt(3) / np.pi)
    c2 = (2 / 3) * (16 - 3 * b3)
    assert c2 == pytest.approx(4.4106, abs=1e-4)
    expected = 1 - 4 * eta + c2 * eta**2
    assert rsa_structure_factor(0.0, eta) == pytest.approx(expected, abs=0.006)


def test_rsa_differs_from_equilibrium_at_second_order():
    # at η = 0.1 the RSA and equilibrium expansions differ by 0.022; the table
    # follows RSA (η³ terms are below 0.005 here)
    eta = 0.1
    rsa = 1 - 4 * eta + 4.4106 * eta**2
    eq = 1 - 4 * eta + 6.6159 * eta**2
    s0 = float(rsa_structure_factor(0.0, eta))
    assert abs(s0 - rsa) < 0.006
    assert abs(s0 - eq) > 0.015


def test_rsa_table_matches_a_fresh_simulation():
    """Small independent ensemble (box vectors of a periodic box) vs the table."""
    L, eta = 25.0, 0.4
    qs, ss = [], []
    for seed in range(12):
        pos = rsa_configuration(L, eta, seed=1000 + seed)
        k, s = box_sk(pos, L, L, 24)
        qs.append(np.hypot(k[:, 0], k[:, 1]))
        ss.append(s)
    q = np.concatenate(qs)
    s = np.concatenate(ss)
    for lo, hi in [(1.0, 3.0), (3.0, 4.5), (4.5, 5.5), (5.5, 6.5), (6.5, 8.0)]:
        sel = (q >= lo) & (q < hi)
        table = rsa_structure_factor(q[sel], eta).mean()
        err = s[sel].std() / np.sqrt(sel.sum() / 2)  # ±k pairs are identical
        assert abs(s[sel].mean() - table) < 4 * err + 0.01, (lo, hi)


def test_rsa_table_shape_and_limits():
    q = np.linspace(0, 250, 2501)
    for eta in (0.0, 0.2, 0.4, 0.5, 0.547):
        S = rsa_structure_factor(q, eta)
        assert np.all(np.isfinite(S)) and np.all(S >= 0)
        assert np.all(S[q > 200] == 1.0)
        assert np.max(np.abs(S[(q > 150) & (q <= 200)] - 1)) < 0.02
    assert np.all(rsa_structure_factor(q, 0.0) == 1.0)
    # first peak sharpens with density
    peaks = [rsa_structure_factor(q, e).max() for e in (0.2, 0.4, 0.547)]
    assert peaks[0] < peaks[1] < peaks[2]
    # S(0) decreases monotonically with η
    s0 = np.array([float(rsa_structure_factor(0.0, e)) for e in np.arange(0, 0.547, 0.01)])
    assert np.all(np.diff(s0) < 0)


def test_sequential_adsorption_interface():
    c = Circle(0.5)
    p = SequentialAdsorption(0.4)
    assert p.isotropic
    assert p.area_fraction(c) == 0.4
    assert p.packing_fraction(c) == pytest.approx(0.4)
    q = np.linspace(0, 30, 50)
    assert np.allclose(p.structure_factor_radial(q, c), rsa_structure_factor(q * 1.0, 0.4))
    assert np.allclose(p.structure_factor(q), rsa_structure_factor(q, 0.4))
    qv = np.stack([q, np.zeros_like(q)], -1) / np.sqrt(2) @ np.array([[1, 1], [-1, 1]])
    assert np.allclose(p.structure_factor_at(qv, c), p.structure_factor_radial(q, c))
    # explicit, larger exclusion diameter: η = F_a σ²/(4R²)
    p2 = SequentialAdsorption(0.2, exclusion_diameter=1.4)
    assert p2.packing_fraction(c) == pytest.approx(0.2 * 1.96)
    assert np.allclose(p2.structure_factor_radial(q, c), rsa_structure_factor(q * 1.4, 0.392))
    key = p.key()
    assert key["type"] == "SequentialAdsorption" and key["fraction"] == 0.4
    assert key["exclusion_diameter"] is None and len(key["table"]) == 16
    pos = p.sample(c, 20.0, seed=1)
    assert len(pos) == round(0.4 * 400 / (np.pi / 4))


def test_sequential_adsorption_errors():
    with pytest.raises(CoronaError, match="area_fraction=0.6"):
        SequentialAdsorption(0.6)
    with pytest.raises(CoronaError, match="area_fraction"):
        SequentialAdsorption(0.0)
    with pytest.raises(CoronaError, match="exclusion_diameter"):
        SequentialAdsorption(0.3, exclusion_diameter=-1)
    c = Circle(0.5)
    with pytest.raises(CoronaError, match=r"exclusion_diameter=0\.8.*>= the shape's exclusion diameter 1"):
        SequentialAdsorption(0.3, exclusion_diameter=0.8).validate(c)
    with pytest.raises(CoronaError, match=r"area_fraction=0\.3.*jamming limit 0\.547.*<= 0\.2"):
        SequentialAdsorption(0.3, exclusion_diameter=1.5).validate(c)
    with pytest.raises(CoronaError, match="packing_fraction"):
        rsa_structure_factor(1.0, 0.6)


# ---------------------------------------------------------------------------
# lattices
# ---------------------------------------------------------------------------
def test_lattice_reciprocal_vectors():
    a = 1.7
    sq = Lattice("square", a)
    G, w = sq.bragg_peaks(2 * np.pi / a * 2.1)
    hk = G * a / (2 * np.pi)
    assert np.allclose(hk, np.rint(hk), atol=1e-12)
    assert len(G) == 4 + 4 + 4  # shells (1,0), (1,1), (2,0); |(2,1)| = √5 > 2.1
    assert np.allclose(w, (2 * np.pi) ** 2 / a**2)
    hexa = Lattice("hexagonal", a)
    G, _ = hexa.bragg_peaks(4 * np.pi / (np.sqrt(3) * a) * 1.01)
    assert len(G) == 6
    assert np.allclose(np.hypot(G[:, 0], G[:, 1]), 4 * np.pi / (np.sqrt(3) * a))
    # G·a_i ∈ 2πℤ
    prod = G @ hexa.lattice_vectors.T / (2 * np.pi)
    assert np.allclose(prod, np.rint(prod), atol=1e-12)
    assert hexa.cell_area == pytest.approx(np.sqrt(3) / 2 * a**2)
    # rotation rotates the peaks
    rot = Lattice("square", a, angle=17.0)                  # degrees
    G, _ = rot.bragg_peaks(2 * np.pi / a * 1.01)
    ang = np.mod(np.arctan2(G[:, 1], G[:, 0]) - np.radians(17.0), np.pi / 2)
    assert np.allclose(np.minimum(ang, np.pi / 2 - ang), 0, atol=1e-12)


def test_lattice_peak_location_height_and_weight():
    a, delta = 1.0, 0.08
    lat = Lattice("hexagonal", a, jitter=delta)
    G, w = lat.bragg_peaks(15)
    wd = lat.peak_width
    assert wd == pytest.approx(np.sqrt(2 * np.pi) / (20 * a))
    n = lat.number_density
    for g, weight in zip(G[[0, 6, 12]], w[[0, 6, 12]]):
        g2 = g @ g
        assert weight == pytest.approx((2 * np.pi) ** 2 * n * np.exp(-g2 * delta**2))
        # the maximum of S near G is at G, with height bg + weight/(2π w²)
        S0 = lat.structure_factor_at(g)
        assert S0 == pytest.approx(1 - np.exp(-g2 * delta**2) + weight / (2 * np.pi * wd**2), rel=1e-9)
        assert S0 == pytest.approx(1 - np.exp(-g2 * delta**2) + n * np.exp(-g2 * delta**2)
                                   * (20 * a) ** 2, rel=1e-9)
        # integrated weight above the background = (2π)² n e^{-G²δ²} (Debye–Waller)
        h = wd / 8
        x = np.arange(-7 * wd, 7 * wd, h) + h / 2
        X, Y = np.meshgrid(x, x)
        q = np.stack([g[0] + X, g[1] + Y], -1)
        bg = 1 - np.exp(-(q**2).sum(-1) * delta**2)
        integral = (lat.structure_factor_at(q) - bg).sum() * h * h
        assert integral == pytest.approx(weight, rel=1e-6)


def test_lattice_background_away_from_peaks():
    lat = Lattice("square", 2.0, jitter=0.15)
    q = np.array([[np.pi / 2, np.pi / 2], [0.1, 0.0], [np.pi * 1.5, np.pi / 2]])
    assert np.allclose(lat.structure_factor_at(q), 1 - np.exp(-(q**2).sum(-1) * 0.15**2))
    # no jitter: S vanishes off the peaks (and at q → 0: hyperuniform)
    assert np.allclose(Lattice("square", 2.0).structure_factor_at(q), 0.0, atol=1e-12)
    # large q: background → 1, peaks damped
    qq = np.array([[100.3, 37.1]])
    assert lat.structure_factor_at(qq)[0] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["square", "hexagonal"])
def test_lattice_matches_brute_force_jittered_lattice(kind):
    """Finite periodic jittered lattice, S on box wave vectors, averaged over
    realisations: off-peak = 1 - e^{-k²δ²}; at k = G the excess is
    N e^{-G²δ²} = (2π)² n e^{-G²δ²} / (box-vector cell (2π)²/A)."""
    a, delta = 1.0, 0.12
    rng = np.random.default_rng(3)
    if kind == "square":
        M = 12
        i, j = np.meshgrid(np.arange(M), np.arange(M), indexing="ij")
        sites = np.stack([i.ravel(), j.ravel()], -1) * a
        Lx = Ly = M * a
    else:
        M, Mp = 12, 7
        i, j = np.meshgrid(np.arange(M), np.arange(Mp), indexing="ij")
        base = np.stack([i.ravel() * a, j.ravel() * np.sqrt(3) * a], -1)
        sites = np.concatenate([base, base + [0.5 * a, np.sqrt(3) / 2 * a]])
        Lx, Ly = M * a, Mp * np.sqrt(3) * a
    N = len(sites)
    lat = Lattice(kind, a, jitter=delta)
    acc = 0
    n_real = 50
    for _ in range(n_real):
        k, s = box_sk(sites + rng.normal(0, delta, sites.shape), Lx, Ly, 24)
        acc = acc + s
    s = acc / n_real
    k2 = (k**2).sum(-1)
    G, w = lat.bragg_peaks(2 * np.pi * 24 / max(Lx, Ly))  # inside the k grid
    on = np.zeros(len(k), bool)
    for g, weight in zip(G, w):
        idx = np.argmin(((k - g) ** 2).sum(-1))
        assert np.allclose(k[idx], g, atol=1e-9)
        on[idx] = True
        bg = 1 - np.exp(-(g @ g) * delta**2)
        model_excess = weight / ((2 * np.pi) ** 2 / (Lx * Ly))
        assert model_excess == pytest.approx(N * np.exp(-(g @ g) * delta**2), rel=1e-9)
        # |Σ e^{-iG·u}|²/N fluctuates with variance ≈ 2 N DW (1 - DW) + (1 - DW)²
        sd = np.sqrt((2 * model_excess * bg + bg**2) / n_real)
        assert abs(s[idx] - bg - model_excess) < 4 * sd + 1e-6 * model_excess
    off = ~on & (k2 > 0)
    bg = 1 - np.exp(-k2[off] * delta**2)
    # shell-averaged off-peak values follow the Debye–Waller background
    for lo, hi in [(3, 6), (6, 9), (9, 12.5)]:
        sel = (np.sqrt(k2[off]) >= lo) & (np.sqrt(k2[off]) < hi)
        assert s[off][sel].mean() == pytest.approx(bg[sel].mean(), rel=0.04)
    # and the model farther than 8 peak widths from every G is exactly that background
    f = k @ lat.lattice_vectors.T / (2 * np.pi)
    dist = np.linalg.norm((f - np.rint(f)) @ lat.reciprocal_vectors, axis=-1)
    far = dist > 8 * lat.peak_width
    assert far.sum() > 100
    assert np.allclose(lat.structure_factor_at(k[far]), 1 - np.exp(-k2[far] * delta**2), atol=1e-9)


def test_lattice_cell_mean_keeps_peak_weights():
    """Cell means of S (for 2-D tables with cells wider than the peaks) keep
    each peak's integrated weight and agree with supersampling."""
    a, delta = 1.0, 0.1
    lat = Lattice("square", a, jitter=delta)
    c = 2 * np.pi / a / 16  # cell; the grid edges ±5π/a lie midway between peaks
    x = -5 * np.pi / a + (np.arange(80) + 0.5) * c
    X, Y = np.meshgrid(x, x)
    q = np.stack([X, Y], -1)
    cm = lat.structure_factor_cell_mean(q, c)
    G, w = lat.bragg_peaks(2 * np.pi / a * 2 * np.sqrt(2) + 1e-9)
    inside = np.all(np.abs(G) < 5 * np.pi / a, axis=1)
    assert inside.sum() == 24
    n = 16
    sub = (np.arange(n) + 0.5) / n * c - c / 2
    bg_mean = 1 - np.mean([np.exp(-((q + [u, v]) ** 2).sum(-1) * delta**2)
                           for u in sub for v in sub], axis=0)
    excess = ((cm - bg_mean) * c * c).sum()
    assert excess == pytest.approx(w[inside].sum(), rel=1e-4)
    # against brute-force supersampling of the point values
    ss = np.mean([lat.structure_factor_at(q + [u, v]) for u in sub for v in sub], axis=0)
    assert np.max(np.abs(ss - cm)) < 2e-3 * cm.max()


@pytest.mark.parametrize("kind, spacing, jitter, angle, domain", [
    ("square", 4.0, 0.4, 0.0, None), ("hexagonal", 1.0, 0.05, 17.0, None),
    ("square", 2.0, 0.0, 30.0, 3.0), ("square", 40.0, 4.0, 0.0, None)])   # the last: many peaks per cell
def test_lattice_cell_means_on_a_grid_are_the_pointwise_ones(kind, spacing, jitter, angle, domain):
    """On a tensor grid (the tables' vertices) the cell means sum each peak's outer product
    of 1-D cell means near it; the same points given as a list take the neighbour loop."""
    lat = Lattice(kind, spacing, jitter=jitter, domain_size=domain, angle=angle)
    cell = 0.2
    x = -9.0 + (np.arange(80) + 0.5) * cell
    y = -5.0 + (np.arange(60) + 0.5) * cell
    q = np.stack(np.meshgrid(x, y), -1)
    flat = q.reshape(-1, 2)
    for factor in (None, Circle(0.3).coherent_form_factor):
        grid = lat.bragg_cell_mean(q, cell, peak_factor=factor)
        points = lat.bragg_cell_mean(flat, cell, peak_factor=factor).reshape(q.shape[:-1])
        assert grid.max() > 0
        np.testing.assert_allclose(grid, points, rtol=1e-9, atol=1e-12 * points.max())
    np.testing.assert_allclose(lat.background_cell_mean(q, cell),
                               lat.background_cell_mean(flat, cell).reshape(q.shape[:-1]), rtol=1e-14, atol=0)


def test_lattice_powder_rings():
    a, delta = 1.0, 0.05
    lat = Lattice("hexagonal", a, jitter=delta, orientation="random")
    assert lat.isotropic and not Lattice("hexagonal", a).isotropic
    G, w = lat.bragg_peaks(8.0)
    g1 = np.hypot(*G[0])
    q = np.linspace(0.01, 10, 200001)
    S = lat.structure_factor_radial(q)
    bg = 1 - np.exp(-q**2 * delta**2)
    sel = np.abs(q - g1) < 1.0
    ring = ((S - bg) * 2 * np.pi * q)[sel].sum() * (q[1] - q[0])
    assert ring == pytest.approx(6 * w[0], rel=1e-4)
    assert q[np.argmax(S)] == pytest.approx(g1, abs=1e-3)
    # structure_factor_at is radial
    qv = np.array([[g1, 0.0], [0.0, g1], [3.0, 4.0]])
    assert np.allclose(lat.structure_factor_at(qv), lat.structure_factor_radial([g1, g1, 5.0]))
    with pytest.raises(CoronaError, match="orientation='random'"):
        Lattice("square", 1.0).structure_factor_radial(q)


def test_lattice_area_fraction_and_errors():
    c = Circle(0.4)
    assert Lattice("square", 1.0).area_fraction(c) == pytest.approx(np.pi * 0.16)
    assert Lattice("hexagonal", 1.0).area_fraction(c) == pytest.approx(np.pi * 0.16 / (np.sqrt(3) / 2))
    Lattice("hexagonal", 1.0).validate(c)
    with pytest.raises(CoronaError, match=r"spacing=0\.7 µm.*exclusion diameter 0\.8"):
        Lattice("square", 0.7).validate(c)
    with pytest.raises(CoronaError, match="kind='cubic'"):
        Lattice("cubic", 1.0)
    with pytest.raises(CoronaError, match="spacing"):
        Lattice("square", 0.0)
    with pytest.raises(CoronaError, match="jitter"):
        Lattice("square", 1.0, jitter=-0.1)
    with pytest.raises(CoronaError, match="domain_size"):
        Lattice("square", 1.0, domain_size=0.5)
    with pytest.raises(CoronaError, match="orientation"):
        Lattice("square", 1.0, orientation="powder")
    k = Lattice("square", 1.0, jitter=0.1).key()
    assert k["type"] == "Lattice" and k["jitter"] == 0.1 and k["domain_size"] == 20.0


# ---------------------------------------------------------------------------
# measured point sets
# ---------------------------------------------------------------------------
def test_pointset_poisson_is_flat():
    rng = np.random.default_rng(11)
    L, N = 40.0, 2500
    ps = PointSet(rng.random((N, 2)) * L, (L, L))
    q = np.linspace(1.0, 15.0, 300)
    S = ps.structure_factor_radial(q)
    assert S.mean() == pytest.approx(1.0, abs=0.04)
    assert np.all(np.abs(S[q > 5] - 1) < 0.35)
    # a shifted box gives the same estimate
    ps2 = PointSet(ps.points + [5.0, -3.0], ((5.0, 45.0), (-3.0, 37.0)))
    assert np.allclose(ps2.structure_factor_radial(q), S, atol=1e-8)
    assert ps.area_fraction(Circle(0.1)) == pytest.approx(N * np.pi * 0.01 / L**2)


def test_pointset_lattice_peaks():
    a, M = 1.0, 30
    i, j = np.meshgrid(np.arange(M), np.arange(M), indexing="ij")
    pts = (np.stack([i.ravel(), j.ravel()], -1) + 0.5) * a
    ps = PointSet(pts, (M * a, M * a), isotropic=False)
    assert not ps.isotropic
    G = 2 * np.pi / a * np.array([[1, 0], [0, 1], [1, 1], [2, -1]])
    off = np.array([[np.pi, 0.3], [4.0, 4.0], [2.0, 5.5]])
    peak = ps.structure_factor_at(G)
    assert np.all(peak > 0.4 * len(pts))  # Hann-tapered Laue peak: (4/9) N
    assert np.allclose(peak, 4 / 9 * len(pts), rtol=1e-6)
    assert np.all(ps.structure_factor_at(off) < 1e-6)
    # radial: first ring at 2π/a; hexagonal points: first ring at 4π/(√3 a)
    psr = PointSet(pts, (M * a, M * a))
    q = np.linspace(1, 10, 901)
    assert q[np.argmax(psr.structure_factor_radial(q))] == pytest.approx(2 * np.pi, abs=0.05)
    Mh, Mp = 30, 17
    i, j = np.meshgrid(np.arange(Mh), np.arange(Mp), indexing="ij")
    base = np.stack([i.ravel(), j.ravel() * np.sqrt(3)], -1) + 0.25
    hexpts = np.concatenate([base, base + [0.5, np.sqrt(3) / 2]])
    psh = PointSet(hexpts, (Mh, Mp * np.sqrt(3)))
    Sh = psh.structure_factor_radial(q)
    assert q[np.argmax(Sh)] == pytest.approx(4 * np.pi / np.sqrt(3), abs=0.05)
    assert np.all(Sh[q < 6] < 0.1)


def test_pointset_rsa_points_match_table():
    """One realisation's estimate scatters by ≈ 0.09 rms about the table
    (no bias: 8 realisations give 0.03); average three."""
    q = np.linspace(3.0, 12.0, 91)
    S = np.mean([PointSet(rsa_configuration(60.0, 0.35, seed=42 + s), (60.0, 60.0))
                 .structure_factor_radial(q) for s in range(3)], axis=0)
    diff = S - rsa_structure_factor(q, 0.35)
    assert np.sqrt(np.mean(diff**2)) < 0.075


def test_pointset_from_files(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.random((50, 2)) * [10.0, 8.0]
    f1 = tmp_path / "p.csv"
    f1.write_text("x,y\n" + "\n".join(f"{x},{y}" for x, y in pts) + "\n")
    f2 = tmp_path / "p.txt"
    f2.write_text("# measured\n\n" + "\n".join(f"{x}\t{y}  0.3" for x, y in pts))
    f3 = tmp_path / "p.npy"
    np.save(f3, pts)
    f4 = tmp_path / "p.ssv"
    f4.write_text("\n".join(f"{x};{y}" for x, y in pts))
    for f in (f1, f2, f3, f4):
        ps = PointSet.from_file(f, box=(10.0, 8.0))
        assert np.allclose(ps.points, pts)
        assert ps.box == ((0.0, 10.0), (0.0, 8.0))
    ps = PointSet.from_file(f1)
    (x0, x1), (y0, y1) = ps.box
    assert x0 <= pts[:, 0].min() and x1 >= pts[:, 0].max()
    assert (x1 - x0) == pytest.approx((np.ptp(pts[:, 0])) * 51 / 49)
    assert PointSet.from_file(f3, isotropic=False).isotropic is False


def test_pointset_file_errors(tmp_path):
    with pytest.raises(CoronaError, match="does not exist"):
        PointSet.from_file(tmp_path / "missing.csv")
    empty = tmp_path / "empty.csv"
    empty.write_text("# nothing\n\n")
    with pytest.raises(CoronaError, match="contains no points"):
        PointSet.from_file(empty)
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2\n3,4\n5,abc\n")
    with pytest.raises(CoronaError, match=r"line 3: cannot read two numbers") as info:
        PointSet.from_file(bad)
    assert "abc" not in str(info.value)      # the file's content is not echoed
    one = tmp_path / "one.csv"
    one.write_text("1 2 3\n4\n")
    with pytest.raises(CoronaError, match="line 2"):
        PointSet.from_file(one)
    npy = tmp_path / "bad.npy"
    np.save(npy, np.zeros(5))
    with pytest.raises(CoronaError, match="shape"):
        PointSet.from_file(npy)
    np.save(tmp_path / "e.npy", np.zeros((0, 2)))
    with pytest.raises(CoronaError, match="contains no points"):
        PointSet.from_file(tmp_path / "e.npy")
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"\x00\x01 not numpy")
    with pytest.raises(CoronaError, match="not a readable .npy"):
        PointSet.from_file(junk)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00\x81\x00")
    with pytest.raises(CoronaError):
        PointSet.from_file(binary)
    with pytest.raises(CoronaError, match="outside box"):
        PointSet([[1.0, 1.0], [11.0, 2.0]], (10.0, 10.0))
    with pytest.raises(CoronaError, match="box"):
        PointSet([[1.0, 1.0]], (10.0, -1.0))
    with pytest.raises(CoronaError, match=r"shape \(N, 2\)"):
        PointSet(np.zeros((3, 3)), (10.0, 10.0))
    with pytest.raises(CoronaError, match="area fraction"):
        PointSet([[1.0, 1.0], [5.0, 5.0]], (10.0, 10.0)).validate(Circle(4.0))


# ---------------------------------------------------------------------------
# micrographs
# ---------------------------------------------------------------------------
def _synthetic_micrograph(rng, H=240, W=320, n=25, radius=7.0, spread=0.0, dark=False):
    from skimage.draw import disk
    img = np.full((H, W), 0.2) + rng.normal(0, 0.03, (H, W))
    centres, radii = [], []
    while len(centres) < n:
        r = radius * (1 + spread * rng.normal()) if spread else radius
        c = rng.uniform([r + 2, r + 2], [H - r - 2, W - r - 2])
        if all(np.hypot(*(c - c2)) > r + r2 + 3 for c2, r2 in zip(centres, radii)):
            centres.append(c)
            radii.append(r)
    for c, r in zip(centres, radii):
        rr, cc = disk(c, r, shape=img.shape)
        img[rr, cc] = 0.8 + rng.normal(0, 0.03, rr.shape)
    if dark:
        img = 1.0 - img
    return img, np.array(centres), np.array(radii)


def _match(found_xy, centres_rc, H, px):
    truth = np.stack([(centres_rc[:, 1] + 0.5) * px, (H - centres_rc[:, 0] - 0.5) * px], -1)
    d, idx = cKDTree(found_xy).query(truth)
    return d, idx


def test_micrograph_recovers_disks():
    from corona.apps.micrograph import from_micrograph
    rng = np.random.default_rng(7)
    img, centres, radii = _synthetic_micrograph(rng)
    px = 0.25
    res = from_micrograph(img, px)
    assert res.count == len(centres)
    d, idx = _match(res.points.points, centres, img.shape[0], px)
    assert len(set(idx)) == len(centres)
    assert d.max() < 0.5 * px  # positions within half a pixel
    assert np.all(np.abs(res.radii[idx] - radii * px) < px)  # radii within a pixel
    assert isinstance(res.shape, Circle)
    assert res.shape.radius == pytest.approx(7.0 * px, abs=0.3 * px)
    assert res.points.box == ((0.0, img.shape[1] * px), (0.0, img.shape[0] * px))
    assert res.area_fraction == pytest.approx(len(centres) * np.pi * 49 / img.size, rel=0.05)
    assert res.threshold is not None and 0.2 < res.threshold < 0.8
    # dark scatterers on a bright background
    res2 = from_micrograph(1.0 - img, px, invert=True)
    assert res2.count == len(centres)
    assert np.allclose(np.sort(res2.radii), np.sort(res.radii))
    # a boolean image and an explicit threshold
    assert from_micrograph(img > 0.5, px).count == len(centres)
    assert from_micrograph(img, px, threshold=0.5).count == len(centres)


def test_micrograph_file_rgb_and_material(tmp_path):
    import imageio.v3 as iio
    from corona.apps.micrograph import from_micrograph
    rng = np.random.default_rng(8)
    img, centres, _ = _synthetic_micrograph(rng, n=12)
    rgb = (np.clip(img, 0, 1)[..., None] * [255, 255, 255]).astype(np.uint8)
    path = tmp_path / "m.png"
    iio.imwrite(path, rgb)
    res = from_micrograph(path, 0.5)
    assert res.count == len(centres)
    mat = res.material("particle")
    assert mat.shape is res.shape and mat.process is res.points


def test_micrograph_size_distribution():
    from corona.model import shapes
    from corona.apps.micrograph import from_micrograph
    rng = np.random.default_rng(9)
    img, centres, radii = _synthetic_micrograph(rng, H=400, W=400, n=40, radius=9.0, spread=0.2)
    res = from_micrograph(img, 1.0)
    assert res.count == len(centres)
    true_spread = radii.std() / radii.mean()
    assert res.radius_spread == pytest.approx(true_spread, abs=0.03)
    if hasattr(shapes, "SizeDistribution"):
        assert isinstance(res.shape, shapes.SizeDistribution)
        assert res.shape.spread == pytest.approx(res.radius_spread)


def test_micrograph_errors(tmp_path):
    from corona.apps.micrograph import from_micrograph
    with pytest.raises(CoronaError, match="no scatterers"):
        from_micrograph(np.zeros((50, 50)), 1.0)
    with pytest.raises(CoronaError, match="no scatterers"):
        from_micrograph(np.zeros((50, 50), dtype=bool), 1.0)
    with pytest.raises(CoronaError, match="no scatterers"):
        from_micrograph(np.random.default_rng(0).random((50, 50)), 1.0, threshold=2.0)
    with pytest.raises(CoronaError, match="does not exist"):
        from_micrograph(tmp_path / "nope.png", 1.0)
    with pytest.raises(CoronaError, match="pixel_size"):
        from_micrograph(np.eye(10), 0.0)
    with pytest.raises(CoronaError, match="shape"):
        from_micrograph(np.zeros((4, 4, 4, 4)), 1.0)


def test_sparse_lattice_cell_mean_keeps_the_peaks_weight(monkeypatch):
    """Many Bragg peaks per table cell: the smooth envelope carries their weight.

    Summing every peak (slow for sparse lattices: minutes for F_a ~ 1e-6) and
    the envelope e^{-q²δ²} must give the same integral over a patch of cells.
    """
    from corona.model import processes
    lat = processes.Lattice("square", 40.0, jitter=4.0)          # 1/40 rad/µm reciprocal spacing
    cell = 0.2                                                     # 64 peaks per cell
    c = (np.arange(-20, 20) + 0.5) * cell
    q = np.stack(np.meshgrid(c, c), -1)
    envelope = lat.bragg_cell_mean(q, cell)
    monkeypatch.setattr(processes.Lattice, "PEAKS_PER_CELL_MAX", 1e9)
    peaks = lat.bragg_cell_mean(q, cell)
    assert envelope.sum() == pytest.approx(peaks.sum(), rel=2e-3)
    # cell by cell, up to the count of peaks on the cell's edges
    np.testing.assert_allclose(envelope, peaks, rtol=0.3, atol=0.05)


@pytest.mark.parametrize("jitter", [0.0, 2.225073858507203e-309, 1e-200, 1e-12])
def test_lattice_cell_mean_finite_for_tiny_jitter(jitter):
    """A jitter of 1e-309 µm once gave 0/0 = NaN in the Debye-Waller cell mean."""
    lat = Lattice("square", 2.0, jitter=jitter)
    c = (np.arange(-8, 8) + 0.5) * 0.3
    q = np.stack(np.meshgrid(c, c), -1)
    S = lat.structure_factor_cell_mean(q, 0.3)
    assert np.all(np.isfinite(S)) and np.all(S >= 0)
    ref = Lattice("square", 2.0, jitter=0.0).structure_factor_cell_mean(q, 0.3)
    np.testing.assert_allclose(S, ref, rtol=1e-5, atol=1e-9)
