"""The plugin's sphere path (shape=sphere) against the numpy reference, mitsuba.chi2 and the furnace."""
import warnings

import numpy as np
import pytest

from bsdf_checks import assert_eval_matches, chi2_bsdf, furnace, interaction

WAVELENGTHS = (450.0, 520.0, 600.0, 700.0)


@pytest.fixture(scope="module")
def layers(mi_variant):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = {
            "hd": mi.load_dict({"type": "corona", "shape": "sphere", "radius": 2.0, "area_fraction": 0.3,
                                "process": "hard-disk"}),
            "sd": mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.5, "area_fraction": 0.2,
                                "process": "hard-disk", "size_spread": 0.1}),
            "poisson": mi.load_dict({"type": "corona", "shape": "sphere", "radius": 5.0,
                                     "area_fraction": 0.05, "process": "poisson"}),
        }
    return out


def _directions(wi, rng, n=3000):
    """Random directions plus many near the forward (-wi) and backward (wi) peaks."""
    from corona.model.mie.layer import frame
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    out = [v]
    for axis, spread in ((-wi, 0.15), (wi, 0.3)):
        th = rng.uniform(0, spread, n)
        ph = rng.uniform(0, 2 * np.pi, n)
        e1, e2 = frame(axis)
        out.append(np.cos(th)[:, None] * axis + np.sin(th)[:, None] * (np.cos(ph)[:, None] * e1
                                                                      + np.sin(ph)[:, None] * e2))
    return np.concatenate(out)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hd", "sd", "poisson"])
def test_eval_matches_numpy_reference(layers, name):
    bsdf = layers[name]
    m = bsdf.material
    rng = np.random.default_rng(2)
    for deg in (0, 30, 60, 80):
        wi = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
        wo = _directions(wi, rng)
        _, _, pdf = assert_eval_matches(bsdf, m.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=1e-4, peak="all")
        # the pdf: lobe selection probabilities x the rows' interpolated density, mixed over the lane
        e = [m.energies(wi[2], lam) for lam in WAVELENGTHS]
        p = np.array([sum(x[k] for x in e) for k in ("coherent", "forward", "backward")])
        p /= p.sum()
        # (each lobe's sampler reaches a sliver past 90°: both densities count everywhere)
        ref_pdf = np.mean([p[1] * m.pdf_lobe("f", wi, wo, lam) + p[2] * m.pdf_lobe("b", wi, wo, lam)
                           for lam in WAVELENGTHS], 0)
        assert np.max(np.abs(np.asarray(pdf) - ref_pdf)) < 1e-4 * ref_pdf.max(), deg


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("component", [1, 2])
# 30° merged into 60°: the sphere plugin branches on the side of wi only, not its angle
@pytest.mark.parametrize("deg", [0, 60, 80])
def test_chi2_lobes(layers, component, deg):
    # the forward (1) and backward (2) lobes separately; ires=32: the test's own integration of
    # the pdf near the pole needs it for the forward peak at normal incidence
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    ctx.component = component
    ok, test = chi2_bsdf(layers["hd"], deg, ctx, sample_count=300_000, res=101, ires=32)
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_size_distribution_both_lobes(layers):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    ok, test = chi2_bsdf(layers["sd"], 30, ctx, sample_count=300_000, res=101, ires=32)
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hd", "poisson"])
def test_white_furnace_by_sampling(layers, name):
    # E[weight] of sample() is the directional albedo: <= 1, and the numpy reference's integral
    bsdf = layers[name]
    for deg in (0, 60):
        mean, _ = furnace(bsdf, deg, WAVELENGTHS, n=400_000, seed=5)
        ref = np.array([bsdf.material.directional_albedo(np.cos(np.radians(deg)), lam, n_phi=128)["total"]
                        for lam in WAVELENGTHS])
        assert np.all(mean <= 1.0 + 3e-3), (deg, mean)
        assert mean == pytest.approx(ref, abs=5e-3), (deg, mean, ref)


def test_both_families_are_one_shell(mi_variant):
    """Spheres are a family of the plugins' one core, not a second stack: Mitsuba's entry points, the
    selection and the update protocol of both variant classes are :class:`corona.mitsuba.core.PluginCore`'s
    own functions."""
    from corona.mitsuba import core, sphere
    from corona.mitsuba.bsdf import bsdf_class
    flat, spheres = bsdf_class(), sphere.sphere_bsdf_class()
    for name in ("eval", "pdf", "eval_pdf", "sample", "_selection", "parameters_changed", "set_components"):
        shared = vars(core.PluginCore)[name]
        assert vars(flat)[name] is shared and vars(spheres)[name] is shared, name


