"""Radius textures of sphere layers: each texel is the Mie layer of its radius.

A sphere's lobe depends on ``x = 2π r/λ`` and the index ``m(λ)``.  The layer's
rows (corona.model.mie.material.SphereMaterial with ``radius_cover``) run in x
from ``2π r_lo/830 nm`` to ``2π r_hi/360 nm`` of the texture's range and each
lane reads them at ``x = 2π r(uv)/λ``; ``S(q r)`` (hard core) and the forward
energies are tabulated in ``u = q r`` and x, so they follow.  A row holds the
index of one radius at ``λ = 2π r_ref/x``: exact for a constant index, within
the phase bound (``RADIUS_INDEX_PHASE``) for water, which refuses wider ranges.
"""
import warnings

import numpy as np
import pytest

from bsdf_checks import assert_eval_matches, bitmap_texture, chi2_bsdf, furnace, run_chi2

WAVELENGTHS = (450.0, 520.0, 600.0, 700.0)
#: texel (uv) -> radius [µm] of the bitmap below; 1.83 and 2.0 fall between rows at every wavelength
TEXELS = {(0.25, 0.25): 1.6, (0.75, 0.25): 2.0, (0.25, 0.75): 2.4, (0.75, 0.75): 1.83}
GRID = [[1.6, 2.0], [2.4, 1.83]]


def _load(**extra):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mi.load_dict({"type": "corona", "shape": "sphere", "area_fraction": 0.2, **extra})


