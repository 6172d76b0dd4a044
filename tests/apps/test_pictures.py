"""The PNG convention of `corona render`, `sweep`, `post` and the gallery
(:func:`corona.apps.pictures.display_srgb`): the corona around a bright lamp stays
visible, and a sweep is exposed once, so that brighter points look brighter."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from corona import CoronaError
from corona.apps.pictures import display_exposure, display_srgb
from corona.color import tonemap_srgb

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
REC709 = np.array([0.2126, 0.7152, 0.0722])


def _srgb(x):
    """IEC 61966-2-1 encoding, written out here (not the code under test)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def test_roll_off_is_reinhards_curve_on_the_luminance():
    """Grey values follow y = x (1 + x/W²)/(1 + x), W the brightest value (>= 1): the
    brightest pixel is white, none above it clips, the order of values is kept, hue too."""
    x = np.array([0.0, 0.01, 0.1, 0.5, 1.0, 3.0, 40.0])
    out = display_srgb(np.repeat(x[None, :, None], 3, -1), exposure=1.0)[0, :, 0]
    W = 40.0
    want = np.round(_srgb(x * (1 + x / W**2) / (1 + x)) * 255).astype(int)
    assert np.abs(out.astype(int) - want).max() <= 1, (out, want)
    assert out[-1] == 255 and np.all(out[:-1] < 255) and np.all(np.diff(out.astype(int)) > 0)
    # a colour keeps its channel ratios (below clipping): linear values back from the sRGB codes
    c = display_srgb(np.array([[[0.2, 0.1, 0.05]]]), exposure=1.0)[0, 0].astype(float) / 255
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    assert lin[0] / lin[1] == pytest.approx(2.0, rel=0.05) and lin[1] / lin[2] == pytest.approx(2.0, rel=0.1)
    # mono images and NaN / negative values
    mono = display_srgb(np.array([[[np.nan], [-1.0], [1.0]]]), exposure=1.0)
    assert mono.shape == (1, 3, 1) and mono[0, 0, 0] == 0 and mono[0, 1, 0] == 0


def test_automatic_exposure_is_the_glow_not_the_lamp():
    """A lamp covering 2 % of the frame at 10⁴ × the glow: the exposure maps the glow's
    99.5th percentile to 1, as without the lamp; the old percentile rule took the lamp."""
    rng = np.random.default_rng(1)
    glow = rng.uniform(0.0, 1.0, (100, 100))
    img = glow.copy()
    yy, xx = np.mgrid[:100, :100]
    lamp = np.hypot(yy - 50, xx - 50) < 8             # 2.0 % of the frame
    img[lamp] = 1e4
    rgb = np.repeat(img[..., None], 3, -1)
    far = np.hypot(yy - 50, xx - 50) > 8 + 2 + 1      # outside the lamp and its widened rim
    q = np.percentile(glow[far], 99.5)
    assert display_exposure(rgb) == pytest.approx(1.0 / q, rel=0.01)
    old = 1.0 / np.percentile(rgb @ REC709, 99.5)
    assert old < 1e-3 * display_exposure(rgb)          # negative control: the lamp's level
    # a frame without a lamp: the 99.5th percentile of all of it
    flat = np.repeat(glow[..., None], 3, -1)
    assert display_exposure(flat) == pytest.approx(1.0 / np.percentile(glow, 99.5), rel=1e-6)
    assert display_exposure(np.zeros((4, 4, 3))) == 1.0
    with pytest.raises(CoronaError, match="exposure"):
        display_srgb(flat, exposure=float("nan"))


