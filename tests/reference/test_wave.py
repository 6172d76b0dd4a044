"""The brute-force wave-optics reference (corona.wave) and its comparison with the
model (corona.validate): a small version of ``corona validate`` (docs/physics.md#validation-figures).

Bounds.  The brute force is a Monte Carlo average, so every bound is the
statistical error (split-half estimate ``noise``, printed by the comparison)
plus a small allowance for the rasteriser (anti-aliasing: single scatterers
agree with their analytic transform to ≤ 0.25 % up to u = 16 with 16
samples per radius, averaged over 32 sub-pixel offsets; the bound there is
0.5 %): ``rms ≤ 1.5 noise + 1 %`` and
``|mean error| ≤ 1 %`` (the mean over ~60 bins has ~noise/8 scatter).  The
seeds are fixed, so the numbers are reproducible.
"""
import math
import os
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import fft as sp_fft

from corona import CoronaError, CoronaWarning, Material
from corona.model import shapes
from corona.apps.cli import main
from corona.model.processes import HardDisk
from corona.model.processes import Lattice, Poisson, Process
from corona.reference import wave
from corona.reference.validate import blob_mask_image, compare, select_cases, all_cases

R = 2.5
LAMS = (400.0, 550.0, 700.0)


def _bound(m):
    return 1.5 * m["noise"] + 0.01


# ----------------------------------------------------------------------
# the rasteriser: one scatterer against its analytic transform
# ----------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("shape,exact", [
    (shapes.Circle(1.0), False),
    (shapes.RegularPolygon(6, 1.0), False),
    (shapes.Square(math.sqrt(0.5), angle=17.0), False),
    (shapes.Mask(blob_mask_image(), 1.0 / 18.0), True),
])
def test_single_scatterer_matches_form_factor(shape, exact):
    rng = np.random.default_rng(3)
    n, M = 256, 32
    h = shape.pixel_size if exact else shape.length_scale / 16
    g = wave.Grid(n, n, h, h)
    P = 0.0
    for _ in range(M):
        t = wave.rasterise(shape, rng.uniform(0, n * h, (1, 2)), g, rng=rng, exact_masks=exact)
        P = P + np.abs(sp_fft.fft2(t)) ** 2
    P = P / M * h**4                                    # |T̂|² with T̂ = h² FFT
    q1 = 2 * np.pi * sp_fft.fftfreq(n, h)
    QX, QY = np.meshgrid(q1, q1, indexing="xy")
    model = shape.form_factor(np.stack([QX, QY], -1)) * shape.area
    if not exact:                                       # the edge ramp's transfer
        P = P / np.sinc(np.hypot(QX, QY) * h / (2 * np.pi)) ** 2
    u = np.hypot(QX, QY) * shape.length_scale
    for lo, hi in [(0, 3), (3, 6), (6, 10), (10, 16)]:
        sel = (u >= lo) & (u < hi) & (model > 1e-3 * model.max())
        ratio = P[sel].sum() / model[sel].sum()
        assert abs(ratio - 1) < 5e-3, (lo, hi, ratio)


@pytest.mark.slow
@pytest.mark.reference
def test_random_shape_draws():
    rng = np.random.default_rng(0)
    sd = shapes.SizeDistribution(shapes.Circle(1.0), 0.2)
    mix = shapes.Mixture([(shapes.RandomOrientation(shapes.Square(1.0)), 3.0),
                          (shapes.SoftEdge(sd, 0.05), 1.0)])
    d = wave._draw(mix, 40000, rng)
    assert len(d.leaves) == 2
    sq = d.leaf == 0
    assert abs(sq.mean() - 0.75) < 0.01
    assert np.all(d.scale[sq] == 1.0) and np.all(d.blur[sq] == 0.0)
    assert abs(d.angle[sq].mean() - np.pi) < 0.05
    s = d.scale[~sq]
    assert abs(s.mean() - 1) < 0.01 and abs(s.std() - 0.2) < 0.01     # number-weighted, mean 1
    assert np.allclose(d.blur[~sq], 0.05)                              # blur outside the scaling


