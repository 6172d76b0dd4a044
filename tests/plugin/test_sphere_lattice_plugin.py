"""Spheres on a fixed lattice in Dr.Jit: the closed-form S(q) per lane
(corona.mitsuba.sphere_lattice.LatticeS) against the numpy lattice's structure_factor_at, on the
peaks, between them and through the Debye–Waller background; the lobe, its samplers, the per-lane
cap and the assembled plugin (process=lattice-* for shape=sphere) against the numpy model."""
import re

import numpy as np
import pytest

import corona


@pytest.mark.parametrize("kind, a, jitter, angle", [("square", 3.0, 0.0, 0.0), ("hexagonal", 4.0, 0.0, 0.0),
                                                    ("square", 3.0, 0.15, 20.0), ("hexagonal", 2.2, 0.15, 0.0)])
def test_structure_factor_matches_numpy(mi_variant, kind, a, jitter, angle):
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeS
    lat = corona.Lattice(kind, a, jitter=jitter, angle=angle)
    rng = np.random.default_rng(7)
    G, _ = lat.bragg_peaks(20.0)
    w = lat.peak_width
    # on the peaks, within two widths of them, and anywhere up to |q| = 25 rad/µm
    q = np.concatenate([G[:40], G[:200] + rng.normal(0.0, w, (min(200, len(G)), 2)),
                        rng.uniform(-25.0, 25.0, (2000, 2))])
    ref = lat.structure_factor_at(q)
    got = np.asarray(LatticeS(lat)(mi.Float(q[:, 0]), mi.Float(q[:, 1])), dtype=np.float64)
    peak = (2 * np.pi) ** 2 * lat.number_density / (2 * np.pi * w * w)
    assert np.max(np.abs(got - ref)) < 1e-4 * peak      # float32: q - G at |q| ~ 20 rad/µm
    assert np.max(np.abs(got - ref) / np.maximum(ref, 1e-3)) < 1e-3
    assert ref[:40].min() > 0.5 * peak * np.exp(-(np.hypot(G[:40, 0], G[:40, 1]).max() * jitter) ** 2)


def test_negative_control_a_shifted_lattice_fails(mi_variant):
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeS
    lat = corona.Lattice("hexagonal", 4.0)
    G, _ = lat.bragg_peaks(10.0)
    wrong = LatticeS(corona.Lattice("hexagonal", 4.0 * 1.01))(mi.Float(G[:, 0]), mi.Float(G[:, 1]))
    assert not np.allclose(np.asarray(wrong), lat.structure_factor_at(G), rtol=0.1)


def _side_weight(wo, wi):
    """A smooth, forward-peaked stand-in for the Mie pattern that picks the side."""
    import drjit as dr
    return dr.exp(3.0 * -dr.dot(wo, wi)) + 0.2


def _order_sampler_pair(lat, theta_deg, lam_um=0.55):
    """(sample, pdf) of the order sampler at one wavelength, the side picked in the ratio of
    :func:`_side_weight` at the two candidate directions (as the lattice lobe picks it by P)."""
    import drjit as dr
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import OrderSampler
    k = 2 * np.pi / lam_um
    sampler = OrderSampler(lat, 2.0 * k)
    th = np.radians(theta_deg)

    def wi_of(n):
        return mi.Vector3f(dr.full(mi.Float, float(np.sin(th)), n), 0.0, float(np.cos(th)))

    def sides(wi, px, py):
        cz = dr.safe_sqrt(1.0 - px * px - py * py)
        up, down = mi.Vector3f(px, py, cz), mi.Vector3f(px, py, -cz)
        a, b = _side_weight(up, wi), _side_weight(down, wi)
        return up, down, a / (a + b)

    def sample(s, *args):
        wi = wi_of(dr.width(s))
        idx, u_side = sampler.orders.sample_reuse(s[0])
        px, py, valid = sampler.sample(wi, k, s[0], mi.Point2f(s[1], s[2]))
        up, down, p_up = sides(wi, px, py)
        wo = dr.select(u_side < p_up, up, down)
        return wo, dr.select(valid, 1.0, 0.0)

    def pdf(wo, *args):
        wi = wi_of(dr.width(wo))
        up, down, p_up = sides(wi, wo.x, wo.y)
        return sampler.pdf(wi, wo, k, dr.select(wo.z > 0, p_up, 1.0 - p_up))

    return sample, pdf, sampler


