"""Spheres on a fixed lattice (corona.model.mie.material.SphereMaterial with corona.Lattice): the
numpy model against independent references.

* the Bragg orders: where each order goes (the grating equation, from reciprocal vectors written
  out here) and what it carries (the kinematic grating efficiency with miepython's amplitudes at
  the order's scattering angle and the Debye–Waller factor), transmitted and reflected, at normal
  and oblique incidence;
* the diffuse part between the orders: a brute-force far-field sum over jittered finite patches
  of sphere centres;
* the energy cap: coherent + lobes <= 1 (square and hexagonal, jitter 0 and > 0, both sides,
  on glass), with the negative control that the uncapped lobes would exceed it.
"""
import math
import warnings

import numpy as np
import pytest

import corona
from corona import CoronaError
from corona.model.mie.material import SphereMaterial

miepython = pytest.importorskip("miepython")   # the test extra installs it


def _mie_f2(m, x, k, cos_theta):
    """``|f|² = (|S1|² + |S2|²) / 2k²`` [µm²/sr], unpolarised, from miepython (van de Hulst's
    amplitudes: norm='wiscombe'; miepython's m = n - iκ is the conjugate of ours)."""
    s1, s2 = miepython.S1_S2(np.conj(m), x, np.atleast_1d(cos_theta), norm="wiscombe")
    return (np.abs(s1) ** 2 + np.abs(s2) ** 2) / (2 * k * k)


def _reciprocal(kind, a):
    """Primitive reciprocal vectors of the unrotated lattice, written out (not from corona)."""
    if kind == "square":
        return 2 * np.pi / a * np.array([[1.0, 0.0], [0.0, 1.0]]), a * a
    # a1 = a (1, 0), a2 = a (1/2, √3/2): b1 = (2π/a)(1, -1/√3), b2 = (2π/a)(0, 2/√3)
    return 2 * np.pi / a * np.array([[1.0, -1.0 / math.sqrt(3.0)], [0.0, 2.0 / math.sqrt(3.0)]]), \
        0.5 * math.sqrt(3.0) * a * a


def _wi(theta_deg, phi_deg):
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("kind,delta,theta,phi", [("hexagonal", 0.2, 0.0, 0.0), ("hexagonal", 0.2, 30.0, 20.0),
                                                 ("square", 0.0, 0.0, 0.0), ("square", 0.0, 140.0, 50.0)])
def test_orders_match_the_grating_equation_and_efficiency(kind, delta, theta, phi):
    # 0.6 µm water droplets 6 µm apart (F_a ≈ 0.03: the cap trims little); θ > 90°: from below
    m = corona.Material(corona.Sphere(0.6), corona.Lattice(kind, 6.0, jitter=delta))
    lam = 550.0
    k = 2 * np.pi / (lam * 1e-3)
    x = k * 0.6
    n_w = complex(m.sphere.index(lam))
    wi = _wi(theta, phi)
    mu_i = abs(wi[2])
    B, area = _reciprocal(kind, 6.0)
    # the cap trims the O(F_a²) by which the kinematic orders and the coherent beam overshoot
    w = float(m._lattice_weight(wi, lam, ()))
    assert 0.98 < w <= 1.0
    fs = m.area_fraction / mu_i
    w_q = m.lattice.peak_width
    checked = 0
    for h, kk in [(1, 0), (0, 1), (-1, 1), (2, -1), (1, 1), (-2, 0), (3, -1)]:
        G = h * B[0] + kk * B[1]
        p_G = G / k - wi[:2]                         # grating equation: (wo + wi)_xy = G / k
        r2 = float(p_G @ p_G)
        if r2 > 0.8:                                 # grazing or evanescent orders are not checked
            continue
        cz = math.sqrt(1 - r2)
        # a window of ±6 peak widths around the order, in p = wo_xy; dΩ = d²p / |cos θo|
        half = 6 * w_q / k
        g = np.linspace(-half, half, 121)
        dp = g[1] - g[0]
        P = np.stack(np.meshgrid(p_G[0] + g, p_G[1] + g, indexing="ij"), -1).reshape(-1, 2)
        czs = np.sqrt(1 - np.sum(P * P, axis=-1))
        q2 = k * k * np.sum((P + wi[:2]) ** 2, axis=-1)
        for side in (-1.0, 1.0):                     # transmitted (far side) and reflected
            wo = np.concatenate([P, side * czs[:, None]], -1)
            val = m.eval(wi, wo, lam, exact=True)
            got = float(np.sum(val / czs) * dp * dp)
            # the order's peak sits on the grating direction (within a grid step)
            peak = P[np.argmax(val)]
            assert np.hypot(*(peak - p_G)) <= 1.5 * dp
            # kinematic efficiency: λ² |f(Θ_G)|² e^{-G²δ²} / (A² μ_i |cos θ_G|), plus the diffuse
            # |f|² (1 - e^{-q²δ²}) / (A μ_i) over the window
            cos_G = float(np.dot(np.array([p_G[0], p_G[1], side * cz]), -wi))
            eta = (lam * 1e-3) ** 2 * _mie_f2(n_w, x, k, cos_G)[0] * math.exp(-(G @ G) * delta ** 2) \
                / (area ** 2 * mu_i * cz)
            cos_all = -(wo @ wi)
            diffuse = float(np.sum(_mie_f2(n_w, x, k, cos_all) * -np.expm1(-q2 * delta ** 2)
                                   / (area * mu_i) / czs) * dp * dp)
            assert got == pytest.approx(w * (eta + diffuse), rel=0.02), (h, kk, side, got, eta, diffuse)
            if delta == 0.0:
                assert diffuse == 0.0
            # the layer's lattice_nodes (its cap's quadrature) hold the same order energy
            nodes = m.lattice_nodes(wi, lam)
            near = (np.abs(nodes["wo"][:, 0] - p_G[0]) <= half) & (np.abs(nodes["wo"][:, 1] - p_G[1]) <= half) \
                & (np.sign(nodes["wo"][:, 2]) == side)
            peaks_only = fs * float(np.sum(nodes["energy"][near & nodes["bragg"]]))
            assert peaks_only == pytest.approx(eta, rel=0.03), (h, kk, side)
            checked += 1
    assert checked >= 8


