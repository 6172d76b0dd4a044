"""Droplet volumes: the corona_mie phase function, the media, dense media, volpath checks (docs/volumes.md)."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import corona
from corona.mitsuba import volume
from corona.model.processes import percus_yevick_3d
from corona.mitsuba.volume import MieVolume, size_nodes

miepython = pytest.importorskip("miepython")


@pytest.fixture
def variant(request):
    before = mi.variant()
    mi.set_variant(request.param)
    corona.register()
    yield request.param
    if before is not None:
        mi.set_variant(before)


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
    from corona.mitsuba import volume
    lam = np.array([380.0, 520.0, 790.0])
    m = np.array([1.34 + 0.01j, 1.335 + 0.01j, 1.33 + 0.01j])
    k = 2 * np.pi / (lam * 1e-3)
    radii, weights = volume.size_nodes(3.0, "gamma", 0.1, n=40)
    mu = np.cos(np.linspace(0.0, np.pi, 181))
    old_block = volume.PAIR_BLOCK
    try:
        volume.PAIR_BLOCK = 16                                       # several blocks per row
        P, C, c_ext, c_sca = volume.size_averaged_scattering(m, k, radii, weights, mu, coherent=coherent)
    finally:
        volume.PAIR_BLOCK = old_block
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


# ----------------------------------------------------------------------
# the Mitsuba plugin
# ----------------------------------------------------------------------
def _mei(n, wi, wavelengths=(450.0, 520.0, 600.0, 700.0)):
    m = dr.zeros(mi.MediumInteraction3f, n)
    m.wi = mi.Vector3f(*[float(c) for c in wi])
    m.sh_frame = mi.Frame3f(m.wi)
    if mi.is_spectral:
        m.wavelengths = mi.Spectrum(*wavelengths)
    return m


def _chi2(params, wi, wavelengths=(450.0, 520.0, 600.0, 700.0)):
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    from bsdf_checks import run_chi2
    ph = mi.load_dict({"type": "corona_mie", **params})
    ctx = mi.PhaseFunctionContext()

    def sample(s, *a):
        wo, w, pdf = ph.sample(ctx, _mei(dr.width(s), wi, wavelengths), s[0], mi.Point2f(s[1], s[2]))
        return wo, dr.select(pdf > 0, 1.0, 0.0)

    def pdf(wo, *a):
        return ph.eval_pdf(ctx, _mei(dr.width(wo), wi, wavelengths), wo)[1]

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=1_000_000, res=101, ires=16)
    return run_chi2(test), test


CHI2_CASES = [
    ({"radius": 0.5}, (450.0, 520.0, 600.0, 700.0)),
    ({"radius": 2.0, "distribution": "lognormal", "variance": 0.2}, (380.0, 480.0, 560.0, 810.0)),
    ({"radius": 5.0, "distribution": "gamma", "variance": 0.05}, (450.0, 520.0, 600.0, 700.0)),
    ({"radius": 4.0, "distribution": "modified_gamma", "variance": 0.1, "gamma_exponent": 0.5},
     (400.0, 500.0, 650.0, 750.0)),
    ({"radius": 3.0, "ior": 1.5, "ior_imag": 0.02}, (450.0, 520.0, 600.0, 700.0)),
    ({"radius": 0.3, "volume_fraction": 0.3}, (450.0, 520.0, 600.0, 700.0)),
    ({"radius": 20.0}, (433.0, 547.0, 611.0, 689.0)),
]


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_spectral"], indirect=True)
@pytest.mark.parametrize("params, wavelengths", CHI2_CASES)
def test_chi2_spectral(variant, params, wavelengths):
    ok, test = _chi2(params, (0.6, 0.0, 0.8), wavelengths)   # run_chi2: the session's test_count
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono"], indirect=True)
@pytest.mark.parametrize("params", [{"radius": 1.0}, {"radius": 10.0, "distribution": "gamma", "variance": 0.1}])
def test_chi2_rgb_mono(variant, params):
    ok, test = _chi2(params, (0.0, 0.6, -0.8))
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_rgb"], indirect=True)
def test_chi2_stock_adapter(variant):
    from mitsuba.chi2 import ChiSquareTest, PhaseFunctionAdapter, SphericalDomain
    from bsdf_checks import run_chi2
    s, p = PhaseFunctionAdapter("corona_mie", {"type": "corona_mie", "radius": 2.0}, wi=[0.6, 0.0, 0.8])
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=s, pdf_func=p, sample_dim=3,
                         sample_count=1_000_000, res=101, ires=16)
    assert run_chi2(test), test.messages


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_spectral"], indirect=True)
def test_chi2_negative_control(variant, tmp_path, monkeypatch):
    """A pdf that is the table's with the forward peak 10 % too low is rejected (Mitsuba writes the
    failed test's chi2_data.py into the working directory: a temporary one)."""
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    ph = mi.load_dict({"type": "corona_mie", "radius": 2.0})
    ctx = mi.PhaseFunctionContext()
    wi = (0.6, 0.0, 0.8)

    def sample(s, *a):
        wo, w, pdf = ph.sample(ctx, _mei(dr.width(s), wi), s[0], mi.Point2f(s[1], s[2]))
        return wo, dr.select(pdf > 0, 1.0, 0.0)

    def pdf(wo, *a):
        val = ph.eval_pdf(ctx, _mei(dr.width(wo), wi), wo)[1]
        cos_t = -dr.dot(wo, mi.Vector3f(*wi))
        return dr.select(cos_t > math.cos(0.2), 0.9 * val, val)

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=1_000_000, res=101, ires=16)
    monkeypatch.chdir(tmp_path)
    assert not test.run()
    assert (tmp_path / "chi2_data.py").exists()


