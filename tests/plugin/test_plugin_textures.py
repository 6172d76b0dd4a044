"""Textures on the corona BSDF: spatially varying, traversable and differentiable layers.

* a circle layer's area fraction, radius and albedo as textures: eval at each texel is the
  material at the local values, energies per texel, chi-square at texels on and between the
  F_a rows, derivatives, re-renders after ``params.update()``, bad textures;
* every opaque scatterer family (ellipse, square, polygon, mixture, soft rectangle) with an F_a
  texture, and mixtures with a radius texture;
* the F_a row the plugin finds for each lane (a guide grid over the rows) is the row a search
  of the rows finds.

References are independent of the plugin's tables and rows: ``Material`` built at the local
parameter values (the exact numpy model), finite differences of the plugin itself for its
derivatives, Mitsuba's chi-square test, and the energy each texel holds.
"""
import drjit as dr
import numpy as np
import pytest

from corona import CoronaError
from corona.parameters import material_from_parameters

from bsdf_checks import assert_eval_matches, bitmap_texture as _bitmap, chi2_bsdf, furnace, smooth_context
from bsdf_checks import transmitted_lobe
from bsdf_checks import uv_interaction as _si

FA_MAP = np.array([[0.05, 0.2], [0.37, 0.61]], dtype=np.float32)   # hard-disk rows and values between
UV = [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]         # the four texel centres
LAMS = (450.0, 520.0, 600.0, 700.0)


def _transmitted(n, seed, theta, spread=0.08):
    rng = np.random.default_rng(seed)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0.0, np.cos(th)])
    d = rng.normal(0.0, spread, (n, 2))            # around the undeviated beam, where the lobe lives
    wo_xy = d - wi[:2]
    keep = np.sum(wo_xy**2, 1) < 0.999
    wo = np.column_stack([wo_xy[keep], -np.sqrt(1 - np.sum(wo_xy[keep] ** 2, 1))])
    return wi, wo


@pytest.fixture(scope="module")
def textured(mi_variant):
    import mitsuba as mi
    return mi.load_dict({"type": "corona", "radius": 3.0, "process": "hard-disk", "albedo": 0.5,
                         "area_fraction": _bitmap(FA_MAP)})


def test_uniform_layer_exposes_value_keys_all_differentiable(mi_variant):
    import mitsuba as mi
    params = mi.traverse(mi.load_dict({"type": "corona", "radius": 3.0, "area_fraction": 0.3}))
    for key in ("area_fraction.value", "radius.value", "albedo.value"):
        assert key in params and params.flags(key) & int(mi.ParamFlags.NonDifferentiable) == 0, key


def test_textured_layer_exposes_its_texture(textured):
    import mitsuba as mi
    params = mi.traverse(textured)
    assert "area_fraction.data" in params and "radius.value" in params


@pytest.mark.parametrize("theta", [0, 40])
def test_eval_is_the_material_at_the_local_area_fraction(textured, theta):
    wi, wo = _transmitted(1500, 3, theta)
    for uv, fa in zip(UV, FA_MAP.ravel()):
        m = material_from_parameters(radius=3.0, process="hard-disk", area_fraction=float(fa))
        # rows every 0.1 % of the lobe; the radial table's own linear interpolation in u
        # (step 0.01) and float32 add up to 1e-4 of the peak on the flanks of dark rings
        assert_eval_matches(textured, transmitted_lobe(m), wi, wo, LAMS, rtol=1e-3, atol=1e-4, uv=uv)


