"""Hard-disk fluid: simulation, shipped S(qσ, η) table, Percus–Yevick route,
and the HardDisk process (docs/physics.md)."""
import os

import numpy as np
import pytest
from scipy import special

from corona import CoronaError
from corona.model.processes import HardDisk
from corona.reference import hard_disk as hd
from corona.model.shapes import Circle


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------
def _gl_panels(a, b, width, order=16):
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.arange(a, b + 0.5 * width, width)
    edges[-1] = b
    lo, hi = edges[:-1, None], edges[1:, None]
    return ((0.5 * (hi - lo) * x + 0.5 * (hi + lo)).ravel(),
            (0.5 * (hi - lo) * w).ravel())


def sum_rule(process, radius=1.0):
    """``∫ T_a T_s d²d`` for a circle: ``(2π)⁻¹ ∫ P(q) S(q) q dq`` with the
    form factor ``P`` of corona.model.shapes.Circle; integrated in ``u = qR`` up to
    the end of the table (qσ = 40, u = 20), then the exact tail of ``∫ T_a``
    (``J0(U)² + J1(U)²``) plus the small ``(S - 1)`` tail by quadrature."""
    shape = Circle(radius)
    U = 40.0 / 2.0
    u, w = _gl_panels(0.0, U, 0.05)
    q = u / radius
    f = shape.form_factor_radial(q) * process.structure_factor_radial(q, shape) * q
    inner = np.sum(w * f) / (2 * np.pi * radius)
    tail_ta = special.j0(U) ** 2 + special.j1(U) ** 2
    u2, w2 = _gl_panels(U, 3000.0, 0.5, 8)
    q2 = u2 / radius
    f2 = shape.form_factor_radial(q2) * (process.structure_factor_radial(q2, shape) - 1.0) * q2
    return inner + tail_ta + np.sum(w2 * f2) / (2 * np.pi * radius)


def pair_distances_ok(pos, L):
    """Independent overlap check: all periodic pair distances >= σ = 1."""
    d = pos[:, None, :] - pos[None, :, :]
    d -= L * np.round(d / L)
    r2 = (d**2).sum(-1)
    np.fill_diagonal(r2, np.inf)
    return np.sqrt(r2.min())


# --------------------------------------------------------------------------
# the shipped table
# --------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.reference
def test_table_file_and_metadata():
    from corona.model.processes.base import DATA
    path = os.path.join(DATA, "hard_disk_structure_factor.npz")
    assert os.path.getsize(path) < 2e6
    t = hd.load_table()
    m = t["metadata"]
    assert m["format_version"] == hd.TABLE_FORMAT_VERSION
    assert m["n_disks"] >= 2000 and "seed" in m and "date" in m
    assert t["eta"][0] == 0.0 and abs(t["eta"][-1] - 0.72) < 1e-12
    assert np.all(np.diff(t["eta"]) > 0)
    assert t["q_sigma"][0] == 0.0 and abs(t["q_sigma"][-1] - 40.0) < 1e-9
    assert t["S"].shape == (t["eta"].size, t["q_sigma"].size)
    assert np.all(np.isfinite(t["S"])) and np.all(t["S"] > 0)
    assert np.all(t["min_distance"][1:] >= 1.0 - 1e-9)      # no overlaps in any run


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("eta, rel_tol", [(0.3, 0.03), (0.5, 0.04)])
def test_table_compressibility_limit_vs_henderson(eta, rel_tol):
    # docs/physics.md#hard-disk-thermodynamics: S(0) = 1/(d(ηZ)/dη) ≈ 0.258 at η=0.3, 0.079 at η=0.5
    ref = float(hd.henderson_structure_factor_zero(eta))
    assert abs(ref - {0.3: 0.258, 0.5: 0.079}[eta]) < 0.001
    S0 = HardDisk(eta).structure_factor(np.array([0.0]))[0]
    assert abs(S0 / ref - 1) < rel_tol, (S0, ref)


