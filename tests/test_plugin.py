"""The Mitsuba plugin: chi-square, agreement with the reference, energy, renders."""
import drjit as dr
import numpy as np
import pytest

import corona
from corona.parameters import material_from_parameters

from bsdf_checks import chi2_test, interaction, smooth_context

ANGLES = [0, 30, 60, 80]
CIRCLE_POISSON = {"process": "poisson", "radius": 0.4, "area_fraction": 0.3}


@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_lobe_circle_poisson(mi_variant, theta):
    ok, test = chi2_test(CIRCLE_POISSON, theta, smooth_context())
    assert ok, test.messages


@pytest.mark.parametrize("theta", [0, 60])
def test_chi2_full_bsdf_with_reflection(mi_variant, theta):
    ok, test = chi2_test({**CIRCLE_POISSON, "albedo": 0.8}, theta, smooth_context())
    assert ok, test.messages


def _directions(n, seed, wi_theta):
    rng = np.random.default_rng(seed)
    z = -rng.uniform(0.05, 1.0, n)  # transmitted side
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


@pytest.mark.parametrize("theta", [0, 45])
def test_eval_matches_reference_material(mi_variant, theta):
    import mitsuba as mi
    params = {"process": "poisson", "radius": 0.6, "area_fraction": 0.25}
    bsdf = mi.load_dict({"type": "corona", **params})
    m = material_from_parameters(**params)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0, np.cos(th)])
    wo = _directions(2000, 1, theta)
    lams = (450.0, 520.0, 600.0, 700.0)
    si = interaction(len(wo), wi, lams)
    val = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T)))  # (4, n)
    d = wo[:, :2] + wi[:2]
    for k, lam in enumerate(lams):
        ref = m.lobe(d, lam) * np.abs(wo[:, 2])  # eval = f |cos θo|
        np.testing.assert_allclose(val[k], ref, rtol=1e-4, atol=1e-4 * ref.max())


def test_sample_weight_is_eval_over_pdf_and_constant(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "poisson", "radius": 0.5, "area_fraction": 0.3})
    n = 50000
    lam = (550.0, 550.0, 550.0, 550.0)  # one wavelength: perfect importance sampling
    si = interaction(n, (0.2, 0.0, np.sqrt(1 - 0.04)), lam)
    ctx = smooth_context()
    rng = np.random.default_rng(2)
    bs, w = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    e, p = bsdf.eval_pdf(ctx, si, bs.wo)
    w, e, p = np.array(w)[0], np.array(e)[0], np.array(p)
    ok = w > 0
    assert ok.mean() > 0.5
    np.testing.assert_allclose(w[ok], e[ok] / p[ok], rtol=1e-5)
    # eval/pdf = the lobe's plane integral, up to the table's float32 rounding
    m = material_from_parameters(process="poisson", radius=0.5, area_fraction=0.3)
    np.testing.assert_allclose(w[ok], m.tabulated_transmittance, rtol=2e-3)


@pytest.mark.parametrize("theta", [0, 60])
def test_cosine_sampling_follows_its_pdf(mi_variant, theta):
    # the comparison strategy of the talk: wo cosine-distributed on the far side
    ok, test = chi2_test({**CIRCLE_POISSON, "sampling": "cosine"}, theta, smooth_context())
    assert ok, test.messages


def test_cosine_and_lobe_sampling_estimate_the_same_energy(mi_variant):
    import mitsuba as mi
    n = 400000
    si = interaction(n, (0.3, 0.0, np.sqrt(1 - 0.09)), (550.0,) * 4)
    rng = np.random.default_rng(5)
    s1, s2 = mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
    ctx = smooth_context()
    est = {}
    for how in ("lobe", "cosine"):
        bsdf = mi.load_dict({"type": "corona", "radius": 2.0, "area_fraction": 0.3,
                             "process": "poisson", "sampling": how})
        bs, w = bsdf.sample(ctx, si, s1, s2)
        e, p = bsdf.eval_pdf(ctx, si, bs.wo)
        w, e, p = np.array(w)[0], np.array(e)[0], np.array(p)
        ok = p > 0
        np.testing.assert_allclose(w[ok], e[ok] / p[ok], rtol=1e-5)
        est[how] = (w.mean(), w.std() / np.sqrt(n))
    # both estimate the transmitted lobe energy; the cosine one is far noisier
    (m_l, e_l), (m_c, e_c) = est["lobe"], est["cosine"]
    assert abs(m_l - m_c) < 4 * np.hypot(e_l, e_c)
    assert e_c > 5 * e_l


def test_unknown_sampling_is_an_error(mi_variant):
    import mitsuba as mi
    with pytest.raises(Exception, match="sampling"):
        mi.load_dict({"type": "corona", "sampling": "uniform"})


@pytest.mark.parametrize("mode", ["aperture", "particle"])
def test_white_furnace(mi_variant, mode):
    """Reflected + transmitted energy <= 1 at every angle and wavelength, and equal to the model."""
    import mitsuba as mi
    params = {"process": "poisson", "radius": 0.3, "area_fraction": 0.5, "albedo": 1.0, "mode": mode}
    bsdf = mi.load_dict({"type": "corona", **params})
    m = material_from_parameters(**params)
    n = 200000
    rng = np.random.default_rng(3)
    for theta in [0, 40, 70, 89]:
        th = np.radians(theta)
        wi = (np.sin(th), 0.0, np.cos(th))
        for lam in (360.0, 550.0, 830.0):
            si = interaction(n, wi, (lam,) * 4)
            bs, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)),
                                mi.Point2f(rng.random(n), rng.random(n)))
            w = np.array(w)[0]
            assert np.all(np.isfinite(w)) and np.all(w >= 0)
            energy = w.mean()
            expected = (m.coherent_transmittance + m.reflectance
                        + m.diffuse_transmittance(lam, cos_theta_i=np.cos(th)))
            assert energy <= 1.0 + 5e-3
            assert energy == pytest.approx(expected, abs=5e-3)


