"""process=breath-figure (corona.model.processes.breath_figure): its parameters, its sum rule, and its
lobe against the exact far field of freshly simulated droplets (issue 46).

The brute-force reference is the far field of one simulated configuration, ``|Σ_j F_j e^{-iq·r_j}|²``
on the periodic box's lattice (corona.reference.breath_figure_optics), from a seed that the shipped
table was not made with.  The measured errors of the approximations are in
benchmarks/results/breath_figure_lobe.json (benchmarks/breath_figure_lobe.py).
"""
from __future__ import annotations

import numpy as np
import pytest

import corona
from corona import CoronaError
from corona.parameters import material_from_parameters


@pytest.mark.parametrize("given, words", [
    (dict(breath_time=200.0), ("breath_time=200.0", "[5, 80] s")),
    (dict(breath_time=4.0), ("breath_time=4.0", "[5, 80] s")),
    (dict(breath_time=-1.0), ("breath_time=-1.0", "(0, 10000]")),
    (dict(contact_angle=120.0), ("contact_angle=120.0", "[10, 90]")),
    (dict(contact_angle=30.0, breath_time=40.0), ("breath_time=40.0", "contact_angle=30")),
    (dict(shape="square"), ("shape must be 'circle'", "Square")),
    (dict(size_spread=0.2), ("shape must be 'circle'", "SizeDistribution")),
])
def test_bad_parameters_are_one_clear_error(given, words):
    with pytest.raises(CoronaError) as err:
        material_from_parameters(process="breath-figure", **given)
    for w in words:
        assert w in str(err.value)


def test_contact_angle_scales_time_by_the_cap_volume():
    # the same water in flatter caps: θ = 40° at t is the hemispherical layer at t k(90°)/k(40°)
    from corona.reference.breath_figure import cap_volume_factor
    k = cap_volume_factor(90.0) / cap_volume_factor(40.0)
    flat = corona.BreathFigure(breath_time=20.0 / k, contact_angle=40.0)
    half = corona.BreathFigure(breath_time=20.0)
    assert flat.mean_radius == pytest.approx(half.mean_radius, rel=1e-9)
    assert corona.BreathFigure(breath_time=40.0).mean_radius > 1.7 * half.mean_radius   # R ∝ t


def test_layer_holds_the_droplets():
    m = material_from_parameters(process="breath-figure", breath_time=20.0)
    radii, frac = m.process.size_classes
    assert isinstance(m.shape, corona.Mixture) and len(m.shape.components) == len(radii)
    assert frac.sum() == pytest.approx(1.0)
    R = np.sum(frac * radii ** 3) / np.sum(frac * radii ** 2)
    assert R == pytest.approx(m.process.mean_radius, rel=0.1)
    assert 0.5 < m.area_fraction < 0.72                # the coverage of a breath figure with renucleation
    assert m.area_fraction == pytest.approx(np.sum(frac * np.pi * radii ** 2) * m.process.number_density,
                                            rel=0.02)    # F_a = n <|A|>, both from the table
    # the lobe is the process's rule (partial structure factors inside the table's rings, qR <= 12;
    # the local monodisperse rule beyond, where the small droplets are still correlated)
    q = np.array([1.0, 40.0]) / m.process.mean_radius
    mean_area = np.sum(frac * np.pi * radii ** 2)
    v = m.lobe_terms(q * m.length_scale, radial=True)["v"] * m.length_scale ** 2 * mean_area
    np.testing.assert_allclose(v, m.process.intensity(q, "partial"), rtol=1e-9)
    assert v[1] == pytest.approx(m.process.intensity(q[1:], "local-monodisperse")[0], rel=1e-9)
    assert abs(v[0] / m.process.intensity(q[:1], "local-monodisperse")[0] - 1) > 0.1   # 0.44 measured


@pytest.mark.parametrize("t", [10.0, 40.0])
def test_local_monodisperse_rule_keeps_the_sum_rule(monkeypatch, t):
    # non-overlapping droplets: the lobe carries F_a (1 - F_a); each class's hard-disk S obeys it
    from corona.model.processes.breath_figure import BreathFigure
    monkeypatch.setattr(BreathFigure, "RULE", "local-monodisperse")
    m = corona.Material(corona.Circle(1.0), BreathFigure(t), mode="particle")
    fa = m.area_fraction
    assert m.diffuse_transmittance() == pytest.approx(fa * (1 - fa), rel=2e-3)
    # negative control: the decoupling rule with the measured S of all the centres is far off forward
    q = np.array([1e-3])
    assert m.process.intensity(q, "decoupling")[0] > 5 * m.process.intensity(q, "local-monodisperse")[0]