@pytest.mark.slow     # 2 s of CPU warm per variant, 5 s cold
@pytest.mark.parametrize("variant", ["llvm_ad_spectral", "scalar_spectral"], indirect=True)
def test_plugin_eval_equals_table(variant):
    v = MieVolume(20.0)
    ph = mi.load_dict({"type": "corona_mie", "radius": 20.0})
    lams = (433.3, 517.7, 604.9, 701.1)
    th = np.array([3e-4, 2e-3, 0.011, 0.05, 0.3, 1.5, 2.6, 3.14])
    ctx = mi.PhaseFunctionContext()
    for t in th:
        wo = [math.sin(t), 0.0, -math.cos(t)]
        val, pdf = ph.eval_pdf(ctx, _mei(1, (0.0, 0.0, 1.0), lams), mi.Vector3f(*wo))
        ref = np.array([v.phase(math.cos(t), lam) for lam in lams]).ravel()
        got = np.array(val).ravel()
        assert np.allclose(got, ref, rtol=2e-3, atol=1e-6), (t, got, ref)
        assert float(np.array(pdf).ravel()[0]) == pytest.approx(ref.mean(), rel=2e-3)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb", "llvm_ad_mono"], indirect=True)
def test_plugin_rgb_channels_are_response_averages(variant):
    from corona.mitsuba.phase import channel_response
    v = MieVolume(5.0)
    lam, w = channel_response()
    rows = v.rgb_table(lam, w)
    ph = mi.load_dict({"type": "corona_mie", "radius": 5.0})
    for t in (0.01, 0.06, 0.4, 2.5):
        val, pdf = ph.eval_pdf(mi.PhaseFunctionContext(), _mei(1, (0.0, 0.0, 1.0)),
                               mi.Vector3f(math.sin(t), 0.0, -math.cos(t)))
        # the node grid of the rows: linear in v = sin²(Θ/2) between the nodes around t
        vn = v.table["v"]
        vt = math.sin(t / 2) ** 2
        i = int(np.searchsorted(vn, vt) - 1)
        f = (vt - vn[i]) / (vn[i + 1] - vn[i])
        ref = rows[:, i] * (1 - f) + rows[:, i + 1] * f
        ref = ref / (4 * np.pi * np.sum(0.5 * (rows[:, 1:] + rows[:, :-1]) * np.diff(vn), axis=1))
        assert np.allclose(np.array(val).ravel()[: len(ref)], ref, rtol=2e-3)
    # RGB rows differ: red's rings are wider than blue's
    if rows.shape[0] == 3:
        assert not np.allclose(rows[0], rows[2], rtol=0.05)