@pytest.mark.slow
@pytest.mark.chi2
# the lattice's kind is data (its Bragg vectors and weights), the jitter a branch (LatticeS.peaks'
# Debye-Waller factor): a fixed square lattice and a jittered hexagonal one take every path that
# (square, 0.15) and (hexagonal, 0) take, as in test_lattice_sampler_chi2
@pytest.mark.parametrize("kind, jitter", [("square", 0.0), ("hexagonal", 0.15)])
# 30° merged into 60°: the same branches (the side of wi), another set of propagating orders
@pytest.mark.parametrize("theta", [0.0, 60.0])
def test_order_sampler_chi2(mi_variant, kind, jitter, theta):
    """The order sampler against its own pdf (Mitsuba's chi-square test).  The crystallites are
    3 spacings wide so that a peak (rms ε = w/k ≈ 0.03 rad) spans the histogram's bins; the test's
    own integration of the pdf takes 32² points a bin (at 16² it counts 0.4 % too much for the square
    at 30° against a 4000² midpoint sum, which matches the sampler's success share to 2e-4)."""
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    from bsdf_checks import run_chi2
    lat = corona.Lattice(kind, 2.2, jitter=jitter, domain_size=6.6)
    sample, pdf, _ = _order_sampler_pair(lat, theta)
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=1_000_000, res=101, ires=32)
    assert run_chi2(test), test.messages


def test_order_sampler_pdf_integrates_to_its_success_share(mi_variant):
    """Σ over the sphere of the pdf equals the share of samples that leave the layer (samples past
    the horizon fail): a wrong Jacobian k² |cos θo| or a dropped order would miss it."""
    import drjit as dr
    import mitsuba as mi
    lat = corona.Lattice("hexagonal", 2.2, jitter=0.15, domain_size=6.6)
    sample, pdf, sampler = _order_sampler_pair(lat, 30.0)
    rng = np.random.default_rng(4)
    n = 1_000_000
    _, ok = sample(mi.Point3f(rng.random(n), rng.random(n), rng.random(n)))
    success = float(np.mean(np.asarray(ok)))
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(rng.random(n), rng.random(n)))
    vals = np.asarray(pdf(d)) * 4 * np.pi
    integral, err = float(np.mean(vals)), float(np.std(vals) / np.sqrt(n))
    assert 0.3 < success < 1.0
    assert abs(integral - success) < 4 * err + 2e-3, (integral, success, err)
    # negative control: without the Jacobian |cos θo| the integral misses
    vals_wrong = vals / np.maximum(np.abs(np.asarray(d.z)), 1e-3)
    assert abs(float(np.mean(vals_wrong)) - success) > 0.1


@pytest.mark.parametrize("kind, a, jitter, theta", [("hexagonal", 4.0, 0.0, 0.0), ("square", 3.0, 0.15, 30.0),
                                                    ("hexagonal", 2.5, 0.15, 60.0)])
def test_lattice_lobe_matches_numpy_between_and_at_orders(mi_variant, kind, a, jitter, theta):
    """``P S`` from the sphere plugin's rows and LatticeS against SphereMaterial._lobes on the same
    rows, at the orders' directions (both sides) and between them."""
    import warnings

    import mitsuba as mi
    from bsdf_checks import interaction
    from corona.model.mie.material import SphereMaterial
    from corona.mitsuba.sphere_lattice import LatticeLobe
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    lat = corona.Lattice(kind, a, jitter=jitter)
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    lobe = LatticeLobe(bsdf.lobe, lat)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0.0, np.cos(th)])
    lams = (450.0, 520.0, 600.0, 700.0)
    rng = np.random.default_rng(11)
    # the orders of 520 nm (the second wavelength) on both sides, and random directions
    k = 2 * np.pi / 0.52
    G, _ = lat.bragg_peaks(2 * k)
    p = G / k - wi[:2]
    p = p[np.hypot(p[:, 0], p[:, 1]) < 0.97][:60]
    cz = np.sqrt(1 - np.sum(p * p, axis=1))
    at = np.concatenate([np.c_[p, cz], np.c_[p, -cz]])
    d = rng.normal(size=(400, 3))
    wo = np.concatenate([at, d / np.linalg.norm(d, axis=1, keepdims=True)])
    si = interaction(wo.shape[0], tuple(wi), lams)
    got = lobe(si, mi.Vector3f(*(mi.Float(wo[:, i].astype(np.float32)) for i in range(3))))
    worst = []
    for lam, g in zip(lams, got):
        Z_f, Z_b, fwd = ref._lobes(wi, wo, lam)
        want = np.where(fwd, Z_f, Z_b)
        g = np.asarray(g, dtype=np.float64)
        scale = float(np.max(want))
        assert np.max(np.abs(g - want)) < 5e-4 * scale, (lam, np.max(np.abs(g - want)) / scale)
        worst.append(np.max(np.abs(g - want)) / scale)
    print("largest |plugin - numpy| / peak:", max(worst))
    # negative control: the Mie pattern without S misses the orders by far
    Z_f, Z_b, fwd = ref._lobes(wi, wo, 520.0)
    P_f, P_b, fwd_p = ref._mie_at(wi, wo, 520.0)
    want = np.where(fwd, Z_f, Z_b)
    assert np.max(np.abs(np.where(fwd_p, P_f, P_b) - want)) > 0.5 * np.max(want)