@pytest.mark.slow
@pytest.mark.reference
def test_table_pressure_and_contact_value_vs_henderson():
    t = hd.load_table()
    eta, Z = t["eta"], t["Z"]
    # pressure: within 0.3 % of Henderson up to η = 0.4 (where Henderson is
    # that good) and 1.5 % up to η = 0.6 (Henderson overestimates there)
    for hi, tol in ((0.4, 0.003), (0.6, 0.015)):
        sel = (eta > 0) & (eta <= hi + 1e-9)
        assert np.max(np.abs(Z[sel] / hd.henderson_compressibility_factor(eta[sel]) - 1)) < tol
    # contact value extrapolated from g(r): agrees with the pressure route
    # (Z - 1)/(2η) within 3 standard errors (+0.3 %) at every η, and with
    # Henderson within 3 standard errors (+1 %) up to η = 0.55
    sel = eta > 0
    gc, gc_err = t["contact_value"][sel], t["contact_value_err"][sel]
    gz = (Z[sel] - 1) / (2 * eta[sel])
    assert np.all(np.abs(gc - gz) < 3 * gc_err + 0.003 * gz)
    sel2 = eta[sel] <= 0.55
    gh = hd.henderson_contact_value(eta[sel][sel2])
    assert np.all(np.abs(gc[sel2] - gh) < 3 * gc_err[sel2] + 0.01 * gh)


def test_table_tends_to_one_at_large_q_and_is_continuous_at_the_join():
    q_far = np.linspace(300, 3000, 2001)
    for eta in (0.05, 0.3, 0.5, 0.65, 0.7, 0.72):
        p = HardDisk(eta)
        assert np.max(np.abs(p.structure_factor(q_far) - 1)) < 0.01
        near = np.max(np.abs(p.structure_factor(np.linspace(40, 80, 801)) - 1))
        far = np.max(np.abs(p.structure_factor(np.linspace(200, 400, 801)) - 1))
        assert far < near
        a, b = p.structure_factor(np.array([40.0 - 1e-9, 40.0 + 1e-9]))
        assert abs(a - b) < 1e-6


@pytest.mark.slow
@pytest.mark.reference
def test_table_rows_have_no_spikes():
    t = hd.load_table()
    q = t["q_sigma"]
    for eta, row in zip(t["eta"], t["S"]):
        if eta == 0:
            continue
        # a spike is a point its neighbours do not predict: a cubic spline
        # through every other grid point must reproduce the points between
        from scipy.interpolate import CubicSpline
        pred = CubicSpline(q[::2], row[::2])(q[1::2])
        assert np.max(np.abs(pred - row[1::2])) < 0.01 * max(1.0, row.max()), eta
        if eta <= 0.69:
            # a fluid: one maximum per oscillation (period ≈ 2π/σ), nothing else
            i = np.flatnonzero((row[1:-1] > row[:-2]) & (row[1:-1] > row[2:]))
            assert len(i) <= 7, (eta, q[i + 1])
            # below the first peak S rises monotonically (no low-q wiggles)
            k = np.argmax(row)
            assert np.all(np.diff(row[: int(0.8 * k)]) > -1e-4), eta


@pytest.mark.slow
@pytest.mark.reference
def test_interpolation_between_rows_is_bounded_by_the_rows():
    t = hd.load_table()
    q = t["q_sigma"][::7]
    i = int(np.searchsorted(t["eta"], 0.3))
    lo, hi = hd.structure_factor_table(q, t["eta"][i]), hd.structure_factor_table(q, t["eta"][i + 1])
    mid = hd.structure_factor_table(q, 0.5 * (t["eta"][i] + t["eta"][i + 1]))
    assert np.all(mid >= np.minimum(lo, hi) - 1e-12) and np.all(mid <= np.maximum(lo, hi) + 1e-12)
    # at a row the interpolation returns the row
    assert np.allclose(hd.structure_factor_table(t["q_sigma"], t["eta"][i]), t["S"][i], atol=1e-12)


