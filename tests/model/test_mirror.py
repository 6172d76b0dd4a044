"""A layer on a mirror, and the coherent double pass through a pane (Quetelet rings).

Independent references: the exact bright-fringe condition 2 n t (cos r_s - cos r_o) = m λ
solved by root finding; Stokes' sums of the internal bounces; a brute-force wave simulation
(random screens, angular-spectrum propagation through the pane and back, far field:
corona.reference.quetelet); the CIE channel averages on a fine wavelength grid; Babinet's
principle and the diffuse energy F_a (1 - F_a) of a binary screen; mitsuba.chi2.
"""
import drjit as dr
import numpy as np
import pytest
from scipy.optimize import brentq

import corona
from corona.parameters import material_from_parameters
from corona.reference.quetelet import double_pass
from corona.model.substrate import GlassPane, Mirror, channel_average_cos, channel_envelopes, fresnel_dielectric

from bsdf_checks import assert_eval_matches, chi2_test, interaction

N = 1.52
LAYER = {"process": "hard-disk", "radius": 5.0, "area_fraction": 0.1, "mode": "particle"}
MIRROR = {**LAYER, "substrate": "mirror"}


def _wo(theta_deg, phi_deg=0.0):
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)), -1)


def _bright_fringes(t_um, theta_s, lam_nm, theta_max):
    """Angles θo [deg] of 2 n t (cos r_s - cos r_o) = m λ, m = 1, 2, ... up to theta_max, by brentq."""
    def delta(th):
        rs = np.arcsin(np.sin(np.radians(theta_s)) / N)
        ro = np.arcsin(np.sin(np.radians(th)) / N)
        return 2 * N * t_um * (np.cos(rs) - np.cos(ro))
    out, m = [], 1
    while delta(theta_max) > m * lam_nm * 1e-3:
        out.append(brentq(lambda th: delta(th) - m * lam_nm * 1e-3, theta_s, theta_max, xtol=1e-12))
        m += 1
    return np.array(out)


# --- the pane ------------------------------------------------------------------------------
def test_mirror_pane_sums_its_internal_bounces():
    pane = Mirror(N, 4000.0, 0.95)
    c = np.linspace(0.05, 1, 40)
    r = pane.face_reflectance(c)
    series = r + sum((1 - r) ** 2 * 0.95 * (0.95 * r) ** k for k in range(4000))
    np.testing.assert_allclose(pane.reflectance(c), series, rtol=1e-12)
    np.testing.assert_allclose(pane.round_trips(c, 550.0, 4000).sum(0), series, rtol=1e-12)
    assert np.all(pane.transmittance(c) == 0) and np.all(pane.reflectance(-c) == 0)   # black behind
    glass = GlassPane(N, thickness=3000.0)
    np.testing.assert_allclose(glass.round_trips(c, 550.0, 4000).sum(0), glass.reflectance(c), rtol=1e-12)


def test_interference_closed_form_is_the_sum_over_round_trips():
    for pane in (Mirror(N, 2500.0, 0.9), GlassPane(N, thickness=2500.0)):
        cs, co = 0.97, np.linspace(0.9, 1.0, 200)
        ks = pane.round_trips(cs, 600.0, 60)[1:, None]
        ko = pane.round_trips(co, 600.0, 60)[1:]
        k = np.arange(1, 60)[:, None]
        phase = 2 * np.pi * k * pane.path_difference(cs, co) / 0.6
        np.testing.assert_allclose(pane.interference(cs, co, 600.0), np.sum(np.sqrt(ks * ko) * np.cos(phase), 0),
                                   rtol=1e-10, atol=1e-14)


def test_parameters_build_the_mirror():
    m = material_from_parameters(**MIRROR)
    assert isinstance(m.substrate, Mirror)
    assert m.substrate.thickness == 4000.0 and m.substrate.ior == N and m.substrate.silver(550.0) == 0.97
    g = material_from_parameters(**LAYER, substrate="glass", substrate_thickness=3000.0)
    assert g.substrate.thickness == 3000.0 and not isinstance(g.substrate, Mirror)
    assert material_from_parameters(**LAYER, substrate="glass").substrate.thickness is None


@pytest.mark.parametrize("params,word", [
    ({"substrate": "mirror", "substrate_thickness": 10.0}, "substrate_thickness"),
    ({"substrate": "mirror", "mirror_reflectance": 1.2}, "mirror_reflectance"),
    ({"substrate": "glass", "mirror_reflectance": 0.9}, "mirror_reflectance"),
    ({"substrate_thickness": 4000.0}, "substrate_thickness"),            # needs a pane
    ({"substrate": "mirror", "shape": "sphere", "radius": 5.0}, "substrate"),
])
def test_bad_mirror_parameters(mi_variant, params, word):
    import mitsuba as mi
    with pytest.raises(corona.CoronaError, match=word):
        material_from_parameters(**params)
    with pytest.raises(Exception, match=word):
        mi.load_dict({"type": "corona", **params})