def _mixture(kind, jitter, domain=3.0):
    import warnings

    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeSampler
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    lat = corona.Lattice(kind, 2.5, jitter=jitter, domain_size=domain * 2.5)
    return bsdf, lat, LatticeSampler(bsdf.lobe, lat)


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("kind, jitter", [("square", 0.0), ("hexagonal", 0.15)])
# 30° merged into 60°: the same branches (the side of wi), another set of propagating orders
@pytest.mark.parametrize("theta", [0.0, 60.0])
def test_lattice_sampler_chi2(mi_variant, kind, jitter, theta):
    """The mixture of the orders and the sphere's own sampler against its pdf (four wavelengths a
    lane, the side by the Mie pattern; crystallites 3 spacings wide, as for the order sampler)."""
    import drjit as dr
    import mitsuba as mi
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    from bsdf_checks import interaction, run_chi2
    bsdf, _, sampler = _mixture(kind, jitter)     # the plugin kept: the sampler reads its rows
    th = np.radians(theta)
    wi = (float(np.sin(th)), 0.0, float(np.cos(th)))

    def sample(s, *args):
        wo, pdf = sampler.sample(interaction(dr.width(s), wi), s[0], mi.Point2f(s[1], s[2]))
        return wo, dr.select(pdf > 0, 1.0, 0.0)

    def pdf(wo, *args):
        return sampler.pdf(interaction(dr.width(wo), wi), wo)

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=1_000_000, res=101, ires=32)
    assert run_chi2(test), test.messages


@pytest.mark.parametrize("theta", [0.0, 30.0])
def test_sample_weights_integrate_the_numpy_lobe(mi_variant, theta):
    """The mean of ``mean_λ Z / pdf`` over the sampler's samples is ``mean_λ ∫ Z dΩ``: the numpy
    model's own quadrature of the lobes (SphereMaterial.lattice_energy, the cap's e) on the same
    rows, within 4 standard errors.  A lobe without S, or a pdf missing an order's Jacobian,
    would miss it."""
    import drjit as dr
    import mitsuba as mi
    from bsdf_checks import interaction
    from corona.model.mie.material import SphereMaterial
    bsdf, _, _ = _mixture("square", 0.15)
    lat = corona.Lattice("square", 3.0, jitter=0.15)
    from corona.mitsuba.sphere_lattice import LatticeSampler
    smp = LatticeSampler(bsdf.lobe, lat)
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    th = np.radians(theta)
    wi = (float(np.sin(th)), 0.0, float(np.cos(th)))
    lams = (450.0, 520.0, 600.0, 700.0)
    n = 400_000
    rng = np.random.default_rng(2)
    si = interaction(n, wi, lams)
    u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
    wo, pdf = smp.sample(si, u[0], mi.Point2f(u[1], u[2]))
    Z = smp.lobe(si, wo)
    w = np.asarray(dr.select(pdf > 0, sum(Z) / len(Z) / dr.maximum(pdf, 1e-30), 0.0), dtype=np.float64)
    est, err = w.mean(), w.std() / np.sqrt(n)
    e = np.mean([ref.lattice_energy(np.array(wi), lam) for lam in lams])
    assert abs(est - e) < 4 * err + 2e-3 * e, (est, err, e)
    # negative control: the Mie pattern alone (S dropped) integrates to another value
    P = smp._mie(si, wo, True)[0] / len(lams)
    w0 = np.asarray(dr.select(pdf > 0, P / dr.maximum(pdf, 1e-30), 0.0), dtype=np.float64)
    assert abs(w0.mean() - e) > 10 * err


def test_furnace_from_sample_weights_through_a_rayleigh_anomaly(mi_variant):
    """The plugin's lobe and sampler with the numpy model's per-lane cap (its exact
    lattice_energy, applied as the lane's constant F_s w): coherent + the mean sample weight stays
    ≤ 1 as λ steps through the grazing exit of the h² + hk + k² = 39 shell of a hexagonal 4 µm
    crystal at normal incidence (554.6 nm).  Negative control: without the cap the layer gains
    energy at the anomaly."""
    import warnings

    import drjit as dr
    import mitsuba as mi
    from bsdf_checks import interaction
    from corona.model.mie.material import SphereMaterial
    from corona.mitsuba.sphere_lattice import LatticeSampler
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    lat = corona.Lattice("hexagonal", 4.0)
    smp = LatticeSampler(bsdf.lobe, lat)
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    b = np.linalg.norm(lat.reciprocal_vectors[0])
    lam_a = 2 * np.pi / (b * np.sqrt(39.0)) * 1e3
    wi = np.array([0.0, 0.0, 1.0])
    n = 200_000
    rng = np.random.default_rng(8)
    raw = []
    for lam in [float(v) for v in lam_a + np.array([-0.4, -0.1, 0.0, 0.05, 0.2])]:
        si = interaction(n, tuple(wi), (lam,) * 4)
        u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
        wo, pdf = smp.sample(si, u[0], mi.Point2f(u[1], u[2]))
        Z = smp.lobe(si, wo)[0]
        w = np.asarray(dr.select(pdf > 0, Z / dr.maximum(pdf, 1e-30), 0.0), dtype=np.float64)
        e = ref.energies(1.0, lam)
        cap = float(ref._lattice_weight(wi, lam, ()))
        scattered = float(e["slant"]) * w.mean()
        err = float(e["slant"]) * w.std() / np.sqrt(n)
        assert float(e["coherent"]) + cap * scattered <= 1.0 + 3 * cap * err, (lam, e["coherent"], cap, scattered)
        raw.append(float(e["coherent"]) + scattered - 3 * err)
        print(f"{lam:.2f} nm: coherent {float(e['coherent']):.4f}, F_s e {scattered:.4f} ± {err:.4f}, w {cap:.4f}, "
              f"capped {float(e['coherent']) + cap * scattered:.4f}")
    assert max(raw) > 1.0        # uncapped, the crystal returns more than it receives


