"""The layer on a glass pane (substrate=glass): Fresnel, the reference, the plugin, energy.

Independent references: Fresnel's equations at normal incidence and at
Brewster's angle; Mitsuba's own ``mi.fresnel`` and ``thindielectric`` plugin;
a brute-force random walk through the layer-pane stack (every path, any
order: corona.reference.stack); mitsuba.chi2.
"""
import numpy as np
import pytest

import corona
from corona.parameters import material_from_parameters
from corona.reference.stack import CLASSES, random_walk
from corona.model.substrate import GlassPane, fresnel_dielectric

from bsdf_checks import assert_eval_matches, chi2_test, furnace, interaction, smooth_context

# a wide lobe (small droplets) with an opaque part that reflects: every component matters
LAYER = {"process": "poisson", "radius": 0.3, "area_fraction": 0.5, "mode": "particle", "albedo": 1.0}
PANE = {**LAYER, "substrate": "glass"}
COS_I = [1.0, 0.6, 0.2, -1.0, -0.6, -0.2]      # + meets the layer first (side front), - the glass


@pytest.fixture(scope="module")
def pane_material():
    return material_from_parameters(**PANE)


# --- the pane alone ------------------------------------------------------------
def test_fresnel_normal_incidence_and_brewster():
    n = 1.52
    assert fresnel_dielectric(1.0, n) == pytest.approx(((n - 1) / (n + 1)) ** 2, rel=1e-12)
    # at Brewster's angle tan θB = n the p wave is not reflected: R = r_s² / 2
    tb = np.arctan(n)
    ct = np.cos(np.arcsin(np.sin(tb) / n))
    rs = (np.cos(tb) - n * ct) / (np.cos(tb) + n * ct)
    assert fresnel_dielectric(np.cos(tb), n) == pytest.approx(rs * rs / 2, rel=1e-12)
    assert fresnel_dielectric(0.0, n) == 1.0


def test_thin_pane_sums_the_internal_bounces():
    pane = GlassPane(1.52)
    c = np.linspace(0.01, 1, 50)
    r = pane.face_reflectance(c)
    t = 1 - r
    series = r + sum(t * t * r ** (2 * k + 1) for k in range(5000))    # R + T²R + T²R³ + ...
    np.testing.assert_allclose(pane.reflectance(c), series, rtol=1e-12)
    np.testing.assert_allclose(pane.reflectance(c) + pane.transmittance(c), 1.0)


def test_fresnel_agrees_with_mitsuba(mi_variant):
    import mitsuba as mi
    c = np.linspace(0.0, 1.0, 101)
    ours = fresnel_dielectric(c, 1.52)
    theirs = np.array(mi.fresnel(mi.Float(c), 1.52)[0])
    np.testing.assert_allclose(ours, theirs, atol=2e-6)


@pytest.mark.parametrize("theta", [0, 50, 85])
def test_glass_first_specular_is_mitsubas_thindielectric(mi_variant, theta):
    """Light meeting the glass first sees the pane's reflection R', as Mitsuba's thindielectric."""
    import mitsuba as mi
    th = np.radians(theta)
    si = interaction(1, (np.sin(th), 0.0, -np.cos(th)))           # from -z: side front -> glass first
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.DeltaReflection
    glass = mi.load_dict({"type": "thindielectric", "int_ior": 1.52, "ext_ior": 1.0})
    _, w_ref = glass.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
    corona_pane = mi.load_dict({"type": "corona", **PANE})
    bs, w = corona_pane.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
    assert int(np.array(bs.sampled_component)[0]) == 3
    np.testing.assert_allclose(np.array(bs.wo).ravel(), [-np.sin(th), 0.0, -np.cos(th)], atol=1e-6)
    np.testing.assert_allclose(np.array(w).ravel(), np.array(w_ref).ravel(), rtol=1e-5)
    # meeting the layer first: the front face's R through the layer once, the rest of the pane's
    # R' (the round trips) through it coherently twice
    si.wi = mi.Vector3f(float(np.sin(th)), 0.0, float(np.cos(th)))
    _, w = corona_pane.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
    c = material_from_parameters(**PANE).coherent_transmittance
    rf = fresnel_dielectric(np.cos(th), 1.52)
    r_pane = np.array(w_ref).ravel()
    np.testing.assert_allclose(np.array(w).ravel(), c * rf + c * c * (r_pane - rf), rtol=1e-5)


# --- the reference -----------------------------------------------------------------
def _directions(n, seed):
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1, 1, n)
    z = np.where(np.abs(z) < 0.02, 0.5, z)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def test_reference_is_reciprocal(pane_material):
    """f_s(wi, wo) = f_s(wo, wi), across the layer and the pane in both directions."""
    wi, wo = _directions(3000, 1), _directions(3000, 2)
    a = pane_material.eval(wi, wo, 550.0) / np.abs(wo[:, 2])
    b = pane_material.eval(wo, wi, 550.0) / np.abs(wi[:, 2])
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    assert np.all(a >= 0) and a.max() > 0