def test_mirror_spectrum_reflectance():
    pane = Mirror(N, 4000.0, ([400.0, 700.0], [0.9, 0.96]))
    assert pane.silver(550.0) == pytest.approx(0.93)
    with pytest.raises(corona.CoronaError, match="mirror_reflectance"):
        Mirror(N, 4000.0, ([400.0, 700.0], [0.9, 1.5]))


@pytest.mark.parametrize("spectrum", [
    "-5:0.9, 700:0.95", "400:0.9, 99999:0.95", "359.9:0.9, 700:0.95", "400:0.9, 830.1:0.95",
    "nan:0.9, 700:0.95", "400:0.9, inf:0.95", ([-5.0, 700.0], [0.9, 0.95]), ([400.0, 1e5], [0.9, 0.95]),
])
def test_mirror_spectrum_wavelengths_in_mitsubas_range(mi_variant, spectrum):
    """Issue 47 item 18: wavelengths of -5 and 99999 nm were taken; now one line naming the
    wavelength and Mitsuba's spectral range [360, 830] nm, in numpy and in the plugin."""
    import mitsuba as mi
    params = {**MIRROR, "mirror_reflectance": spectrum}
    with pytest.raises(corona.CoronaError, match=r"mirror_reflectance.*out of range; allowed \[360, 830\] nm"):
        material_from_parameters(**params)
    if isinstance(spectrum, str):
        with pytest.raises(Exception, match=r"allowed \[360, 830\] nm"):
            mi.load_dict({"type": "corona", **params})


def test_mirror_spectrum_range_ends_are_accepted(mi_variant):
    """Negative control: a spectrum spanning exactly [360, 830] nm loads and is read at its nodes."""
    import mitsuba as mi
    m = material_from_parameters(**MIRROR, mirror_reflectance="360:0.8, 600:0.9, 830:0.95")
    assert m.substrate.silver(360.0) == 0.8 and m.substrate.silver(830.0) == 0.95
    assert mi.load_dict({"type": "corona", **MIRROR, "mirror_reflectance": "360:0.8, 830:0.95"}) is not None


# --- fringes ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mirror_materials():
    return {t: material_from_parameters(**MIRROR, substrate_thickness=t) for t in (2000.0, 4000.0, 6000.0)}


@pytest.mark.parametrize("t", [2000.0, 4000.0, 6000.0])
@pytest.mark.parametrize("theta_s", [0.0, 10.0, 20.0])
def test_fringe_maxima_follow_the_exact_condition(mirror_materials, t, theta_s):
    """Maxima of eval (over the smooth incoherent reflection of the same layer) sit where
    2 n t (cos r_s - cos r_o) = m λ, within 1 % of the local fringe spacing."""
    m = mirror_materials[t]
    lam = 550.0
    span = 3.0 if theta_s == 0 else 1.5
    exact = _bright_fringes(t, theta_s, lam, theta_s + span)
    assert len(exact) >= 3
    lo = theta_s + 0.5 * (exact[0] - theta_s) if theta_s == 0 else theta_s + 0.3 * (exact[0] - theta_s)
    th = np.linspace(lo, exact[-1] + 0.5 * (exact[-1] - exact[-2]), 100_001)
    wi = _wo(theta_s, 180.0)              # the light's image is at θo = θs, φ = 0
    wo = _wo(th)
    smooth = material_from_parameters(**LAYER, substrate="glass").eval(wi, wo, lam)
    ratio = m.eval(wi, wo, lam) / smooth
    i = np.flatnonzero((ratio[1:-1] > ratio[:-2]) & (ratio[1:-1] >= ratio[2:])) + 1
    # parabolic refinement
    a, b, c = ratio[i - 1], ratio[i], ratio[i + 1]
    found = th[i] + 0.5 * (a - c) / (a - 2 * b + c) * (th[1] - th[0])
    spacing = np.gradient(exact) if len(exact) > 1 else np.array([exact[0] - theta_s])
    assert len(found) == len(exact)
    assert np.max(np.abs(found - exact) / spacing) < 0.01, (found, exact)


def test_first_ring_on_the_normal():
    """Light on the normal, 550 nm: the first bright ring at 1.17°, 0.83°, 0.68° for t = 2, 4, 6 mm."""
    for t, deg in ((2000.0, 1.17), (4000.0, 0.83), (6000.0, 0.68)):
        pane = Mirror(N, t)
        th = np.linspace(0.3, 1.5, 120_001)
        q = pane.interference(1.0, np.cos(np.radians(th)), 550.0)
        first = np.flatnonzero((q[1:-1] > q[:-2]) & (q[1:-1] >= q[2:]))[0] + 1
        assert th[first] == pytest.approx(deg, abs=0.005)