def _cap_ratio(bsdf, cap, ref, wis, lams):
    """The plugin's per-lane energy (LatticeCap) over the numpy model's quadrature (lattice_energy)."""
    import drjit as dr
    import mitsuba as mi
    n = len(wis)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*(mi.Float(wis[:, i].astype(np.float32)) for i in range(3)))
    si.wavelengths = mi.Spectrum(*(mi.Float(lams[:, i].astype(np.float32)) for i in range(4)))
    states, _ = bsdf.lobe.states(si, True)
    got = np.array([np.asarray(a + b, dtype=np.float64) for a, b in cap.energies(si, states)])
    want = np.array([[ref.lattice_energy(wis[i], lams[i, m]) for i in range(n)] for m in range(4)])
    return got / want


@pytest.mark.parametrize("kind, a, jitter", [pytest.param("hexagonal", 4.0, 0.0, marks=pytest.mark.slow),  # 2 s CPU
                                             ("square", 3.0, 0.0),
                                             ("hexagonal", 2.2, 0.0),
                                             # the jittered lattice's diffuse part: 3.5 s of CPU warm
                                             pytest.param("square", 3.0, 0.15, marks=pytest.mark.slow)])
def test_lattice_cap_energy_matches_the_model_quadrature(mi_variant, kind, a, jitter):
    """The cap's energy per lane in closed form (the orders by the rim rule, LatticeCap) against the
    numpy model's quadrature of the lobes (SphereMaterial.lattice_energy, itself within 2e-4 of a
    160² brute quadrature per order) at random (λ, wi): within the cap's 0.6 % margin, for a
    jittered lattice too (its diffuse part from the table in row and μ_i)."""
    import warnings

    import mitsuba as mi
    from corona.model.mie.material import SphereMaterial
    from corona.mitsuba.sphere_lattice import LatticeCap
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    lat = corona.Lattice(kind, a, jitter=jitter)
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    rng = np.random.default_rng(3)
    n = 24
    th = np.arccos(rng.uniform(0.05, 1, n))
    ph = rng.uniform(0, 2 * np.pi, n)
    wis = np.c_[np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]
    r = _cap_ratio(bsdf, LatticeCap(bsdf.lobe, lat), ref, wis, rng.uniform(360, 830, (n, 4)))
    print("e_plugin / e_numpy:", r.min(), r.max())
    assert np.all(np.abs(r - 1) < 0.005)


@pytest.mark.slow     # 2.5 s of CPU warm
def test_lattice_cap_energy_through_rayleigh_anomalies(mi_variant):
    """Through the 554.6 nm anomaly (hexagonal 4 µm, normal incidence) and θi 0–60° at 550 nm
    (hexagonal 4 µm, square 3 µm): the per-lane energy within 0.5 % of the model's quadrature.
    Negative control: the energy of a crystal 1 % wider misses it."""
    import warnings

    import mitsuba as mi
    from corona.model.mie.material import SphereMaterial
    from corona.mitsuba.sphere_lattice import LatticeCap
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1})
    lat = corona.Lattice("hexagonal", 4.0)
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    b = np.linalg.norm(lat.reciprocal_vectors[0])
    lam_a = 2 * np.pi / (b * np.sqrt(39.0)) * 1e3
    lams = np.repeat((lam_a + np.linspace(-1.0, 0.5, 16))[:, None], 4, 1)
    wis = np.tile([0.0, 0.0, 1.0], (16, 1))
    r = _cap_ratio(bsdf, LatticeCap(bsdf.lobe, lat), ref, wis, lams)
    assert np.all(np.abs(r - 1) < 0.005), (r.min(), r.max())
    wrong = _cap_ratio(bsdf, LatticeCap(bsdf.lobe, corona.Lattice("hexagonal", 4.04)), ref, wis, lams)
    assert np.max(np.abs(wrong - 1)) > 0.01
    th = np.radians(np.linspace(0, 60, 31))
    wis = np.c_[np.sin(th), 0 * th, np.cos(th)]
    for kind, a in (("hexagonal", 4.0), ("square", 3.0)):
        lat = corona.Lattice(kind, a)
        ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
        r = _cap_ratio(bsdf, LatticeCap(bsdf.lobe, lat), ref, wis, np.full((31, 4), 550.0))
        assert np.all(np.abs(r - 1) < 0.005), (kind, r.min(), r.max())