def _directions(wi, rng, n=1500):
    """Random directions plus many near the forward and backward peaks."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    fwd = -wi + rng.normal(0.0, 0.08, (n, 3))
    back = wi + rng.normal(0.0, 0.3, (n // 2, 3))
    out = np.concatenate([v, fwd / np.linalg.norm(fwd, axis=1, keepdims=True),
                          back / np.linalg.norm(back, axis=1, keepdims=True)])
    return out


@pytest.fixture(scope="module")
def textured(mi_variant):
    # a constant index: the rows in x are exact for every radius (no index to carry)
    return {p: _load(process=p, ior=1.33, radius=bitmap_texture(GRID)) for p in ("poisson", "hard-disk")}


@pytest.mark.parametrize("process", ["poisson", "hard-disk"])
def test_texels_match_the_numpy_layer_of_their_radius(textured, process):
    # each texel against the numpy layer of its radius: on the plugin's own rows (at_radius: float32
    # rounding) and on that radius's own table (other rows: their interpolation, < 1e-3 of the
    # peak); negative control: the neighbouring texel's radius differs by more than 1 % of the peak
    from corona.parameters import material_from_parameters
    bsdf = textured[process]
    assert bsdf.radius_cover == pytest.approx((1.6, 2.4))
    xr = bsdf.material.rows["x"]
    assert xr[0] <= 2 * np.pi * 1.6 / 0.83 * (1 + 1e-6) and xr[-1] >= 2 * np.pi * 2.4 / 0.36 * (1 - 1e-6)
    rng = np.random.default_rng(4)
    for deg in (0, 40):
        wi = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
        wo = _directions(wi, rng)
        for uv, r in TEXELS.items():
            r = float(np.float32(r))
            for lam in WAVELENGTHS:       # between rows: the lookup interpolates
                x = 2 * np.pi * r / (lam * 1e-3)
                assert np.min(np.abs(xr - x)) > 1e-6 * x or r in (1.6, 2.4)
            same = bsdf.material.at_radius(r)
            val, ref, _ = assert_eval_matches(bsdf, same.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=2e-5,
                                              peak="all", uv=uv)
            own = material_from_parameters(shape="sphere", radius=r, process=process, area_fraction=0.2,
                                           ior=1.33)
            assert_eval_matches(bsdf, own.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=1e-3, peak="all", uv=uv)
            other = bsdf.material.at_radius(2.0 if r != 2.0 else 1.83)
            ref2 = np.stack([other.eval(wi, wo, lam) for lam in WAVELENGTHS])
            assert np.max(np.abs(val - ref2)) > 1e-2 * ref.max(), (uv, r)


def test_water_texture_within_its_span_and_refused_beyond(mi_variant):
    # water: the rows hold the index of the middle radius, so a texel of another radius reads it at
    # λ r_ref/r; within the span (2 µm: a factor 1.02) the texel is within 1.5 % of the peak of its
    # own table (measured 0.9 %, docs/layer.md#sphere-radius-textures); a wider range is refused
    from corona import CoronaError
    from corona.parameters import material_from_parameters
    bsdf = _load(radius=bitmap_texture([[1.97, 2.0], [2.03, 2.0]]))
    rng = np.random.default_rng(5)
    wi = np.array([0.0, 0.0, 1.0])
    wo = _directions(wi, rng)
    for uv, r in (((0.25, 0.25), 1.97), ((0.25, 0.75), 2.03)):
        r = float(np.float32(r))
        assert_eval_matches(bsdf, bsdf.material.at_radius(r).eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=2e-5,
                            peak="all", uv=uv)
        own = material_from_parameters(shape="sphere", radius=r, area_fraction=0.2)
        assert_eval_matches(bsdf, own.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=1.5e-2, peak="all", uv=uv)
    with pytest.raises(CoronaError, match=r"corona BSDF: the radius texture: radius=1\.6 … 2\.4 is out of "
                       r"range for shape='sphere' with a dispersive ior \(water\).*allowed radii within a factor "
                       r"1\.02 of 1\.96 µm, or a constant ior for any range"):
        import mitsuba as mi
        try:
            mi.load_dict({"type": "corona", "shape": "sphere", "radius": bitmap_texture(GRID)})
        except RuntimeError as err:       # Mitsuba wraps the plugin's error
            raise CoronaError(str(err).splitlines()[-1].split("CoronaError: ")[-1]) from None


@pytest.mark.slow     # 2 s of CPU warm per process
@pytest.mark.parametrize("process", ["poisson", "hard-disk"])
def test_furnace_at_each_texel(textured, process):
    # what a texel returns of what it receives is its own numpy layer's directional albedo, <= 1
    bsdf = textured[process]
    for uv, r in TEXELS.items():
        same = bsdf.material.at_radius(float(np.float32(r)))
        for deg in (0, 60):
            mean, err = furnace(bsdf, deg, WAVELENGTHS, n=200_000, uv=uv)
            ref = np.array([same.directional_albedo(np.cos(np.radians(deg)), lam, n_phi=96)["total"]
                            for lam in WAVELENGTHS])
            assert np.all(mean <= 1.0 + 3 * err + 1e-4), (uv, deg, mean)
            assert mean == pytest.approx(ref, abs=5e-3), (uv, deg, mean, ref)


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("uv,deg", [((0.25, 0.75), 0), ((0.75, 0.75), 40)])
def test_chi2_at_a_textured_point(textured, uv, deg):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    test = chi2_bsdf(textured["hard-disk"], deg, ctx, uv=uv, sample_count=400_000, res=101, ires=32)[1]
    assert run_chi2(test), test.messages


def test_no_nan_at_the_bounds_and_updates(mi_variant, upload_branch):
    # a texture at its bounds, bilinear between them (values inside the range), then updated: inside
    # the rows' radii nothing is rebuilt; beyond them the rows are rebuilt about the new range; bad
    # values are one line naming the radius
    import drjit as dr
    import mitsuba as mi

    from bsdf_checks import plugin_eval
    tex = {"type": "bitmap", "bitmap": mi.Bitmap(np.array([[0.5, 0.8], [0.8, 0.5]], np.float32)[..., None]),
           "raw": True, "filter_type": "bilinear"}
    bsdf = _load(radius=tex, ior=1.33, process="hard-disk")
    params = mi.traverse(bsdf)
    rng = np.random.default_rng(8)
    wi = np.array([0.3, 0.0, np.sqrt(0.91)])
    wo = _directions(wi, rng, n=500)
    for uv in ((0.0, 0.0), (0.25, 0.25), (0.5, 0.5), (0.999, 0.001), (1.0, 1.0)):
        val, pdf = plugin_eval(bsdf, wi, wo, WAVELENGTHS, uv=uv)
        assert np.all(np.isfinite(val)) and np.all(np.isfinite(pdf)), uv
        mean, _ = furnace(bsdf, 30, WAVELENGTHS, n=50_000, uv=uv)
        assert np.all(np.isfinite(mean)) and np.all(mean <= 1.0 + 5e-3), (uv, mean)
    material = bsdf.material
    params["radius.data"] = mi.TensorXf(np.array([[0.55, 0.8], [0.7, 0.5]], np.float32)[..., None])
    params.update()
    assert bsdf.material is material
    params["radius.data"] = mi.TensorXf(np.array([[0.4, 0.8], [1.1, 0.5]], np.float32)[..., None])
    params.update()
    assert bsdf.material is not material and bsdf.radius_cover == pytest.approx((0.4, 1.1))
    val, pdf = plugin_eval(bsdf, wi, wo, WAVELENGTHS, uv=(0.25, 0.75))
    assert np.all(np.isfinite(val)) and np.all(np.isfinite(pdf))
    for bad in (0.0, -1.0, float("nan"), 30.0):
        params["radius.data"] = mi.TensorXf(np.array([[bad, 0.8], [0.7, 0.5]], np.float32)[..., None])
        with pytest.raises(Exception, match=r"radius=.* is out of range for shape='sphere'; allowed \(0, 25\] µm"):
            params.update()
    dr.eval()


def test_uniform_radius_updates_without_a_rebuild(mi_variant, upload_branch):
    # radius.value within the rows' radii: the same tables, the value the numpy layer of that radius
    # on them; beyond them: the rows are rebuilt about the new value (a new kernel)
    import mitsuba as mi
    bsdf = _load(radius=2.0, ior=1.33)
    lo, hi = bsdf.radius_cover
    assert lo == pytest.approx(2.0 / 1.05) and hi == pytest.approx(2.0 * 1.05)
    params = mi.traverse(bsdf)
    material = bsdf.material
    rng = np.random.default_rng(9)
    wi = np.array([0.0, 0.0, 1.0])
    wo = _directions(wi, rng, n=500)
    import drjit as dr
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for k, r in enumerate((2.07, 1.93, 2.01)):
            dr.kernel_history()
            params["radius.value"] = r
            params.update()
            assert bsdf.material is material
            assert_eval_matches(bsdf, material.at_radius(float(np.float32(r))).eval, wi, wo, WAVELENGTHS,
                                rtol=0.0, atol=2e-5, peak="all")
            jit = [h for h in dr.kernel_history() if h.get("type") == dr.KernelType.JIT]
            if k:       # the same kernels: the radius is an opaque value
                assert jit and all(h.get("cache_hit") for h in jit), jit
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    params["radius.value"] = 2.5
    params.update()
    assert bsdf.material is not material and bsdf.radius_cover == pytest.approx((2.5 / 1.05, 2.5 * 1.05))
    assert_eval_matches(bsdf, bsdf.material.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=2e-5, peak="all")
    # water: the rows of a uniform radius serve the span its index allows (2 µm: a factor 1.02)
    water = _load(radius=2.0)
    assert water.radius_cover[1] / 2.0 == pytest.approx(1.0201, abs=2e-4)