@pytest.mark.parametrize("variant", ["llvm_ad_spectral", "llvm_ad_rgb"], indirect=True)
def test_zero_interaction_no_nan(variant):
    ph = mi.load_dict({"type": "corona_mie", "radius": 3.0})
    mei = dr.zeros(mi.MediumInteraction3f, 1000)
    mei.wi = mi.Vector3f(0.0, 0.0, 1.0)
    rng = np.random.default_rng(1)
    wo, w, pdf = ph.sample(mi.PhaseFunctionContext(), mei, mi.Float(rng.random(1000)),
                           mi.Point2f(rng.random(1000), rng.random(1000)))
    for a in (wo, w, pdf):
        assert np.all(np.isfinite(np.array(a)))
    assert np.allclose(np.linalg.norm(np.array(wo), axis=0), 1.0, atol=1e-5)
    val, pdf2 = ph.eval_pdf(mi.PhaseFunctionContext(), mei, wo)
    assert np.allclose(np.array(pdf2), np.array(pdf), rtol=1e-4)


def test_unknown_plugin_parameter_is_an_error(mi_variant):
    with pytest.raises(Exception, match="radious"):
        mi.load_dict({"type": "corona_mie", "radious": 3.0})


# ----------------------------------------------------------------------
# media
# ----------------------------------------------------------------------
def test_lwc_number_density_and_sigma_t(mi_variant):
    med, info = volume.homogeneous_medium(10.0, lwc=0.3, return_info=True)
    N = 0.3 / (volume.WATER_DENSITY * 4 / 3 * np.pi * (10e-6) ** 3)
    assert info["number_density"] == pytest.approx(N, rel=1e-9)
    v = MieVolume(10.0)
    assert np.allclose(info["sigma_t"], N * v.table["c_ext"] * 1e-12)
    # the same medium from number densities in 1/m³ and 1/cm³, and in a millimetre scene
    _, b = volume.homogeneous_medium(10.0, number_density=N, return_info=True)
    _, c = volume.homogeneous_medium(10.0, number_density_cm3=N * 1e-6, scene_unit=1e-3, return_info=True)
    assert np.allclose(b["sigma_t"], info["sigma_t"]) and np.allclose(c["sigma_t"], info["sigma_t"] * 1e-3)
    assert mi.load_dict(med) is not None


@pytest.mark.parametrize("kwargs, word", [
    (dict(lwc=-0.1), "lwc"),
    (dict(lwc=0.1, number_density=1e8), "exactly one"),
    (dict(), "exactly one"),
    (dict(number_density_cm3=1e15), "volume fraction"),
    (dict(lwc=0.1, scene_unit=0.0), "scene_unit"),
    (dict(lwc=0.1, ior=1.5), "lwc"),
])
def test_bad_medium_one_clear_error(kwargs, word):
    with pytest.raises(corona.CoronaError, match=word):
        volume.homogeneous_medium(5.0, **kwargs)


@pytest.mark.slow
@pytest.mark.render
def test_heterogeneous_medium_renders(mi_variant):
    z, y, x = np.mgrid[0:8, 0:8, 0:8] / 7.0
    dens = np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2) / 0.05)
    med, info = volume.heterogeneous_medium(5.0, dens, lwc=0.5, scene_unit=20.0,
                                            bbox=([-1, -1, 1], [1, 1, 3]), return_info=True)
    c = info["volume"].table["c_ext"]
    assert info["sigma_t_spread"] == pytest.approx(np.ptp(c) / np.interp(550.0, info["wavelength"][::-1], c[::-1]))
    scene = volume.slab_scene(None, size=16, spp=16)
    scene["cloud"] = {"type": "cube", "bsdf": {"type": "null"}, "interior": med,
                      "to_world": mi.ScalarTransform4f().translate([0, 0, 2])}
    img = np.array(mi.render(mi.load_dict(scene)))
    assert np.all(np.isfinite(img)) and img.mean() > 0
    with pytest.raises(corona.CoronaError, match="density"):
        volume.heterogeneous_medium(5.0, -dens, lwc=0.5)


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


