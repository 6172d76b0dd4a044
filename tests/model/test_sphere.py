"""Layers of Mie spheres (corona.Sphere, the sphere material): normalisation, tables, energy, sampling."""
import warnings

import numpy as np
import pytest
from scipy import signal, special, stats

import corona
from corona import CoronaError
from corona.model.mie import theory as mie
from corona.parameters import material_from_parameters


@pytest.fixture(scope="module")
def poisson():
    return corona.Material(corona.Sphere(5.0), corona.Poisson(0.05))


@pytest.fixture(scope="module")
def hard_disk():
    # the radius of ``poisson``: its tests check properties that hold at any radius (furnace,
    # sampling against the pdf, the forward energy by quadrature), and the two layers then share
    # one table of Mie rows (the rows depend on the sphere alone; the process comes after them)
    return corona.Material(corona.Sphere(5.0), corona.HardDisk(0.3))


def _dirs(rng, n, hemisphere=None):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if hemisphere is not None:
        v[:, 2] = hemisphere * np.abs(v[:, 2])
    return v


def test_material_dispatch_and_inputs(poisson):
    from corona.model.mie.material import SphereMaterial
    assert isinstance(poisson, SphereMaterial)
    assert poisson.mode == "particle"
    with pytest.raises(CoronaError, match="mode='aperture'"):
        corona.Material(corona.Sphere(5.0), corona.Poisson(0.1), mode="aperture")
    with pytest.raises(CoronaError, match="albedo"):
        corona.Material(corona.Sphere(5.0), corona.Poisson(0.1), albedo=0.5)
    with pytest.raises(CoronaError, match="size distribution"):
        corona.Material(corona.SoftEdge(corona.Sphere(5.0), 0.1), corona.Poisson(0.1))
    with pytest.raises(CoronaError, match="ior=-1"):
        corona.Sphere(5.0, ior=-1.0)
    with pytest.raises(CoronaError, match="κ"):
        corona.Sphere(5.0, ior=1.33 - 0.1j)
    with pytest.raises(CoronaError, match="planar transmission profile"):
        corona.Sphere(5.0).form_factor_radial(1.0)


def test_parameters():
    m = material_from_parameters(shape="sphere", radius=3.0, area_fraction=0.1, process="poisson")
    assert m.sphere.radius == 3.0 and m.sphere.ior is None and m.mode == "particle"
    m = material_from_parameters(shape="sphere", radius=3.0, ior=1.5, ior_imag=0.01, size_spread=0.1)
    assert m.sphere.ior == 1.5 + 0.01j and m.sizes.spread == 0.1
    for bad, msg in [(dict(ior=1.5), "need shape='sphere'"),
                     (dict(shape="sphere", ior_imag=0.1), "needs ior"),
                     (dict(shape="sphere", mode="aperture"), "mode='aperture'"),
                     (dict(shape="sphere", process="lattice-hex", size_spread=0.1),
                      "size_spread=0.1 is out of range for shape='sphere' on a lattice"),
                     (dict(shape="sphere", ior=-2.0), "ior=-2")]:
        with pytest.raises(CoronaError, match=msg):
            material_from_parameters(**bad)


def test_normalisation_is_n_dsigma_domega(poisson):
    # at normal incidence, eval = f |cos θo| = n dσ/dΩ with n = F_a / (π r²) and
    # dσ/dΩ = (|S1|² + |S2|²) / (2k²), independently from corona.model.mie.theory (cap inactive: w = 1)
    lam = 550.0
    theta = np.radians([0.5, 2.0, 10.0, 60.0, 120.0, 170.0, 179.5])
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], -1)
    e = poisson.energies(1.0, lam)
    assert e["weight"] < 1.0                     # Poisson: 1 + O(F_a²) is capped
    val = poisson.eval(wi, wo, lam, exact=True) / e["weight"]
    n = 0.05 / (np.pi * 5.0**2)
    ref = n * mie.differential_cross_section(mie.water_ior(lam), 5.0, lam * 1e-3, np.cos(theta))
    assert val == pytest.approx(ref, rel=1e-10)