@pytest.mark.slow
@pytest.mark.reference
def test_diffuse_part_matches_a_brute_force_patch_sum():
    """Between the orders, the layer's eval equals the mean far-field intensity of jittered
    finite patches of spheres, ``(1 / (A μ_i)) |f(Θ)|² ⟨|Σ_j e^{i q·r_j}|²⟩ / N``."""
    a, delta, r, lam = 3.0, 0.35, 0.5, 600.0
    m = corona.Material(corona.Sphere(r), corona.Lattice("square", a, jitter=delta))
    k = 2 * np.pi / (lam * 1e-3)
    n_w = complex(m.sphere.index(lam))
    wi = _wi(20.0, 0.0)
    w = float(m._lattice_weight(wi, lam, ()))
    assert 0.98 < w <= 1.0
    rng = np.random.default_rng(3)
    n_side, n_real = 24, 300
    ij = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1).reshape(-1, 2)
    sites = ij * a
    # directions whose q = k (wo + wi)_xy falls midway between orders, both sides of the layer
    B = 2 * np.pi / a
    qs = np.array([[0.5 * B, 0.5 * B], [1.5 * B, 0.5 * B], [-0.5 * B, 2.5 * B], [2.5 * B, -1.5 * B]])
    for side in (-1.0, 1.0):
        p = qs / k - wi[:2]
        cz = np.sqrt(1 - np.sum(p * p, axis=-1))
        wo = np.concatenate([p, side * cz[:, None]], -1)
        model = m.eval(wi, wo, lam, exact=True)
        acc = np.zeros(len(qs))
        for _ in range(n_real):
            pos = sites + rng.normal(0.0, delta, sites.shape)
            acc += np.abs(np.exp(1j * pos @ qs.T).sum(axis=0)) ** 2 / len(sites)
        S_brute = acc / n_real
        brute = w * _mie_f2(n_w, k * r, k, -(wo @ wi)) / (a * a * wi[2]) * S_brute
        # n_real realisations of a speckle of mean S: relative noise 1/√n_real ≈ 6 %
        np.testing.assert_allclose(model, brute, rtol=0.2)
        np.testing.assert_allclose(S_brute, -np.expm1(-np.sum(qs * qs, -1) * delta ** 2), rtol=0.2)


LATTICES = [
    ("square", 0.0), ("square", 0.15), ("hexagonal", 0.0), ("hexagonal", 0.15),
]


@pytest.mark.parametrize("kind,jitter", LATTICES)
def test_furnace_is_at_most_one(kind, jitter):
    # 1 µm droplets at 2.2 µm spacing: a dense crystal whose kinematic orders carry more than the
    # light the coherent beam loses: the cap w must bind
    m = corona.Material(corona.Sphere(1.0), corona.Lattice(kind, 2.2, jitter=jitter))
    capped = 0
    for ci in (1.0, 0.8, 0.5, 0.2, -0.7):
        for lam in (420.0, 650.0):
            e = m.directional_albedo(ci, lam, phi_i=0.4)
            assert e["total"] <= 1.0 + 1e-9, (ci, lam, e)
            assert e["lobe_transmission"] > 0 and e["lobe_reflection"] > 0
            st = math.sqrt(1 - ci * ci)
            wi = np.array([st * math.cos(0.4), st * math.sin(0.4), ci])
            raw = float(m._slant(ci)) * m.lattice_energy(wi, lam) + e["coherent"]
            capped += raw > 1.0
    assert capped > 0           # negative control: without the cap the layer would gain energy


def test_furnace_on_glass():
    m = corona.Material(corona.Sphere(1.0), corona.Lattice("hexagonal", 3.0, jitter=0.1),
                        substrate=corona.GlassPane())
    for ci in (1.0, 0.6, -0.6, -1.0):
        e = m.directional_albedo(ci, 550.0, phi_i=0.2)
        assert e["total"] <= 1.0 + 1e-9, (ci, e)
        assert e["lobe_reflection"] > 0 and e["lobe_transmission"] > 0