def test_rings_centred_on_the_normal_and_the_zero_order_through_the_image(mirror_materials):
    """The modulation depends on wo only through θo (rings about the normal), and its zero
    order (Δ = 0, the brightest) is the ring θo = θs through the light's image."""
    m = mirror_materials[4000.0]
    smooth = material_from_parameters(**LAYER, substrate="glass")
    theta_s = 10.0
    wi = _wo(theta_s, 180.0)
    phis = np.linspace(0, 360, 13)
    for th in (9.7, 10.0, 10.4):
        wo = _wo(th, phis)
        r = m.eval(wi, wo, 550.0) / smooth.eval(wi, wo, 550.0)
        np.testing.assert_allclose(r, r[0], rtol=1e-9)
    # within the zero-order fringe (±0.01°, its width 0.035°) the maximum is at θo = θs, and its
    # height that of Δ = 0, in every azimuth
    pane = m.substrate
    cs = np.cos(np.radians(theta_s))
    rf = float(fresnel_dielectric(cs, N))
    peak = rf + m.coherent_transmittance * 2 * (pane.reflectance(cs) - rf + pane.interference(cs, cs, 550.0))
    th = np.linspace(theta_s - 0.01, theta_s + 0.01, 2001)
    for phi in (0.0, 90.0, 200.0):
        wo = _wo(th, phi)
        r = m.eval(wi, wo, 550.0) / (m.lobe(wi[:2] + wo[..., :2], 550.0) * wo[:, 2])
        assert th[np.argmax(r)] == pytest.approx(theta_s, abs=2e-5)
        assert r.max() == pytest.approx(peak, rel=1e-6)


def test_glass_without_thickness_is_the_incoherent_sum():
    plain = material_from_parameters(**LAYER, substrate="glass")
    thick = material_from_parameters(**LAYER, substrate="glass", substrate_thickness=4000.0)
    wi, wo = _wo(5.0, 180.0), _wo(np.linspace(0.1, 30, 3000))
    c = plain.coherent_transmittance
    f = plain.lobe(wi[:2] + wo[..., :2], 500.0)
    # the front face once (the smaller R of the two angles), the round trips P = T²R/(1 - R²) of
    # each path through the layer's coherent C (Stokes: R' = R + P = 2R / (1 + R))
    r_i, r_o = fresnel_dielectric(wi[2], N), fresnel_dielectric(wo[:, 2], N)
    p_i, p_o = (1 - r_i) ** 2 * r_i / (1 - r_i**2), (1 - r_o) ** 2 * r_o / (1 - r_o**2)
    expected = f * (np.minimum(r_i, r_o) + c * (p_i + p_o)) * wo[:, 2]
    np.testing.assert_allclose(plain.eval(wi, wo, 500.0), expected, rtol=1e-12)
    old = c * f * (2 * r_i / (1 + r_i) + 2 * r_o / (1 + r_o)) * wo[:, 2]      # the front face twice
    assert np.min(old / plain.eval(wi, wo, 500.0)) > 1.2
    ratio = thick.eval(wi, wo, 500.0) / plain.eval(wi, wo, 500.0)
    # bare glass: the round trips C T²R ≈ 0.030 on each path against R ≈ 0.043 once: faint rings
    assert 1.0 + 0.5 < ratio.max() < 1.0 + 0.7 and 1.0 - 0.7 < ratio.min() < 1.0 - 0.5
    # transmission is untouched
    wt = wo * np.array([1, 1, -1])
    np.testing.assert_allclose(thick.eval(wi, wt, 500.0), plain.eval(wi, wt, 500.0), rtol=1e-12)


@pytest.mark.parametrize("params", [MIRROR, {**LAYER, "substrate": "glass", "substrate_side": "back",
                                              "substrate_thickness": 2000.0, "albedo": 0.5},
                                    {**MIRROR, "shape": "square", "radius": 3.0}])
def test_reciprocal(params):
    """f_s(wi, wo) = f_s(wo, wi): Δ changes sign, cos(2πkΔ/λ) does not."""
    m = material_from_parameters(**params)
    rng = np.random.default_rng(4)
    wi = _wo(rng.uniform(0, 30, 2000), rng.uniform(0, 360, 2000))
    wo = _wo(rng.uniform(0, 30, 2000), rng.uniform(0, 360, 2000))
    side = -1.0 if params.get("substrate_side") == "back" else 1.0
    wi, wo = wi * np.array([1, 1, side]), wo * np.array([1, 1, side])
    a = m.eval(wi, wo, 530.0) / np.abs(wo[:, 2])
    b = m.eval(wo, wi, 530.0) / np.abs(wi[:, 2])
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)
    assert a.max() > 0