def test_tables_match_mie(poisson):
    # (a) at a row's wavelength the tabulated lobe (linear in the chord) is Mie at each direction
    # to 1 % (median where the lobe exceeds 1e-3 of its peak), forward (Θ < 10°) and backward
    # (Θ > 160°, the glory), at oblique incidence
    from corona.model.mie.layer import frame
    rng = np.random.default_rng(1)
    wi = np.array([0.3, 0.1, np.sqrt(1 - 0.1)])
    lam = float(poisson.rows["wavelength"][40])
    th = np.concatenate([np.radians(rng.uniform(0, 10, 300)), np.radians(rng.uniform(160, 180, 300))])
    ph = rng.uniform(0, 2 * np.pi, th.size)
    e1, e2 = frame(-wi)
    wo = np.cos(th)[:, None] * -wi + np.sin(th)[:, None] * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2)
    tab, ex = poisson.eval(wi, wo, lam), poisson.eval(wi, wo, lam, exact=True)
    for sel in (slice(0, 300), slice(300, 600)):
        big = ex[sel] > 1e-3 * ex[sel].max()
        assert np.median(np.abs(tab[sel][big] / ex[sel][big] - 1)) < 0.01
    # (b) between rows the lobe is interpolated linearly in x: Mie's resonance ripple in x is
    # not followed, but what a spectral render sees, the lobe averaged over a 20 nm band, is:
    # within 2 % in the corona (Θ < 10°) and 10 % over the glory (170° … 179.5°)
    wi = np.array([0.0, 0.0, 1.0])
    deg = np.array([0, 1, 2, 3, 4, 6, 8, 10, 170, 172, 174, 176, 178, 179, 179.5])
    th = np.radians(deg)
    wo = np.stack([np.sin(th), 0 * th, -np.cos(th)], -1)
    lams = np.linspace(540.0, 560.0, 81)
    tab = np.mean([poisson.eval(wi, wo, v) for v in lams], 0)
    ex = np.mean([poisson.eval(wi, wo, v, exact=True) for v in lams], 0)
    rel = np.abs(tab / ex - 1)
    assert rel[deg < 90].max() < 0.02
    assert rel[deg > 90].max() < 0.10


def test_rows_sorted_in_place(poisson):
    # the refinement sorts its rows into place (corona.model.mie.layer._gather_rows_in_place, no copy
    # of the table): the permutation against numpy's fancy indexing, and a built table's rows in
    # strictly increasing x, each the lobe of its own x (test_tables_match_mie checks a row's values)
    from corona.model.mie.layer import _gather_rows_in_place
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 500):
        a, b = rng.random((n, 5)), rng.random(n)
        src = rng.permutation(n)
        want_a, want_b = a[src], b[src]
        _gather_rows_in_place([a, b], src)
        assert np.array_equal(a, want_a) and np.array_equal(b, want_b)
    x = poisson.rows["x"]
    assert np.all(np.diff(x) > 0)
    assert np.allclose(poisson.rows["wavelength"], 2e3 * np.pi * poisson.sphere.radius / x)


def test_row_energies_are_q_sca(poisson):
    # the rows' ∫ P dΩ over both hemispheres is Q_sca of the series (to the tables' accuracy)
    d = poisson._derived
    r = poisson.rows
    qs = np.array([mie.efficiencies(mie.water_ior(lam), x)["q_sca"] for lam, x in
                   zip(r["wavelength"][::40], r["x"][::40])])
    assert (d["T_f"] + d["T_b"])[::40] == pytest.approx(qs, rel=2e-3)
    assert r["q_sca"][::40] == pytest.approx(qs, rel=1e-10)
    assert np.all(d["e_f"] == d["T_f"])        # Poisson: S = 1


@pytest.mark.parametrize("which", ["poisson", "hard_disk"])
def test_white_furnace(which, request):
    m = request.getfixturevalue(which)
    for deg in (0, 30, 60, 80):
        for lam in (400.0, 700.0):
            e = m.directional_albedo(np.cos(np.radians(deg)), lam, n_phi=128)
            assert e["total"] <= 1.0 + 2e-4, (deg, lam, e)
            assert e["coherent"] >= 0 and e["forward"] > 0 and e["backward"] > 0


def test_energy_closure_dilute_absorbing():
    # coherent + scattered + absorbed = 1 in the dilute limit (first order in F_a):
    # |1 - F_a s0|² + F_a Q_sca = 1 - F_a Q_abs + O(F_a²)
    fa = 1e-3
    m = corona.Material(corona.Sphere(2.0, ior=1.33 + 0.002j), corona.Poisson(fa))
    e = m.directional_albedo(1.0, 550.0)
    q = mie.efficiencies(1.33 + 0.002j, 2 * np.pi * 2.0 / 0.55)
    assert q["q_abs"] > 0.1
    assert e["total"] == pytest.approx(1 - fa * q["q_abs"], abs=3 * fa * fa + 2e-6)