def test_truncated_medium_helper(mi_variant):
    full = volume.homogeneous_medium(10.0, lwc=0.2, distribution="gamma", variance=0.01, return_info=True)[1]
    med, cut = volume.homogeneous_medium(10.0, lwc=0.2, distribution="gamma", variance=0.01, truncation=5.0,
                                         return_info=True)
    f = cut["truncated_fraction"]
    s_full = full["sigma_t"] * full["albedo"]
    assert np.allclose(cut["sigma_t"], full["sigma_t"] - f * s_full, rtol=1e-9)
    assert np.allclose(cut["sigma_t"] * cut["albedo"], (1 - f) * s_full, rtol=1e-9)
    assert med["phase"]["truncation"] == 5.0


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_spectral"], indirect=True)
@pytest.mark.parametrize("params, wavelengths", [
    ({"radius": 10.0, "distribution": "gamma", "variance": 0.01, "truncation": 5.0}, (450.0, 520.0, 600.0, 700.0)),
    ({"radius": 0.5, "ior": 1.59, "host_ior": 1.33}, (400.0, 480.0, 590.0, 720.0)),
])
def test_chi2_truncated_and_host(variant, params, wavelengths):
    ok, test = _chi2(params, (0.6, 0.0, 0.8), wavelengths)
    assert ok, test.messages


@pytest.mark.parametrize("variant", ["llvm_ad_spectral"], indirect=True)
def test_plugin_host_and_truncation_equal_the_table(variant):
    params = dict(radius=2.0, ior=1.59, host_ior=1.33, truncation=3.0)
    v = MieVolume(**params)
    ph = mi.load_dict({"type": "corona_mie", **params})
    lams = (433.3, 517.7, 604.9, 701.1)
    for t in (1e-3, 0.02, 0.06, 0.5, 2.0, 3.1):
        val, _ = ph.eval_pdf(mi.PhaseFunctionContext(), _mei(1, (0.0, 0.0, 1.0), lams),
                             mi.Vector3f(math.sin(t), 0.0, -math.cos(t)))
        ref = np.array([v.phase(math.cos(t), lam) for lam in lams]).ravel()
        assert np.allclose(np.array(val).ravel(), ref, rtol=2e-3, atol=1e-6), (t, np.array(val), ref)