@pytest.mark.slow     # the module's sphere layers (Mie tables)
def test_sphere_components_are_chosen_at_load(layers):
    """A sphere layer holds its components (lobe, substrate, rows' layout, F_a rows, sampler) as objects
    chosen at load."""
    from corona.mitsuba import lobes, sphere
    hd, poisson = layers["hd"], layers["poisson"]
    assert isinstance(hd.lobe, sphere.MieRowsLobe) and isinstance(hd.substrate, sphere.SpheresAlone)
    assert isinstance(hd.chords, sphere.ChordRows) and isinstance(hd.sampler, sphere.MieRowsSampling)
    assert isinstance(hd.fa_tables, lobes.CentredFaTables)       # a uniform F_a with a hard core
    assert isinstance(poisson.fa_tables, lobes.FixedFaTables) and not isinstance(poisson.fa_tables,
                                                                                 lobes.CentredFaTables)


def test_bad_input(mi_variant):
    import mitsuba as mi
    # Mitsuba wraps the plugin's CoronaError in its parser's error; the one line is kept
    with pytest.raises(Exception, match=r"size_spread=0.1 is out of range for shape='sphere' on a lattice; "
                                        r"allowed 0 \(the reflected Bragg orders"):
        mi.load_dict({"type": "corona", "shape": "sphere", "process": "lattice-hex", "size_spread": 0.1})
    # a radius texture (here procedural: its sampled range) wider than water's index allows
    with pytest.raises(Exception, match=r"radius=1 … 3 is out of range for shape='sphere' with a dispersive ior "
                                        r"\(water\).*or a constant ior for any range"):
        mi.load_dict({"type": "corona", "shape": "sphere",
                      "radius": {"type": "checkerboard", "color0": 1.0, "color1": 3.0}})


def test_area_fraction_texture_poisson(mi_variant):
    # a checkerboard of F_a 0.1 / 0.4 is, square by square, the uniform layer of that F_a
    import mitsuba as mi
    tex = {"type": "checkerboard", "color0": 0.1, "color1": 0.4}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        layer = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 2.0, "process": "poisson",
                              "area_fraction": tex})
        uni = {fa: mi.load_dict({"type": "corona", "shape": "sphere", "radius": 2.0, "process": "poisson",
                                 "area_fraction": fa}) for fa in (0.1, 0.4)}
    rng = np.random.default_rng(4)
    wi = np.array([np.sin(0.6), 0.0, np.cos(0.6)])
    wo = _directions(wi, rng, n=500)
    n = len(wo)
    checker = mi.load_dict(tex)
    for uv in ((0.25, 0.25), (0.75, 0.25)):
        si = interaction(n, wi)
        si.uv = mi.Point2f(np.full(n, uv[0], np.float32), np.full(n, uv[1], np.float32))
        fa = round(float(np.asarray(checker.eval_1(si))[0]), 6)       # the square's value
        si_u = interaction(n, wi)
        wov = mi.Vector3f(wo.T.astype(np.float32))
        v, p = layer.eval_pdf(mi.BSDFContext(), si, wov)
        vr, pr = uni[fa].eval_pdf(mi.BSDFContext(), si_u, wov)
        np.testing.assert_allclose(np.asarray(v), np.asarray(vr), rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(np.asarray(p), np.asarray(pr), rtol=1e-5, atol=1e-7)
        xi = rng.random((3, n)).astype(np.float32)
        bs, w = layer.sample(mi.BSDFContext(), si, mi.Float(xi[0]), mi.Point2f(xi[1], xi[2]))
        bsr, wr = uni[fa].sample(mi.BSDFContext(), si_u, mi.Float(xi[0]), mi.Point2f(xi[1], xi[2]))
        np.testing.assert_allclose(np.asarray(w), np.asarray(wr), rtol=1e-5, atol=1e-6)


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_wide_spread_small_spheres(mi_variant):
    # rows far apart in x (a 40 % spread of 0.5 µm droplets, the widest relative row step a table
    # has: SIZE_ROW_DX at the smallest x): each lobe's sampler reaches past 90° (chords up to 1.47
    # since the rows of a spread are at most 2 % of x apart; 1.7 before), where the pdf counts both
    # lobes' densities
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 0.5, "area_fraction": 0.2,
                             "process": "poisson", "size_spread": 0.4})
    assert bsdf.reach > 1.45
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    ok, test = chi2_bsdf(bsdf, 50, ctx, sample_count=300_000, res=101, ires=32)
    assert ok, test.messages