# --- the brute-force wave reference -------------------------------------------------------
@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("theta_s,back,t", [(0.0, 0.97, 4000.0), (10.0, 0.97, 2000.0), (0.0, "glass", 4000.0)])
def test_wave_reference(theta_s, back, t):
    """Double-pass intensity over C times the single pass of the same screens, per direction,
    against the model's factor of the round trips; the incoherent sum and a 3 % thicker pane
    are rejected (negative controls)."""
    area_fraction = 0.03
    ref = double_pass(theta_s_deg=theta_s, thickness=t, back=back, radius=0.5, area_fraction=area_fraction,
                      n_screens=96, n_samples=2**15, length=4000.0, seed=3)
    near = np.abs(ref["sin_o"] - ref["sin_s"]) < 0.03
    so, ratio, sigma = ref["sin_o"][near], ref["ratio"][near], ref["sigma"][near]

    def model(pane):
        cs, co = np.sqrt(1 - ref["sin_s"] ** 2), np.sqrt(1 - so ** 2)
        inc = pane.round_trips(cs, 550.0, 80)[1:].sum(0) + pane.round_trips(co, 550.0, 80)[1:].sum(0)
        return inc, inc + 2 * pane.interference(cs, co, 550.0)

    def pane_of(thick):
        return GlassPane(N, thickness=thick) if back == "glass" else Mirror(N, thick, back)
    inc, coh = model(pane_of(t))
    # the model drops scattering twice: at most ~ D/C ≈ F_a of the incoherent part
    tol = 4 * sigma + area_fraction * inc
    assert np.mean(np.abs(ratio - coh) <= tol) > 0.97, np.max(np.abs(ratio - coh) / tol)
    assert np.mean((ratio - coh) / inc) == pytest.approx(0.0, abs=0.01)
    assert np.mean(np.abs(ratio - inc) <= tol) < 0.3                        # negative control: no fringes
    _, wrong = model(pane_of(1.03 * t))
    assert np.mean(np.abs(ratio - wrong) <= tol) < 0.7                      # negative control: thickness


def test_wave_reference_2d_rings():
    """2-D screens of discs on a 1 mm mirror, lit on the normal: the ring profile of the
    double-pass diffuse intensity over C times the single pass of the same screens, against the
    model's round trips averaged over each ring as measured; the incoherent sum and a 3 %
    thicker pane are rejected (negative controls)."""
    from corona.reference.quetelet import double_pass_2d
    t, area_fraction = 1000.0, 0.03
    ref = double_pass_2d(thickness=t, back=0.97, radius=1.5, area_fraction=area_fraction, n_screens=3,
                         n_samples=1024, length=512.0, n_rings=60, orders=2, seed=2)
    inside = ref["ring_of"] >= 0
    idx, w = ref["ring_of"][inside], ref["single_grid"][inside]
    co = np.sqrt(1 - ref["sin_grid"][inside] ** 2)
    n = len(ref["ratio"])

    def model(pane):
        inc = pane.round_trips(1.0, 550.0, 80)[1:].sum(0) + pane.round_trips(co, 550.0, 80)[1:].sum(0)
        coh = inc + 2 * pane.interference(1.0, co, 550.0)
        tot = np.bincount(idx, w, n)
        return np.bincount(idx, w * inc, n) / tot, np.bincount(idx, w * coh, n) / tot

    inc, coh = model(Mirror(N, t, 0.97))
    ratio, sigma = ref["ratio"], ref["sigma"]
    assert ref["sin_o"][-1] > 0.06 and np.ptp(coh) > 3.0            # ten rings, deep fringes
    tol = 4 * sigma + area_fraction * inc
    assert np.mean(np.abs(ratio - coh) <= tol) > 0.97, np.max(np.abs(ratio - coh) / tol)
    assert np.mean((ratio - coh) / inc) == pytest.approx(0.0, abs=0.01)
    assert np.sqrt(np.mean(((ratio - coh) / inc) ** 2)) < 0.03
    assert np.mean(np.abs(ratio - inc) <= tol) < 0.3                        # negative control: no fringes
    _, wrong = model(Mirror(N, 1.03 * t, 0.97))
    assert np.mean(np.abs(ratio - wrong) <= tol) < 0.7                      # negative control: thickness


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("area_fraction", [0.03, 0.2])
def test_wave_reference_front_face_once(area_fraction):
    """A screen on the front face, no back reflection: the face's reflection crosses the screen
    once.  Diffuse: R_min f over C f (old convention: R_i + R_o, the face counted on both
    passes); the mirror image: C R (old: C² R)."""
    ref = double_pass(theta_s_deg=0.0, thickness=4000.0, back=0.0, radius=2.0, area_fraction=area_fraction,
                      n_screens=16, n_samples=2**15, length=4000.0, front_reflection=True, seed=3)
    near = np.abs(ref["sin_o"]) < 0.03
    c, ratio = ref["coherent"], ref["ratio"][near]
    r0, ro = fresnel_dielectric(1.0, N), fresnel_dielectric(np.sqrt(1 - ref["sin_o"][near] ** 2), N)
    new, old = np.minimum(r0, ro) / c, r0 + ro
    # the 1-D screen's edges add ~ +2 % at R = 2 µm (scaling as 1/R: docs/physics.md#the-front-face)
    assert np.max(np.abs(ratio / new - 1)) < 0.04
    assert np.min(np.abs(ratio / old - 1)) > 0.15                           # negative control
    pane = GlassPane(N, thickness=4000.0)
    assert ref["specular"] == pytest.approx(float(pane.specular_through_layer(1.0, 550.0, c)
                                                  - c * c * pane.inner_reflectance(1.0)), rel=0.01)
    assert abs(ref["specular"] / (c * c * r0) - 1) > 0.05                    # negative control


