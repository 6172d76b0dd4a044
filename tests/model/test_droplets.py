"""Droplets in a volume (corona.model.mie.volume): size distributions, the hard-sphere structure
factor of dense media, the phase function's tables against Mie theory (miepython), a host
medium, forward-peak truncation (docs/volumes.md).  The Mitsuba side: tests/plugin/test_volume.py."""
import math

import numpy as np
import pytest

import corona
from corona.model.mie import volume as droplets
from corona.model.mie.volume import MieVolume, size_nodes
from corona.model.processes import percus_yevick_3d

miepython = pytest.importorskip("miepython")


# ----------------------------------------------------------------------
# structure factor and size distributions
# ----------------------------------------------------------------------
@pytest.mark.parametrize("phi", [0.01, 0.1, 0.3, 0.45])
def test_percus_yevick_compressibility_route(phi):
    s0 = (1 - phi) ** 4 / (1 + 2 * phi) ** 2
    assert percus_yevick_3d(0.0, 1.0, phi) == pytest.approx(s0, rel=1e-12)
    # continuous across the series / closed-form switch at qσ = 0.5, and S -> 1 at large q
    s = percus_yevick_3d([0.4999999, 0.5000001, 200.0], 1.0, phi)
    assert s[0] == pytest.approx(s[1], rel=1e-6)
    assert s[2] == pytest.approx(1.0, abs=0.01)
    # negative control: another φ's compressibility differs
    assert abs(percus_yevick_3d(0.0, 1.0, phi * 1.05) - s0) > 1e-3 * s0


def test_percus_yevick_second_virial():
    # low density: S(q) = 1 - φ 24 j1(qσ)/(qσ)·... exactly 1 + n ∫ (g - 1) e^{iqr}: g = 0 inside σ
    q = np.linspace(0.1, 20, 50)
    phi = 1e-4
    n = phi / (np.pi / 6)
    ft = 4 * np.pi * (np.sin(q) - q * np.cos(q)) / q**3        # ∫_{r<1} e^{iqr} d³r
    assert np.allclose(percus_yevick_3d(q, 1.0, phi), 1 - n * ft, atol=1e-7)


@pytest.mark.slow
def test_percus_yevick_against_simulation():
    sim = pytest.importorskip("corona.reference.hard_sphere")
    q, S = sim.structure_factor_mc(volume_fraction=0.3, n=400, sweeps=300, seed=1)
    sel = (q > 2.0) & (q < 14.0)
    py = percus_yevick_3d(q[sel], 1.0, 0.3)
    assert np.max(np.abs(S[sel] - py)) < 0.12
    # the peak at qσ ≈ 7 is seen (S > 1.15) where Poisson would give 1
    assert S[(q > 6.5) & (q < 7.5)].mean() > 1.15


@pytest.mark.slow
@pytest.mark.parametrize("dist", ["lognormal", "gamma", "modified_gamma"])
def test_size_nodes_reproduce_effective_radius_and_variance(dist):
    r, w = size_nodes(8.0, dist, 0.15, gamma_exponent=1.0 if dist != "modified_gamma" else 0.5)
    reff = (w * r**3).sum() / (w * r**2).sum()
    veff = (w * r**4).sum() * (w * r**2).sum() / (w * r**3).sum() ** 2 - 1
    assert reff == pytest.approx(8.0, rel=2e-3)
    assert veff == pytest.approx(0.15, rel=2e-2)


@pytest.mark.slow
@pytest.mark.parametrize("dist, radius, variance", [("lognormal", 8.0, 0.15), ("lognormal", 0.5, 0.005),
                                                     ("gamma", 5.0, 0.02), ("gamma", 20.0, 0.1)])
