"""What a spectral render sees of the sphere lobes: their CIE 1931 XYZ against Mie theory.

A render integrates each pixel over wavelength with the camera's colour matching functions, so
what reaches an image of a sphere layer is the lobes' colour, ``X(Θ) = ∫ P(λ, Θ) x̄(λ) dλ`` (and
Y, Z), not one wavelength's lobe.  For one-size droplets of 8 µm and more the single wavelengths
miss the issue's 1 % between rows (resonances narrower than the rows: docs/mie.md, "Where the goals
stand"), while the colours meet it at every radius.  This file holds the colours to the goals
(energy-weighted RMS of X, Y and Z ≤ 1 %, the scale of Y within 0.5 %, per lobe) over the whole
radius range, 0.5-25 µm, water with its dispersion.

The table side is ``SphereMaterial._lobes`` (what the plugin evaluates, to 1e-4 of the lobe's
peak: tests/plugin/test_plugin_sphere.py); the reference is ``corona.model.mie.theory.amplitudes``
(checked against miepython in tests/model/test_mie.py) at water's index ``theory.water_ior``,
``P = (|S1|² + |S2|²) / (2π x²)`` per steradian: nothing of the table builder.  The wavelength
integral is stratified Monte Carlo over 360-830 nm (equal-energy illuminant), the same draws for
both sides; with 2048 strata its noise is below 0.1 % RMS (benchmarks/mie_colour_accuracy.py
measured the figures at 4 × 8192: Y RMS ≤ 0.43 %, scale ≤ 0.20 %).  A negative control shows
that the same figures see a 1 % error of the radius.
"""
import warnings

import numpy as np
import pytest

import corona
from corona.color import cie1931_xyz
from corona.model.mie import theory as mie

LAM_MIN, LAM_MAX = 360.0, 830.0
STRATA = 2048
RMS_GOAL, SCALE_GOAL = 0.01, 0.005


def _material(radius):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return corona.Material(corona.Sphere(radius), corona.Poisson(area_fraction=0.01))


def _angles(radius):
    """Scattering angles (midpoints 0.2/x_max apart from each lobe's axis), ``sin Θ dΘ`` and the
    lobe of each (0 forward, 1 backward)."""
    x_max = 2 * np.pi * radius / (LAM_MIN * 1e-3)
    n = int(np.ceil(0.5 * np.pi / (0.2 / x_max)))
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    ang = np.concatenate([th, np.pi - th])
    sinw = np.concatenate([np.sin(th), np.sin(th)]) * (0.5 * np.pi / n)
    return ang, sinw, np.repeat([0, 1], n)


def _colours(material, radius, ang, seed=0, theory=True):
    """XYZ (3, M) of the table's lobes (``material``) and of Mie theory at ``radius`` [µm] (None
    without ``theory``)."""
    width = (LAM_MAX - LAM_MIN) / STRATA
    lams = LAM_MIN + (np.arange(STRATA) + np.random.default_rng(seed).random(STRATA)) * width
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(ang), 0 * ang, -np.cos(ang)], -1)
    tab, ref = np.zeros((3, ang.size)), np.zeros((3, ang.size))
    chunk = max(1, 1_000_000 // ang.size)
    for s in range(0, STRATA, chunk):
        lam = lams[s:s + chunk]
        zf, zb, fwd = material._lobes(wi, np.broadcast_to(wo, (lam.size,) + wo.shape), lam[:, None])
        cmf = cie1931_xyz(lam).T * width                   # (3, B)
        tab += cmf @ np.where(fwd, zf, zb)
        if theory:
            x = 2 * np.pi * radius / (lam * 1e-3)
            S1, S2 = mie.amplitudes(mie.water_ior(lam).astype(np.complex128), x, np.cos(ang))
            ref += cmf @ ((np.abs(S1) ** 2 + np.abs(S2) ** 2) / (2 * np.pi * x[:, None] ** 2))
    return tab, (ref if theory else None)


def _figures(tab, ref, sinw):
    """Energy-weighted RMS of ``tab/ref - 1`` for X, Y, Z and the scale of Y, of one lobe."""
    w = ref * sinw
    rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2, -1) / np.sum(w, -1))
    return rms, float(np.sum(tab[1] * sinw) / np.sum(w[1]) - 1)


@pytest.mark.slow
@pytest.mark.parametrize("radius", [0.5, 2.0, 8.0, 20.0, 25.0])
def test_lobe_colours_match_mie_theory(radius):
    ang, sinw, lobe = _angles(radius)
    tab, ref = _colours(_material(radius), radius, ang)
    for which, name in ((0, "forward"), (1, "backward")):
        sel = lobe == which
        rms, scale = _figures(tab[:, sel], ref[:, sel], sinw[sel])
        assert np.all(rms <= RMS_GOAL), (name, "X, Y, Z RMS", rms)
        assert abs(scale) <= SCALE_GOAL, (name, "Y scale", scale)
    if radius in (2.0, 20.0):
        # negative control: the table of a 1 % smaller droplet against the same Mie colours (the
        # same wavelengths): the forward corona's rings move by 1 %, well above the goal (1.7-3 %
        # Y RMS measured at 2-20 µm)
        fwd = lobe == 0
        wrong, _ = _colours(_material(0.99 * radius), radius, ang[fwd], theory=False)
        rms, _ = _figures(wrong, ref[:, fwd], sinw[fwd])
        print("a 1 % smaller droplet: X, Y, Z RMS", rms)
        assert rms[1] > 1.5 * RMS_GOAL, rms