def _rings(exr_rgb, png):
    """(share of the glow's pixels neither black nor white, the PNG's ring contrast, the EXR's).

    The glow: pixels between 1e-5 and 0.25 × the peak luminance, off the lamps (widened by 2 px).
    Rings: the azimuthal mean of the luminance around the smaller lamp (the torch's image, which
    wears the dust's corona) at 6-20 px; the contrast is the largest rise after a dip (codes for the
    PNG, relative to the dip for the EXR)."""
    from scipy import ndimage
    L = exr_rgb @ REC709
    peak = L.max()
    lamps = L > 0.25 * peak
    glow = (L > 1e-5 * peak) & ~ndimage.binary_dilation(lamps, iterations=2)
    p = png[..., :3].astype(float)
    ok = ((p[glow].max(-1) > 2) & (p[glow].min(-1) < 253)).mean()
    lab, n = ndimage.label(lamps)
    sizes = ndimage.sum(np.ones_like(L), lab, range(1, n + 1))
    cy, cx = ndimage.center_of_mass(lamps, lab, int(np.argmin(sizes)) + 1)
    yy, xx = np.mgrid[:L.shape[0], :L.shape[1]]
    r = np.hypot(yy - cy, xx - cx).round().astype(int)
    ring = np.arange(6, 21)

    png_prof = ndimage.mean(p @ REC709, r, ring)
    exr_prof = ndimage.mean(L, r, ring)
    png_rise = max(png_prof[j] - png_prof[:j].min() for j in range(1, ring.size))
    exr_rise = max(exr_prof[j] / exr_prof[:j].min() - 1 for j in range(1, ring.size))
    return ok, png_rise, exr_rise


@pytest.mark.slow
@pytest.mark.render
def test_render_png_keeps_the_rings_around_a_large_lamp(tmp_path):
    """scenes/dusty_mirror.xml -D torch_z=0.5 (the torch covers 1.2 % of the frame): through
    the command line, the PNG keeps the glow off black and off white and the rings' rise
    (the EXR's rise is the reference); the old rule (99.5th percentile to white) loses both."""
    import imageio.v3 as iio
    import mitsuba as mi
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "corona.apps.cli", "render",
                        os.path.join(ROOT, "scenes", "dusty_mirror.xml"), "-D", "torch_z=0.5",
                        "-D", "res=96", "-D", "spp=16", "--out", str(out)],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    rgb = np.array(mi.Bitmap(str(out / "dusty_mirror.exr")), dtype=np.float64)
    L = rgb @ REC709
    assert (L > 0.25 * L.max()).mean() > 0.005                  # the lamps cover > 0.5 % of the frame
    png = iio.imread(out / "dusty_mirror.png")
    ok, rise, exr_rise = _rings(rgb, png)
    assert exr_rise > 0.1                                        # the EXR has rings to keep
    assert ok >= 0.95 and rise >= 3.0, (ok, rise)
    old_ok, old_rise, _ = _rings(rgb, tonemap_srgb(rgb))         # negative control
    assert old_ok < 0.5 and old_rise < 1.0, (old_ok, old_rise)


@pytest.mark.slow
@pytest.mark.render
def test_sweep_is_exposed_once(tmp_path):
    """F_a 0.1 against 0.4 (scenes/sweep_area_fraction.xml, holes in a foil): the lobe carries
    F_a (1 - F_a), so the denser layer's glow is brighter in its PNG; exposed per point (the
    old way) the two look alike.  ``exposure`` still sets it."""
    import imageio.v3 as iio
    import mitsuba as mi

    from corona.apps.sweep import Executor, run_sweep
    scene = os.path.join(ROOT, "scenes", "sweep_area_fraction.xml")
    grid = {"area_fraction": ["0.1", "0.4"], "res": ["32"], "spp": ["8"]}
    index = run_sweep(scene, grid, str(tmp_path / "a"), executor=Executor(workers=0), progress=False)
    assert [p["status"] for p in index["points"]] == ["rendered", "rendered"]
    exrs = [np.array(mi.Bitmap(str(tmp_path / "a" / p["exr"])), dtype=np.float64) for p in index["points"]]
    pngs = [iio.imread(tmp_path / "a" / p["png"])[..., :3].astype(float) @ REC709 for p in index["points"]]
    shared = index["exposure"]
    assert shared == pytest.approx(min(display_exposure(e) for e in exrs))
    for e, png in zip(exrs, pngs):
        np.testing.assert_array_equal(png, display_srgb(e, shared)[..., :3].astype(float) @ REC709)
    centre = np.zeros((32, 32), bool)
    centre[14:18, 14:18] = True                                    # the lamp and its first pixels
    glow = [png[~centre].mean() for png in pngs]
    assert glow[1] > 1.3 * glow[0], glow
    own = [(display_srgb(e).astype(float) @ REC709)[~centre].mean() for e in exrs]   # negative control
    assert own[1] < 1.15 * own[0], own
    fixed = run_sweep(scene, grid, str(tmp_path / "b"), executor=Executor(workers=0), progress=False,
                      exposure=0.5)
    assert fixed["exposure"] == 0.5
    for p, e in zip(fixed["points"], exrs):
        np.testing.assert_array_equal(iio.imread(tmp_path / "b" / p["png"])[..., :3], display_srgb(e, 0.5))


