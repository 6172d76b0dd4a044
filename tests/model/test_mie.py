"""Mie amplitudes and efficiencies (corona.model.mie.theory) against miepython, published values and limits."""
import numpy as np
import pytest
from scipy import special

from corona import CoronaError
from corona.model.mie import theory as mie

miepython = pytest.importorskip("miepython")  # the test extra installs it

CASES = [(1.33, 0.5), (1.33, 5.0), (1.33, 57.1), (1.5, 10.0), (1.55 + 0.1j, 3.0),
         (1.5 + 1.0j, 1.0), (1.33 + 1e-5j, 100.0), (0.75, 10.0), (2.5 + 0.3j, 25.0)]


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("m,x", CASES)
def test_amplitudes_match_miepython(m, x):
    # miepython uses m = n - iκ (e^{+iωt}): its amplitudes are the complex conjugates of ours
    mu = np.cos(np.linspace(0.0, np.pi, 181))
    s1, s2 = mie.amplitudes(m, x, mu)
    r1, r2 = miepython.S1_S2(np.conj(m), x, mu, norm="wiscombe")
    scale = np.abs(r1).max()
    assert np.max(np.abs(s1 - np.conj(r1))) < 1e-9 * scale
    assert np.max(np.abs(s2 - np.conj(r2))) < 1e-9 * scale


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("m,x", CASES)
def test_efficiencies_match_miepython(m, x):
    e = mie.efficiencies(m, x)
    qext, qsca, qback, g = miepython.efficiencies_mx(np.conj(m), x)
    assert e["q_ext"] == pytest.approx(qext, rel=1e-9)
    assert e["q_sca"] == pytest.approx(qsca, rel=1e-9)
    # Q_back is a cancelling sum: the two codes agree to 1.3e-8 at (2.5+0.3i, 25), where ours
    # moves by 1.4e-9 with 20 more terms and miepython sits 1.3e-8 off that converged value
    assert e["q_back"] == pytest.approx(qback, rel=1e-7, abs=1e-14)
    assert e["g"] == pytest.approx(g, rel=1e-8, abs=1e-12)


# Published values.  Wiscombe 1979 (NCAR/TN-140+STR, test cases of MIEV0; m = n - iκ there,
# conjugated here) and the BHMIE example of Bohren & Huffman 1983, Appendix A.
PUBLISHED = [
    # m, x, Q_ext, Q_sca, g  (None: not quoted)
    (0.75, 10.0, 2.232265, 2.232265, 0.896473),
    (0.75, 1000.0, 1.997908, 1.997908, 0.844944),
    (1.33 + 1e-5j, 1.0, None, 0.093923, 0.184517),
    (1.33 + 1e-5j, 100.0, None, 2.096594, 0.868959),
    (1.5 + 1j, 0.055, 0.101491, 0.000011, 0.000491),
    (1.5 + 1j, 1.0, 2.336321, 0.663454, 0.192136),
    (1.5 + 1j, 100.0, 2.097502, None, None),
    (10 + 10j, 1.0, None, 2.049405, -0.110664),
    (10 + 10j, 100.0, None, 1.836785, 0.556215),
]


@pytest.mark.parametrize("m,x,qext,qsca,g", PUBLISHED)
def test_wiscombe_published_values(m, x, qext, qsca, g):
    e = mie.efficiencies(m, x)
    for key, ref in (("q_ext", qext), ("q_sca", qsca), ("g", g)):
        if ref is not None:
            assert e[key] == pytest.approx(ref, abs=1.5e-6), key


def test_bohren_huffman_bhmie_example():
    # m = 1.55, r = 0.525 µm, λ = 0.6328 µm (x = 5.213): Q_ext = Q_sca = 3.10543, Q_back = 2.92534,
    # g = 0.63314 (Bohren & Huffman 1983, Appendix A)
    e = mie.efficiencies(1.55, 2 * np.pi * 0.525 / 0.6328)
    assert e["q_ext"] == pytest.approx(3.10543, abs=1e-5)
    assert e["q_sca"] == pytest.approx(3.10543, abs=1e-5)
    assert e["q_back"] == pytest.approx(2.92534, abs=1e-5)
    assert e["g"] == pytest.approx(0.63314, abs=1e-5)