@pytest.mark.slow
def test_large_droplets_coherent_is_one_minus_fa_squared():
    # optical theorem: t = 1 - F_a s0 with s0 -> 1 for large spheres: (1 - F_a)² like opaque disks
    m = corona.Material(corona.Sphere(12.0), corona.HardDisk(0.3))
    c = m.coherent_transmission(1.0, 500.0)
    assert c == pytest.approx(0.49, rel=0.04)
    # and Babinet's diffraction peak: near Θ = 0 the lobe is that of opaque disks times |s0|²,
    # the forward amplitude relative to the disk's (S(0) = s0 x²/2; s0 -> 1 as x -> ∞)
    disk = corona.Material(corona.Circle(12.0), corona.HardDisk(0.3), mode="particle")
    d = np.array([[1e-3, 0.0], [4e-3, 0.0], [7e-3, 0.0]])        # u = 2π r |d| / λ < 1.1
    j, t = m._row(500.0)
    s0 = complex(*(m.rows["s0"][j] * (1 - t) + m.rows["s0"][j + 1] * t))
    assert 1.02 < abs(s0) ** 2 < 1.10
    w = float(m.energies(1.0, 500.0)["weight"])       # the energy cap, a factor of its own
    assert m.lobe(d, 500.0) / w == pytest.approx(disk.lobe(d, 500.0) * abs(s0) ** 2, rel=0.02)


def test_mie_corona_is_not_airy():
    # the claim, measured: water droplets of 10 µm at 550 nm have their first minimum
    # about 8 % inside Airy's u = 3.8317 and a first ring about twice as bright relative to the centre
    x = 2 * np.pi * 5.0 / 0.55
    th = np.linspace(1e-4, 0.1, 20000)
    s1, s2 = mie.amplitudes(mie.water_ior(550.0), x, np.cos(th))
    inten = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2)
    u = x * np.sin(th)
    u_min = u[signal.argrelmin(inten)[0][0]]
    ring = inten[signal.argrelmax(inten)[0][0]] / inten[0]
    airy_ring = (2 * special.j1(5.1356) / 5.1356) ** 2
    assert 0.05 < 1 - u_min / 3.8317 < 0.11
    assert 1.7 < ring / airy_ring < 2.4


def test_sampling_matches_pdf(hard_disk):
    # chords drawn by sample_lobe follow pdf_lobe (Kolmogorov-Smirnov on the chord's CDF, computed
    # from the pdf by quadrature), forward and backward, at a wavelength between two rows
    rng = np.random.default_rng(3)
    wi = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    r = hard_disk.rows
    lam = 0.3 * r["wavelength"][10] + 0.7 * r["wavelength"][11]
    from corona.model.mie.layer import frame
    for which, axis in (("f", -wi), ("b", wi)):
        wo = hard_disk.sample_lobe(which, wi, rng.random((4000, 3)), lam)
        assert np.allclose(np.linalg.norm(wo, axis=1), 1.0)
        s = np.linalg.norm(wo - axis, axis=1)
        e1, e2 = frame(axis)
        grid = np.linspace(0, np.sqrt(2), 4001)
        dirs = (1 - 0.5 * grid**2)[:, None] * axis + (grid * np.sqrt(1 - 0.25 * grid**2))[:, None] * e1
        pdf = hard_disk.pdf_lobe(which, wi, dirs, lam) * 2 * np.pi * grid      # density of the chord
        cdf = np.concatenate([[0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(grid))])
        assert cdf[-1] == pytest.approx(1.0, abs=2e-3)
        p = stats.kstest(s, lambda v: np.interp(v, grid, cdf / cdf[-1])).pvalue
        assert p > 1e-3, (which, p)


def test_size_distribution_smooths_the_glory():
    # a 10 % lognormal spread of radii washes out the glory's rings: the backscattered lobe
    # varies less around Θ = 180° than for one size
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = corona.Material(corona.Sphere(1.5), corona.Poisson(0.05))
        many = corona.Material(corona.SizeDistribution(corona.Sphere(1.5), 0.1), corona.Poisson(0.05))
    th = np.radians(np.linspace(160, 179.9, 400))
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(th), 0 * th, -np.cos(th)], -1)
    ripple = lambda v: np.std(np.diff(np.log(v), 2))          # curvature of log: the rings
    one_r = sum(ripple(one.eval(wi, wo, lam)) for lam in (450.0, 550.0, 650.0))
    many_r = sum(ripple(many.eval(wi, wo, lam)) for lam in (450.0, 550.0, 650.0))
    assert many_r < 0.6 * one_r
    # ⟨C⟩ <= ⟨P⟩ (Cauchy–Schwarz) and equality at Θ = 0 only for one size
    r = many.rows
    assert np.all(r["C_f"] <= r["P_f"] * (1 + 1e-9))