def test_jitter_moves_energy_from_orders_to_the_diffuse_part():
    sharp = corona.Material(corona.Sphere(0.6), corona.Lattice("square", 5.0, jitter=0.0))
    soft = corona.Material(corona.Sphere(0.6), corona.Lattice("square", 5.0, jitter=0.4))
    wi = np.array([0.0, 0.0, 1.0])
    B = 2 * np.pi / 5.0
    k = 2 * np.pi / 0.55
    between = np.array([[0.5 * B / k, 0.5 * B / k, -math.sqrt(1 - 0.5 * (B / k) ** 2)]])
    assert float(sharp.eval(wi, between, 550.0)[0]) == 0.0       # a perfect crystal: orders only
    assert float(soft.eval(wi, between, 550.0)[0]) > 0.0
    # the lobes' total is about the same (the Debye–Waller weight goes to the diffuse part)
    e0 = sharp.directional_albedo(1.0, 550.0)
    e1 = soft.directional_albedo(1.0, 550.0)
    assert e1["forward"] + e1["backward"] == pytest.approx(e0["forward"] + e0["backward"], rel=0.05)


def test_refusals_name_the_reason():
    with pytest.raises(CoronaError, match="size_spread=0.1 is out of range.*lattice"):
        corona.Material(corona.SizeDistribution(corona.Sphere(1.0), 0.1), corona.Lattice("square", 3.0))
    with pytest.raises(CoronaError, match="spacing"):
        corona.Material(corona.Sphere(1.0), corona.Lattice("square", 1.5))      # spheres overlap
    assert isinstance(corona.Material(corona.Sphere(1.0), corona.Lattice("square", 3.0)), SphereMaterial)


@pytest.mark.slow
@pytest.mark.parametrize("rho", [0.97, 0.995, 0.999, 1.001])
def test_grazing_order_energy_and_furnace(rho):
    """An order leaving near grazing (a Rayleigh anomaly, ``|cos θ_G| → 0``): its energy from
    ``eval`` integrated in the polar angles of ``wo`` (``dΩ = sin θ dθ dφ``, no singularity)
    equals what the cap counts (lattice_nodes), and the furnace holds there."""
    m = corona.Material(corona.Sphere(1.0), corona.Lattice("hexagonal", 4.0, jitter=0.0))
    B, _ = _reciprocal("hexagonal", 4.0)
    G = 5 * B[0] - 3 * B[1]
    k = np.hypot(*G) / rho                     # |wo_xy| of the order = rho at normal incidence
    lam = 2 * np.pi / k * 1e3
    wi = np.array([0.0, 0.0, 1.0])
    r_w = 6 * m.lattice.peak_width / k
    r0, ph0 = np.hypot(*G) / k, math.atan2(G[1], G[0])
    th = np.linspace(math.asin(min(r0 - r_w, 1.0)), math.asin(min(r0 + r_w, 1.0)), 1500)
    ph = np.linspace(ph0 - r_w / r0, ph0 + r_w / r0, 160)
    T, PH = np.meshgrid(th, ph, indexing="ij")
    got = 0.0
    for side in (-1.0, 1.0):
        wo = np.stack([np.sin(T) * np.cos(PH), np.sin(T) * np.sin(PH), side * np.cos(T)], -1).reshape(-1, 3)
        got += float(np.sum(m.eval(wi, wo, lam).reshape(T.shape) * np.sin(T)) * (th[1] - th[0]) * (ph[1] - ph[0]))
    nodes = m.lattice_nodes(wi, lam)
    near = np.hypot(nodes["wo"][:, 0] - G[0] / k, nodes["wo"][:, 1] - G[1] / k) < r_w
    counted = float(m._slant(1.0)) * float(m._lattice_weight(wi, lam, ())) * float(np.sum(nodes["energy"][near]))
    assert got > 0
    assert counted == pytest.approx(got, rel=3e-3)
    assert m.directional_albedo(1.0, lam)["total"] <= 1.0 + 1e-9


def test_dimensionless_lobe_is_the_lobe_on_a_lattice():
    m = corona.Material(corona.Sphere(0.6), corona.Lattice("square", 5.0, jitter=0.1))
    lam = 550.0
    B = 2 * np.pi / 5.0
    u = np.array([[B * 0.6, 0.0], [0.0, B * 0.6], [0.5 * B * 0.6, 0.5 * B * 0.6], [40.0, 0.0]])
    d = u * (lam * 1e-3) / (2 * np.pi * 0.6)
    v = m.lobe_dimensionless(u, lam)
    ref = np.where(np.sum(d * d, -1) < 1, m.lobe(d, lam), 0.0) / (m.area_fraction * (0.6 / (lam * 1e-3)) ** 2)
    np.testing.assert_allclose(v, ref, rtol=1e-12)
    assert v[0] > 100 * v[2] > 0                  # an order against the diffuse part between them
    with pytest.raises(CoronaError, match="anisotropic"):
        m.lobe_dimensionless_radial(np.array([1.0]), lam)