@pytest.mark.slow
@pytest.mark.reference
def test_wave_reference_bare_glass_with_its_front_face():
    """Bare glass with a thickness, every path: front face once plus the round trips (within the
    noise of the front face's interference with the round trips, averaged over the band); the
    old convention (the front face on both passes through C) is 25 % off."""
    ref = double_pass(theta_s_deg=0.0, thickness=4000.0, back="glass", radius=2.0, area_fraction=0.03,
                      n_screens=32, n_samples=2**15, length=4000.0, front_reflection=True, seed=3)
    near = np.abs(ref["sin_o"]) < 0.03
    so, ratio, c = ref["sin_o"][near], ref["ratio"][near], ref["coherent"]
    pane = GlassPane(N, thickness=4000.0)
    co = np.sqrt(1 - so**2)
    new = pane.reflected_lobe_factor(1.0, co, 550.0, c) / c
    old = pane.reflectance(1.0) + pane.reflectance(co) + 2 * pane.interference(1.0, co, 550.0)
    assert np.mean(ratio / new - 1) == pytest.approx(0.0, abs=0.03)
    assert np.mean(ratio / old - 1) < -0.15                                  # negative control
    spec = pane.specular_through_layer(1.0, 550.0, c)
    assert ref["specular"] == pytest.approx(float(spec), rel=0.03)


@pytest.mark.slow
@pytest.mark.reference
def test_babinet_and_binary_screen_per_pass():
    """Per pass the screen scatters F_a (1 - F_a) (binary screen, wave reference), and the
    aperture and particle layers of the same F_a share one lobe (Babinet): the reflected lobe
    over C is the same."""
    ref = double_pass(theta_s_deg=0.0, radius=5.0, area_fraction=0.2, n_screens=16, seed=1)
    fa = 1 - np.sqrt(ref["coherent"])
    assert ref["single"].sum() == pytest.approx(fa * (1 - fa), rel=0.02)
    wi, wo = _wo(3.0, 180.0), _wo(np.linspace(0.1, 8, 500), 30.0)
    par = material_from_parameters(**{**MIRROR, "area_fraction": 0.3})
    ape = material_from_parameters(**{**MIRROR, "mode": "aperture", "area_fraction": 0.3})
    d_xy = wi[:2] + wo[..., :2]
    np.testing.assert_allclose(par.lobe(d_xy, 550.0), ape.lobe(d_xy, 550.0), rtol=1e-10)
    # each mode's reflected lobe is that one lobe times the pane's factor with its own C
    for m in (par, ape):
        factor = m.substrate.reflected_lobe_factor(wi[2], wo[:, 2], 550.0, m.coherent_transmittance)
        np.testing.assert_allclose(m.eval(wi, wo, 550.0), m.lobe(d_xy, 550.0) * factor * wo[:, 2], rtol=1e-10)
    # the reflected lobe's energy: the front face once (R D), the round trips on both passes
    # (each C D P), plus the interference
    e = par.directional_albedo(1.0, 550.0)
    c, r = par.coherent_transmittance, float(par.substrate.reflectance(1.0))
    rf = float(fresnel_dielectric(1.0, N))
    d = 0.3 * 0.7
    assert e["lobe_reflection"] == pytest.approx(d * (rf + 2 * c * (r - rf)), rel=0.05)


# --- energy ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("params", [
    MIRROR,
    {**MIRROR, "process": "poisson", "mode": "aperture", "area_fraction": 0.8, "albedo": 1.0},   # the cap
    {**MIRROR, "process": "poisson", "radius": 0.5, "area_fraction": 0.2, "substrate_thickness": 2000.0},
    {**LAYER, "substrate": "glass", "substrate_thickness": 3000.0, "albedo": 0.5},
])
@pytest.mark.parametrize("cos_i", [1.0, 0.5, 0.15])
def test_white_furnace(params, cos_i):
    m = material_from_parameters(**params)
    e = m.directional_albedo(cos_i, 550.0)
    assert e["total"] <= 1.0 + 1e-9
    # the bound behind it (docs/physics.md): both ends of the excess in P_s within the slack
    d = m.lobe_weight * m.plane_integral / (4 * np.pi**2)
    c, rho, v = m.coherent_transmittance, m.reflectance, m.double_pass_visibility
    first = (rho + c * c + 2 * c * d * (1 + v) <= 1.0 + 1e-12 and c * d * v <= 1.0 - rho - c - c * d + 1e-12
             and c * d * (1 + v) <= 1.0 - rho - c * c - d + 1e-12)
    second = c * d + d * c * c * v * v / (1 - c) - c * (1 - c) <= 1.0 - rho - c - d + 1e-12
    assert first or second
    if isinstance(m.substrate, Mirror):
        assert e["coherent"] == 0 and e["lobe_transmission"] == 0


