"""The renderer's sphere lobes against Mie theory at radii and wavelengths between the table rows.

The reference is ``corona.mie.differential_cross_section`` evaluated at each direction (checked
against miepython in model/test_mie.py), not the table builder: a dilute Poisson layer at normal
incidence, where ``eval / (F_s w) = P = n dσ/dΩ / F_a``.  Per lobe: the energy-weighted RMS of
``P_table / P_mie - 1``, the overall scale, and (forward) the positions of the first three
minima and maxima of the lobe.
"""
import warnings

import numpy as np
import pytest

import corona
from corona import mie


def _lobe(material, theta, lam, exact):
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], -1)
    zf, zb, fwd = material._lobes(wi, wo, lam, exact=exact)
    return np.where(fwd, zf, zb)


def _mie_P(sphere, theta, lam):
    """P = dσ/dΩ / (π r²) from corona.mie directly."""
    m = complex(sphere.index(lam))
    return mie.differential_cross_section(m, sphere.radius, lam * 1e-3, np.cos(theta)) / (np.pi * sphere.radius**2)


def _extrema(theta, p, n=3):
    d = np.diff(p)
    idx = np.concatenate([np.where((d[:-1] < 0) & (d[1:] >= 0))[0][:n], np.where((d[:-1] > 0) & (d[1:] <= 0))[0][:n]]) + 1
    out = []
    for i in np.sort(idx):
        y0, y1, y2 = p[i - 1], p[i], p[i + 1]
        den = y0 - 2 * y1 + y2
        out.append(theta[i] + (0.5 * (y0 - y2) / den if den != 0 else 0.0) * (theta[1] - theta[0]))
    return np.array(out)


CASES = [(1.3, None, 487.3), (1.3, None, 611.9), (4.7, None, 533.3), (4.7, None, 402.9),
         (2.3, 1.5, 702.1),
         # near a narrow resonance (x = 42.76, m = 1.45): rows 0.02 apart in x smear it; the
         # backward lobe is 3.2 % RMS off there (measured); known, see docs/mie.md
         pytest.param(3.1, 1.45, 455.5, marks=pytest.mark.xfail(strict=True, reason="resonance between rows: "
                                                                 "backward lobe 3.2 % RMS"))]


@pytest.mark.parametrize("radius,ior,lam", CASES)
def test_lobes_between_rows_match_mie(radius, ior, lam):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = corona.Material(corona.Sphere(radius, ior=ior), corona.Poisson(0.01))
    r = mat.rows
    x = 2 * np.pi * radius / (lam * 1e-3)
    j = np.searchsorted(r["x"], x)
    gap = (x - r["x"][j - 1]) / (r["x"][j] - r["x"][j - 1])
    assert 0.05 < gap < 0.95                      # really between two rows
    n = 40000
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        tab = _lobe(mat, ang, lam, exact=False)
        ref = _mie_P(mat.sphere, ang, lam)
        w = ref * np.sin(th)
        rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
        scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
        assert rms < 0.01, (name, rms)
        assert abs(scale) < 0.005, (name, scale)
        if name == "forward":
            e_tab, e_ref = _extrema(th, tab), _extrema(th, ref)
            assert e_tab.size == e_ref.size == 6
            assert np.max(np.abs(e_tab / e_ref - 1)) < 0.002, (e_tab, e_ref)


def test_negative_control_detects_a_shifted_lobe():
    # the same checks see a 1 % change of the radius (the rings move by 1 %)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = corona.Material(corona.Sphere(4.7 * 1.01), corona.Poisson(0.01))
    th = (np.arange(40000) + 0.5) * (0.5 * np.pi / 40000)
    tab = _lobe(mat, th, 533.3, exact=False)
    ref = _mie_P(corona.Sphere(4.7), th, 533.3)
    e_tab, e_ref = _extrema(th, tab), _extrema(th, ref)
    assert np.max(np.abs(e_tab / e_ref - 1)) > 0.005
    w = ref * np.sin(th)
    assert np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w)) > 0.01
