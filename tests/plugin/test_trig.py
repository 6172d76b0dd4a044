"""Sines and cosines of the plugin's kernels: the same to float precision on every backend.

Dr.Jit lowers ``dr.sin`` / ``dr.cos`` of float32 on CUDA to the GPU's ``sin.approx.ftz.f32`` /
``cos.approx.ftz.f32``, whose error is absolute (about 2^-21.4 within [-π, π], more beyond): a
rectangle's ``sinc`` at ``q a / 2 = 2.5e-3`` (550 nm, wo = (-0.389, -0.164, -0.907)) was off by
1.3e-4 relative on an H200.  The kernels call :func:`corona.mitsuba.common.sincos` (the argument
reduced to [-π, π] with 2π in three float32 parts, then Dr.Jit's polynomial ``dr.sincos``, the
same on every backend) instead.  Here: the reduction over a wide range, the kernel's sinc at
large arguments against float64, the plugin's analytic lobes with ``dr.sin`` / ``dr.cos``
replaced by a model of the GPU instructions (they must not change), and no plugin module
calling ``dr.sin`` / ``dr.cos``.
"""
import ast
import pathlib

import drjit as dr
import numpy as np
import pytest

from bsdf_checks import assert_eval_matches, transmitted_lobe

SRC = pathlib.Path(__file__).resolve().parents[2] / "src" / "corona" / "mitsuba"


def _wide(n=400_000, seed=0):
    """float32 angles: log-uniform magnitudes 1e-6 .. 1e6 of both signs, and the float32 values
    nearest multiples of π/2 up to 1e5 (where the reduced angle is small)."""
    rng = np.random.default_rng(seed)
    x = 10.0 ** rng.uniform(-6, 6, n) * rng.choice([-1.0, 1.0], n)
    k = rng.integers(1, int(1e5 / (np.pi / 2)), n // 4) * rng.choice([-1, 1], n // 4)
    return np.concatenate([x, k * (np.pi / 2)]).astype(np.float32)


def test_reduce_angle_is_within_an_ulp_over_a_wide_range(mi_variant):
    import mitsuba as mi

    from corona.mitsuba.common import reduce_angle
    x = _wide()
    r = np.asarray(reduce_angle(mi.Float(x)), dtype=np.float64)
    x64 = x.astype(np.float64)                    # the float32 value taken as exact
    ref = x64 - 2 * np.pi * np.round(x64 / (2 * np.pi))
    d = r - ref
    d -= 2 * np.pi * np.round(d / (2 * np.pi))    # (k may round the other way at an odd multiple of π)
    # within [-π, π] but for k's rounding of x/2π in float32 (beyond by at most 2π ulp(x/2π))
    slack = 2 * np.pi * np.spacing(np.abs(x64 / (2 * np.pi)).astype(np.float32)) + 1e-6
    assert np.all(np.abs(r) <= np.pi + slack), np.max(np.abs(r) - np.pi - slack)
    ulp = np.spacing(np.abs(ref).astype(np.float32)).astype(np.float64)
    bound = 1.5 * ulp + np.abs(np.round(x64 / (2 * np.pi))) * 1e-15
    worst = np.argmax(np.abs(d) / bound)
    assert np.abs(d[worst]) <= bound[worst], (x[worst], r[worst], ref[worst])


def test_sincos_is_float_precise_where_drjit_alone_is_not(mi_variant):
    import mitsuba as mi

    from corona.mitsuba.common import sincos
    x = _wide()
    s, c = (np.asarray(v, dtype=np.float64) for v in sincos(mi.Float(x)))
    x64 = x.astype(np.float64)
    err = max(np.max(np.abs(s - np.sin(x64))), np.max(np.abs(c - np.cos(x64))))
    assert err < 2e-7, err
    # relative where the sine is small (a sinc near its peak, a zero of it)
    small = np.abs(np.sin(x64)) > 1e-30
    rel = np.abs(s - np.sin(x64))[small] / np.abs(np.sin(x64))[small]
    tiny_x = np.abs(x64) < 1.0
    assert np.max(rel[tiny_x[small]]) < 3e-7
    # negative control: Dr.Jit's own reduction alone misses that bound above 3·10⁴
    big = mi.Float(np.linspace(3e4, 1e5, 200_001).astype(np.float32))
    plain = np.max(np.abs(np.asarray(dr.sin(big), dtype=np.float64)
                          - np.sin(np.asarray(big, dtype=np.float64))))
    assert plain > 2e-7, plain


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3, 3e4, 1e5])
def test_sinc_product_matches_float64_at_large_arguments(mi_variant, scale):
    import mitsuba as mi

    from corona.mitsuba.kernels import sinc_product
    rng = np.random.default_rng(1)
    x = (rng.uniform(-1, 1, 100_000) * scale).astype(np.float32)
    y = (rng.uniform(-1, 1, 100_000) * scale).astype(np.float32)
    v = np.asarray(sinc_product(mi.Float(x), mi.Float(y)), dtype=np.float64)
    x64, y64 = x.astype(np.float64), y.astype(np.float64)
    sinc = lambda t: np.where(t == 0, 1.0, np.sin(t) / np.where(t == 0, 1.0, t))
    ref = sinc(x64) * sinc(y64)
    # sin to 2e-7 absolute, the quotient to a few ulps: |Δ| <= 2e-7 (1/|x| + 1/|y|) |other| + 4 ulp
    amp = lambda t: np.minimum(1.0, 1.0 / np.maximum(np.abs(t), 1e-30))
    bound = 2e-7 * (amp(x64) * np.abs(sinc(y64)) + amp(y64) * np.abs(sinc(x64))) + 5e-7 * np.abs(ref)
    worst = np.argmax(np.abs(v - ref) / bound)
    assert abs(v[worst] - ref[worst]) <= bound[worst], (x[worst], y[worst], v[worst], ref[worst])