def test_visibility_cap_only_where_needed():
    assert material_from_parameters(**MIRROR).double_pass_visibility == 1.0
    # a layer that returns all the light itself (C + D = 1, nothing absorbed): no room for fringes
    capped = material_from_parameters(**{**MIRROR, "process": "poisson", "mode": "aperture",
                                         "area_fraction": 0.8, "albedo": 1.0})
    assert capped.double_pass_visibility == 0.0
    partly = material_from_parameters(**{**MIRROR, "process": "poisson", "mode": "aperture",
                                         "area_fraction": 0.6, "albedo": 1.0})
    assert 0.0 < partly.double_pass_visibility < 1.0


# --- the plugin -------------------------------------------------------------------------------------
def test_plugin_matches_reference_spectral(mi_variant):
    import mitsuba as mi
    if not mi.is_spectral:
        pytest.skip("spectral check")
    lams = (450.0, 520.0, 600.0, 700.0)
    for params, theta_s in ((MIRROR, 0.0), ({**MIRROR, "substrate_thickness": 2000.0}, 15.0),
                            ({**LAYER, "substrate": "glass", "substrate_thickness": 5000.0}, 5.0)):
        bsdf = mi.load_dict({"type": "corona", **params})
        m = material_from_parameters(**params)
        wi = _wo(theta_s, 180.0)
        wo = _wo(np.linspace(theta_s + 0.02, theta_s + 4, 400), 20.0)
        assert_eval_matches(bsdf, m.eval, wi, wo, lams, rtol=0.0, atol=2e-3)
        # behind the mirror: black
        if params["substrate"] == "mirror":
            si = interaction(4, -wi, lams)
            bs, w = bsdf.sample(mi.BSDFContext(), si, mi.Float([0.1, 0.4, 0.6, 0.9]), mi.Point2f(0.3, 0.6))
            assert np.all(np.array(w) == 0)


@pytest.mark.slow
def test_rgb_channels_average_the_fringes():
    """RGB: each channel's modulation (the mirror's reflected lobe over that of the same layer on
    plain glass, both as the plugin renders them) is the modulation averaged over the channel's
    response (reference: numpy eval on a 0.5 nm grid weighted by the CIE → sRGB response); the
    fringes wash out after a few orders instead of aliasing between sample wavelengths.  In this
    process, in scalar_rgb (the variant is put back after)."""
    import mitsuba as mi
    previous = mi.variant()
    mi.set_variant("scalar_rgb")
    corona.register()
    try:
        from corona.color import XYZ_TO_SRGB, cie1931_xyz
        from corona.mitsuba.common import channel_response as _channel_response
        P = dict(process="hard-disk", radius=5.0, area_fraction=0.1, mode="particle")
        layers = [dict(P, substrate="mirror", substrate_thickness=4000.0), dict(P, substrate="glass")]
        bsdfs = [mi.load_dict({"type": "corona", **p}) for p in layers]
        mats = [material_from_parameters(**p) for p in layers]
        lq, _ = _channel_response()
        lam = np.arange(360.0, 830.5, 0.5)
        resp = np.maximum(XYZ_TO_SRGB @ cie1931_xyz(lam).T, 0)
        wi = np.array([0.0, 0.0, 1.0]); out = []
        for th in np.linspace(0.2, 6.0, 59):
            wo = np.array([np.sin(np.radians(th)), 0, np.cos(np.radians(th))])
            si = mi.SurfaceInteraction3f(); si.wi = mi.Vector3f(*wi)
            row = [th]
            for b, m in zip(bsdfs, mats):
                row += list(np.array(b.eval(mi.BSDFContext(), si, mi.Vector3f(*wo))))
                v = m.eval(wi[None], wo[None], lam)
                row += list(np.trapezoid(resp * v, lam, axis=1) / np.trapezoid(resp, lam, axis=1))
                row += list(m.eval(wi[None], wo[None], lq.ravel()).reshape(lq.shape).mean(1))   # 8 a channel
            out.append([float(x) for x in row])
    finally:
        if previous:
            mi.set_variant(previous)
    rows = np.array(out)
    mirror, glass = rows[:, 1:10], rows[:, 10:19]
    ratio = mirror / glass                      # per channel: plugin, fine grid, 8 wavelengths
    plugin, ref, naive = ratio[:, 0:3], ratio[:, 3:6], ratio[:, 6:9]
    # the 8-point channel quadrature of the lobe itself errs by a few per cent where the lobe
    # changes fast with λ (Airy zeros, the red channel's two lobes): compare relative to the
    # channel's brightest value, and the rms of the relative error
    err = np.abs(plugin - ref) / ref
    assert np.max(np.abs(plugin - ref) * glass[:, 3:6] / mirror[:, 3:6].max(0)) < 0.01
    assert np.sqrt(np.mean(err**2)) < 0.025
    # the rings wash out: beyond 4° the modulation of every channel is within 10 % of its mean
    far = rows[:, 0] > 4.0
    assert np.max(np.abs(ref[far] / ref[far].mean(0) - 1)) < 0.1
    assert np.max(np.abs(plugin[far] / plugin[far].mean(0) - 1)) < 0.1
    # negative control: 8 wavelengths a channel without the bin average alias the fringes
    assert np.max(np.abs(naive - ref) / ref) > 0.2


