"""The Mitsuba plugin: chi-square, agreement with the reference, energy, renders."""
import os
import shutil

import drjit as dr
import numpy as np
import pytest

import corona
from corona.parameters import material_from_parameters

from bsdf_checks import (assert_eval_matches, chi2_test, furnace, interaction, run_chi2, smooth_context,
                         transmitted_lobe)

# incidences of the chi-square runs: the pole (0), off the pole with the horizon cutting one side
# (60; 30 was merged into it: sample/pdf branch on the side of wi only, cos_i > 0 or < 0, never on
# its angle, so 30 and 60 take the same path with the lobe at another place), grazing (80)
ANGLES = [0, 60, 80]
CIRCLE_POISSON = {"process": "poisson", "radius": 0.4, "area_fraction": 0.3}


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_lobe_circle_poisson(mi_variant, theta):
    ok, test = chi2_test(CIRCLE_POISSON, theta, smooth_context())
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("theta", [0, 60])
def test_chi2_full_bsdf_with_reflection(mi_variant, theta):
    ok, test = chi2_test({**CIRCLE_POISSON, "albedo": 0.8}, theta, smooth_context())
    assert ok, test.messages


# ----------------------------------------------------------------------------
# the back side (wi.z < 0): the layer is two-sided and symmetric under z -> -z
# ----------------------------------------------------------------------------
BACK_MATERIALS = {
    "circle-poisson+albedo": {**CIRCLE_POISSON, "albedo": 0.8},
    "ellipse-hard-disk": {"shape": "ellipse", "radius": 0.3, "aspect": 1.6, "angle": 20,
                          "process": "hard-disk", "area_fraction": 0.4, "albedo": 0.5, "mode": "particle"},
}


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("theta", [180, 150, 100])   # wi from below: 0°, 30°, 80° from -z
@pytest.mark.parametrize("name", list(BACK_MATERIALS))
def test_chi2_back_side(mi_variant, name, theta):
    ok, test = chi2_test(BACK_MATERIALS[name], theta, smooth_context())
    assert ok, test.messages


@pytest.mark.parametrize("name", list(BACK_MATERIALS))
def test_back_side_is_the_mirror_of_the_front(mi_variant, name):
    """eval and pdf at (wi, wo) equal those at the mirrored pair (wi, wo with z -> -z),
    for every direction (both hemispheres, incidences up to 85°), and sampling from
    below sends the lobe up and the reflection down with weight eval / pdf."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **BACK_MATERIALS[name]})
    rng = np.random.default_rng(11)
    n = 4000
    th = rng.uniform(0, np.radians(85), n)
    ph = rng.uniform(0, 2 * np.pi, n)
    wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    flip = np.array([1.0, 1.0, -1.0])
    lams = (450.0, 520.0, 600.0, 700.0)
    out = []
    for a, b in ((wi, wo), (wi * flip, wo * flip)):
        si = interaction(n, (0.0, 0.0, 1.0), lams)
        si.wi = mi.Vector3f(np.ascontiguousarray(a.T, dtype=np.float32))
        e, p = bsdf.eval_pdf(mi.BSDFContext(), si, mi.Vector3f(np.ascontiguousarray(b.T, dtype=np.float32)))
        out.append((np.array(e), np.array(p)))
    (e_front, p_front), (e_back, p_back) = out
    assert np.mean(e_front[0] > 0) > 0.3            # both the lobe and the reflection are hit
    np.testing.assert_allclose(e_back, e_front, rtol=1e-5, atol=1e-7 * e_front.max())
    np.testing.assert_allclose(p_back, p_front, rtol=1e-5, atol=1e-7 * p_front.max())

    # sampling from below (wi.z < 0)
    m = 100_000
    wi_back = (np.sin(0.5), 0.0, -np.cos(0.5))
    si = interaction(m, wi_back, lams)
    ctx = mi.BSDFContext()
    bs, w = bsdf.sample(ctx, si, mi.Float(rng.random(m)), mi.Point2f(rng.random(m), rng.random(m)))
    w, comp, wo_s = np.array(w), np.array(bs.sampled_component), np.array(bs.wo).T
    alive = np.any(w > 0, axis=0)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(wo_s[alive & (comp != 2), 2] > 0)  # coherent beam and lobe go through (up)
    assert np.all(wo_s[alive & (comp == 2), 2] < 0)  # reflection stays below
    np.testing.assert_allclose(wo_s[alive & (comp == 0)], np.broadcast_to(-np.array(wi_back), wo_s[alive & (comp == 0)].shape),
                               atol=1e-6)            # the coherent beam continues along -wi
    smooth = alive & (comp != 0)
    e, p = bsdf.eval_pdf(ctx, interaction(int(smooth.sum()), wi_back, lams), mi.Vector3f(wo_s[smooth].T))
    np.testing.assert_allclose(w[:, smooth], np.array(e) / np.array(p), rtol=1e-4)
    # energy from below equals the model's (coherent + propagating lobe + reflection)
    mat = material_from_parameters(**BACK_MATERIALS[name])
    for k, lam in enumerate(lams):
        expected = (mat.coherent_transmittance + mat.reflectance
                    + mat.diffuse_transmittance(lam, cos_theta_i=np.cos(0.5)))
        assert w[k].mean() == pytest.approx(expected, abs=5 * w[k].std() / np.sqrt(m) + 2e-3)


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
    # eval = f |cos θo| on the transmitted side
    assert_eval_matches(bsdf, transmitted_lobe(m), wi, _directions(2000, 1, theta), rtol=1e-4, atol=1e-4)


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


@pytest.mark.slow
@pytest.mark.chi2
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
    for theta in [0, 40, 70, 89]:
        for lam in (360.0, 550.0, 830.0):
            mean, _ = furnace(bsdf, theta, (lam,) * 4)
            expected = (m.coherent_transmittance + m.reflectance
                        + m.diffuse_transmittance(lam, cos_theta_i=np.cos(np.radians(theta))))
            assert mean[0] <= 1.0 + 5e-3
            assert mean[0] == pytest.approx(expected, abs=5e-3)


@pytest.mark.slow
@pytest.mark.chi2
def test_stock_chi2_adapter(mi_variant):
    """Mitsuba's own BSDFAdapter (zero wavelengths, no `active`) passes."""
    import mitsuba as mi
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    sample, pdf = BSDFAdapter("corona", {"type": "corona", **CIRCLE_POISSON, "radius": 0.2},
                              ctx=smooth_context())
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3)
    assert run_chi2(test), test.messages