def test_energies_follow_the_local_area_fraction(textured):
    """Sample weights average to the local albedo: F_a² + lobe + ρ(1 - F_a) (white furnace per texel)."""
    for uv, fa in zip(UV, FA_MAP.ravel()):
        m = material_from_parameters(radius=3.0, process="hard-disk", area_fraction=float(fa), albedo=0.5)
        total = furnace(textured, 0.0, uv=uv, seed=5)[0][0]
        expect = m.coherent_transmittance + m.diffuse_transmittance(550.0, 1.0) + m.reflectance
        assert abs(total - expect) < 0.01 * expect + 2e-3, (fa, total, expect)
        assert total <= 1.0 + 3e-3


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("fa", [0.2, 0.37])
def test_chi2_at_local_values_of_a_textured_area_fraction(textured, fa):
    """0.2 sits on a hard-disk table row, 0.37 between two: the mixture of rows is sampled exactly."""
    (u, v), = [uv for uv, f in zip(UV, FA_MAP.ravel()) if abs(f - fa) < 1e-6]
    ok, test = chi2_bsdf(textured, 30, smooth_context(), uv=(u, v))
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_with_a_textured_radius(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "hard-disk", "area_fraction": 0.3,
                         "radius": _bitmap([[0.6, 1.5]])})
    ok, test = chi2_bsdf(bsdf, 20, smooth_context(), uv=(0.25, 0.5))       # radius 0.6, below the table's 1.5
    assert ok, test.messages