def test_wiscombe_amplitude_table():
    # Wiscombe 1979, m = 1.5 - 1i (conjugated: 1.5 + 1i), x = 1, Θ = 0, 30, ..., 180°
    s1_ref = [0.584080 + 0.190515j, 0.565702 + 0.187200j, 0.517525 + 0.178443j, 0.456340 + 0.167167j,
              0.400212 + 0.156643j, 0.362157 + 0.149391j, 0.348844 + 0.146829j]
    s2_ref = [0.584080 + 0.190515j, 0.500161 + 0.145611j, 0.287964 + 0.041054j, 0.0362285 - 0.0618265j,
              -0.174875 - 0.122959j, -0.305682 - 0.143846j, -0.348844 - 0.146829j]
    s1, s2 = mie.amplitudes(1.5 + 1j, 1.0, np.cos(np.radians(np.arange(0, 181, 30))))
    assert np.max(np.abs(s1 - np.conj(s1_ref))) < 1.5e-6
    assert np.max(np.abs(s2 - np.conj(s2_ref))) < 1.5e-6


@pytest.mark.slow
def test_extinction_paradox():
    # Q_ext -> 2 at large x (van de Hulst §8.2), approached like x^(-2/3) (edge term)
    xs = [100.0, 1000.0, 10000.0]
    dev = [abs(mie.efficiencies(1.33, x)["q_ext"] - 2.0) for x in xs]
    assert dev[0] > dev[1] > dev[2]
    assert dev[2] < 0.01
    # van de Hulst's edge correction 2 + 1.992 x^(-2/3) (m -> 1 excluded: here the ripple is small)
    assert mie.efficiencies(1.33, 10000.0)["q_ext"] == pytest.approx(2 + 1.992 * 1e4 ** (-2 / 3), abs=3e-3)


@pytest.mark.parametrize("m,x", [(1.33, 30.0), (1.33 + 0.05j, 30.0), (1.5 + 1j, 8.0)])
def test_energy_closure(m, x):
    # ∫ dσ/dΩ dΩ = Q_sca π r² by quadrature of the amplitudes (independent of the Q_sca series);
    # Q_abs = Q_ext - Q_sca is 0 without absorption and > 0 with it; g = <cos Θ> likewise
    mu, w = special.roots_legendre(int(4 * x) + 200)
    s1, s2 = mie.amplitudes(m, x, mu)
    i = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2)
    q_sca = 2 * np.pi * np.sum(w * i) / (np.pi * x * x)          # k = 1, r = x
    g = 2 * np.pi * np.sum(w * mu * i) / (np.pi * x * x) / q_sca
    e = mie.efficiencies(m, x)
    assert q_sca == pytest.approx(e["q_sca"], rel=1e-10)
    assert g == pytest.approx(e["g"], rel=1e-9)
    if np.imag(m) == 0:
        assert abs(e["q_abs"]) < 1e-12
    else:
        assert e["q_abs"] > 0.01
    # the optical theorem: Q_ext = 4 Re S(0) / x²
    assert e["q_ext"] == pytest.approx(4 * e["s0"].real / x**2, rel=1e-12)


