"""shape=annulus (corona.model.shapes.annulus), the family added through the registry alone, and
the user's ring of docs/adding_a_scatterer.md: form factor against independent references, the
brute force, the plugin against Material.lobe."""
import math
import os
import re

import numpy as np
import pytest
from scipy import integrate, special

import corona
from corona.model.shapes.annulus import Annulus
from corona.parameters import SPEC, material_from_parameters

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _two_airy(q, R, r):
    """|π R² 2 J1(qR)/(qR) - π r² 2 J1(qr)/(qr)|² / (π (R² - r²)), written out (q > 0)."""
    a = np.pi * R * R * 2 * special.j1(q * R) / (q * R) - np.pi * r * r * 2 * special.j1(q * r) / (q * r)
    return a * a / (np.pi * (R * R - r * r))


@pytest.mark.parametrize("R,ratio", [(1.0, 0.5), (3.0, 0.2), (2.0, 0.85)])
def test_form_factor_is_the_difference_of_two_airy_amplitudes(R, ratio):
    a = Annulus(R, ratio)
    q = np.linspace(0.01, 40.0 / R, 700)
    ref = _two_airy(q, R, ratio * R)
    assert np.allclose(a.form_factor_radial(q), ref, rtol=1e-10, atol=1e-12 * ref.max())
    # the 2D form factor at any direction of q is the radial one (an isotropic shape)
    phi = np.random.default_rng(0).uniform(0, 2 * np.pi, q.size)
    q2 = np.column_stack([q * np.cos(phi), q * np.sin(phi)])
    assert np.allclose(a.form_factor(q2), ref, rtol=1e-10, atol=1e-12 * ref.max())
    assert math.isclose(a.form_factor_radial(0.0), a.area, rel_tol=1e-12)
    # negative control: the two disks' intensities added (no interference) differ by far
    wrong = (np.pi * (R**2 * 2 * special.j1(q * R) / (q * R))**2
             + np.pi * ((ratio * R)**2 * 2 * special.j1(q * ratio * R) / (q * ratio * R))**2) / (1 - ratio**2)
    assert np.max(np.abs(wrong - ref)) > 0.1 * ref.max()


def test_amplitude_is_the_hankel_transform_of_the_ring():
    """Â(q) = 2π ∫_r^R J0(qρ) ρ dρ by quadrature (no Bessel identity used)."""
    a = Annulus(2.0, 0.4)
    for q in (0.0, 0.3, 1.7, 4.2, 9.9):
        ref, _ = integrate.quad(lambda rho: 2 * np.pi * special.j0(q * rho) * rho, 0.8, 2.0, epsabs=1e-13)
        assert abs(a.amplitude_radial(q).real - ref) < 1e-9 * a.area, q


def test_spec_validation_and_unused_warning():
    assert SPEC["inner_ratio"].applies == ("shape=annulus", "shape=mixture")
    m = material_from_parameters(shape="annulus", radius=3.0, inner_ratio=0.7, area_fraction=0.2)
    assert isinstance(m.shape, Annulus) and m.shape.radius == 3.0 and m.shape.inner_ratio == 0.7
    with pytest.raises(corona.CoronaError, match=r"inner_ratio=0.95 is out of range; allowed \[0, 0.9\]"):
        material_from_parameters(shape="annulus", inner_ratio=0.95, area_fraction=0.2)
    with pytest.warns(corona.CoronaWarning, match="inner_ratio"):
        material_from_parameters(shape="circle", radius=2.0, inner_ratio=0.3)
    # a mixture's annuli read it too
    mix = material_from_parameters(shape="mixture", mixture="annulus:3:1, circle:1:1", inner_ratio=0.3, area_fraction=0.2)
    assert repr(mix.shape.components[0][0]) == "Annulus(radius=3, inner_ratio=0.3)"