@pytest.mark.parametrize("t", [5.0, 10.0, 40.0])
def test_shipped_rule_keeps_the_sum_rule(t):
    # no more light through the layer than its open area lets through: the partial rule's class
    # averages and the table's noise gave 1.03 (10 s) to 1.16 (40 s) of F_a (1 - F_a) before its scale
    m = material_from_parameters(process="breath-figure", breath_time=t)
    fa = m.area_fraction
    assert m.diffuse_transmittance() == pytest.approx(fa * (1 - fa), rel=2e-3)
    assert m.diffuse_transmittance() + m.coherent_transmittance <= (1 - fa) * (1 + 2e-3)


#: The chosen rule's RMS relative error over the rings against seed 7 (measured 0.14, 0.22, 0.52 over
#: seeds 7 and 8 in benchmarks/results/breath_figure_lobe.json), with headroom.
TOLERANCE = {10.0: 0.3, 20.0: 0.4, 40.0: 0.8}


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("t", [10.0, 20.0, 40.0])
def test_lobe_against_the_far_field_of_simulated_droplets(t):
    from corona.reference.breath_figure import simulate_breath_figure
    from corona.reference.breath_figure_optics import far_field_rings, ring_error
    box = 400.0
    bf = simulate_breath_figure([t], box=box, seed=7)            # not a seed of the table (1, 2)
    a, c = bf.radii[0], bf.centres[0]
    m = material_from_parameters(process="breath-figure", breath_time=t)
    Rm, R = m.length_scale, m.process.mean_radius
    # rings of 0.25 in q R; the exact far field alone (the rules' lobes come from the model)
    r = far_field_rings(c, a, box, length=Rm, u_max=14.0 * Rm / R, du=0.25 * Rm / R, exact_only=True)
    exact = r["exact"] * a.size / box ** 2                       # per area [µm²]

    def rms(per_area):
        return ring_error(exact, per_area)["rms"]
    model = m.area_fraction * m.lobe_dimensionless_radial(r["u"]) * Rm ** 2
    n = m.process.number_density
    other = {rule: rms(n * m.process.intensity(r["u"] / Rm, rule)) for rule in m.process.RULES}
    assert rms(model) == pytest.approx(other[m.process.RULE], rel=1e-3)    # the layer's lobe is its rule
    assert rms(model) < TOLERANCE[t]
    assert other["decoupling"] > 3.0                             # negative control: 9-30 here
    if t < 30.0:                                                 # by a factor 3-4 there (at 40 s: 0.52 vs 0.55)
        assert other["partial"] < 0.5 * other["local-monodisperse"]


def test_plugin_takes_the_process_by_name(mi_variant):
    """Through the registry's process path, with the plugin's code unchanged: its eval is the model's
    lobe as tabulated (the radial table) at the layer's own coverage."""
    import mitsuba as mi
    from bsdf_checks import assert_eval_matches
    bsdf = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": 14.0})
    material = material_from_parameters(process="breath-figure", breath_time=14.0)
    wi = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    d = material.sample(np.random.default_rng(0).random((2000, 2)), 550.0)
    wo_xy = d - wi[:2]
    wo_xy = wo_xy[np.hypot(wo_xy[:, 0], wo_xy[:, 1]) < 0.99]
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy ** 2).sum(1))])
    # the renderer's radial table (linear in u, step 0.01) against the lobe: its kinks (the partial
    # structure factors are linear between rings) cost at most 0.5 %, 1e-4 RMS
    dd = np.stack([np.linspace(1e-3, 0.6, 5000), np.zeros(5000)], -1)
    ex, tb = material.lobe(dd, 550.0), material.lobe_tabulated(dd, 550.0)
    rel = np.abs(tb / ex - 1)[ex > 1e-3 * ex.max()]
    assert rel.max() < 5e-3 and np.sqrt(np.mean(rel ** 2)) < 1e-4
    table = lambda wi_, wo_, lam: material.lobe_tabulated((wo_ + wi_)[:, :2], lam) * np.abs(wo_[:, 2])
    assert_eval_matches(bsdf, table, wi, wo, (450.0, 550.0, 650.0, 550.0), rtol=2e-3, atol=1e-4)
    with pytest.raises(Exception, match=r"breath_time=100.0 is out of range; allowed \[5, 80\] s"):
        mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": 100.0})