#: Spheres of 1 µm on a hexagonal lattice of 4 µm spacing (area fraction π / (√3/2 · 16)).
HEX4 = {"type": "corona", "shape": "sphere", "radius": 1.0, "process": "lattice-hex",
        "area_fraction": float(np.pi / (np.sqrt(3.0) / 2.0 * 16.0))}
#: ... and on a square lattice of 3 µm spacing.
SQUARE3 = {"type": "corona", "shape": "sphere", "radius": 1.0, "process": "lattice-square",
           "area_fraction": float(np.pi / 9.0)}


def _layer(params, domain=None):
    """The plugin on a lattice (``domain``: a crystallite that many spacings wide instead)."""
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeLayer
    bsdf = mi.load_dict(params)
    if domain is not None:
        lat = bsdf.lobe.lattice
        bsdf.lobe = LatticeLayer(bsdf.lobe.rows, corona.Lattice(lat.kind, lat.spacing, jitter=lat.jitter,
                                                                domain_size=domain * lat.spacing))
    return bsdf


def test_plugin_loads_the_lattice_with_the_models_spacing(mi_variant):
    bsdf = _layer({**HEX4, "jitter": 0.1})
    lat = bsdf.lobe.lattice
    assert lat.kind == "hexagonal" and abs(lat.spacing - 4.0) < 1e-9 and lat.jitter == 0.1
    assert abs(_layer(SQUARE3).lobe.lattice.spacing - 3.0) < 1e-9


@pytest.mark.parametrize("params, theta", [(HEX4, 0.0), (SQUARE3, 30.0), ({**SQUARE3, "jitter": 0.15}, 0.0)])
def test_eval_matches_the_numpy_model_at_and_between_orders(mi_variant, params, theta):
    """``eval`` (``F_s w P S``, as the model's ``eval``) against SphereMaterial.eval on the same rows, at the orders of 520 nm on both sides and
    between them: the lobe within float32 (5e-4 of the peak), the cap within the closed form's
    0.35 %.  Negative control: where the model's cap binds (w < 0.99), the
    uncapped lobe misses the model."""
    from bsdf_checks import assert_eval_matches, plugin_eval
    from corona.model.mie.material import SphereMaterial
    bsdf = _layer(params)
    lat = bsdf.lobe.lattice
    ref = SphereMaterial(corona.Sphere(1.0), lat, radius_cover=bsdf.radius_cover)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0.0, np.cos(th)])
    k = 2 * np.pi / 0.52
    G, _ = lat.bragg_peaks(2 * k)
    p = G / k - wi[:2]
    p = p[np.hypot(p[:, 0], p[:, 1]) < 0.97][:60]
    cz = np.sqrt(1 - np.sum(p * p, axis=1))
    rng = np.random.default_rng(5)
    d = rng.normal(size=(300, 3))
    wo = np.concatenate([np.c_[p, cz], np.c_[p, -cz], d / np.linalg.norm(d, axis=1, keepdims=True)])
    assert_eval_matches(bsdf, ref.eval, wi, wo, rtol=0.0045, atol=5e-4)
    # negative control: without the cap (w = 1) the plugin's lobe is brighter than the model's
    cap = bsdf.lobe.cap
    capped = cap.capped
    cap.capped = lambda si, states, active=True: [{**s, "w": 1.0} for s in capped(si, states, active)]
    try:
        val, _ = plugin_eval(bsdf, wi, wo)
    finally:
        cap.capped = capped
    want = np.stack([ref.eval(wi, wo, lam) for lam in (450.0, 520.0, 600.0, 700.0)])
    w = np.array([ref._lattice_weight(wi, lam, ()) for lam in (450.0, 520.0, 600.0, 700.0)])
    print("the model's cap w:", w)
    for m in np.nonzero(w < 0.99)[0]:        # where the cap binds, the uncapped lobe misses
        assert np.max(val[m] - want[m]) > 0.5 * (1 / w[m] - 1) * want[m].max()


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("params, theta", [(HEX4, 0.0), (SQUARE3, 30.0), ({**SQUARE3, "jitter": 10.0}, 60.0)])
def test_plugin_chi2(mi_variant, params, theta):
    """The plugin's sample against its pdf (smooth components; crystallites 3 spacings wide so
    that the histogram resolves the peaks)."""
    from bsdf_checks import chi2_bsdf, smooth_context
    ok, test = chi2_bsdf(_layer(params, domain=3.0), theta, smooth_context(), ires=32)
    assert ok, test.messages


def _uncapped(bsdf):
    cap = bsdf.lobe.cap
    capped = cap.capped
    cap.capped = lambda si, states, active=True: [{**s, "w": 1.0, "e_f": s["e_f"] / s["w"], "e_b": s["e_b"] / s["w"]}
                                                  for s in capped(si, states, active)]
    return lambda: setattr(cap, "capped", capped)