# --- the size range a sphere layer's tables hold --------------------------------------------------
@pytest.mark.parametrize("radius", [5.0, 20.0, 25.0])
def test_size_spread_is_limited_by_the_largest_droplets(radius):
    from corona.model.mie.layer import SPHERE_SIZES_MAX, largest_sphere, largest_spread
    allowed = largest_spread(radius)
    assert 0.0 < allowed < 0.5
    # the bisection's answer: at the allowed spread the largest droplets are at the limit
    assert largest_sphere(radius, allowed) <= SPHERE_SIZES_MAX < largest_sphere(radius, allowed * 1.01)
    corona.Material(corona.SizeDistribution(corona.Sphere(radius), allowed), corona.Poisson(0.05))
    with pytest.raises(corona.CoronaError) as err:
        corona.Material(corona.SizeDistribution(corona.Sphere(radius), min(0.5, allowed * 1.05)),
                        corona.Poisson(0.05))
    msg = str(err.value)
    assert "size_spread=" in msg and f"radius={radius:g}" in msg and f"<= {allowed:.3g}" in msg
    assert "\n" not in msg


def test_largest_sphere_holds_the_scattered_power_of_the_distribution():
    # independent check of the tail: the lognormal's scattered power s² p(s) beyond the top is ~1e-6
    from scipy import stats
    from corona.model.mie.layer import SIZE_TAIL, largest_sphere
    radius, spread = 10.0, 0.2
    top = largest_sphere(radius, spread) / radius
    sigma = np.sqrt(np.log1p(spread ** 2))
    mu = -0.5 * sigma ** 2                         # mean size 1
    # s² p(s) of a lognormal is a lognormal with mu + 2 sigma² (up to its normalisation)
    beyond = stats.lognorm(sigma, scale=np.exp(mu + 2 * sigma ** 2)).sf(top)
    assert SIZE_TAIL / 3 < beyond < SIZE_TAIL * 3


def test_forward_energy_with_structure_factor_by_quadrature(hard_disk):
    # e_f(x_j, μ) = T_f + ∫ C (S(q) - 1) dΩ over the forward lobe, against a direct quadrature on a
    # fine (chord, azimuth) grid with S at each direction's own in-plane q (no coarse grids of
    # ⟨S⟩_φ); the cap's margin (ENERGY_MARGIN, 0.4 %) bounds what the table may be off
    from corona.model.mie.layer import CHORD_MAX, INCIDENCE_MU, frame
    m = hard_disk
    r, d = m.rows, m._derived
    C = r["C_f"] if r["C_f"].size else r["P_f"]
    s_nodes = np.arange(C.shape[1]) * float(r["ds"])
    s = np.linspace(0.0, CHORD_MAX, 4001)[1:]
    ws = np.full(s.size, s[1] - s[0])
    ws[-1] *= 0.5
    phi = (np.arange(256) + 0.5) * (2 * np.pi / 256)
    cos_t, sin_t = 1 - 0.5 * s * s, s * np.sqrt(1 - 0.25 * s * s)
    rows = np.linspace(0, r["x"].size - 1, 5).astype(int)
    worst = 0.0
    for k in (0, 5, 9):                     # μ = 1, 0.5, 0.1
        mu = INCIDENCE_MU[k]
        wi = np.array([np.sqrt(1 - mu * mu), 0.0, mu])
        wt = -wi
        e1, e2 = frame(wt)
        wo = cos_t[:, None, None] * wt + sin_t[:, None, None] * (np.cos(phi)[None, :, None] * e1
                                                                  + np.sin(phi)[None, :, None] * e2)
        q_xy = np.linalg.norm((wo - wt)[..., :2], axis=-1)          # |(wo + wi)_xy|, (s, φ)
        for j in rows:
            Cs = np.interp(s, s_nodes, C[j])
            S1 = m.structure_factor(r["x"][j] * q_xy) - 1.0
            ref = d["T_f"][j] + np.sum(Cs * s * ws * np.sum(S1, axis=1) * (2 * np.pi / phi.size))
            got = d["e_f_mu"][j, k]
            worst = max(worst, abs(got / ref - 1))
            assert got == pytest.approx(ref, rel=4e-3), (k, j, got, ref)
    # the structure factor matters here: S = 1 would be off by more than the tolerance
    assert np.max(np.abs(d["e_f_mu"][rows] / d["T_f"][rows, None] - 1)) > 0.05