def test_index_one_is_no_pane():
    plain = material_from_parameters(**LAYER)
    clear = material_from_parameters(**PANE, substrate_ior=1.0)
    wi, wo = _directions(500, 3), _directions(500, 4)
    np.testing.assert_allclose(clear.eval(wi, wo, 480.0), plain.eval(wi, wo, 480.0), rtol=1e-12)
    assert clear.specular_reflection(0.7) == 0.0
    assert clear.coherent_transmission(-0.3) == pytest.approx(plain.coherent_transmittance)


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("cos_i", [1.0, 0.3, -0.6])
def test_reference_matches_brute_force_paths(pane_material, cos_i):
    """Each component = the energy of the paths it stands for in a random walk through the stack;
    what the model drops is >= 0, and the model never exceeds the walk."""
    rw = random_walk(pane_material, cos_i, 550.0, n=150_000, seed=7)
    model = pane_material.directional_albedo(cos_i, 550.0)
    # the walk's front face reflects the scattered light at the scattered angle (R_o); the model
    # takes min(R_i, R_o), reciprocal: the difference, ∫ f (R_o - min(R_i, R_o)), is added to it
    pane = pane_material.substrate
    r_i = float(pane.face_reflectance(cos_i))
    s = np.sqrt(1 - cos_i * cos_i)
    (gap,) = pane_material._lobe_integrals(
        550.0, (s, 0.0), [lambda co: pane.face_reflectance(co) - np.minimum(r_i, pane.face_reflectance(co))])
    if cos_i > 0:
        assert 0 <= gap <= 0.2 * rw["lobe_reflection_front"]      # a wide lobe (R = 0.3 µm)
        model = {**model, "lobe_reflection": model["lobe_reflection"] + gap}
    for k in CLASSES[:-1]:
        assert model[k] == pytest.approx(rw[k], abs=4 * rw["sigma"] + 2e-3 * model[k]), k
    assert rw["unfinished"] < 1e-4
    walk_total = rw["reflected"] + rw["transmitted"]
    assert model["total"] <= walk_total + 4 * rw["sigma"]
    assert walk_total - model["total"] == pytest.approx(rw["dropped"], abs=5 * rw["sigma"])
    assert model["total"] <= 1.0


@pytest.mark.parametrize("cos_i", COS_I)
def test_reference_white_furnace_at_most_the_layer_alone(pane_material, cos_i):
    alone = material_from_parameters(**LAYER).directional_albedo(abs(cos_i), 550.0)["total"]
    with_pane = pane_material.directional_albedo(cos_i, 550.0)["total"]
    assert with_pane <= 1.0
    if cos_i > 0:   # meeting the layer first, the pane only removes energy (docs/physics.md#the-layer-on-glass-substrateglass)
        assert with_pane <= alone + 1e-12


# --- the plugin ----------------------------------------------------------------------
def test_components_and_flags(mi_variant):
    import mitsuba as mi
    F = mi.BSDFFlags
    b = mi.load_dict({"type": "corona", **PANE})
    assert b.component_count() == 5
    for i, flag in enumerate([F.DeltaTransmission, F.GlossyTransmission, F.DiffuseReflection,
                              F.DeltaReflection, F.GlossyReflection]):
        assert mi.has_flag(b.flags(i), flag)
        assert mi.has_flag(b.flags(), flag)
    plain = mi.load_dict({"type": "corona", **LAYER})
    assert plain.component_count() == 3
    assert not mi.has_flag(plain.flags(), F.DeltaReflection)
    aniso = mi.load_dict({"type": "corona", **PANE, "shape": "square", "radius": 0.5})
    assert mi.has_flag(aniso.flags(4), F.Anisotropic)


@pytest.mark.parametrize("side", ["front", "back"])
@pytest.mark.parametrize("theta", [0, 45, 75])
def test_eval_matches_reference(mi_variant, side, theta):
    import mitsuba as mi
    params = {**PANE, "substrate_side": side, "radius": 0.6, "area_fraction": 0.25, "albedo": 0.5}
    bsdf = mi.load_dict({"type": "corona", **params})
    m = material_from_parameters(**params)
    th = np.radians(theta)
    wo = _directions(3000, 5)
    for sign in (1, -1):
        wi = np.array([np.sin(th), 0.0, sign * np.cos(th)])
        assert_eval_matches(bsdf, m.eval, wi, wo, rtol=2e-4, atol=2e-4)