@pytest.mark.slow     # 2 s of CPU warm per case
@pytest.mark.parametrize("params, theta", [(HEX4, 0.0), (HEX4, 30.0), ({**SQUARE3, "jitter": 0.15}, 30.0)])
def test_furnace_from_the_plugins_sample_weights(mi_variant, params, theta):
    """The plugin's directional albedo (coherent beam + lobe, its own sample weights) ≤ 1 at
    four wavelengths; a perfect crystal is bright (the cap binds: ≥ 0.95)."""
    from bsdf_checks import furnace
    mean, err = furnace(_layer(params), theta, wavelengths=(420.0, 520.0, 640.0, 780.0))
    print(mean, err)
    assert np.all(mean - 3 * err <= 1.0), (mean, err)
    if params is HEX4:
        assert np.all(mean >= 0.95), mean


@pytest.mark.slow     # 6.4 s of CPU with the tables cached
def test_furnace_through_a_rayleigh_anomaly(mi_variant):
    """Through the 554.6 nm grazing exit of the h² + hk + k² = 39 shell (hexagonal 4 µm, normal
    incidence): the plugin's albedo ≤ 1; negative control, uncapped (w = 1) it gains energy."""
    from bsdf_checks import furnace
    bsdf = _layer(HEX4)
    lat = bsdf.lobe.lattice
    b = np.linalg.norm(lat.reciprocal_vectors[0])
    lam_a = 2 * np.pi / (b * np.sqrt(39.0)) * 1e3
    lams = tuple(float(v) for v in lam_a + np.array([-0.4, -0.1, 0.0, 0.2]))
    mean, err = furnace(bsdf, 0.0, wavelengths=lams, n=400_000)
    print("capped:", mean, err)
    assert np.all(mean - 3 * err <= 1.0), (mean, err)
    restore = _uncapped(bsdf)
    try:
        raw, raw_err = furnace(bsdf, 0.0, wavelengths=lams, n=400_000)
    finally:
        restore()
    print("uncapped:", raw, raw_err)
    assert np.all(raw - 3 * raw_err > 1.0), (raw, raw_err)


@pytest.mark.slow
@pytest.mark.render
def test_render_has_no_nan(mi_variant):
    import mitsuba as mi
    from bsdf_checks import layer_scene
    props = ('<float name="radius" value="1"/><string name="process" value="lattice-hex"/>'
             '<float name="area_fraction" value="0.2"/><float name="jitter" value="0.05"/>')
    img = np.asarray(mi.render(mi.load_string(layer_scene(props, spp=4, res=12))))
    assert img.shape[:2] == (12, 12) and np.all(np.isfinite(img))
    assert img.mean() > 0.1


def test_lattice_layer_refuses_glass_and_varying_textures(mi_variant):
    import mitsuba as mi
    from bsdf_checks import bitmap_texture
    for extra, want in (({"substrate": "glass"}, "substrate='glass' is out of range for shape='sphere' with "
                                                 "process='lattice-hex' in the renderer; allowed none"),
                        ({"area_fraction": bitmap_texture([[0.1, 0.2], [0.15, 0.2]])},
                         "a area_fraction texture is out of range for shape='sphere' with process='lattice-hex'")):
        with pytest.raises(Exception) as err:
            mi.load_dict({**HEX4, **extra})
        lines = [ln for ln in str(err.value).splitlines() if "CoronaError" in ln]
        assert lines and want in lines[-1], str(err.value)


def test_finite_at_a_zero_interaction(mi_variant):
    """sample / eval / pdf without ``active`` at a zero-initialised interaction (wavelengths 0, as
    mitsuba.chi2's adapters pass): finite."""
    from bsdf_checks import assert_finite_at_a_zero_interaction
    assert_finite_at_a_zero_interaction(_layer({**HEX4, "jitter": 0.05}))


@pytest.mark.slow     # builds the jittered lattice's diffuse table once in an empty cache: 4 s of CPU
def test_jittered_diffuse_table_is_kept_in_the_cache(mi_variant, tmp_path, monkeypatch):
    """A jittered lattice's diffuse table (seconds of quadrature) is built once: the second load
    reads it from the table cache, equal to the fresh build; another jitter is another table.

    The diffuse tables go to an empty folder (the rows come from the suite's cache as before: their
    caching is tested with the rows).  The fresh build compared with the cache hit is the first
    load's own build; a build after it returns a stand-in of the same shape: the test asks only
    whether the cache asked for one (the key holds the jitter), not for its values."""
    from corona.model import tabulated
    from corona.model.mie import lattice_cap
    cached = tabulated.cached

    def diffuse_in_tmp(params, build, **kw):
        if "lattice_diffuse" not in params:
            return cached(params, build, **kw)
        with monkeypatch.context() as mp:
            mp.setenv("CORONA_CACHE_DIR", str(tmp_path))
            return cached(params, build, **kw)

    monkeypatch.setattr(tabulated, "cached", diffuse_in_tmp)
    params = {**SQUARE3, "jitter": 0.15}
    calls, built = [], []
    build = lattice_cap.diffuse_rows_mu

    def spy(*a, **k):
        calls.append(a[2])
        built.append(build(*a, **k) if not built else np.ones_like(built[0]))
        return built[-1]

    monkeypatch.setattr(lattice_cap, "diffuse_rows_mu", spy)
    first = _layer(params)
    second = _layer(params)
    assert calls == [0.15]                            # the second load built nothing
    assert list(tmp_path.glob("*.npz")), "the diffuse table was not written to the cache"
    assert np.any(built[0] > 0)
    np.testing.assert_array_equal(np.asarray(second.lobe.cap.D), built[0].ravel().astype(np.float32))
    np.testing.assert_array_equal(np.asarray(first.lobe.cap.D), np.asarray(second.lobe.cap.D))
    _layer({**params, "jitter": 0.2})
    assert calls == [0.15, 0.2]