@pytest.mark.parametrize("fa", [0.1, 0.3, 0.5, 0.65])
def test_sum_rule_circles(fa):
    # docs/physics.md#the-model: ∫ T_a T_s d²d = 1 - F_a exactly for non-overlapping disks
    got = sum_rule(HardDisk(fa))
    assert abs(got / (1 - fa) - 1) < 0.005, got


def test_sum_rule_quadrature_itself():
    # with S = 1 the same quadrature must give ∫ T_a = 1
    from corona.model.processes import Poisson
    assert abs(sum_rule(Poisson(0.3)) - 1) < 1e-6


# --------------------------------------------------------------------------
# Percus–Yevick route
# --------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.reference
def test_percus_yevick_low_density_limits():
    q = np.linspace(0, 40, 801)
    # compressibility limit and contact value close to Henderson at low η
    assert abs(hd.structure_factor_py(0.0, 0.1) / hd.henderson_structure_factor_zero(0.1) - 1) < 0.002
    assert abs(hd.contact_value_percus_yevick(0.1) / hd.henderson_contact_value(0.1) - 1) < 0.01
    assert np.all(hd.structure_factor_py(q, 0.0) == 1.0)
    # PY sets h = -1 inside the core exactly, so it obeys the sum rule too
    class PY:      # (S_PY - 1 beyond qσ = 100 is < 1e-3 and adds < 1e-6 here)
        def structure_factor_radial(self, q_abs, shape):
            qs = np.asarray(q_abs) * 2 * shape.radius
            out = np.ones_like(qs)
            out[qs <= 100] = hd.structure_factor_py(qs[qs <= 100], 0.5)
            return out
    assert abs(sum_rule(PY()) / 0.5 - 1) < 1e-3


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("eta, tol", [(0.1, 0.006), (0.2, 0.01)])
def test_percus_yevick_agrees_with_simulation_at_low_density(eta, tol):
    q = np.linspace(0, 40, 1601)
    diff = np.abs(HardDisk(eta).structure_factor(q) - hd.structure_factor_py(q, eta))
    assert diff.max() < tol, diff.max()


# --------------------------------------------------------------------------
# simulation
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_run():
    return hd.simulate_hard_disks(0.5, n_disks=400, n_sweeps=4000, n_equilibration=1000,
                                  sample_every=50, seed=7, progress=False)


@pytest.mark.slow
def test_simulation_has_no_overlaps(short_run):
    r = short_run
    assert r.min_distance >= 1.0 - 1e-9
    for pos in list(r.positions) + list(r.snapshots):
        assert np.all((pos >= 0) & (pos < r.box_length))
        assert pair_distances_ok(pos, r.box_length) >= 1.0 - 1e-9
    assert abs(r.n_disks * np.pi / 4 / r.box_length**2 - 0.5) < 1e-12


@pytest.mark.slow
@pytest.mark.reference
def test_simulation_thermodynamics_vs_henderson(short_run):
    r = short_run
    # pressure: Henderson's Z is within ~0.5 % of the exact one at η = 0.5
    Zh = float(hd.henderson_compressibility_factor(0.5))
    assert abs(r.compressibility_factor / Zh - 1) < 0.015
    # contact value extrapolated from g(r): within 4 % of (Z - 1)/(2η)
    gh = float(hd.henderson_contact_value(0.5))
    assert abs(r.contact_value / gh - 1) < 0.04, (r.contact_value, gh)
    # the two routes to g(σ⁺) agree
    assert abs(r.contact_value / r.contact_value_pressure - 1) < 0.04
    # g vanishes inside the core and tends to 1
    assert np.all(r.g[r.r_sigma < 0.99] == 0)
    assert abs(np.mean(r.g[(r.r_sigma > 4) & (r.r_sigma < 5)]) - 1) < 0.03
    # S(k) tends to 1 and has its first peak near qσ ≈ 5.8
    assert abs(np.mean(r.S[r.q_sigma > 30]) - 1) < 0.02
    assert 5.4 < r.q_sigma[np.argmax(r.S)] < 6.2
    assert np.all(np.isfinite(r.S_err[r.q_sigma > 1]))


