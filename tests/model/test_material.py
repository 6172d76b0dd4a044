"""The numpy reference material: factors, Babinet, scaling, sampling."""
import numpy as np
import pytest
from scipy import special, stats

import corona
from corona.model import tabulated
from corona.model.material import Material


def airy_lobe(d, lam_nm, radius, fa):
    """docs/physics.md#the-model written out independently: F_a (π R²/λ²) (2 J1(u)/u)²."""
    lam = lam_nm * 1e-3
    u = 2 * np.pi * radius * np.hypot(d[..., 0], d[..., 1]) / lam
    airy = np.where(u > 1e-9, 2 * special.j1(u) / np.where(u > 1e-9, u, 1), 1.0)
    return fa * np.pi * radius**2 / lam**2 * airy**2


@pytest.mark.parametrize("radius,lam", [(0.5, 550.0), (2.0, 400.0), (15.0, 700.0)])
def test_lobe_is_fa_times_airy(radius, lam):
    m = Material(corona.Circle(radius), corona.Poisson(0.2))
    d = np.random.default_rng(1).uniform(-1, 1, (500, 2)) * (lam * 1e-3 / radius)
    ref = airy_lobe(d, lam, radius, 0.2)
    np.testing.assert_allclose(m.lobe(d, lam), ref, rtol=1e-10, atol=1e-12 * ref.max())


def test_table_interpolation_matches_exact_lobe():
    m = Material(corona.Circle(0.5), corona.Poisson(0.3))
    d = np.random.default_rng(2).uniform(-1.5, 1.5, (4000, 2))
    exact = m.lobe(d, 550.0)
    tab = m.lobe_tabulated(d, 550.0)
    peak = exact.max()
    # linear interpolation on du = 0.01: error well below 1e-4 of the peak
    assert np.max(np.abs(tab - exact)) < 1e-4 * peak


def test_babinet_particle_and_aperture():
    c = corona.Circle(0.5)
    a = Material(c, corona.Poisson(0.3), mode="aperture")
    p = Material(c, corona.Poisson(0.3), mode="particle")
    d = np.random.default_rng(3).uniform(-1, 1, (100, 2))
    np.testing.assert_array_equal(a.lobe(d, 500), p.lobe(d, 500))
    assert a.coherent_transmittance == pytest.approx(0.09)
    assert p.coherent_transmittance == pytest.approx(0.49)
    assert a.opaque_fraction == pytest.approx(0.7) and p.opaque_fraction == pytest.approx(0.3)


def test_wavelength_scaling():
    """lobe(d, λ) = (λ'/λ)² lobe(d λ'/λ, λ') (docs/physics.md#the-model: depends on u, prefactor R²/λ²)."""
    m = Material(corona.Circle(1.0), corona.Poisson(0.1))
    d = np.random.default_rng(4).uniform(-0.5, 0.5, (200, 2))
    l1, l2 = 450.0, 675.0
    np.testing.assert_allclose(m.lobe(d, l1), (l2 / l1) ** 2 * m.lobe(d * l2 / l1, l2), rtol=1e-12)


def test_diffuse_transmittance_poisson_integrates_to_fa():
    """∫T_a = 1 over the plane, so a Poisson layer's lobe carries F_a; the tables
    (|u| <= U) hold Rayleigh's encircled energy of it, the evanescent Airy tail
    J0(U)² + J1(U)² is added analytically."""
    m = Material(corona.Circle(5.0), corona.Poisson(0.25))
    U = m.table.u_max
    encircled = 1 - special.j0(U) ** 2 - special.j1(U) ** 2  # Rayleigh's encircled energy
    assert m.tabulated_transmittance == pytest.approx(0.25 * encircled, rel=1e-5)
    assert m.diffuse_transmittance() == pytest.approx(0.25, rel=1e-6)


@pytest.mark.parametrize("radius, fa", [(2.0, 0.3), (0.5, 0.5), (5.0, 0.1)])
def test_diffuse_transmittance_meets_the_sum_rule_for_hard_disks(radius, fa):
    """Hard circles: ∫T_a T_s = 1 - F_a over the plane, so the lobe carries
    F_a (1 - F_a) (it was 0.2073 instead of 0.21 for Circle(2) + HardDisk(0.3)
    before the evanescent tail was added).  The table's own sum-rule error is
    <= 0.1 % (benchmarks/results/hard_disk.json)."""
    m = Material(corona.Circle(radius), corona.HardDisk(fa))
    assert m.diffuse_transmittance() == pytest.approx(fa * (1 - fa), rel=1e-3)
    assert m.tabulated_transmittance < m.diffuse_transmittance()