# ----------------------------------------------------------------------
# renders
# ----------------------------------------------------------------------
def _medium(radius, tau, thickness, **kw):
    """A slab medium of optical depth ``tau`` at 550 nm (per scene unit)."""
    v = MieVolume(radius, **kw)
    N = tau / (v.cross_sections(550.0)["c_ext"] * thickness)     # per µm² per scene unit
    T = v.table
    st = N * T["c_ext"]
    med = {"type": "homogeneous", "sigma_t": volume._spectrum(T["wavelength"], st / st.max()),
           "scale": float(st.max()),
           "albedo": volume._spectrum(T["wavelength"], T["c_sca"] / T["c_ext"]),
           "phase": {"type": "corona_mie", "radius": radius, **kw}}
    return med, N


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"], indirect=True)
def test_white_furnace_closed_volume(variant):
    T = mi.ScalarTransform4f
    def scene(with_ball):
        s = {"type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1000},
             "sensor": {"type": "perspective", "fov": 30,
                        "to_world": T().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                        "sampler": {"type": "independent", "sample_count": 128}},
             "env": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}}
        if with_ball:
            s["ball"] = {"type": "sphere", "bsdf": {"type": "null"},
                         "interior": {"type": "homogeneous", "sigma_t": 4.0, "albedo": 1.0,
                                      "phase": {"type": "corona_mie", "radius": 5.0,
                                                "distribution": "gamma", "variance": 0.05}}}
        return mi.load_dict(s)
    base = np.array(mi.render(scene(False))).mean()
    img = np.array(mi.render(scene(True)))
    se = img.mean(-1).std() / math.sqrt(img.shape[0] * img.shape[1])
    assert abs(img.mean() - base) < 4 * se + 1e-3, (img.mean(), base, se)
    if variant == "llvm_ad_rgb":
        assert base == pytest.approx(1.0, abs=1e-6)


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("variant", ["llvm_ad_spectral"], indirect=True)
def test_thin_slab_equals_corona_layer(variant):
    """volpath through a slab of τ = 0.05 (single scattering) against the corona sphere layer of
    the same droplets (F_a = column density × π r²), ring by ring over 0.3°–12°.

    The slab's single-scattered radiance is the layer's times ``A(μo) / w``: ``A`` the
    attenuation of the beam in and of the scattered light out (``(e^{-τ} - e^{-τ/μo}) /
    (τ (1/μo - 1))``), ``w`` the layer's lobe weight (the energy cap of Poisson droplets)."""
    r, tau, h = 5.0, 0.05, 0.01
    med, N = _medium(r, tau, h)
    fa = N * h * math.pi * r * r
    fov, size = 24.0, 64
    a = np.array(mi.render(mi.load_dict(volume.slab_scene(med, thickness=h, fov=fov, size=size,
                                                             spp=512, max_depth=2)), seed=3))
    b = np.array(mi.render(mi.load_dict(volume.slab_scene(
        layer={"type": "corona", "shape": "sphere", "radius": r, "area_fraction": fa},
        fov=fov, size=size, spp=16, max_depth=2))))
    bins = np.radians(np.linspace(0.3, 12.0, 13))
    c, pa, n = volume.radial_profile(a.mean(-1), fov, bins)
    _, pb, _ = volume.radial_profile(b.mean(-1), fov, bins)
    # standard errors from the pixels' scatter around the layer's profile
    _, sq, _ = volume.radial_profile((a.mean(-1)) ** 2, fov, bins)
    se = np.sqrt(np.maximum(sq[:, 0] - pa[:, 0] ** 2, 0) / n)
    w = corona.Material(corona.Sphere(r), corona.Poisson(fa)).energies(1.0, 550.0)["weight"]
    mu_o = np.cos(c)
    A = (np.exp(-tau) - np.exp(-tau / mu_o)) / (tau * (1 / mu_o - 1))
    expected = pb[:, 0] * A / w
    z = (pa[:, 0] - expected) / se
    assert np.all(np.abs(z) < 4.0), (z, pa[:, 0] / expected)
    # pooled over the aureole (< 3°) and over the rings (3°–12°)
    for sel in (c < math.radians(3.0), c >= math.radians(3.0)):
        ratio = pa[sel, 0].sum() / expected[sel].sum()
        err = math.sqrt((se[sel] ** 2).sum()) / expected[sel].sum()
        assert abs(ratio - 1) < 3 * err + 0.01, (ratio, err)
    # negative control: droplets of 6 µm (rings 17 % narrower) are told apart
    b6 = np.array(mi.render(mi.load_dict(volume.slab_scene(
        layer={"type": "corona", "shape": "sphere", "radius": 6.0, "area_fraction": fa},
        fov=fov, size=size, spp=16, max_depth=2))))
    _, p6, _ = volume.radial_profile(b6.mean(-1), fov, bins)
    assert np.max(np.abs((pa[:, 0] - p6[:, 0] * A / w) / se)) > 6.0


def ring_contrast(image, fov, rows, theta, lo_deg=2.5, hi_deg=11.5):
    """Mean ``(I_max - I_min) / (I_max + I_min)`` of the green channel over the rings: the
    maxima and minima of the single-scattering phase function's green row (``rows``, at the
    angles ``theta``) between ``lo_deg`` and ``hi_deg``, each read in a ring 0.3° wide."""
    g = np.log(rows[1])
    sel = (theta > math.radians(lo_deg)) & (theta < math.radians(hi_deg))
    i = np.flatnonzero(sel)[1:-1]
    peaks = theta[i[(g[i] > g[i - 1]) & (g[i] > g[i + 1])]]
    dips = theta[i[(g[i] < g[i - 1]) & (g[i] < g[i + 1])]]
    half = math.radians(0.15)
    def level(angles):
        bins = np.sort(np.concatenate([angles - half, angles + half]))
        _, m, _ = volume.radial_profile(image[..., 1], fov, bins)
        return m[::2, 0]
    hi, lo = level(peaks).mean(), level(dips).mean()
    return float((hi - lo) / (hi + lo))


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("variant", ["llvm_ad_rgb"], indirect=True)
def test_ring_contrast_falls_with_optical_depth(variant):
    from corona.mitsuba.phase import channel_response
    r, h, fov = 5.0, 0.01, 24.0
    kw = dict(distribution="gamma", variance=0.01)
    rows = MieVolume(r, **kw).rgb_table(*channel_response())
    theta = MieVolume(r, **kw).table["theta"]
    contrast = []
    for tau in (0.05, 0.3, 1.0, 3.0):
        med, _ = _medium(r, tau, h, **kw)
        img = np.array(mi.render(mi.load_dict(volume.slab_scene(med, thickness=h, fov=fov, size=96,
                                                                   spp=128, max_depth=64)), seed=1))
        contrast.append(ring_contrast(img, fov, rows, theta))
    assert contrast[0] > 0.1
    assert all(a > b for a, b in zip(contrast, contrast[1:])), contrast


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("variant", ["llvm_ad_rgb"], indirect=True)
def test_truncation_removes_fireflies_of_a_cloud_deck(variant):
    """The glory's view from above a thick deck (τ = 10, 10 µm droplets, multiple scattering):
    with the forward peak truncated at 2.5° or at 10° the backscattered radiance agrees within
    its noise and the similarity bound (below 2 %), while the untruncated phase function's
    next-event estimates on the peak (~10³/sr) make the pixels' spread several times larger."""
    import sys
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "scripts"))
    from volume_pictures import glory_scene

    def render(truncation, spp):
        img = np.array(mi.render(mi.load_dict(glory_scene(truncation, res=24, spp=spp, variant=variant)),
                                 seed=5)).mean(-1)
        return img.mean(), img.std() / math.sqrt(img.size), img.std()

    a, sa, da = render(2.5, 128)
    b, sb, db = render(10.0, 128)
    assert abs(a - b) < 3 * math.hypot(sa, sb) + 0.02 * b, (a, b, sa, sb)
    c, sc, dc = render(0.0, 128)
    assert dc > 3 * db, (dc, db)
    assert np.isfinite(c) and c > 0


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