@pytest.mark.slow
@pytest.mark.reference
def test_simulation_is_reproducible():
    kw = dict(n_disks=100, n_sweeps=200, n_equilibration=100, sample_every=50, progress=False)
    a = hd.simulate_hard_disks(0.4, seed=3, **kw)
    b = hd.simulate_hard_disks(0.4, seed=3, **kw)
    c = hd.simulate_hard_disks(0.4, seed=4, **kw)
    assert np.array_equal(a.S, b.S) and np.array_equal(a.positions, b.positions)
    assert not np.array_equal(a.positions, c.positions)


@pytest.mark.slow
@pytest.mark.reference
def test_compressed_start_is_a_valid_configuration():
    r = hd.simulate_hard_disks(0.68, n_disks=150, n_sweeps=100, n_equilibration=50,
                               sample_every=50, seed=1, progress=False, start="compressed")
    assert pair_distances_ok(r.positions[0], r.box_length) >= 1.0 - 1e-9


# --------------------------------------------------------------------------
# the process
# --------------------------------------------------------------------------
def test_process_geometry_and_radial_lookup():
    c = Circle(0.5)
    p = HardDisk(0.4)
    assert p.isotropic and p.area_fraction(c) == 0.4
    assert abs(p.packing_fraction(c) - 0.4) < 1e-12          # σ = 2R: η = F_a
    q = np.linspace(0, 100, 1001)                             # rad/µm, σ = 1 µm
    assert np.allclose(p.structure_factor_radial(q, c), p.structure_factor(q))
    qv = np.stack([q, np.zeros_like(q)], -1)
    assert np.allclose(p.structure_factor_at(qv, c), p.structure_factor(q))
    p2 = HardDisk(0.2, exclusion_diameter=1.5)                # larger exclusion disks
    assert abs(p2.packing_fraction(c) - 0.2 * 1.5**2) < 1e-12
    assert np.allclose(p2.structure_factor_radial(q, c), p2.structure_factor(q * 1.5, 0.45))
    assert "HardDisk" in repr(p2) and p2.key()["type"] == "HardDisk"


@pytest.mark.slow
@pytest.mark.reference
def test_bad_inputs():
    for bad in (0.0, 1.0, -0.1, float("nan"), "x"):
        with pytest.raises(CoronaError):
            HardDisk(bad)
    with pytest.raises(CoronaError):
        HardDisk(0.3, exclusion_diameter=0.0)
    with pytest.raises(CoronaError, match=r"area_fraction=0.8 gives packing fraction 0.8 > 0.72.*"
                                          r"allowed area_fraction ≤ 0.72"):
        HardDisk(0.8).validate(Circle(1.0))
    with pytest.raises(CoronaError, match="allowed area_fraction"):
        HardDisk(0.5, exclusion_diameter=3.0).structure_factor_radial([1.0], Circle(1.0))
    HardDisk(0.72).validate(Circle(1.0))
    with pytest.raises(CoronaError):
        HardDisk(0.3).structure_factor([1.0], packing_fraction=0.75)
    with pytest.raises(CoronaError):
        hd.structure_factor_py([1.0], 0.9)
    for eta in (0.0, 0.85, "x"):
        with pytest.raises(CoronaError):
            hd.simulate_hard_disks(eta, n_disks=100, n_sweeps=10, progress=False)
    with pytest.raises(ValueError):
        hd.simulate_hard_disks(0.3, n_disks=10, n_sweeps=10, progress=False)
    with pytest.raises(ValueError):
        hd.simulate_hard_disks(0.3, n_disks=100, n_sweeps=10, progress=False, start="bogus")