# ----------------------------------------------------------------------
# the ensemble against the model
# ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def hd03():
    m = Material(shapes.Circle(R), HardDisk(0.3), mode="aperture")
    bf = wave.brute_force(m, realisations=24, n_scatterers=600, q_max=1.02 * 2 * np.pi / 0.7,
                          seed=1, progress=False)
    return m, bf, compare(m, bf, LAMS, particle=Material(shapes.Circle(R), HardDisk(0.3),
                                                         mode="particle"))


@pytest.mark.slow
def test_hard_disk_lobe_matches_model(hd03):
    m, bf, res = hd03
    assert bf.pixel_transfer == "ramp-deconvolved" and bf.samples_per_radius >= 16
    for lam in LAMS:
        w = res["wavelengths"][lam]
        assert w["bins"] > 40 and w["u_region"][1] > 8          # the lobe down to 1 % of its peak
        assert w["rms"] <= _bound(w), (lam, w)
        assert abs(w["mean"]) <= 0.01, (lam, w)
        # sum rule on the same grid points (the model integrates to F_a(1-F_a) over the plane)
        assert w["window_brute"] == pytest.approx(w["window_model"], rel=0.01)
    w = res["wavelengths"][700.0]            # the crop covers |d| <= 1 at 700 nm
    assert w["propagating_covered"]
    assert w["propagating_brute"] == pytest.approx(w["propagating_model"], rel=0.01)
    assert res["particle_lobe_equal"]


@pytest.mark.slow
def test_coherent_weights_and_babinet(hd03):
    m, bf, _ = hd03
    fa = m.area_fraction
    assert bf.coherent_weight == pytest.approx(fa**2, rel=2e-3)
    p = bf.with_mode("particle")
    assert p.coherent_weight == pytest.approx((1 - fa) ** 2, rel=2e-3)
    assert p.diffuse_weight == pytest.approx(bf.diffuse_weight, rel=1e-9)    # Babinet
    # Parseval: coherent + diffuse = ⟨mean t²⟩ ≈ F_a (binary screen, less the edge ramp's
    # ∫(c - c²) = h/6 per unit length: F_a · h/(3R) for circles)
    h = bf.grid.h
    assert bf.coherent_weight + bf.diffuse_weight == pytest.approx(fa * (1 - h / (3 * R)), rel=2e-3)