@pytest.mark.parametrize("params, word", [
    (dict(radius="abc"), "radius='abc' is not a number"),
    (dict(variance="x", distribution="lognormal"), "variance='x' is not a number"),
    (dict(ior_imag="k"), "ior_imag='k' is not a number"),
    (dict(radius=True), "radius=True is not a number"),
    (dict(distribution="modified_gamma", variance=0.1, gamma_exponent=1e5), "gamma_exponent"),
])
def test_corona_mie_bad_strings_name_the_parameter(mi_variant, params, word):
    with pytest.raises(Exception) as err:
        mi.load_dict({"type": "corona_mie", **params})
    assert word in corona._validation.one_line_error(err.value)


@pytest.mark.slow
@pytest.mark.render
def test_scene_unit_is_bounded(mi_variant):
    """scene_unit=1e300 gave an infinite σ_t (NaN renders); now one line.  Negative control:
    the range's ends give finite σ_t within float32 and a finite render."""
    for bad in (1e300, 1e10, 1e-10, float("inf")):
        with pytest.raises(corona.CoronaError, match="scene_unit"):
            volume.homogeneous_medium(5.0, lwc=0.1, scene_unit=bad)
    for unit in volume.SCENE_UNIT_RANGE:
        med, info = volume.homogeneous_medium(5.0, lwc=0.1, scene_unit=unit, return_info=True)
        assert np.all(np.isfinite(info["sigma_t"].astype(np.float32))) and np.isfinite(np.float32(med["scale"]))
        scene = volume.slab_scene(med, size=8, spp=4)
        assert np.all(np.isfinite(np.array(mi.render(mi.load_dict(scene)))))


@pytest.mark.parametrize("density, bbox, word", [
    (np.ones((4, 4, 4)) * (1 + 1j), None, "complex128"),
    (np.full((4, 4, 4), "a"), None, "<U1"),
    (np.array([[["a", 1.0]] * 2] * 2, dtype=object), None, "object"),
    (np.ones((4, 4, 4)), ([np.nan, 0, 0], [1, 1, 1]), "bbox"),
    (np.ones((4, 4, 4)), ([0, 0, 0], [1, np.inf, 1]), "bbox"),
    (np.ones((4, 4, 4)), ([0, 0, 0], [1, 0, 1]), "bbox"),
    (np.ones((4, 4, 4)), ([0, 0], [1, 1]), "bbox"),
    (np.ones((4, 4, 4)), "box", "bbox"),
])
def test_heterogeneous_medium_bad_grid_or_bbox(mi_variant, density, bbox, word):
    with pytest.raises(corona.CoronaError, match=word) as err:
        volume.heterogeneous_medium(5.0, density, lwc=0.1, bbox=bbox)
    assert "\n" not in str(err.value)