@pytest.mark.slow
@pytest.mark.chi2
def test_a_failing_chi2_writes_its_data_outside_the_working_directory(mi_variant, tmp_path, monkeypatch):
    """A wrong pdf (uniform instead of the lobe) is rejected, and Mitsuba's chi2_data.py
    goes to a temporary directory, not the working directory."""
    import mitsuba as mi
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    monkeypatch.chdir(tmp_path)
    sample, _ = BSDFAdapter("corona", {"type": "corona", **CIRCLE_POISSON}, ctx=smooth_context())
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, sample_dim=3, sample_count=100_000,
                         pdf_func=lambda wo, *args: dr.full(mi.Float, 1 / (4 * dr.pi), dr.width(wo)))
    assert not run_chi2(test)
    assert not (tmp_path / "chi2_data.py").exists()
    folder = test.messages.rsplit("(histogram and density: ", 1)[1].split("/chi2_data.py")[0]
    assert os.path.isfile(os.path.join(folder, "chi2_data.py"))
    shutil.rmtree(folder)


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


@pytest.mark.slow
@pytest.mark.render
def test_render_has_no_nan(mi_variant):
    import mitsuba as mi
    from corona.apps.scenes import street_light_scene
    scene = mi.load_dict(street_light_scene(resolution=32, bsdf={"type": "corona", **CIRCLE_POISSON}))
    img = np.array(mi.render(scene, spp=4))
    assert np.all(np.isfinite(img)) and img.max() > 0


def mitsuba_channel_responses(mono: bool):
    """The RGB (or mono) channel responses from Mitsuba's own CIE 1931 table and
    XYZ → linear sRGB matrix (``mitsuba.scalar_rgb``; not corona's code): on a
    0.1 nm grid over [360, 830] nm, negative lobes clipped; ȳ for mono."""
    import mitsuba.scalar_rgb as sr
    lam = np.linspace(360.0, 830.0, 4701)
    xyz = np.array([sr.cie1931_xyz(float(x)) for x in lam])                     # (n, 3)
    if mono:
        return lam, xyz[:, 1:2].T
    rgb = np.array([sr.xyz_to_srgb(sr.Color3f(*map(float, c))) for c in xyz])  # (n, 3)
    return lam, np.maximum(rgb, 0.0).T


def quantile_wavelengths(lam, response, n):
    """``n`` wavelengths at the equal-weight (midpoint) quantiles of ``response``."""
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (response[1:] + response[:-1]) * np.diff(lam))])
    return np.interp((np.arange(n) + 0.5) / n * cdf[-1], cdf, lam)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono", "scalar_spectral"])
