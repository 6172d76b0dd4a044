"""Colour: corona.color is Mitsuba's CIE 1931 colorimetry for numpy, checked against
Mitsuba itself and against published CIE values; images are written by mi.Bitmap."""
import numpy as np
import pytest

import corona  # noqa: F401  (libLLVM before drjit)
from corona import color


def test_matching_functions_are_mitsubas():
    import mitsuba.scalar_rgb as sr
    lam = np.concatenate([np.random.default_rng(0).uniform(340.0, 850.0, 300), [360.0, 555.0, 830.0]])
    ref = np.array([sr.cie1931_xyz(float(x)) for x in lam])
    np.testing.assert_allclose(color.cie1931_xyz(lam), ref, rtol=0, atol=2e-6)
    assert color.cie1931_xyz(lam.reshape(3, -1)).shape == (3, lam.size // 3, 3)
    # the matrix is mi.xyz_to_srgb's
    xyz = np.random.default_rng(1).random((5, 3))
    ref = np.array([sr.xyz_to_srgb(sr.Color3f(*map(float, c))) for c in xyz])
    np.testing.assert_allclose(color.xyz_to_linear_srgb(xyz), ref, rtol=0, atol=1e-6)   # float32
    np.testing.assert_array_equal(color.XYZ_TO_SRGB, color.xyz_to_linear_srgb(np.eye(3)).T)


def test_cie_physics():
    """Published CIE facts: ȳ(555 nm) = 1; equal areas of x̄, ȳ, z̄ (E is the
    equal-energy white); the chromaticity of illuminant A (Planck at 2856 K) is
    (0.44757, 0.40745); D65 maps to sRGB white (R = G = B)."""
    import mitsuba.scalar_rgb as sr
    assert color.cie1931_xyz(555.0)[1] == pytest.approx(1.0, abs=1e-3)
    lam = np.arange(360.0, 831.0)
    areas = color.cie1931_xyz(lam).sum(axis=0)
    assert areas / areas[1] == pytest.approx([1.0, 1.0, 1.0], abs=5e-4)
    xyz = (color.blackbody(lam, 2856.0)[:, None] * color.cie1931_xyz(lam)).sum(axis=0)
    assert xyz[:2] / xyz.sum() == pytest.approx([0.44757, 0.40745], abs=2e-4)
    d65 = np.array([sr.cie_d65(float(x)) for x in lam])
    rgb = color.spectrum_to_linear_srgb(d65, lam)
    assert rgb / rgb.mean() == pytest.approx([1.0, 1.0, 1.0], abs=1e-3)


def test_tonemap_is_the_srgb_transfer_curve():
    """IEC 61966-2-1: 12.92 x below 0.0031308, 1.055 x^(1/2.4) - 0.055 above."""
    lin = np.array([[[0.0, 0.0031308, 0.18], [0.5, 1.0, 4.0], [-1.0, np.nan, 0.01]]])
    out = color.tonemap_srgb(lin, exposure=1.0)
    assert out.dtype == np.uint8
    assert out.tolist() == [[[0, 10, 118], [188, 255, 255], [0, 0, 25]]]
    # default exposure: the 99.5th percentile of the luminance maps to 1
    assert color.tonemap_srgb(np.full((4, 4, 3), 7.0)).max() == 255


def test_write_images_uses_mitsuba_bitmaps(tmp_path, mi_variant):
    import imageio.v3 as iio
    import mitsuba as mi

    from corona.apps.render import write_images
    rgb = np.random.default_rng(2).random((6, 5, 3)).astype(np.float32) * 2
    files = write_images(rgb, str(tmp_path), "x", exposure=0.7)
    exr = mi.Bitmap(files["exr"])
    assert exr.pixel_format() == mi.Bitmap.PixelFormat.RGB and not exr.srgb_gamma()
    np.testing.assert_array_equal(np.array(exr), rgb)                 # linear sRGB, float32
    png = mi.Bitmap(files["png"])
    assert png.srgb_gamma() and png.component_format() == mi.Struct.Type.UInt8
    from corona.apps.pictures import display_srgb       # the PNG convention (tests/apps/test_pictures.py)
    np.testing.assert_array_equal(iio.imread(files["png"]), display_srgb(rgb, 0.7))