@pytest.mark.slow
@pytest.mark.chi2
# 25° merged into 60°: the same path through sample/pdf (no branch on the angle of wi)
@pytest.mark.parametrize("theta", [0, 60])
def test_chi2_reflected_lobe(mi_variant, theta):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyReflection
    ok, test = chi2_test({**MIRROR, "radius": 0.5, "area_fraction": 0.2, "substrate_thickness": 300.0},
                         theta, ctx, sample_count=400_000)
    assert ok, test.messages


def test_sample_weight_is_eval_over_pdf_and_furnace(mi_variant):
    import mitsuba as mi
    params = {**MIRROR, "radius": 2.0, "area_fraction": 0.2}
    bsdf = mi.load_dict({"type": "corona", **params})
    m = material_from_parameters(**params)
    n = 200_000
    rng = np.random.default_rng(5)
    for cos_i in (1.0, 0.6):
        lam = 550.0
        si = interaction(n, (np.sqrt(1 - cos_i**2), 0.0, cos_i), (lam,) * 4)
        bs, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
        w = np.array(w)[0]
        comp = np.array(bs.sampled_component)
        assert set(np.unique(comp[w > 0])) <= {3, 4}
        expected = m.directional_albedo(cos_i, lam)
        assert w.mean() == pytest.approx(expected["total"], abs=4 * w.std() / np.sqrt(n) + 2e-3)
        assert w.mean() <= 1.0
        e, p = bsdf.eval_pdf(mi.BSDFContext(), si, bs.wo)
        ok = (comp == 4) & (np.array(p) > 0)
        np.testing.assert_allclose(w[ok], np.array(e)[0][ok] / np.array(p)[ok], rtol=1e-4)


@pytest.mark.slow     # the scalar variant, lane by lane: 1.3 s of CPU warm
def test_vectorised_rgb_fringes_equal_the_scalar_variant(mi_variant):
    """The vectorised RGB plugin (its response wavelengths a symbolic Dr.Jit loop) gives the
    mirror's eval, pdf and sampled weights of the scalar variant (one Python loop over them,
    checked against the fine-grid channel averages in test_rgb_channels_average_the_fringes),
    and of itself where a derivative flows (the loop unrolled then)."""
    variant = "llvm_ad_rgb"
    import mitsuba as mi
    params = {**MIRROR, "radius": 3.0, "area_fraction": 0.2, "substrate_thickness": 1000.0,
              "mirror_reflectance": "gold", "albedo": 0.3}
    theta = np.linspace(0.3, 12.0, 24)
    wi = (np.sin(np.radians(10.0)), 0.0, np.cos(np.radians(10.0)))
    wo = _wo(theta, 30.0)
    rng = np.random.default_rng(3)
    s1, s2 = rng.random(theta.size), rng.random((theta.size, 2))
    out = {}
    try:
        for v in (variant, variant.replace("llvm_ad", "scalar")):
            mi.set_variant(v)
            corona.register()
            bsdf = mi.load_dict({"type": "corona", **params})
            ctx = mi.BSDFContext()
            if v.startswith("llvm"):
                si = interaction(theta.size, wi)
                wo_v = mi.Vector3f(*[mi.Float(c) for c in wo.T])
                e, p = bsdf.eval_pdf(ctx, si, wo_v)
                bs, w = bsdf.sample(ctx, si, mi.Float(s1), mi.Point2f(*[mi.Float(c) for c in s2.T]))
                out[v] = [np.array(e).T, np.array(p), np.array(w).T, np.array(bs.pdf)]
                dr.enable_grad(wo_v)
                e, p = bsdf.eval_pdf(ctx, si, wo_v)
                unrolled = [np.array(dr.detach(e)).T, np.array(dr.detach(p))]
            else:
                rows = []
                for k in range(theta.size):
                    si = mi.SurfaceInteraction3f()
                    si.wi = mi.Vector3f(*wi)
                    e, p = bsdf.eval_pdf(ctx, si, mi.Vector3f(*wo[k]))
                    bs, w = bsdf.sample(ctx, si, float(s1[k]), mi.Point2f(*s2[k]))
                    rows.append([np.array(e).ravel(), float(p), np.array(w).ravel(), float(bs.pdf)])
                out[v] = [np.array([r[i] for r in rows]) for i in range(4)]
    finally:
        mi.set_variant(mi_variant)
    vec, ref = out.values()
    for a, b in zip(unrolled, vec[:2]):
        np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6 * np.max(np.abs(b)))
    for a, b in zip(vec, ref):
        assert np.max(np.abs(b)) > 0
        np.testing.assert_allclose(a.reshape(b.shape), b, rtol=2e-5, atol=2e-6 * np.max(np.abs(b)))