def test_other_variants_agree_with_reference(mi_variant, variant):
    """RGB / mono channels are the lobe averaged over the channel's response (Mitsuba's
    CIE 1931 colorimetry); scalar_spectral = llvm at the same wavelengths."""
    import mitsuba as mi
    from corona.mitsuba.bsdf import N_RESPONSE
    params = {"process": "poisson", "radius": 0.5, "area_fraction": 0.3}
    m = material_from_parameters(**params)
    wo_np = np.array([0.15, -0.1, -np.sqrt(1 - 0.15**2 - 0.01)])

    def lobe(lams):
        return m.lobe(np.tile(wo_np[:2], (len(lams), 1)), lams) * abs(wo_np[2])

    try:
        mi.set_variant(variant)
        corona.register()
        bsdf = mi.load_dict({"type": "corona", **params})
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(0, 0, 1)
        if mi.is_spectral:
            si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 700.0)
        val = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*map(float, wo_np)))).ravel()
        if mi.is_spectral:
            np.testing.assert_allclose(val, lobe(np.array([450.0, 520.0, 600.0, 700.0])), rtol=2e-4)
        else:
            lam, resp = mitsuba_channel_responses(mi.is_monochromatic)
            # the documented rule: the mean over N_RESPONSE equal-weight quantiles of each response
            nodes = [quantile_wavelengths(lam, r, N_RESPONSE) for r in resp]
            np.testing.assert_allclose(val, [lobe(ls).mean() for ls in nodes], rtol=3e-4)
            # ... which approximates the exact colorimetric average ∫ f r dλ / ∫ r dλ: the lobe
            # changes 3× over the spectrum here, and the red channel's second (blue) lobe
            # gets one of the 8 nodes: 1.7 % low in red, < 0.2 % in green, blue and mono
            exact = np.trapezoid(resp * lobe(lam), lam, axis=1) / np.trapezoid(resp, lam, axis=1)
            np.testing.assert_allclose(val, exact, rtol=0.025)
            np.testing.assert_allclose(val[-2:], exact[-2:], rtol=2e-3)
        ctx = smooth_context()
        bs, w = bsdf.sample(ctx, si, 0.3, mi.Point2f(0.4, 0.7))
        e, p = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_allclose(np.array(w).ravel(), np.array(e).ravel() / float(np.array(p).ravel()[0]),
                                   rtol=1e-5)
    finally:
        mi.set_variant(mi_variant)


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono"])
@pytest.mark.parametrize("params", [
    {"process": "hard-disk", "radius": 0.4, "area_fraction": 0.4, "mode": "particle"},   # one row at F_a
    {**CIRCLE_POISSON, "albedo": 0.5, "substrate": "glass"},                               # one row, a pane
])
def test_channel_tables_agree_with_the_model_and_sample_their_pdf(mi_variant, variant, params):
    """RGB / mono evaluate a uniform radial layer from one table per channel (the mean over the
    channel's response wavelengths, precomputed in s = L |d|): across the lobe each channel is
    the mean of the model's lobe over the N_RESPONSE quantile wavelengths of Mitsuba's own
    colorimetry (where it is above 1e-3 of its peak), and sampling follows its pdf (chi-square)."""
    import mitsuba as mi
    from corona.mitsuba.bsdf import N_RESPONSE
    m = material_from_parameters(**{k: v for k, v in params.items() if k not in ("substrate",)})
    try:
        mi.set_variant(variant)
        corona.register()
        bsdf = mi.load_dict({"type": "corona", **params})
        assert bsdf.channel_tables_on
        # directions across the lobe (|d| to 0.9: past the Airy disk's first zero), normal incidence
        dx = np.linspace(0.005, 0.87, 160)      # (d = 0: the coherent beam's own direction)
        dy = 0.25 * dx
        wo_np = np.stack([dx, dy, -np.sqrt(1 - dx**2 - dy**2)], 1)
        si = interaction(len(dx), (0.0, 0.0, 1.0))
        wo = mi.Vector3f(*[mi.Float(c.astype(np.float32)) for c in wo_np.T])
        val = np.array(bsdf.eval(smooth_context(), si, wo)).reshape(-1, len(dx))
        lam, resp = mitsuba_channel_responses(mi.is_monochromatic)
        want = []
        for r in resp:
            ls = quantile_wavelengths(lam, r, N_RESPONSE)
            lobe = np.array([m.lobe(wo_np[:, :2], np.full(len(dx), x)) for x in ls]).mean(0)
            want.append(lobe * np.abs(wo_np[:, 2]))
        want = np.array(want)
        if "substrate" in params:    # the pane's T'(θo) on the lobe in transmission
            r = np.array([float(np.array(mi.fresnel(mi.Float(float(c)), 1.52)[0])[0]) for c in np.abs(wo_np[:, 2])])
            want = want * (1 - 2 * r / (1 + r))
        big = want > 1e-3 * want.max()
        np.testing.assert_allclose(val[big], want[big], rtol=2e-2)
        rel = np.abs(val[big] - want[big]) / want[big]
        assert np.sqrt(np.mean(rel**2)) < 2e-3
        for theta in (0, 60):
            ok, test = chi2_test(params, theta, smooth_context())
            assert ok, test.messages
    finally:
        mi.set_variant(mi_variant)


def test_traverse_albedo(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **CIRCLE_POISSON, "albedo": 0.0})
    params = mi.traverse(bsdf)
    assert "albedo.value" in params
    si = interaction(1, (0.0, 0.0, 1.0))
    wo = mi.Vector3f(0.0, 0.6, 0.8)  # reflection side
    assert np.all(np.array(bsdf.eval(mi.BSDFContext(), si, wo)) == 0)
    params["albedo.value"] = 0.5
    params.update()
    m = material_from_parameters(**CIRCLE_POISSON, albedo=0.5)
    val = np.array(bsdf.eval(mi.BSDFContext(), si, wo))
    np.testing.assert_allclose(val, m.reflectance / np.pi * 0.8, rtol=1e-5)
    params["albedo.value"] = 2.0
    with pytest.raises(Exception, match="albedo"):
        params.update()