def test_large_sphere_forward_lobe_is_airy():
    # at large x the forward lobe is the Fraunhofer diffraction of the geometric cross-section:
    # S(Θ) -> x² J1(u)/u, u = x sin Θ (van de Hulst §8.3); inside the central peak (u < 3)
    # the refracted light adds O(1/x²) relative to it and the edge terms O(x^(-2/3))
    x = 2000.0
    u = np.linspace(0.05, 3.0, 40)
    mu = np.sqrt(1 - (u / x) ** 2)
    s1, s2 = mie.amplitudes(1.33, x, mu)
    mie_i = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2)
    airy = (x * x * special.j1(u) / u) ** 2
    rel = np.abs(mie_i / airy - 1)
    assert rel.max() < 0.03
    # and the diffraction peak (u < 10) holds about half of the extinction: ≈ πr² of σ_ext ≈ 2πr²
    uu = np.linspace(1e-4, 10.0, 4000)
    s1, s2 = mie.amplitudes(1.33, x, np.sqrt(1 - (uu / x) ** 2))
    ii = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2)
    # dΩ = 2π sin Θ dΘ ≈ 2π u du / x²;  σ/(πr²) with k = 1, r = x
    peak = np.trapezoid(2 * np.pi * uu * ii / x**2, uu) / (np.pi * x * x)
    airy_peak = 1 - special.j0(10.0) ** 2 - special.j1(10.0) ** 2       # Rayleigh's encircled energy
    assert peak == pytest.approx(airy_peak, rel=0.03)


def test_water_ior_against_tabulated():
    # water at 20 °C relative to air (Tilton & Taylor 1938; CRC Handbook): F, D, C lines
    n = mie.water_ior([486.13, 589.29, 656.27])
    assert n == pytest.approx([1.33712, 1.33299, 1.33115], abs=5e-5)
    assert np.all(np.diff(mie.water_ior(np.linspace(360, 830, 50))) < 0)    # normal dispersion


def test_bad_input():
    with pytest.raises(CoronaError, match="x=.*-1"):
        mie.efficiencies(1.33, -1.0)
    with pytest.raises(CoronaError, match="κ >= 0"):
        mie.efficiencies(1.33 - 0.1j, 5.0)
    with pytest.raises(CoronaError, match="mu="):
        mie.amplitudes(1.33, 5.0, [1.5])


def test_riccati_bessel_upward_recurrence_matches_scipy():
    # ψ_n = x j_n and x y_n by upward recurrence up to Wiscombe's N, against scipy.special
    from scipy import special
    from corona.model.mie.theory import _riccati_bessel
    x = np.array([0.3, 2.0, 17.5, 140.0, 436.0])
    N = int(mie.n_terms(x.max()))
    psi, chi = _riccati_bessel(x, N)
    for i, xi in enumerate(x):
        n = np.arange(int(mie.n_terms(xi)) + 1)
        jn, yn = special.spherical_jn(n, xi) * xi, special.spherical_yn(n, xi) * xi
        assert np.max(np.abs(psi[i, n] - jn) / np.abs(jn).max()) < 1e-9
        assert np.max(np.abs(chi[i, n] - yn) / np.abs(yn)) < 1e-10


def test_amplitudes_both_ways_match_amplitudes():
    # the odd/even real matrix products give S(μ) and S(-μ) as the direct sums do
    x = np.array([0.5, 12.3, 87.0])
    m = np.array([1.33, 1.5 + 0.01j, 1.45])
    mu = np.cos(np.linspace(0.0, 0.5 * np.pi, 101))
    basis = mie.AngularBasis(mu, int(mie.n_terms(x.max())))
    S1f, S2f, S1b, S2b = mie.amplitudes_both_ways(m, x, basis)
    for i in range(x.size):
        s1, s2 = mie.amplitudes(m[i], x[i], np.concatenate([mu, -mu]))
        k = mu.size
        top = np.abs(s1).max()
        for got, want in ((S1f[i], s1[:k]), (S2f[i], s2[:k]), (S1b[i], s1[k:]), (S2b[i], s2[k:])):
            assert np.max(np.abs(got - want)) < 1e-10 * top
    # negative control: the backward sums with the parity signs left out are not S(-μ)
    assert np.max(np.abs(S1b[2] - S1f[2])) > 1e-3 * np.abs(S1f[2]).max()