# --- the silvering's spectrum ---------------------------------------------------------------------
def test_named_silvering_is_the_metal_behind_glass():
    """'silver' is |(n - N)/(n + N)|² from the metal's tabulated index behind the glass; its blue
    end is darker (the plasma edge), aluminium is flatter; a wrong name is one clear error."""
    ag = Mirror(N, 4000.0, "silver")
    assert ag.spectral and ag.silver(550.0) == pytest.approx(0.945, abs=0.01)
    assert ag.silver(400.0) < ag.silver(550.0) - 0.05
    al = Mirror(N, 4000.0, "aluminium")
    assert np.ptp(al.silver(np.linspace(420, 700, 8))) < 0.06
    # the index matters: behind air (n = 1) silver reflects more
    assert Mirror(1.0001, 4000.0, "silver").silver(550.0) > ag.silver(550.0)
    text = Mirror(N, 4000.0, "400:0.85, 700:0.97")
    assert text.silver(550.0) == pytest.approx(0.91)
    with pytest.raises(corona.CoronaError, match="mirror_reflectance"):
        material_from_parameters(**MIRROR, mirror_reflectance="tin")


@pytest.mark.parametrize("reflectance", ["silver", "400:0.85, 700:0.97", "object"])
def test_plugin_silvering_spectrum_per_wavelength(mi_variant, reflectance):
    """Spectral plugin against numpy at each lane's wavelength: the reflected lobe with its fringes
    and the mirror image's weight (a constant R_m at 550 nm would be off by the spectrum's slope)."""
    import mitsuba as mi
    if not mi.is_spectral:
        pytest.skip("spectral check")
    lams = (420.0, 500.0, 600.0, 690.0)
    prop = ({"type": "spectrum", "value": [(400.0, 0.85), (700.0, 0.97)]} if reflectance == "object"
            else reflectance)
    bsdf = mi.load_dict({"type": "corona", **MIRROR, "mirror_reflectance": prop})
    m = material_from_parameters(**MIRROR, mirror_reflectance="400:0.85, 700:0.97" if reflectance == "object"
                                 else reflectance)
    wi = _wo(5.0, 180.0)
    wo = _wo(np.linspace(5.02, 9.0, 400), 20.0)
    si = interaction(len(wo), wi, lams)
    e = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T.astype(np.float32))))
    const = material_from_parameters(**MIRROR, mirror_reflectance=float(m.substrate.silver(550.0)))
    for k, lam in enumerate(lams):
        ref = m.eval(wi, wo, lam)
        assert np.max(np.abs(e[k] - ref)) < 2e-3 * ref.max()
        if abs(lam - 550.0) > 100:                                  # negative control: R_m at 550 nm
            assert np.max(np.abs(const.eval(wi, wo, lam) - ref)) > 1e-2 * ref.max()
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.DeltaReflection
    _, w = bsdf.sample(ctx, interaction(1, wi, lams), 0.5, mi.Point2f(0.5, 0.5))
    np.testing.assert_allclose(np.array(w).ravel(), [m.specular_reflection(wi[2], lam) for lam in lams], rtol=1e-4)


@pytest.mark.slow
def test_rgb_silvering_spectrum(mi_variant):
    """RGB variants take a metal's name, 'nm:value' text or a <spectrum> of wavelength:value pairs
    (each response wavelength gets its R_m); a texture object, already a colour there, is refused
    by name.  In this process, in scalar_rgb (the variant is put back after)."""
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    corona.register()
    try:
        P = dict(process="hard-disk", radius=5.0, area_fraction=0.1, mode="particle", substrate="mirror")
        si = mi.SurfaceInteraction3f(); si.wi = mi.Vector3f(0, 0, 1)
        ctx = mi.BSDFContext(); ctx.type_mask = mi.BSDFFlags.DeltaReflection
        weights = []
        sp = {"type": "spectrum", "value": [(400.0, 0.85), (700.0, 0.97)]}
        for r in ("silver", 0.97, sp):
            _, w = mi.load_dict({"type": "corona", **P, "mirror_reflectance": r}).sample(
                ctx, si, 0.5, mi.Point2f(0.5, 0.5))
            weights.append(np.array(w, dtype=float).ravel())
        silver, flat, ramp = weights
        with pytest.raises(Exception) as err:
            mi.load_dict({"type": "corona", **P, "mirror_reflectance": {"type": "srgb", "color": [0.9, 0.9, 0.9]}})
        assert "mirror_reflectance" in str(err.value)
    finally:
        mi.set_variant(mi_variant)
    assert silver[2] < silver[0] - 0.01                 # silver's blue channel darker than its red
    assert np.ptp(flat) < 1e-6
    assert ramp[2] < ramp[1] < ramp[0]
