"""Spectral → colour conversion for pictures and the plugin's RGB channels (numpy).

The colorimetry is Mitsuba's own: the CIE 1931 2° colour matching functions
``mi.cie1931_xyz`` (CIE's 1 nm table over [360, 830] nm, linearly
interpolated, zero outside) and the XYZ → linear sRGB (Rec. 709 primaries,
D65 white) matrix of ``mi.xyz_to_srgb``.  They are read through the
variant-independent ``mitsuba.scalar_rgb`` module, so nothing here activates
or changes the Mitsuba variant.  Only the Planck spectrum and the sRGB
transfer curve (IEC 61966-2-1) are written out here.

Examples
--------
The matching functions at 555 nm (the peak of ȳ), and a flat spectrum — the
CIE equal-energy white E — in linear sRGB (Mitsuba's matrix, D65 white):

>>> from corona.color import cie1931_xyz, spectrum_to_linear_srgb
>>> cie1931_xyz(555.0).round(3)
array([0.512, 1.   , 0.006])
>>> lam = np.arange(360.0, 831.0)
>>> rgb = spectrum_to_linear_srgb(np.ones_like(lam), lam)
>>> (rgb / rgb[1]).round(3)          # E is redder than D65: sRGB(1, 1, 1) is D65
array([1.271, 1.   , 0.959])
"""
from __future__ import annotations

import functools
import importlib

import numpy as np


@functools.lru_cache(maxsize=1)
def _mitsuba():
    """Mitsuba's scalar RGB variant module (its colour functions take plain floats)."""
    return importlib.import_module("mitsuba.scalar_rgb")


@functools.lru_cache(maxsize=1)
def _cie_table() -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's CIE 1931 table at its 1 nm nodes: (wavelengths (n,), x̄ȳz̄ (n, 3))."""
    mi = _mitsuba()
    nodes = np.arange(float(mi.MI_CIE_MIN), float(mi.MI_CIE_MAX) + 0.5, 1.0)
    return nodes, np.array([mi.cie1931_xyz(float(lam)) for lam in nodes], dtype=np.float64)


@functools.lru_cache(maxsize=1)
def _xyz_to_srgb() -> np.ndarray:
    """The 3×3 matrix of ``mi.xyz_to_srgb`` (a linear map: its images of the unit vectors)."""
    mi = _mitsuba()
    return np.array([mi.xyz_to_srgb(mi.Color3f(*e)) for e in np.eye(3)], dtype=np.float64).T


def __getattr__(name):
    # XYZ_TO_SRGB is built on first use, so `import corona.color` loads no Mitsuba variant
    if name == "XYZ_TO_SRGB":
        return _xyz_to_srgb()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def cie1931_xyz(wavelength) -> np.ndarray:
    """CIE 1931 2° colour matching functions x̄, ȳ, z̄ at ``wavelength`` [nm].

    Mitsuba's ``mi.cie1931_xyz`` for numpy arrays of any shape: its 1 nm
    table, linearly interpolated between the nodes, zero outside
    [360, 830] nm.

    Returns
    -------
    ndarray (..., 3), float64
    """
    lam = np.asarray(wavelength, dtype=np.float64)
    nodes, values = _cie_table()
    return np.stack([np.interp(lam, nodes, values[:, k], left=0.0, right=0.0) for k in range(3)], axis=-1)


def xyz_to_linear_srgb(xyz) -> np.ndarray:
    """XYZ (..., 3) → linear sRGB (..., 3) by Mitsuba's ``mi.xyz_to_srgb`` matrix."""
    return np.asarray(xyz, dtype=np.float64) @ _xyz_to_srgb().T


def blackbody(wavelength, temperature: float) -> np.ndarray:
    """Planck's spectral radiance (relative units) at ``wavelength`` [nm].

    ``B(λ, T) ∝ λ⁻⁵ / (exp(hc / λkT) - 1)`` (the constant ``2hc²`` is left out).
    """
    lam = np.asarray(wavelength, dtype=np.float64) * 1e-9
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    return 1.0 / (lam**5 * np.expm1(h * c / (lam * k * temperature)))


def spectrum_to_linear_srgb(spectra, wavelengths) -> np.ndarray:
    """Integrate spectra (..., n_λ) sampled at ``wavelengths`` [nm] to linear sRGB (..., 3).

    ``XYZ = Σ_λ s(λ) (x̄, ȳ, z̄)(λ) Δλ`` (relative units: no normalisation),
    then Mitsuba's XYZ → linear sRGB matrix.
    """
    w = np.asarray(wavelengths, dtype=np.float64)
    cmf = cie1931_xyz(w)                                # (n, 3)
    dl = np.gradient(w)
    xyz = np.tensordot(np.asarray(spectra) * dl, cmf, axes=([-1], [0]))
    return xyz_to_linear_srgb(xyz)


def tonemap_srgb(rgb, exposure: float | None = None, percentile: float = 99.5) -> np.ndarray:
    """Linear RGB → 8-bit sRGB with the standard transfer curve (IEC 61966-2-1).

    ``exposure`` scales the linear values; by default the ``percentile`` of
    the luminance (Rec. 709 weights) maps to 1.  NaN and negative values
    become 0, values above 1 clip to 255.
    """
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, dtype=np.float64)), 0.0)
    if exposure is None:
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
        ref = np.percentile(lum, percentile)
        exposure = 1.0 / ref if ref > 0 else 1.0
    x = np.clip(rgb * exposure, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (x * 255 + 0.5).astype(np.uint8)