def test_size_nodes_span_scipy_stats_quantiles(dist, radius, variance):
    """The nodes span the area-weighted distribution's 1e-4 .. 1 - 1e-4 quantiles, as
    scipy.stats gives them (size_nodes computes them with scipy.special alone)."""
    from scipy import optimize, special, stats
    r, _ = size_nodes(radius, dist, variance)
    if dist == "lognormal":
        s2 = math.log1p(variance)
        area = stats.lognorm(math.sqrt(s2), scale=radius / (1 + variance) ** 2.5 * math.exp(2 * s2))
        lo, hi = area.ppf(1e-4), area.ppf(1 - 1e-4)
    else:
        lg = lambda a, k: special.gammaln(a + 1 + k)
        alpha = optimize.brentq(lambda a: math.exp(lg(a, 4) + lg(a, 2) - 2 * lg(a, 3)) - 1 - variance,
                                -2.999 + 1e-9, 1e5, xtol=1e-12)
        B = 1.0 / (radius / math.exp(special.gammaln(alpha + 4) - special.gammaln(alpha + 3)))
        lo, hi = (stats.gamma(alpha + 3).ppf([1e-4, 1 - 1e-4]) / B)
    t, _ = np.polynomial.legendre.leggauss(r.size)
    np.testing.assert_allclose(r, lo + (hi - lo) * 0.5 * (t + 1), rtol=1e-12)


def test_modified_gamma_with_exponent_one_is_gamma():
    a = size_nodes(6.0, "gamma", 0.2)
    b = size_nodes(6.0, "modified_gamma", 0.2, gamma_exponent=1.0)
    assert np.allclose(a[0], b[0]) and np.allclose(a[1], b[1])


@pytest.mark.parametrize("kwargs, word", [
    (dict(radius=-1.0), "radius"),
    (dict(radius=5.0, distribution="gauss", variance=0.1), "distribution"),
    (dict(radius=5.0, distribution="gamma", variance=0.7), "variance"),
    (dict(radius=5.0, distribution="mono", variance=0.1), "variance"),
    (dict(radius=5.0, ior_imag=-0.1), "ior_imag"),
    (dict(radius=5.0, ior=0.5), "ior"),
    (dict(radius=5.0, volume_fraction=0.6), "volume_fraction"),
    (dict(radius=5.0, host_ior=0.5), "host_ior"),
    (dict(radius=5.0, host_ior=4.0), "host_ior"),
    (dict(radius=5.0, host_ior="water"), "host_ior"),
    (dict(radius=5.0, ior=1.5, host_ior=1.5), "ior"),
    (dict(radius=5.0, truncation=-1.0), "truncation"),
    (dict(radius=5.0, truncation=45.0), "truncation"),
])
def test_bad_droplets_one_clear_error(kwargs, word):
    with pytest.raises(corona.CoronaError, match=word):
        MieVolume(**kwargs).table


# ----------------------------------------------------------------------
# the phase function against Mie theory
# ----------------------------------------------------------------------
def _miepython_phase(m, radius, lam, mu):
    x = 2 * np.pi * radius / (lam * 1e-3)
    s1, s2 = miepython.S1_S2(np.conj(m), x, mu, norm="wiscombe")
    qsca = miepython.efficiencies_mx(np.conj(m), x)[1]
    return (np.abs(s1) ** 2 + np.abs(s2) ** 2) / (2 * np.pi * x * x * qsca)


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("radius", [1.0, 20.0])
def test_exact_phase_matches_miepython(radius):
    v = MieVolume(radius)
    mu = np.cos(np.radians([0.05, 1.0, 7.0, 40.0, 138.0, 179.5]))
    for lam in (437.1, 612.9):
        ref = _miepython_phase(complex(corona.model.mie.theory.water_ior(lam)), radius, lam, mu)
        assert np.allclose(v.exact_phase(mu, lam), ref, rtol=1e-6)