@pytest.mark.slow
@pytest.mark.reference
def test_wrong_factor_would_fail():
    """Poisson screens with linear superposition (the model's own assumption,
    S = 1): ``⟨|T̂|²⟩/(Aλ²) = n|Â|²/λ²`` exactly, for a square (|A| ≠ πR²) at two
    wavelengths.  A 5 % error in any factor (λ², |A|, h², the box area) is
    far outside the bound."""
    sq = shapes.Square(R / math.sqrt(2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CoronaWarning)
        m = Material(sq, Poisson(0.1))
    bf = wave.brute_force(m, realisations=8, n_scatterers=400, q_max=17.0 / R, seed=2,
                          overlaps="add", progress=False)
    res = compare(m, bf, (400.0, 700.0))
    for lam in (400.0, 700.0):
        w = res["wavelengths"][lam]
        assert w["rms"] <= _bound(w) and abs(w["mean"]) <= 0.01, w
        # the same comparison with a model off by 5 %
        wrong = dict(w)
        bad = compare(_Scaled(m, 1.05), bf, (lam,))["wavelengths"][lam]
        assert abs(bad["mean"]) > 0.04 and not (abs(bad["mean"]) <= 0.01), (wrong, bad)
    assert bf.coherent_weight == pytest.approx(0.1**2, rel=2e-3)


class _Scaled:
    """A material whose lobe is off by a constant factor (negative control)."""

    def __init__(self, m, f):
        self._m, self._f = m, f

    def __getattr__(self, name):
        return getattr(self._m, name)

    def lobe(self, d, lam):
        return self._f * self._m.lobe(d, lam)


@pytest.mark.slow
@pytest.mark.reference
def test_poisson_overlaps_are_a_model_limitation():
    """With the physical union (t = min(1, Σ A)) the coherent weight is that of
    the Boolean model, (1 - e^{-F_a})², not F_a²; the report states this."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CoronaWarning)
        m = Material(shapes.Circle(R), Poisson(0.3))
    bf = wave.brute_force(m, realisations=2, n_scatterers=400, q_max=5.0 / R, seed=3, progress=False)
    assert bf.coherent_weight == pytest.approx((1 - math.exp(-0.3)) ** 2, rel=0.03)
    assert bf.overlap_loss == pytest.approx(1 - (1 - math.exp(-0.3)) / 0.3, abs=0.02)


@pytest.mark.slow
@pytest.mark.reference
def test_lattice_positions_are_periodic():
    lat = Lattice("hexagonal", 6.0, jitter=0.0)
    src = wave.positions_source(lat, shapes.Circle(2.0), n_scatterers=300)
    p = src.draw(0, np.random.default_rng(0))
    Lx, Ly = src.box
    # every site has its six neighbours at distance a across the periodic box
    dx = p[:, None, :] - p[None, :, :]
    dx -= np.array([Lx, Ly]) * np.round(dx / np.array([Lx, Ly]))
    r = np.hypot(dx[..., 0], dx[..., 1])
    assert np.all(np.sum(np.abs(r - 6.0) < 1e-9, axis=1) == 6)


# ----------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------
class _Blob(shapes.Shape):
    area = 1.0
    length_scale = 1.0


class _Odd(Process):
    def area_fraction(self, shape):
        return 0.2


@pytest.fixture(scope="module")
def small():
    return Material(shapes.Circle(R), HardDisk(0.2))


@pytest.mark.slow
@pytest.mark.reference
@pytest.mark.parametrize("kwargs,word", [
    ({"realisations": 0}, "realisations"),
    ({"overlaps": "merge"}, "overlaps"),
    ({"samples_per_radius": 1}, "samples_per_radius"),
    ({"max_grid": 64}, "grid"),
    ({"q_max": -1.0}, "q_max"),
])
def test_bad_arguments(small, kwargs, word):
    with pytest.raises(CoronaError, match=word):
        wave.brute_force(small, progress=False, n_scatterers=64, **kwargs)


@pytest.mark.slow
@pytest.mark.reference
def test_bad_material_shape_and_process():
    with pytest.raises(CoronaError, match="material"):
        wave.brute_force("circle")
    with pytest.raises(CoronaError, match="not supported"):
        wave._draw(_Blob(), 3, np.random.default_rng())
    with pytest.raises(CoronaError, match="not supported"):
        wave.positions_source(_Odd(), shapes.Circle(1.0))
    with pytest.raises(CoronaError, match="angle"):
        wave.positions_source(Lattice("square", 3.0, angle=17.0), shapes.Circle(1.0))


@pytest.mark.slow
@pytest.mark.reference
def test_bad_wavelength_and_cases(hd03):
    _, bf, _ = hd03
    with pytest.raises(CoronaError, match="wavelength"):
        bf.lobe(-550.0)
    with pytest.raises(CoronaError, match="cases"):
        select_cases(all_cases(quick=True), ["no-such-case"])


@pytest.mark.slow
def test_cli_validate(tmp_path):
    runner = CliRunner()
    out = tmp_path / "rep"
    r = runner.invoke(main, ["validate", "--out", str(out), "--cases", "circle-hd-0.30",
                             "--realisations", "4", "--scatterers", "300", "--no-progress"])
    assert r.exit_code == 0, r.output
    text = (out / "README.md").read_text()
    assert "circle-hd-0.30" in text and "| aperture |" in text
    assert os.path.getsize(out / "circle-hd-0.30.png") > 10_000
    bad = runner.invoke(main, ["validate", "--out", str(out), "--cases", "nothing-like-this"])
    assert bad.exit_code == 2 and "corona: error: cases=" in bad.output


def test_brute_force_refuses_a_mie_layer_in_one_line():
    """A Mie layer is a layer too, but the brute force sums planar screens' far fields."""
    from corona.model.material import Layer
    from corona.reference.wave import brute_force
    sphere = Material(shapes.Sphere(2.0), Poisson(0.1))
    assert isinstance(sphere, Layer)
    with pytest.raises(CoronaError, match=r"out of range for the brute force.*planar screens") as err:
        brute_force(sphere, realisations=1, n_scatterers=16)
    assert "\n" not in str(err.value)
