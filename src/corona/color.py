"""Spectral → colour conversion for pictures (numpy).

CIE 1931 2° colour matching functions by the multi-lobe Gaussian fit of
Wyman, Sloan & Shirley, "Simple analytic approximations to the CIE XYZ colour
matching functions", JCGT 2(2), 2013 (error below the spread of the
measured data); XYZ → linear sRGB (D65) by the IEC 61966-2-1 matrix.
"""
from __future__ import annotations

import numpy as np

XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])


def _g(x, mu, s1, s2):
    s = np.where(x < mu, s1, s2)
    return np.exp(-0.5 * ((x - mu) / s) ** 2)


def cie1931_xyz(wavelength) -> np.ndarray:
    """x̄, ȳ, z̄ at ``wavelength`` [nm]; shape (..., 3)."""
    lam = np.asarray(wavelength, dtype=np.float64)
    x = 1.056 * _g(lam, 599.8, 37.9, 31.0) + 0.362 * _g(lam, 442.0, 16.0, 26.7) - 0.065 * _g(lam, 501.1, 20.4, 26.2)
    y = 0.821 * _g(lam, 568.8, 46.9, 40.5) + 0.286 * _g(lam, 530.9, 16.3, 31.1)
    z = 1.217 * _g(lam, 437.0, 11.8, 36.0) + 0.681 * _g(lam, 459.0, 26.0, 13.8)
    return np.stack([x, y, z], axis=-1)


def blackbody(wavelength, temperature: float) -> np.ndarray:
    """Planck's spectral radiance (relative units) at ``wavelength`` [nm]."""
    lam = np.asarray(wavelength, dtype=np.float64) * 1e-9
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    return 1.0 / (lam**5 * np.expm1(h * c / (lam * k * temperature)))


def spectrum_to_linear_srgb(spectra, wavelengths) -> np.ndarray:
    """Integrate spectra (..., n_λ) sampled at ``wavelengths`` [nm] to linear sRGB (..., 3)."""
    w = np.asarray(wavelengths, dtype=np.float64)
    cmf = cie1931_xyz(w)                                # (n, 3)
    dl = np.gradient(w)
    xyz = np.tensordot(np.asarray(spectra) * dl, cmf, axes=([-1], [0]))
    return xyz @ XYZ_TO_SRGB.T


def tonemap_srgb(rgb, exposure: float | None = None, percentile: float = 99.5) -> np.ndarray:
    """Linear RGB → 8-bit sRGB with the standard transfer curve.

    ``exposure`` scales the linear values; by default the ``percentile`` of
    the luminance maps to 1.
    """
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, dtype=np.float64)), 0.0)
    if exposure is None:
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
        ref = np.percentile(lum, percentile)
        exposure = 1.0 / ref if ref > 0 else 1.0
    x = np.clip(rgb * exposure, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (x * 255 + 0.5).astype(np.uint8)