def test_propagating_transmittance_is_at_most_plane_integral():
    m = Material(corona.Circle(0.3), corona.Poisson(0.3))
    full = m.diffuse_transmittance()
    prev = np.inf
    for c in [1.0, 0.8, 0.5, 0.2, 0.0]:
        e = m.diffuse_transmittance(550.0, cos_theta_i=c)
        assert 0 < e <= full + 1e-12
        assert e <= prev + 1e-12  # grazing incidence loses more to the evanescent cut
        prev = e


def test_propagating_transmittance_against_monte_carlo():
    m = Material(corona.Circle(0.3), corona.Poisson(0.3))
    rng = np.random.default_rng(5)
    d = m.sample(rng.random((400000, 2)), 600.0)
    s = np.sin(np.radians(50))
    inside = np.hypot(d[:, 0] - s, d[:, 1]) <= 1.0
    mc = m.tabulated_transmittance * inside.mean()
    assert m.diffuse_transmittance(600.0, cos_theta_i=np.cos(np.radians(50))) == pytest.approx(mc, rel=5e-3)


def test_sample_follows_pdf_radial_chi2():
    m = Material(corona.Circle(0.5), corona.Poisson(0.3))
    lam = 500.0
    rng = np.random.default_rng(6)
    d = m.sample(rng.random((200000, 2)), lam)
    r = np.hypot(d[:, 0], d[:, 1])
    edges = np.linspace(0, 1.2, 61)
    rr = np.linspace(0, 1.2, 120001)
    dens = m.pdf(np.stack([rr, 0 * rr], -1), lam) * 2 * np.pi * rr
    cdf = np.concatenate([[0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(rr))])
    expected = np.diff(np.interp(edges, rr, cdf)) * r.size
    observed = np.histogram(r, edges)[0]
    keep = expected > 5
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3
    # the angle is uniform
    phi = np.arctan2(d[:, 1], d[:, 0])
    assert stats.kstest((phi + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-3


def test_pdf_is_lobe_over_its_integral():
    """Perfect importance sampling: pdf ∝ tabulated lobe, normalised over the plane."""
    m = Material(corona.Circle(0.7), corona.Poisson(0.3))
    d = np.random.default_rng(7).uniform(-1, 1, (1000, 2))
    ratio = m.lobe_tabulated(d, 480) / m.pdf(d, 480)
    keep = m.pdf(d, 480) > 0
    np.testing.assert_allclose(ratio[keep], m.tabulated_transmittance, rtol=1e-9)


def test_bad_input_errors():
    with pytest.raises(corona.CoronaError, match="radius"):
        corona.Circle(-1)
    with pytest.raises(corona.CoronaError, match="area_fraction"):
        corona.Poisson(1.5)
    with pytest.raises(corona.CoronaError, match="mode"):
        Material(corona.Circle(1), corona.Poisson(0.1), mode="sideways")
    with pytest.raises(corona.CoronaError, match="albedo"):
        Material(corona.Circle(1), corona.Poisson(0.1), albedo=2)
    with pytest.raises(corona.CoronaError, match="wavelength"):
        Material(corona.Circle(1), corona.Poisson(0.1)).lobe(np.zeros(2), 100.0)
    with pytest.raises(corona.CoronaError, match="shape"):
        Material("circle", corona.Poisson(0.1))


def test_table_cache_roundtrip_and_damage(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        return {"values": np.arange(10.0)}

    params = {"test": 1}
    a = tabulated.cached(params, build)
    b = tabulated.cached(params, build)
    assert len(calls) == 1 and np.array_equal(a["values"], b["values"])
    path = tmp_path / (tabulated.cache_key(params) + ".npz")
    path.write_bytes(path.read_bytes()[:50])  # truncate: must be detected and rebuilt
    c = tabulated.cached(params, build)
    assert len(calls) == 2 and np.array_equal(c["values"], np.arange(10.0))
    assert tabulated.cache_info()["tables"] == 1
    assert tabulated.cache_clear() == 1 and tabulated.cache_info()["tables"] == 0


def test_mixture_parameter_follows_the_decoupling_formula():
    """shape=mixture: lobe = (F_a/<|A|>) [<|Â|²> + |<Â>|² (S - 1)] / λ², from Airy amplitudes."""
    from scipy.special import j1

    from corona.parameters import material_from_parameters
    m = material_from_parameters(shape="mixture", mixture="circle:1.0:0.3, circle:1.5:0.7",
                                 process="hard-disk", area_fraction=0.4)
    lam = 0.6  # µm
    d = np.stack([np.linspace(0.005, 0.8, 300), np.zeros(300)], -1)
    q = 2 * np.pi * d[:, 0] / lam
    w, R = np.array([0.3, 0.7]), np.array([1.0, 1.5])
    area = np.pi * R**2
    amp = area[:, None] * 2 * j1(np.outer(R, q)) / np.outer(R, q)          # Â_i(q), real
    mean_sq = (w[:, None] * amp**2).sum(0)                                 # <|Â|²>
    sq_mean = (w[:, None] * amp).sum(0) ** 2                               # |<Â>|²
    S = m.process.structure_factor_at(np.stack([q, 0 * q], -1), m.shape)
    expected = 0.4 / (w @ area) * (mean_sq + sq_mean * (S - 1)) / lam**2
    np.testing.assert_allclose(m.lobe(d, lam * 1e3), expected, rtol=1e-6, atol=1e-9 * expected.max())
    # the exclusion diameter is the largest type's: η = F_a (π σ²/4) / <|A|>
    assert m.process.packing_fraction(m.shape) == pytest.approx(0.4 * np.pi * 3.0**2 / 4 / (w @ area))


@pytest.mark.slow
def test_lattice_table_keeps_each_bragg_peak_weight():
    """The 2D table of a lattice transmits what the exact lobe does into |d| <= 1.

    The Bragg peaks are far narrower than a table cell; each must enter the
    table with its exact weight C(G) W_G (a form factor taken at the cell
    centre instead of at the peak overestimated this by 3.7 % for R = 2.5 µm).
    """
    from corona.model import processes
    from corona.model import shapes
    R, fa = 1.5, 0.3
    a = np.sqrt(np.pi * R**2 / fa)
    m = Material(shapes.Circle(R), processes.Lattice("square", a, jitter=0.1 * a))
    lam = 550.0
    n = 2048                                   # d grid resolving the peaks (rms width ~ 3 points)
    g = (np.arange(n) + 0.5) / n * 2 - 1
    exact = 0.0
    for i in range(0, n, 256):
        dx, dy = np.meshgrid(g, g[i:i + 256])
        inside = dx**2 + dy**2 <= 1
        exact += (m.lobe(np.stack([dx, dy], -1), lam) * inside).sum() * (2 / n) ** 2
    assert m.diffuse_transmittance(lam, cos_theta_i=1.0) == pytest.approx(exact, rel=3e-3)


def test_anisotropic_shape_on_a_powder_lattice_builds_its_table():
    """A square on a randomly oriented lattice: a 2-D table with the powder's radial S
    (the Bragg cell means are for fixed lattices only; this used to raise)."""
    from corona.model import processes
    from corona.model import shapes
    m = Material(shapes.Square(2.0), processes.Lattice("square", 8.0, jitter=0.2, orientation="random"),
                 use_cache=False)
    assert not m.isotropic and m.process.isotropic
    assert np.all(np.isfinite(m.table.values)) and np.all(m.table.values >= 0)
    # non-overlapping squares: the lobe's plane integral (the table plus the form factor's
    # evanescent tail beyond it) is F_a (1 - F_a) (the sum rule).  The powder's Bragg rings are
    # narrower than the table's cells and sampled at its vertices, which misplaces a few % of
    # their weight: measured +2.3 % here (a known limit of 2-D tables for powder lattices)
    fa = m.area_fraction
    assert m.diffuse_transmittance() == pytest.approx(fa * (1 - fa), rel=0.03)


@pytest.mark.parametrize("shape", [
    "spread of random hexagons", "circle", "spread of circles"])
def test_isotropic_shape_on_a_lattice_grid_equals_its_2d_form_factors(shape):
    """On a lattice the lobe is a 2-D table; an isotropic shape's form factors there are evaluated
    radially, once per distance of a vertex from the centre (``Material._grid_form_factors_radial``).
    Vertex by vertex they must equal the shape's own 2-D evaluation (to the orientation quadrature's
    error, 1e-6 of the peak): a wrong distance, a mis-scattered vertex or a radial path that is
    not the shape's would fail."""
    from corona.model.shapes import RandomOrientation, RegularPolygon, SizeDistribution
    shapes = {"spread of random hexagons": SizeDistribution(RandomOrientation(RegularPolygon(6, 1.0, angle=10.0)),
                                                            spread=0.5, distribution="schulz"),
              "circle": corona.Circle(1.0),
              "spread of circles": SizeDistribution(corona.Circle(1.0), spread=0.3)}
    m = Material(shapes[shape], corona.Lattice("square", 3.0, jitter=0.3))
    assert m.shape.isotropic and not m.isotropic
    n, step = 64, 0.11
    P, C = m._grid_form_factors_radial(n, step)
    c = (2 * np.arange(n) + 1 - n) * (0.5 * step)
    q = np.stack(np.meshgrid(c, c, indexing="xy"), -1).reshape(-1, 2)
    pick = np.random.default_rng(3).choice(n * n, 400, replace=False)
    P2, C2 = m._form_factors(q[pick], radial=False)
    assert np.max(np.abs(P.ravel()[pick] - P2)) <= 1e-6 * P2.max()
    assert np.max(np.abs(C.ravel()[pick] - C2)) <= 1e-6 * C2.max()
    # negative control: the same values one vertex off
    assert np.max(np.abs(np.roll(P, 1, axis=1).ravel()[pick] - P2)) > 1e-3 * P2.max()