@pytest.mark.slow
@pytest.mark.reference
def test_brute_force_rasterises_one_ring():
    pytest.importorskip("numba")
    from scipy import fft as sp_fft

    from corona.reference import wave
    shape = Annulus(1.0, 0.5)
    rng = np.random.default_rng(3)
    n, M, h = 256, 16, 1.0 / 16
    g = wave.Grid(n, n, h, h)
    P = 0.0
    for _ in range(M):
        t = wave.rasterise(shape, rng.uniform(0, n * h, (1, 2)), g, rng=rng)
        P = P + np.abs(sp_fft.fft2(t)) ** 2
    q1 = 2 * np.pi * sp_fft.fftfreq(n, h)
    QX, QY = np.meshgrid(q1, q1, indexing="xy")
    P = P / M * h**4 / np.sinc(np.hypot(QX, QY) * h / (2 * np.pi)) ** 2   # the edge ramp's transfer
    model = shape.form_factor(np.stack([QX, QY], -1)) * shape.area
    u = np.hypot(QX, QY)
    for lo, hi in [(0, 3), (3, 6), (6, 10), (10, 16)]:
        sel = (u >= lo) & (u < hi) & (model > 1e-3 * model.max())
        assert abs(P[sel].sum() / model[sel].sum() - 1) < 5e-3, (lo, hi)


def _plugin_matches_model(bsdf, material):
    from bsdf_checks import assert_eval_matches
    wi = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    d = material.sample(np.random.default_rng(0).random((2000, 2)), 550.0)
    wo_xy = d - wi[:2]
    keep = np.hypot(wo_xy[:, 0], wo_xy[:, 1]) < 0.99
    wo_xy = wo_xy[keep]
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy**2).sum(1))])
    exact = lambda wi_, wo_, lam: material.lobe((wo_ + wi_)[:, :2], lam) * np.abs(wo_[:, 2])
    # the radial table in u (step 0.01, linear) against the exact lobe
    assert_eval_matches(bsdf, exact, wi, wo, (450.0, 550.0, 650.0, 550.0), rtol=2e-3, atol=1e-4)


def test_plugin_eval_matches_the_model_by_name_and_as_an_instance(mi_variant):
    import mitsuba as mi
    given = {"shape": "annulus", "radius": 3.0, "inner_ratio": 0.6, "process": "hard-disk", "area_fraction": 0.3}
    reference = corona.Material(Annulus(3.0, 0.6), corona.HardDisk(0.3))
    _plugin_matches_model(mi.load_dict({"type": "corona", **given}), reference)
    bsdf = mi.load_dict({"type": "corona", "shape": corona.scatterer(Annulus(3.0, 0.6)), "area_fraction": 0.3})
    _plugin_matches_model(bsdf, reference)


def _docs_code() -> str:
    text = open(os.path.join(ROOT, "docs", "adding_a_scatterer.md"), encoding="utf-8").read()
    return re.search(r"```python\n(.*?)```", text, re.S).group(1)


def test_the_docs_ring_is_at_most_30_lines_and_is_the_annulus(mi_variant, restored_registry):
    import mitsuba as mi
    code = _docs_code()
    assert len(code.strip().splitlines()) <= 30
    ns: dict = {}
    variant = mi.variant()
    exec(compile(code.replace('mi.set_variant("llvm_ad_spectral")', f'mi.set_variant("{variant}")'),
                 "adding_a_scatterer.md", "exec"), ns)
    ring = ns["Ring"](4.0, 0.6)
    q = np.linspace(0.0, 12.0, 400)
    assert np.allclose(ring.form_factor_radial(q), Annulus(4.0, 0.6).form_factor_radial(q), rtol=1e-8,
                       atol=1e-12 * ring.area)
    _plugin_matches_model(ns["bsdf"], corona.Material(Annulus(4.0, 0.6), corona.HardDisk(0.3)))
    with pytest.raises(Exception, match=r"hole=1.2 is out of range; allowed \[0, 0.9\]"):
        mi.load_dict({"type": "corona", "shape": "ring", "hole": 1.2})