def _approximate(fn):
    """A model of the GPU's sin.approx / cos.approx: the angle in revolutions in float32
    (``x · (1/2π)``), its fraction on a grid of 2^-22 revolutions (an absolute error up to
    7.5e-7, growing with |x| by the float32 product), then exact."""
    import mitsuba as mi

    def approx(x):
        t = x * float(np.float32(0.5 / np.pi))
        f = t - dr.round(t)
        f = dr.round(f * 4194304.0) * (1.0 / 4194304.0)
        return dr.sincos(mi.Float(2.0 * np.pi) * f)[0 if fn == "sin" else 1]
    return approx


MATERIALS = {
    "rectangle": {"shape": "rectangle", "radius": 0.25, "aspect": 1.5, "process": "poisson"},
    "square": {"shape": "square", "radius": 0.3, "process": "poisson"},
    "mixture": {"shape": "mixture", "mixture": "circle:0.35:0.6, square:0.3:0.4", "process": "poisson"},
    "ellipse": {"shape": "ellipse", "radius": 0.3, "aspect": 1.6, "angle": 20, "process": "poisson"},
    "hexagon": {"shape": "polygon", "sides": 6, "radius": 0.35, "process": "poisson"},
}


@pytest.mark.parametrize("name", list(MATERIALS))
def test_analytic_lobes_do_not_use_the_gpus_approximate_sine(mi_variant, monkeypatch, name):
    """The analytic kernels against the tabulated lobe (test_plugin_materials' bound) with
    ``dr.sin`` / ``dr.cos`` replaced by :func:`_approximate`: a kernel that called them would
    fail as the rectangle did on CUDA (the model moves its eval at the H200's worst direction by
    1.7e-4); the directions sampled from the lobe and that direction."""
    import mitsuba as mi

    from corona.parameters import material_from_parameters
    params = MATERIALS[name]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", **params})
        m = material_from_parameters(**params)
    assert bsdf.kernel.kind == "analytic"
    monkeypatch.setattr(dr, "sin", _approximate("sin"))
    monkeypatch.setattr(dr, "cos", _approximate("cos"))
    rng = np.random.default_rng(0)
    wi = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    d = m.sample(rng.random((3000, 2)), 550.0)
    wo_xy = np.concatenate([d - wi[:2], [[-0.38873023, -0.16448995]]])
    wo_xy = wo_xy[np.hypot(wo_xy[:, 0], wo_xy[:, 1]) < 0.99]
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy**2).sum(1))])
    assert_eval_matches(bsdf, transmitted_lobe(m, tabulated=True), wi, wo, (550.0,) * 4,
                        rtol=1e-4, atol=1e-5)


def test_no_plugin_module_calls_drjits_sin_or_cos():
    """``dr.sin`` / ``dr.cos`` are CUDA's approximate instructions: the plugin's modules take
    sines and cosines from :func:`corona.mitsuba.common.sincos` (``dr.sincos``, a polynomial on
    every backend, directly only where the angle is within [0, 2π])."""
    found = []
    for path in sorted(SRC.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "dr" \
                    and node.attr in ("sin", "cos"):
                found.append(f"{path.name}:{node.lineno} dr.{node.attr}")
    assert not found, found