def test_radius_scales_the_layer(mi_variant):
    """radius texture value r: the lobe of a layer loaded with radius r (σ/R fixed)."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "hard-disk", "area_fraction": 0.3,
                         "edge_width": 0.1, "radius": _bitmap([[1.0, 2.0]])})
    wi, wo = _transmitted(1000, 4, 20)
    # at r = 1 the edge width (given for the largest radius, 2) is halved with it
    m = material_from_parameters(process="hard-disk", area_fraction=0.3, radius=1.0, edge_width=0.05)
    assert_eval_matches(bsdf, transmitted_lobe(m), wi, wo, LAMS, rtol=2e-3, atol=1e-4, uv=(0.25, 0.5))


def _eval_sum(bsdf, params, key, value, wi, wo, uv=(0.5, 0.5)):
    import mitsuba as mi
    params[key] = value
    params.update()
    return float(np.sum(np.array(bsdf.eval(mi.BSDFContext(), _si(len(wo), wi, uv), mi.Vector3f(wo.T)))))


@pytest.mark.parametrize("key,value,h", [("area_fraction.value", 0.335, 2e-3),
                                         ("radius.value", 2.0, 2e-3),
                                         ("albedo.value", 0.4, 1e-2)])
def test_gradients_match_central_differences(mi_variant, key, value, h):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "hard-disk", "radius": 2.0,
                         "area_fraction": 0.31, "albedo": 0.4})
    params = mi.traverse(bsdf)
    wi, wo = _transmitted(400, 6, 30)
    if key == "albedo.value":                                   # the reflected side
        wo = wo * np.array([1.0, 1.0, -1.0])
    fd = (_eval_sum(bsdf, params, key, value + h, wi, wo) - _eval_sum(bsdf, params, key, value - h, wi, wo)) / (2 * h)
    # reverse mode
    x = mi.Float(value)
    dr.enable_grad(x)
    params[key] = x
    params.update()
    y = dr.sum(dr.sum(bsdf.eval(mi.BSDFContext(), _si(len(wo), wi, (0.5, 0.5)), mi.Vector3f(wo.T))))
    dr.backward(y)
    rev = float(np.asarray(dr.grad(x)).ravel()[0])
    # forward mode
    x2 = mi.Float(value)
    dr.enable_grad(x2)
    params[key] = x2
    params.update()
    y2 = dr.sum(dr.sum(bsdf.eval(mi.BSDFContext(), _si(len(wo), wi, (0.5, 0.5)), mi.Vector3f(wo.T))))
    dr.forward(x2)
    fwd = float(np.asarray(dr.grad(y2)).ravel()[0])
    assert abs(fd) > 0
    assert abs(rev - fd) < 0.01 * abs(fd), (rev, fd)
    assert abs(fwd - fd) < 0.01 * abs(fd), (fwd, fd)


def _scene(bsdf_fa):
    import mitsuba as mi
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 4], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "pane": {"type": "rectangle", "bsdf": {"type": "corona", "radius": 4.0,
                                               "process": "hard-disk", "area_fraction": bsdf_fa}},
        "lamp": {"type": "sphere", "radius": 0.05, "center": [0, 0, -3],
                 "emitter": {"type": "area", "radiance": {"type": "uniform", "value": 200.0}}},
    })


@pytest.mark.slow
@pytest.mark.render
def test_update_rerenders_without_recompiling_and_matches_a_fresh_load(mi_variant):
    import mitsuba as mi
    scene = _scene(0.3)
    params = mi.traverse(scene)
    mi.render(scene, seed=1)
    params["pane.bsdf.area_fraction.value"] = 0.36
    params.update()
    dr.kernel_history_clear()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        img = np.array(mi.render(scene, seed=1))
        hist = dr.kernel_history()
    compiled = [k for k in hist if k.get("type") == dr.KernelType.JIT and not k.get("cache_hit", True)]
    assert not compiled, f"{len(compiled)} kernel(s) recompiled after params.update()"
    fresh = np.array(mi.render(_scene(0.36), seed=1))
    # the fresh layer has a table row at 0.36 itself; the updated one interpolates (rows: 0.1 %)
    np.testing.assert_allclose(img, fresh, rtol=1e-3, atol=1e-5)


def test_bad_textures_fail_at_load_naming_the_parameter(mi_variant):
    import mitsuba as mi
    with pytest.raises(Exception, match="area_fraction"):        # above the hard-disk limit somewhere
        mi.load_dict({"type": "corona", "radius": 2.0, "area_fraction": _bitmap([[0.3, 0.8]])})
    with pytest.raises(Exception, match="area_fraction"):        # negative somewhere
        mi.load_dict({"type": "corona", "radius": 2.0, "area_fraction": _bitmap([[0.3, -0.1]])})
    with pytest.raises(Exception, match="radius"):               # a zero radius
        mi.load_dict({"type": "corona", "radius": _bitmap([[0.0, 1.0]])})
    with pytest.raises(Exception, match="albedo"):
        mi.load_dict({"type": "corona", "radius": 2.0, "albedo": _bitmap([[0.3, 1.2]])})
    with pytest.raises(Exception, match="lattice"):              # F_a sets a lattice's geometry
        mi.load_dict({"type": "corona", "radius": 2.0, "process": "lattice-hex",
                      "area_fraction": _bitmap([[0.3, 0.4]])})


def test_update_outside_the_rows_rebuilds_and_stays_exact(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "radius": 3.0, "area_fraction": 0.2})
    params = mi.traverse(bsdf)
    params["area_fraction.value"] = 0.6                          # beyond 0.2 ± 0.1
    params.update()
    wi, wo = _transmitted(500, 8, 0)
    m = material_from_parameters(radius=3.0, area_fraction=0.6)
    assert_eval_matches(bsdf, transmitted_lobe(m), wi, wo, LAMS, rtol=1e-3, atol=1e-4, uv=(0.5, 0.5))
    with pytest.raises(CoronaError, match="area_fraction"):
        params["area_fraction.value"] = 0.9
        params.update()


# --------------------------------------------------------------------------------------------------
# every opaque scatterer family: F_a textures for anisotropic lobes and mixtures, radius textures
# for mixtures
# --------------------------------------------------------------------------------------------------
#: F_a at the four texel centres; below the hard-disk limit of every shape here (square: ~0.46)
FAMILY_FA_MAP = np.array([[0.05, 0.15], [0.26, 0.33]], dtype=np.float32)
FAMILIES = {
    "ellipse": {"shape": "ellipse", "radius": 2.0, "aspect": 0.6, "angle": 20.0},
    "square": {"shape": "square", "radius": 1.5},
    "polygon": {"shape": "polygon", "sides": 5, "radius": 1.8},
    "mixture": {"shape": "mixture", "mixture": "circle:1.5:0.5, square:1.2:0.5"},
    "soft-rectangle": {"shape": "rectangle", "radius": 1.5, "aspect": 0.5, "edge_width": 0.1},
}


def _check(bsdf, m, wi, wo, uv, rtol=1e-3):
    # rows of S within 0.1 % (linear; the plugin's Hermite is closer), the kernel's float32
    # and its radial S - 1 table (linear in |u|, step 0.01): 1e-4 of the peak on dark fringes
    assert_eval_matches(bsdf, transmitted_lobe(m), wi, wo, LAMS, rtol=rtol, atol=1e-4, uv=uv)


@pytest.fixture(scope="module", params=sorted(FAMILIES))
def family(request, mi_variant):
    import mitsuba as mi
    name = request.param
    bsdf = mi.load_dict({"type": "corona", "process": "hard-disk", "albedo": 0.5, **FAMILIES[name],
                         "area_fraction": _bitmap(FAMILY_FA_MAP)})
    return name, bsdf


@pytest.mark.parametrize("theta", [0, 35])
def test_every_family_is_the_material_at_the_local_area_fraction(family, theta):
    name, bsdf = family
    assert bsdf.n_rows > 2                                  # rows over the texture's range
    wi, wo = _transmitted(1200, 3, theta)
    for uv, fa in zip(UV, FAMILY_FA_MAP.ravel()):
        m = material_from_parameters(process="hard-disk", area_fraction=float(fa), **FAMILIES[name])
        _check(bsdf, m, wi, wo, uv)


def test_a_rows_lobe_differs_from_the_loaded_one(family):
    """Negative control: the lobe at F_a = 0.05 is not the one at the texture's largest F_a."""
    import mitsuba as mi
    name, bsdf = family
    wi, wo = _transmitted(800, 4, 0, spread=0.03)
    val = np.array(bsdf.eval(mi.BSDFContext(), _si(len(wo), wi, UV[0]), mi.Vector3f(wo.T)))
    m = material_from_parameters(process="hard-disk", area_fraction=float(FAMILY_FA_MAP.max()), **FAMILIES[name])
    ref = m.lobe(wo[:, :2] + wi[:2], LAMS[0]) * np.abs(wo[:, 2]) * (FAMILY_FA_MAP[0, 0] / FAMILY_FA_MAP.max())
    assert np.max(np.abs(val[0] - ref)) > 0.05 * ref.max()