def _between_nodes(v, lo_deg, hi_deg, n=40):
    """cos Θ at points 37 % of the way (in Θ) between consecutive table nodes in [lo, hi]."""
    th = v.table["theta"]
    idx = np.flatnonzero((th >= math.radians(lo_deg)) & (th < math.radians(hi_deg)))
    idx = idx[:: max(1, idx.size // n)]
    return np.cos(th[idx] + 0.37 * (th[idx + 1] - th[idx]))


def _between_rows(v):
    x = v.table["x"]
    return [2 * np.pi * v.radius / (xx * 1e-3) for xx in (0.6 * x[3] + 0.4 * x[4], 0.3 * x[-6] + 0.7 * x[-5])]


@pytest.mark.slow
@pytest.mark.parametrize("kwargs, fwd_tol, all_tol", [
    (dict(radius=1.0), 0.01, 0.02),
    (dict(radius=5.0, distribution="gamma", variance=0.05), 0.01, 0.02),
    (dict(radius=20.0), 0.03, 0.3),
])
def test_table_between_nodes_and_rows_matches_mie(kwargs, fwd_tol, all_tol):
    """The table at angles between its nodes and wavelengths between its rows against Mie theory.

    Forward (Θ < 15°: aureole and rings) to ``fwd_tol``; all angles within ``all_tol`` of the
    mean over a few nodes (one large droplet's backward ripple varies faster in x than the rows
    follow: the rows interpolate it, as the surface lobe's rows do)."""
    v = MieVolume(**kwargs)
    for lam in _between_rows(v):
        mu = _between_nodes(v, 0.02, 15.0)
        ratio = v.phase(mu, lam) / v.exact_phase(mu, lam)
        assert np.median(np.abs(ratio - 1)) < fwd_tol, (lam, ratio)
        mu = _between_nodes(v, 15.0, 179.0, n=400)
        tab, ex = v.phase(mu, lam), v.exact_phase(mu, lam)
        k = 10
        tb = tab[: tab.size // k * k].reshape(-1, k).mean(1)
        eb = ex[: ex.size // k * k].reshape(-1, k).mean(1)
        assert np.median(np.abs(tb / eb - 1)) < all_tol, (lam, tb / eb)


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("coherent", [False, True])
def test_size_averaged_scattering_is_the_sum_over_sizes(coherent):
    """The table build's size average (S1 ± S2 in real products, pairs in blocks by series
    length) against miepython's S1, S2 and efficiencies summed size by size and row by row,
    with rows and sizes whose series lengths differ (several blocks), an absorbing index."""
    lam = np.array([380.0, 520.0, 790.0])
    m = np.array([1.34 + 0.01j, 1.335 + 0.01j, 1.33 + 0.01j])
    k = 2 * np.pi / (lam * 1e-3)
    radii, weights = droplets.size_nodes(3.0, "gamma", 0.1, n=40)
    mu = np.cos(np.linspace(0.0, np.pi, 181))
    old_block = droplets.PAIR_BLOCK
    try:
        droplets.PAIR_BLOCK = 16                                       # several blocks per row
        P, C, c_ext, c_sca = droplets.size_averaged_scattering(m, k, radii, weights, mu, coherent=coherent)
    finally:
        droplets.PAIR_BLOCK = old_block
    assert (C is None) == (not coherent)
    for j in range(lam.size):
        x = k[j] * radii
        s1 = np.array([miepython.S1_S2(np.conj(m[j]), xx, mu, norm="wiscombe")[0] for xx in x])
        s2 = np.array([miepython.S1_S2(np.conj(m[j]), xx, mu, norm="wiscombe")[1] for xx in x])
        # miepython's "wiscombe" S are conjugates of Bohren & Huffman's (e^{+iωt}); |S|² is the same
        ref_P = weights @ (np.abs(s1) ** 2 + np.abs(s2) ** 2)
        np.testing.assert_allclose(P[j], ref_P, rtol=1e-7)        # two Mie codes: ~1e-9 apart
        if coherent:
            ref_C = np.abs(weights @ s1) ** 2 + np.abs(weights @ s2) ** 2
            np.testing.assert_allclose(C[j], ref_C, rtol=1e-7, atol=1e-10 * ref_C.max())
        eff = np.array([miepython.efficiencies_mx(np.conj(m[j]), xx)[:2] for xx in x])
        area = np.pi * radii**2
        assert c_ext[j] == pytest.approx(weights @ (eff[:, 0] * area), rel=1e-7)
        assert c_sca[j] == pytest.approx(weights @ (eff[:, 1] * area), rel=1e-7)


@pytest.mark.parametrize("radius", [0.5, 3.0, 12.0])
def test_table_normalised_and_asymmetry(radius):
    v = MieVolume(radius)
    lam = v.table["wavelength"][7]
    assert v.integral(lam) == pytest.approx(1.0, abs=1e-9)
    m = complex(corona.model.mie.theory.water_ior(lam))
    g = corona.model.mie.theory.efficiencies(m, 2 * np.pi * radius / (lam * 1e-3))["g"]
    assert v.table["g"][7] == pytest.approx(g, abs=2e-3)
    e = corona.model.mie.theory.efficiencies(m, 2 * np.pi * radius / (lam * 1e-3))
    assert v.table["c_ext"][7] == pytest.approx(e["q_ext"] * np.pi * radius**2, rel=1e-9)


def test_absorbing_droplets_lower_albedo():
    v = MieVolume(3.0, ior=1.5, ior_imag=0.01)
    cs = v.cross_sections(550.0)
    e = corona.model.mie.theory.efficiencies(1.5 + 0.01j, 2 * np.pi * 3.0 / 0.55)
    assert cs["albedo"] == pytest.approx(e["q_sca"] / e["q_ext"], rel=1e-3)
    assert cs["albedo"] < 0.8


# ----------------------------------------------------------------------
# a host medium: wavelength λ / n_host, relative index m = n / n_host
# ----------------------------------------------------------------------
HOSTS = [  # (radius µm, particle ior, ior_imag, host ior): latex in water, water in oil, pigment in resin
    (0.5, 1.59, 0.0, 1.33),
    (2.0, "water", 0.0, 1.45),
    (0.3, 2.0, 0.05, 1.5),
]


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("radius, ior, kappa, host", HOSTS)
def test_host_medium_matches_miepython(radius, ior, kappa, host):
    """miepython with n_env (its own conversion to x = π d n_env / λ0 and m / n_env) for the
    efficiencies, and its phase function at that x and m."""
    v = MieVolume(radius, ior=ior, ior_imag=kappa, host_ior=host)
    mu = np.cos(np.radians([0.5, 5.0, 30.0, 90.0, 150.0, 179.0]))
    for lam in (437.1, 612.9):
        n = complex(corona.model.mie.theory.water_ior(lam)) if ior == "water" else ior
        m_abs = n + 1j * kappa
        qext, qsca, _, g = miepython.efficiencies(np.conj(m_abs), 2 * radius, lam * 1e-3, n_env=host)
        cs = v.cross_sections(lam)
        e = corona.model.mie.theory.efficiencies(m_abs / host, 2 * np.pi * radius * host / (lam * 1e-3))
        assert e["q_ext"] == pytest.approx(qext, rel=1e-6) and e["q_sca"] == pytest.approx(qsca, rel=1e-6)
        ref = _miepython_phase(m_abs / host, radius * host, lam, mu)      # x = 2π r n_host / λ
        assert np.allclose(v.exact_phase(mu, lam), ref, rtol=1e-6)
        # the table (between its rows) within its interpolation error; C_ext = Q_ext π r²
        assert np.allclose(v.phase(mu, lam), ref, rtol=0.03)
        assert cs["c_ext"] == pytest.approx(qext * np.pi * radius**2, rel=5e-3)
        assert cs["g"] == pytest.approx(g, abs=5e-3)
    # negative control: the same particles in air scatter differently
    air = MieVolume(radius, ior=ior, ior_imag=kappa)
    assert not np.allclose(air.exact_phase(mu, 550.0), v.exact_phase(mu, 550.0), rtol=0.05)


def test_host_medium_scales_the_rings():
    """Droplets in a host of index n_h have the rings of droplets n_h times larger in air with the
    index m = n / n_h: the phase function depends on x = 2π r n_h / λ and m only."""
    a = MieVolume(3.0, ior=1.6, host_ior=1.25)
    b = MieVolume(3.75, ior=1.6 / 1.25)
    mu = np.cos(np.radians(np.linspace(0.1, 179.9, 50)))
    assert np.allclose(a.exact_phase(mu, 520.0), b.exact_phase(mu, 520.0), rtol=1e-9)
    assert a.cross_sections(520.0)["c_ext"] == pytest.approx(b.cross_sections(520.0)["c_ext"] / 1.25**2, rel=2e-3)


def test_dense_medium_structure_factor_lowers_sigma_s():
    # 0.2 µm latex-like spheres at φ = 0.3: forward scattering suppressed by S(q) < 1 at small q
    dil = MieVolume(0.2, ior=1.2)
    den = MieVolume(0.2, ior=1.2, volume_fraction=0.3)
    a, b = dil.cross_sections(550.0), den.cross_sections(550.0)
    assert b["c_sca"] < 0.6 * a["c_sca"]
    # the gain is ∫ p S dΩ for one size (C = P): check it by quadrature at the table's nodes
    lam = den.table["wavelength"][5]
    v = dil.table["v"]
    k = 2 * np.pi / (lam * 1e-3)
    S = percus_yevick_3d(2 * k * np.sqrt(v), 0.4, 0.3)
    p = dil.table["p"][5]
    gain = 4 * np.pi * np.sum(0.5 * ((p * S)[1:] + (p * S)[:-1]) * np.diff(v))
    assert den.table["s_gain"][5] == pytest.approx(gain, rel=1e-9)
    assert np.allclose(den.table["p"][5], p * S / gain, rtol=1e-9)
    # dilute droplets: no change
    assert MieVolume(5.0, volume_fraction=1e-7).cross_sections(550.0)["s_gain"] == pytest.approx(1, abs=1e-5)


# ----------------------------------------------------------------------
# forward-peak truncation
# ----------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, angle", [
    (dict(radius=10.0, distribution="gamma", variance=0.01), 5.0),
    (dict(radius=1.0), 10.0),
    (dict(radius=3.0, ior=1.5, ior_imag=0.01, host_ior=1.2), 2.0),
])
def test_truncation_keeps_wide_angles_and_absorption(kwargs, angle):
    """σ_s p(Θ) is unchanged outside the cone (exactly: the glory, the bows), σ_a = σ_t - σ_s is
    unchanged, p* integrates to 1, and σ_s (1 - g) (the transport coefficient that sets the
    reflectance of a thick cloud) changes by at most f (1 - cos Θ_c) σ_s."""
    full, cut = MieVolume(**kwargs).table, MieVolume(**kwargs, truncation=angle).table
    ic = int(cut["truncation_node"])
    assert math.radians(angle) <= cut["theta"][ic] < math.radians(angle) + 0.02
    f = cut["truncated_fraction"]
    assert np.all((f > 0.01) & (f < 0.7)), f
    assert np.allclose(cut["c_sca"][:, None] * cut["p"][:, ic:], full["c_sca"][:, None] * full["p"][:, ic:],
                       rtol=1e-9)
    assert np.allclose(cut["c_ext"] - cut["c_sca"], full["c_ext"] - full["c_sca"], rtol=1e-9, atol=1e-9)
    assert np.allclose(cut["c_sca"], (1 - f) * full["c_sca"], rtol=1e-12)
    v = MieVolume(**kwargs, truncation=angle)
    lam = cut["wavelength"][3]
    assert v.integral(lam) == pytest.approx(1.0, abs=1e-9)
    tr_cut, tr_full = cut["c_sca"] * (1 - cut["g"]), full["c_sca"] * (1 - full["g"])
    bound = f * full["c_sca"] * (1 - math.cos(cut["theta"][ic]))
    assert np.all(np.abs(tr_cut - tr_full) <= bound * (1 + 1e-6) + 1e-9)
    # the peak is gone: p* inside the cone at most p at the cone's edge / (1 - f)
    assert np.all(cut["p"][:, :ic].max(axis=1) <= full["p"][:, ic] / (1 - f) * (1 + 1e-9))
    assert np.all(full["p"][:, 0] > full["p"][:, ic])            # (there was a peak to cut)


# ----------------------------------------------------------------------
# bad values named (issue 47: items 14, 15)
# ----------------------------------------------------------------------
@pytest.mark.parametrize("gamma", [1e-300, 1e-3, 0.09, 10.5, 1e3, 1e5, 1e300])
def test_extreme_gamma_exponent_is_one_line(gamma):
    """γ outside [0.1, 10] ended in an OverflowError (γ -> 0) or 'cannot convert float NaN'
    (γ -> ∞) from inside the quadrature; now one line naming it."""
    with pytest.raises(corona.CoronaError, match=r"gamma_exponent=.* is out of range; allowed \[0.1, 10\]"):
        size_nodes(10.0, "modified_gamma", 0.1, gamma)


@pytest.mark.parametrize("gamma", [0.1, 0.5, 2.0, 10.0])
@pytest.mark.parametrize("variance", [0.001, 0.1, 0.5])
def test_gamma_exponent_range_ends_are_finite(gamma, variance):
    """Negative control: the range's ends and the published models' values build finite
    nodes with the requested effective radius (within 1 %)."""
    r, w = size_nodes(10.0, "modified_gamma", variance, gamma)
    assert np.all(np.isfinite(r)) and np.all(r > 0) and np.all(np.isfinite(w))
    assert (w * r ** 3).sum() / (w * r ** 2).sum() == pytest.approx(10.0, rel=0.01)