def test_post_png_is_the_same_convention(tmp_path):
    """`corona post`'s PNG is display_srgb of its EXR: the glow's exposure by default (the old
    default, exposure 1 and a clip, turned the glow around a bright lamp white), ``exposure``
    when given."""
    import imageio.v3 as iio
    import mitsuba as mi

    from corona.apps import post
    img = np.zeros((24, 32, 3), np.float32)
    img[12, 16] = 500.0                                   # a lamp on black
    src = tmp_path / "in.exr"
    mi.Bitmap(img).write(str(src))
    layer = dict(radius=3.0, area_fraction=0.3, mode="particle", process="hard-disk")
    post.apply_file(str(src), str(tmp_path / "o.exr"), 30.0, layer, progress=False)
    lin = np.array(mi.Bitmap(str(tmp_path / "o.exr")), dtype=np.float64)
    for exposure in (None, 0.3):
        post.apply_file(str(src), str(tmp_path / "o.png"), 30.0, layer, exposure=exposure, progress=False)
        np.testing.assert_array_equal(iio.imread(tmp_path / "o.png")[..., :3], display_srgb(lin, exposure))
    post.apply_file(str(src), str(tmp_path / "auto.png"), 30.0, layer, progress=False)
    auto = iio.imread(tmp_path / "auto.png")[..., :3].astype(float) @ REC709
    ring = np.zeros((24, 32), bool)
    ring[8:17, 12:21] = True
    ring[12, 16] = False                                  # around the lamp, off its pixel
    assert ((auto[ring] > 2) & (auto[ring] < 253)).all(), auto[ring]
    old = tonemap_srgb(lin, exposure=1.0).astype(float) @ REC709      # negative control
    assert (old[ring] >= 253).mean() > 0.3


def test_dilate_cross_is_scipys_binary_dilation():
    """The exposure's lamp rim (numpy shifts, :func:`corona.apps.pictures.dilate_cross`) is
    scipy.ndimage's binary dilation by the 4-neighbour cross, iterated: masks touching the
    frame's edges, several sizes and widths; a negative control with the 8-neighbour square."""
    from scipy import ndimage

    from corona.apps.pictures import dilate_cross
    rng = np.random.default_rng(3)
    for shape, density in (((1, 1), 1.0), ((7, 5), 0.05), ((40, 64), 0.01), ((33, 33), 0.3)):
        mask = rng.random(shape) < density
        mask[0, -1] = True                                     # a lamp on the corner
        for k in (0, 1, 2, 5):
            assert np.array_equal(dilate_cross(mask, k), ndimage.binary_dilation(mask, iterations=k) if k else mask)
    one = np.zeros((9, 9), bool)
    one[4, 4] = True
    square = ndimage.binary_dilation(one, np.ones((3, 3), bool), iterations=2)
    assert not np.array_equal(dilate_cross(one, 2), square)   # the cross, not the square
    assert dilate_cross(one, 2).sum() == 13                    # the city-block disc of radius 2
