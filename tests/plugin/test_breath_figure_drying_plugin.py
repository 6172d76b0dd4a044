"""The Mitsuba plugin with a ``dry_time`` texture (process=breath-figure, the fading phase; issue 46):
each lane against the numpy model at its own dry time, a uniform texture against the float, a texel's
derivative against central differences, chi-square of sample against pdf, and the white furnace."""
import numpy as np
import pytest

from corona.model.processes.breath_figure import dry_time_range
from corona.parameters import material_from_parameters

LAMS = (420.0, 520.0, 640.0, 780.0)
BREATH = 20.0
#: The dry times the table covers after 20 s of growth (0 to 90 % of the water gone, ~18 s).
HI = dry_time_range(BREATH)[1]


def _model(tau):
    return material_from_parameters(process="breath-figure", breath_time=BREATH, dry_time=float(tau))


def _cut(tau, n=200, lam=450.0):
    """Transmitted directions along a cut through the lobe at dry time ``tau``: rings u = q R in [0.3, 12]."""
    R = _model(tau).process.mean_radius
    d = np.linspace(0.3, 12.0, n) / R * (lam * 1e-3) / (2 * np.pi)
    return np.array([0.0, 0.0, 1.0]), np.column_stack([d, 0 * d, -np.sqrt(1 - d * d)])


def _load(values, **extra):
    import mitsuba as mi

    from bsdf_checks import bitmap_texture
    return mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": BREATH,
                         "dry_time": bitmap_texture(values), **extra})


def test_dry_time_texture_lanes_match_the_model_at_their_times(mi_variant):
    """Texels at 0 s (growth), 0.35 HI (between rows) and 0.8 HI: each lane's lobe is the model's at its
    own dry time within 2 % + 0.5 % of the peak; negative control: the 0.35 HI lane is not the model
    at 0.25 HI."""
    from bsdf_checks import assert_eval_matches, transmitted_lobe
    taus = [0.0, 0.35 * HI, 0.8 * HI]
    bsdf = _load([taus])
    assert bsdf.time_name == "dry_time" and bsdf.time_cover == pytest.approx((0.0, 0.8 * HI))
    for i, tau in enumerate(taus):
        wi, wo = _cut(tau)
        assert_eval_matches(bsdf, transmitted_lobe(_model(tau)), wi, wo, LAMS, rtol=0.02, atol=0.005,
                            uv=((i + 0.5) / 3, 0.5))
    wi, wo = _cut(0.35 * HI)
    with pytest.raises(AssertionError):
        assert_eval_matches(bsdf, transmitted_lobe(_model(0.25 * HI)), wi, wo, LAMS, rtol=0.02, atol=0.005,
                            uv=(0.5, 0.5))


def test_uniform_dry_time_texture_is_the_uniform_parameter(mi_variant):
    import mitsuba as mi

    from bsdf_checks import plugin_eval
    tau = 0.5 * HI
    tex = _load([[tau, tau]])
    flat = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": BREATH, "dry_time": tau})
    wi, wo = _cut(tau)
    a, _ = plugin_eval(tex, wi, wo, LAMS, uv=(0.25, 0.5))
    b, _ = plugin_eval(flat, wi, wo, LAMS)
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=1e-4 * b.max())


@pytest.mark.parametrize("values, extra, words", [
    ([[0.0, 30.0]], {}, ("dry_time texture spans [0, 30] s", "within [0, 18.", "breath_time=20")),
    ([[-1.0, 5.0]], {}, ("dry_time texture spans [-1, 5] s",)),
    ([[1.0, 5.0]], {"process": "hard-disk"}, ("dry_time can be a texture only",)),
])
def test_bad_dry_time_texture_is_one_clear_error(mi_variant, values, extra, words):
    with pytest.raises(Exception, match="dry_time") as err:      # (Mitsuba's loader wraps the CoronaError)
        _load(values, **extra)
    for w in words:
        assert w in str(err.value), str(err.value)


def test_both_times_textured_is_one_clear_error(mi_variant):
    import mitsuba as mi

    from bsdf_checks import bitmap_texture
    with pytest.raises(Exception, match="cannot both vary"):
        mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": bitmap_texture([[10.0, 20.0]]),
                      "dry_time": bitmap_texture([[1.0, 2.0]])})
    with pytest.raises(Exception, match="cannot both vary"):
        mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": bitmap_texture([[10.0, 20.0]]),
                      "dry_time": 1.0})


def test_dry_time_texel_derivative_matches_central_differences(mi_variant):
    """d/d(one texel of dry_time) of the lobe summed along a cut, reverse and forward mode, against the
    central difference of the same BSDF after params.update() (no rebuild between the three)."""
    import drjit as dr
    import mitsuba as mi

    from bsdf_checks import uv_interaction
    lo, mid, hi = 0.2 * HI, 0.4 * HI, 0.6 * HI
    bsdf = _load([[mid, lo], [lo, hi]])
    params = mi.traverse(bsdf)
    assert "dry_time.data" in params
    wi, wo = _cut(mid, n=300)

    def q(x):
        data = dr.select(dr.arange(mi.UInt32, 4) == 0, x, dr.select(dr.arange(mi.UInt32, 4) == 3,
                                                                    mi.Float(hi), mi.Float(lo)))
        params["dry_time.data"] = mi.TensorXf(data, shape=(2, 2, 1))
        params.update()
        return dr.sum(dr.sum(bsdf.eval(mi.BSDFContext(), uv_interaction(len(wo), wi, (0.25, 0.25), LAMS),
                                       mi.Vector3f(wo.T))))
    h = 0.02
    fd = (float(q(mi.Float(mid + h))[0]) - float(q(mi.Float(mid - h))[0])) / (2 * h)
    x = mi.Float(mid)
    dr.enable_grad(x)
    y = q(x)
    dr.backward(y)
    ad = float(np.asarray(dr.grad(x)).ravel()[0])
    x = mi.Float(mid)
    dr.enable_grad(x)
    y = q(x)
    dr.forward(x)
    fwd = float(np.asarray(dr.grad(y)).ravel()[0])
    assert abs(fd) > 1e-3 * abs(float(dr.detach(y)[0])) / HI      # the lobe does change with dry time here
    assert abs(ad - fd) <= 0.02 * abs(fd), (ad, fd)
    assert abs(fwd - fd) <= 0.02 * abs(fd), (fwd, fd)


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_with_a_dry_time_texture(mi_variant):
    """sample against pdf at a lane between the rows (0.35 HI, uv = (0, 0))."""
    from test_breath_figure_plugin import _chi2_turned
    bsdf = _load([[0.35 * HI, 0.0]])
    ok, test = _chi2_turned(bsdf, 30.0)
    assert ok, test.messages


@pytest.mark.slow
def test_furnace_with_a_dry_time_texture_matches_the_model(mi_variant):
    """A lane between the rows (0.35 HI): the mean sample weight within 0.5 % of the numpy model's
    directional albedo at that dry time, at 0° and 60°; no energy gain."""
    from bsdf_checks import furnace
    tau = 0.35 * HI
    bsdf = _load([[tau, 0.0, 0.9 * HI]])
    model = _model(tau)
    for deg in (0.0, 60.0):
        mean, err = furnace(bsdf, deg, LAMS, n=200_000, seed=5, uv=(1 / 6, 0.5))
        ref = np.array([model.directional_albedo(np.cos(np.radians(deg)), lam)["total"] for lam in LAMS])
        assert np.all(mean <= 1.0 + 4 * err), (deg, mean, err)
        assert np.all(np.abs(mean - ref) <= 0.005 * ref + 4 * err), (deg, mean, ref, err)