@pytest.mark.parametrize("cos_i", COS_I)
def test_white_furnace_per_incidence(mi_variant, pane_material, cos_i):
    """Sampled energy (all components) <= 1 and equal to the reference's directional albedo."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **PANE})
    for lam in (400.0, 650.0):
        mean, err, shares = furnace(bsdf, np.degrees(np.arccos(cos_i)), (lam,) * 4, seed=11, components=(0, 3))
        expected = pane_material.directional_albedo(cos_i, lam)
        assert mean[0] <= 1.0 + 3 * err[0]
        assert mean[0] == pytest.approx(expected["total"], abs=4 * err[0] + 1e-3)
        # the delta components carry exactly their weights
        for share, key in zip(shares[:, 0], ("coherent", "specular")):
            assert share == pytest.approx(expected[key], abs=5e-3)


def test_delta_weights_match_reference(mi_variant, pane_material):
    import mitsuba as mi
    for cos_i in COS_I:
        s = np.sqrt(1 - cos_i * cos_i)
        si = interaction(1, (s, 0.0, cos_i))
        for flag, comp, ref in ((mi.BSDFFlags.DeltaTransmission, 0, pane_material.coherent_transmission(cos_i)),
                                (mi.BSDFFlags.DeltaReflection, 3, pane_material.specular_reflection(cos_i))):
            ctx = mi.BSDFContext()
            ctx.type_mask = flag
            bs, w = mi.load_dict({"type": "corona", **PANE}).sample(ctx, si, 0.3, mi.Point2f(0.5, 0.5))
            assert int(np.array(bs.sampled_component)[0]) == comp
            np.testing.assert_allclose(np.array(w).ravel(), float(ref), rtol=1e-5)


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("extra,theta", [
    ({}, 0), ({}, 60), ({"albedo": 0.0}, 30),                     # meets the layer first
    ({"substrate_side": "back"}, 45),                              # meets the glass first
    ({"shape": "square", "radius": 0.5, "albedo": 0.0}, 30),       # anisotropic lobe, reflected too
    ({"sampling": "cosine"}, 40),
])
def test_chi2_smooth_parts(mi_variant, extra, theta):
    ok, test = chi2_test({**PANE, "radius": 0.4, "area_fraction": 0.3, **extra}, theta, smooth_context(),
                         sample_count=400_000)
    assert ok, test.messages


def test_sample_weight_is_eval_over_pdf(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", **PANE})
    n = 20000
    si = interaction(n, (0.5, 0.0, np.sqrt(0.75)))
    ctx = smooth_context()
    rng = np.random.default_rng(2)
    bs, w = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    e, p = bsdf.eval_pdf(ctx, si, bs.wo)
    w, e, p = np.array(w), np.array(e), np.array(p)
    ok = p > 0
    comp = np.array(bs.sampled_component)
    assert set(np.unique(comp[ok])) == {1, 2, 4}
    np.testing.assert_allclose(w[:, ok], e[:, ok] / p[ok], rtol=1e-5)


def test_index_one_plugin_is_no_pane(mi_variant):
    import mitsuba as mi
    a = mi.load_dict({"type": "corona", **LAYER})
    b = mi.load_dict({"type": "corona", **PANE, "substrate_ior": 1.0})
    wo = _directions(1000, 9)
    si = interaction(len(wo), (0.3, 0.1, -np.sqrt(0.9)))
    ctx = mi.BSDFContext()
    ea, pa = a.eval_pdf(ctx, si, mi.Vector3f(wo.T))
    eb, pb = b.eval_pdf(ctx, si, mi.Vector3f(wo.T))
    np.testing.assert_allclose(np.array(eb), np.array(ea), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(np.array(pb), np.array(pa), rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("params,word", [
    ({"substrate": "plastic"}, "substrate"),
    ({"substrate_ior": 1.5}, "substrate_ior"),                      # needs substrate=glass
    ({"substrate": "glass", "substrate_ior": 0.5}, "substrate_ior"),
    ({"substrate": "glass", "substrate_side": "left"}, "substrate_side"),
])
def test_bad_substrate_parameters(mi_variant, params, word):
    import mitsuba as mi
    with pytest.raises(corona.CoronaError, match=word):
        material_from_parameters(**params)
    with pytest.raises(Exception, match=word):
        mi.load_dict({"type": "corona", **params})


def test_each_substrate_is_one_component_chosen_when_the_layer_is_built():
    """The layer holds one substrate object (none, a pane, a pane with its double pass, a
    mirror), picked once; pane=False in directional_albedo is the bare one (same numbers as
    the layer built without a pane; negative control: with its pane they differ)."""
    import warnings
    from corona.model.substrate import BareLayer, DoublePass, Mirror, OnPane
    layer = (corona.Circle(2.0), corona.HardDisk(0.3))
    cases = [(None, BareLayer), (GlassPane(), OnPane), (GlassPane(side="back"), OnPane),
             (GlassPane(thickness=1000.0), DoublePass), (Mirror(), DoublePass)]
    for pane, kind in cases:
        m = corona.Material(*layer, substrate=pane)
        assert type(m.substrate_part) is kind and m.substrate_part.pane is pane
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        drops = corona.Material(corona.Sphere(2.0), corona.HardDisk(0.3), substrate=GlassPane())
    assert type(drops.substrate_part) is OnPane
    on_glass = corona.Material(*layer, substrate=GlassPane(side="back"))
    alone = corona.Material(*layer)
    for ci in (0.7, -0.7):
        assert on_glass.directional_albedo(ci, 550.0, pane=False) == alone.directional_albedo(ci, 550.0)
        assert on_glass.directional_albedo(ci, 550.0) != alone.directional_albedo(ci, 550.0)
    assert not np.any(alone.specular_reflection(np.array([0.5, -0.5]), 550.0))