def test_single_precision_products_keep_the_lobes():
    # the tables' angular products in float32: |S|² of both lobes, energy-weighted as the
    # tables are judged, stays within 1e-5 of Mie theory in float64 (water, x = 150 and 340)
    x = np.array([150.0, 340.0])
    m = np.full(x.size, complex(mie.water_ior(361.3)))
    s = np.linspace(0.0, np.sqrt(2.0), 3000)
    mu = 1.0 - 0.5 * s * s
    basis = mie.AngularBasis(mu, int(mie.n_terms(x.max())), np.float32)
    assert basis.pi_odd.dtype == np.float32
    S1f, S2f, S1b, S2b = mie.amplitudes_both_ways(m, x, basis)
    for i in range(x.size):
        s1, s2 = mie.amplitudes(m[i], x[i], np.concatenate([mu, -mu]))
        k = mu.size
        for (a1, a2), (b1, b2) in (((S1f[i], S2f[i]), (s1[:k], s2[:k])), ((S1b[i], S2b[i]), (s1[k:], s2[k:]))):
            got = np.abs(a1) ** 2 + np.abs(a2) ** 2
            want = np.abs(b1) ** 2 + np.abs(b2) ** 2
            w = want * s
            rms = np.sqrt(np.sum(w * (got / want - 1) ** 2) / np.sum(w))
            assert rms < 1e-5, rms
            assert rms > 1e-12        # single precision indeed (float64 agrees to ~1e-14)


@pytest.mark.parametrize("m", [1.333, 1.5 + 0.01j])
def test_power_both_ways_matches_amplitudes(m):
    # the size spreads' kernel (coefficients by order, real arithmetic for a real index, the
    # float64 products here) against the direct sums: |S|² at ±μ, the forward S1, S2, S(0) and the
    # efficiencies; sizes spanning many terms in one block, so that the terms past each size's own N
    # are left out as coefficients() leaves them out
    x = np.array([3.2, 9.7, 25.0, 61.5, 140.0])
    mm = np.full(x.size, m, dtype=complex)
    mu = np.cos(np.linspace(0.0, 0.5 * np.pi, 151))
    N = int(mie.n_terms(x.max()))
    basis = mie.AngularBasis(mu, N)
    psi, chi = mie._riccati_bessel(x, N, by_order=True)
    D = mie._log_derivative(mm * x, N)
    work = {}
    for _ in range(2):                        # the second call reuses the scratch arrays
        R, s0, q_sca, q_ext = mie._power_both_ways(mm, x, basis, psi, chi, D, work)
    eff = mie.efficiencies(mm, x)
    for i in range(x.size):
        s1, s2 = mie.amplitudes(m, x[i], np.concatenate([mu, -mu]))
        k = mu.size
        pf = np.abs(s1[:k]) ** 2 + np.abs(s2[:k]) ** 2
        pb = np.abs(s1[k:]) ** 2 + np.abs(s2[k:]) ** 2
        np.testing.assert_allclose(R[0, i], pf, rtol=1e-9, atol=1e-12 * pf.max())
        np.testing.assert_allclose(R[1, i], pb, rtol=1e-9, atol=1e-12 * pf.max())
        top = np.abs(s1).max()
        for got, want in ((R[2, i] + 1j * R[3, i], s1[:k]), (R[4, i] + 1j * R[5, i], s2[:k])):
            assert np.max(np.abs(got - want)) < 1e-10 * top
        assert abs(s0[i] - eff["s0"][i]) < 1e-10 * abs(eff["s0"][i])
        np.testing.assert_allclose([q_sca[i], q_ext[i]] / x[i] ** 2, [eff["q_sca"][i], eff["q_ext"][i]], rtol=1e-10)
    # negative control: the index of another sphere is far from these lobes
    R2 = mie._power_both_ways(mm * 1.01, x, basis, psi, chi, mie._log_derivative(mm * 1.01 * x, N))[0]
    assert np.max(np.abs(R2[1, -1] / R[1, -1] - 1)) > 0.1