#: Spheres of 1 µm at area fraction 0.2 on a lattice (issue 47, items 2 and 3: with a jitter of
#: microns every order's e^{-G²δ²} underflowed float32 (half the samples lost: mean weight 0.33-0.56)
#: and then float64 (ZeroDivisionError in OrderSampler.density_q)).
JITTERED = {"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.2}
#: the jitter's allowed range reaches corona.parameters.LENGTH_MAX
JITTERS = [("lattice-square", 1.0, (0.0, 89.9, 95.0)), ("lattice-hex", 1.5, (0.0, 85.0, 89.9)),
           ("lattice-hex", 10.0, (0.0, 60.0, 85.0, 89.9, 95.0, 150.0)),
           ("lattice-square", 30.0, (0.0, 60.0, 85.0, 89.9, 95.0, 150.0)),
           ("lattice-hex", "max", (0.0, 60.0, 85.0, 89.9, 95.0, 150.0))]


def _jittered(process, jitter):
    import warnings

    import mitsuba as mi
    from corona.parameters import LENGTH_MAX, material_from_parameters
    params = {**JITTERED, "process": process, "jitter": LENGTH_MAX if jitter == "max" else jitter}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = material_from_parameters(**{k: v for k, v in params.items() if k != "type"})
        return mi.load_dict(params), model


@pytest.mark.slow
@pytest.mark.parametrize("process, jitter, angles", JITTERS, ids=lambda v: str(v) if not isinstance(v, tuple) else "")
def test_jittered_lattice_furnace_matches_the_model(mi_variant, process, jitter, angles):
    """The plugin's mean sample weight on a jittered lattice, up to the jitter's maximum and 89.9°
    from either side: ≤ 1 within 4 standard errors and within 1 % of the numpy model's
    directional_albedo (its lattice quadrature: the orders and the diffuse part)."""
    from bsdf_checks import furnace
    bsdf, model = _jittered(process, jitter)
    lams = (420.0, 520.0, 640.0, 780.0)
    for deg in angles:
        mean, err = furnace(bsdf, deg, lams, n=200_000, seed=7)
        ref = np.array([model.directional_albedo(np.cos(np.radians(deg)), lam)["total"] for lam in lams])
        assert np.all(mean <= 1.0 + 4 * err), (deg, mean, err)
        assert np.all(np.abs(mean - ref) <= 0.01 * ref), (deg, mean, ref, err)


@pytest.mark.slow
@pytest.mark.parametrize("jitter", [10.0, 30.0, "max"])
def test_jittered_lattice_keeps_its_light_and_samples(mi_variant, jitter):
    """Normal incidence, a jitter of many spacings: no order's weight is left, the orders' branch is
    off (the sphere's sampler alone), sample / eval / pdf finite, and the mean weight the
    model's (0.997) within 1 %; a small jitter keeps the orders' branch at its full share."""
    import mitsuba as mi
    from bsdf_checks import assert_finite_at_a_zero_interaction, furnace, plugin_eval
    bsdf, model = _jittered("lattice-hex", jitter)
    smp = bsdf.lobe.sampler
    assert smp.alpha == 0.0 and smp.orders.count == 0 and bsdf.lobe.cap.count == 0
    lams = (450.0, 520.0, 600.0, 700.0)
    mean, err = furnace(bsdf, 0.0, lams, n=50_000)
    ref = np.array([model.directional_albedo(1.0, lam)["total"] for lam in lams])
    assert np.all(np.abs(mean - ref) <= 0.01 * ref), (mean, ref, err)
    rng = np.random.default_rng(2)
    wo = rng.normal(size=(500, 3))
    val, pdf = plugin_eval(bsdf, (0.3, 0.0, np.sqrt(0.91)), wo / np.linalg.norm(wo, axis=1, keepdims=True), lams)
    assert np.all(np.isfinite(val)) and np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    assert_finite_at_a_zero_interaction(bsdf)
    assert _jittered("lattice-hex", 0.15)[0].lobe.sampler.alpha == 0.5


@pytest.mark.slow
@pytest.mark.parametrize("scalar, jit", [("scalar_spectral", "llvm_ad_spectral"), ("scalar_rgb", "llvm_ad_rgb")])
def test_lattice_layer_in_scalar_variants_is_the_jit_one(mi_variant, scalar, jit):
    """Spheres on a lattice load in the scalar variants (issue 47, item 8: a TypeError at load, then
    numpy masks and ``~`` of a Python bool) and give the JIT variant's eval, pdf and samples, one
    direction at a time."""
    import drjit as dr
    import mitsuba as mi
    params = {"type": "corona", "shape": "sphere", "radius": 1.0, "process": "lattice-hex",
              "area_fraction": 0.5, "jitter": 0.05}
    rng = np.random.default_rng(4)
    wo = rng.normal(size=(4, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    u = rng.random((4, 3))
    wi = (0.3, 0.0, float(np.sqrt(0.91)))
    lams = (450.0, 520.0, 600.0, 700.0)

    def run(variant, batch):
        # the JIT variant: all directions in one call (RGB's 24 wavelengths a lane compile slowly);
        # the scalar one: one at a time
        mi.set_variant(variant)
        corona.register()
        bsdf = mi.load_dict(params)
        ctx = mi.BSDFContext()
        n = len(wo) if batch else 1
        out = []
        for k in range(1 if batch else len(wo)):
            pick = slice(None) if batch else slice(k, k + 1)
            si = dr.zeros(mi.SurfaceInteraction3f, n) if batch else mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*wi)
            if mi.is_spectral:
                si.wavelengths = mi.Spectrum(*lams) if batch else mi.Spectrum(list(lams))
            arg = (lambda a: mi.Float(a.astype(np.float32))) if batch else (lambda a: float(a[0]))
            val, pdf = bsdf.eval_pdf(ctx, si, mi.Vector3f(*(arg(wo[pick, i]) for i in range(3))))
            bs, w = bsdf.sample(ctx, si, arg(u[pick, 0]), mi.Point2f(arg(u[pick, 1]), arg(u[pick, 2])))
            cols = [np.array(val).reshape(-1, n), np.array(pdf).reshape(1, n), np.array(bs.wo).reshape(3, n),
                    np.array(w).reshape(-1, n)]
            out.append(np.concatenate(cols).T)
        return np.concatenate(out).astype(np.float64)

    try:
        want = run(jit, True)
        got = run(scalar, False)
    finally:
        mi.set_variant(mi_variant)
        corona.register()
    assert np.all(np.isfinite(got))
    assert np.sum(want[:, -3:]) > 0                     # some samples succeed
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6 * np.max(np.abs(want)))


def test_wide_lattices_are_refused_in_one_line(mi_variant):
    """Each Bragg order the per-lane cap holds costs every sample a Mie lookup per wavelength (issue 47,
    item 9: 25 µm spheres, 6·10⁵ orders, ~12 ms a sample): a lattice wider than
    LATTICE_ORDERS_MAX orders is one line naming the spacing, the parameters and the limit; the
    widest accepted one holds at most that many (negative control: 1 µm spheres just inside load)."""
    import warnings

    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LATTICE_ORDERS_MAX
    for radius, fa, process in ((25.0, 0.3, "lattice-hex"), (1.0, 0.01, "lattice-hex"), (2.0, 0.05, "lattice-square")):
        with pytest.raises(Exception) as err:
            mi.load_dict({"type": "corona", "shape": "sphere", "radius": radius, "area_fraction": fa,
                          "process": process})
        lines = [ln for ln in str(err.value).splitlines() if "CoronaError" in ln]
        assert lines and re.search(rf"the lattice spacing [0-9.]+ µm \(radius={radius:g}, area_fraction={fa:g}\) is "
                                   rf"out of range for shape='sphere' with process='{process}' in the renderer; "
                                   rf"allowed at most [0-9.]+ µm .*at most {LATTICE_ORDERS_MAX}", lines[-1]), lines
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.0155,
                             "process": "lattice-hex"})
    assert 0.9 * LATTICE_ORDERS_MAX < bsdf.lobe.cap.count <= LATTICE_ORDERS_MAX


def test_a_dropped_plugin_is_freed_and_its_lobe_says_so(mi_variant):
    """The plugin holds its lobe, the lobe (MieRowsLobe, and a lattice's LatticeLayer over it) holds
    the plugin weakly: a dropped plugin's tables go at once, without the garbage collector (a strong
    reference back would keep them until a full collection), and its lobe's later use is one
    CoronaError, not an AttributeError deep in a kernel."""
    import gc
    import warnings
    import weakref

    import mitsuba as mi
    from bsdf_checks import interaction
    for params in ({"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": 0.1}, HEX4):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bsdf = mi.load_dict(params)
        rows = getattr(bsdf.lobe, "rows", bsdf.lobe)
        states, _ = rows.states(interaction(4, (0.0, 0.0, 1.0)), True)   # serves while the plugin lives
        assert len(states) == 4
        alive = weakref.ref(bsdf)
        was = gc.isenabled()
        gc.disable()
        try:
            del bsdf
            assert alive() is None, params
        finally:
            if was:
                gc.enable()
        with pytest.raises(corona.CoronaError, match="sphere plugin of this MieRowsLobe was dropped"):
            rows.states(interaction(4, (0.0, 0.0, 1.0)), True)