def test_energy_per_texel(family):
    """Sample weights average to each texel's own energy: coherent + lobe + reflection (white furnace)."""
    name, bsdf = family
    for uv, fa in zip(UV, FAMILY_FA_MAP.ravel()):
        m = material_from_parameters(process="hard-disk", area_fraction=float(fa), albedo=0.5, **FAMILIES[name])
        total = furnace(bsdf, 0.0, uv=uv, seed=5)[0][0]
        expect = m.coherent_transmittance + m.diffuse_transmittance(550.0, 1.0) + m.reflectance
        assert abs(total - expect) < 0.01 * expect + 3e-3, (name, fa, total, expect)
        assert total <= 1.0 + 3e-3


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("name", ["ellipse", "mixture"])
def test_chi2_between_rows(mi_variant, name):
    """F_a = 0.26 lies between two rows; the lobe is sampled from the table at the lowest F_a."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "hard-disk", **FAMILIES[name],
                         "area_fraction": _bitmap(FAMILY_FA_MAP)})
    assert not np.any(np.isclose(bsdf.fa_rows_np, 0.26, rtol=0, atol=1e-6))
    ok, test = chi2_bsdf(bsdf, 20, smooth_context(), uv=UV[2])
    assert ok, test.messages


MIXTURE = "circle:2:0.5, square:1.5:0.3, circle:1:0.2"


def test_mixture_radius_texture_scales_every_size(mi_variant):
    """radius texture r on a mixture: the mixture with every radius times r / (its largest radius)."""
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "shape": "mixture", "mixture": MIXTURE, "process": "hard-disk",
                         "area_fraction": 0.3, "edge_width": 0.1, "radius": _bitmap([[1.0, 2.0]])})
    assert "radius.data" in mi.traverse(bsdf)
    wi, wo = _transmitted(1000, 4, 20)
    for uv, r in (((0.25, 0.5), 1.0), ((0.75, 0.5), 2.0)):
        k = r / 2.0
        scaled = f"circle:{2 * k}:0.5, square:{1.5 * k}:0.3, circle:{1 * k}:0.2"
        # lengths given (edge_width) belong to the largest radius at load, 2, and scale with it
        m = material_from_parameters(shape="mixture", mixture=scaled, process="hard-disk",
                                     area_fraction=0.3, edge_width=0.1 * k)
        _check(bsdf, m, wi, wo, uv, rtol=2e-3)
    # negative control: at r = 1 it is not the mixture as given
    m = material_from_parameters(shape="mixture", mixture=MIXTURE, process="hard-disk", area_fraction=0.3,
                                 edge_width=0.1)
    val = np.array(bsdf.eval(mi.BSDFContext(), _si(len(wo), wi, (0.25, 0.5)), mi.Vector3f(wo.T)))
    ref = m.lobe(wo[:, :2] + wi[:2], LAMS[0]) * np.abs(wo[:, 2])
    assert np.max(np.abs(val[0] - ref)) > 0.05 * ref.max()


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_with_a_mixture_radius_texture(mi_variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "shape": "mixture", "mixture": MIXTURE, "process": "hard-disk",
                         "area_fraction": 0.3, "radius": _bitmap([[0.8, 2.0]])})
    ok, test = chi2_bsdf(bsdf, 20, smooth_context(), uv=(0.25, 0.5))
    assert ok, test.messages


# --------------------------------------------------------------------------------------------------
# the F_a row of each lane: the plugin's guide grid over the rows against a search of the rows
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("process,lo,hi", [pytest.param("hard-disk", 0.005, 0.6, marks=pytest.mark.slow),  # 1.7 s CPU
                                            ("rsa", 0.01, 0.5)])
def test_row_of_each_area_fraction(mi_variant, process, lo, hi):
    import mitsuba as mi
    probe = mi.load_dict({"type": "corona", "radius": 5.0, "process": process,
                          "area_fraction": 0.5 * (lo + hi)})
    rng = np.random.default_rng(3)
    # random values, the rows themselves and their float32 neighbours (where rounding bites)
    rows = probe.fa_rows_np.astype(np.float32)
    vals = np.concatenate([[lo, hi], rng.uniform(lo, hi, 3000), rows, np.nextafter(rows, 0),
                           np.nextafter(rows, 1)]).astype(np.float32)
    vals = np.clip(vals, lo, hi)
    n = vals.size
    bsdf = mi.load_dict({"type": "corona", "radius": 5.0, "process": process,
                         "area_fraction": {"type": "bitmap", "bitmap": mi.Bitmap(vals[None, :, None]),
                                           "raw": True, "filter_type": "nearest"}})
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(((np.arange(n) + 0.5) / n).astype(np.float32), np.full(n, 0.5, np.float32))
    layer = bsdf._layer(si, True)
    fa, j, t = (np.array(layer[k]) for k in ("fa", "j", "t"))
    rows = np.array(bsdf.fa_rows)
    ref = np.clip(np.searchsorted(rows, fa, side="right") - 1, 0, bsdf.n_rows - 2)
    exact = j == ref
    # elsewhere only float32 rounding at a guide cell's edge: fa one ulp below the next row
    assert np.all(exact | ((j == ref + 1) & (np.abs(t) < 1e-5))), np.where(~exact)
    assert np.mean(exact) > 0.999
    assert np.all((t > -1e-5) & (t <= 1.0))
    np.testing.assert_allclose(rows[j] + t * (rows[j + 1] - rows[j]), fa, atol=1e-6)


def test_anisotropic_sampling_table_is_the_layer_scaled_once(mi_variant, monkeypatch):
    # a textured F_a on an anisotropic lobe samples from the table at the lowest F_a: the same layer
    # (its absolute lengths scaled once to the rows' radius cover), not scaled a second time
    import mitsuba as mi
    import corona.mitsuba.bsdf as plugin
    from bsdf_checks import bitmap_texture
    seen = []
    real = plugin.material_from_parameters

    def spy(**kw):
        seen.append(kw)
        return real(**kw)
    monkeypatch.setattr(plugin, "material_from_parameters", spy)
    mi.load_dict({"type": "corona", "shape": "square", "radius": 2.0, "process": "hard-disk",
                  "edge_width": 0.1, "area_fraction": bitmap_texture([[0.1, 0.3], [0.3, 0.3]])})
    layer, low = seen[-2], seen[-1]                # the layer at its cover, then its lowest-F_a table
    assert low["area_fraction"] == pytest.approx(0.1, rel=1e-6)
    assert low["radius"] == layer["radius"]
    assert low["edge_width"] == pytest.approx(layer["edge_width"], rel=1e-12)