def test_zero_initialised_interaction_gives_no_nan(mi_variant):
    """mitsuba.chi2.BSDFAdapter's si has zero wavelengths and no `active`."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **CIRCLE_POISSON})
    si = dr.zeros(mi.SurfaceInteraction3f, 16)
    si.wi = mi.Vector3f(0, 0, 1)
    bs, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(np.linspace(0, 0.99, 16)),
                        mi.Point2f(np.linspace(0, 0.99, 16), np.linspace(0.1, 0.9, 16)))
    assert np.all(np.isfinite(np.array(w)))
    p = bsdf.pdf(mi.BSDFContext(), si, mi.Vector3f(0.1, 0.0, -0.99))
    assert np.all(np.isfinite(np.array(p)))
    # grazing, exactly opposite and exactly equal directions
    for wo in [(1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)]:
        e = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo)))
        assert np.all(np.isfinite(e)) and np.all(e >= 0)


def test_stock_chi2_adapter(mi_variant):
    """Mitsuba's own BSDFAdapter (zero wavelengths, no `active`) passes."""
    import mitsuba as mi
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    sample, pdf = BSDFAdapter("corona", {"type": "corona", **CIRCLE_POISSON, "radius": 0.2},
                              ctx=smooth_context())
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3)
    assert test.run(), test.messages


def test_xml_and_dict_load(mi_variant):
    import mitsuba as mi
    b = mi.load_string('<bsdf version="3.0.0" type="corona">'
                       '<float name="radius" value="0.7"/><string name="process" value="poisson"/>'
                       '<float name="area_fraction" value="0.2"/></bsdf>')
    assert "Circle(radius=0.7)" in str(b)
    corona.register()  # idempotent


@pytest.mark.parametrize("params,word", [
    ({"radius": -1.0}, "radius"),
    ({"area_fraction": 1.5}, "area_fraction"),
    ({"shape": "blob"}, "shape"),
    ({"mode": "sideways"}, "mode"),
    ({"bogus": 1.0}, "bogus"),
    ({"shape": "mixture", "mixture": "circle:1"}, "mixture"),
    ({"shape": "mixture", "mixture": "circle:1:0.5, blob:1:0.5"}, "mixture shape"),
    ({"mixture": "circle:1:1"}, "mixture"),
])
def test_bad_parameters_fail_at_load(mi_variant, params, word):
    import mitsuba as mi
    with pytest.raises(Exception, match=word):
        mi.load_dict({"type": "corona", "process": "poisson", **params})


def test_render_has_no_nan(mi_variant):
    import mitsuba as mi
    from corona.scenes import street_light_scene
    scene = mi.load_dict(street_light_scene(resolution=32, bsdf={"type": "corona", **CIRCLE_POISSON}))
    img = np.array(mi.render(scene, spp=4))
    assert np.all(np.isfinite(img)) and img.max() > 0


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono", "scalar_spectral"])
def test_other_variants_agree_with_reference(mi_variant, variant):
    """RGB / mono channels are the lobe averaged over the channel's response; scalar = llvm."""
    import mitsuba as mi
    from corona.mitsuba_bsdf import _channel_response
    params = {"process": "poisson", "radius": 0.5, "area_fraction": 0.3}
    m = material_from_parameters(**params)
    wo_np = np.array([0.15, -0.1, -np.sqrt(1 - 0.15**2 - 0.01)])
    try:
        mi.set_variant(variant)
        corona.register()
        bsdf = mi.load_dict({"type": "corona", **params})
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(0, 0, 1)
        if mi.is_spectral:
            si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 700.0)
            lams = np.array([[450.0], [520.0], [600.0], [700.0]])
        else:
            lams, _ = _channel_response()
        val = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*map(float, wo_np)))).ravel()
        ref = np.array([m.lobe(np.tile(wo_np[:2], (len(ls), 1)), ls).mean() for ls in lams]) * abs(wo_np[2])
        np.testing.assert_allclose(val, ref, rtol=2e-4)
        ctx = smooth_context()
        bs, w = bsdf.sample(ctx, si, 0.3, mi.Point2f(0.4, 0.7))
        e, p = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_allclose(np.array(w).ravel(), np.array(e).ravel() / float(np.array(p).ravel()[0]),
                                   rtol=1e-5)
    finally:
        mi.set_variant(mi_variant)


def test_traverse_albedo(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **CIRCLE_POISSON, "albedo": 0.0})
    params = mi.traverse(bsdf)
    assert "albedo" in params
    si = interaction(1, (0.0, 0.0, 1.0))
    wo = mi.Vector3f(0.0, 0.6, 0.8)  # reflection side
    assert np.all(np.array(bsdf.eval(mi.BSDFContext(), si, wo)) == 0)
    params["albedo"] = 0.5
    params.update()
    m = material_from_parameters(**CIRCLE_POISSON, albedo=0.5)
    val = np.array(bsdf.eval(mi.BSDFContext(), si, wo))
    np.testing.assert_allclose(val, m.reflectance / np.pi * 0.8, rtol=1e-5)
    params["albedo"] = 2.0
    with pytest.raises(Exception, match="albedo"):
        params.update()
