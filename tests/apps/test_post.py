"""corona post: a uniform layer at the camera as a convolution in direction space.

References: Mitsuba renders through the corona pane (the plugin), brute-force
quadrature of the lobe over the frame (``Material.lobe``), the ACES white point.
"""
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

import corona
import corona.apps.post as post

LAYER = dict(radius=3.0, area_fraction=0.3, mode="particle", process="hard-disk")


def _lobe_energy_in_frame(m, width, height, fov, j, n=6, lams=post.WAVELENGTHS[::6]):
    """Brute force: ``∫_frame lobe(p - p_j) d²p`` per channel, by ``n x n`` midpoint
    samples of every pixel's footprint in the tangent plane (Jacobian cos⁴θ)."""
    tx, ty, s = post.pixel_tangents(width, height, fov)
    w = post.channel_responses("srgb", 3, lams)
    t_j = np.array([tx[j[1]], ty[j[0]]])
    p_j = t_j / np.sqrt(1 + t_j @ t_j)
    sub = (np.arange(n) + 0.5) / n - 0.5
    TX, TY = np.meshgrid(tx, ty)
    total = np.zeros(3)
    for a in sub:
        for b in sub:
            T = np.stack([TX + a * s, TY + b * s], -1)
            r2 = (T ** 2).sum(-1)
            P = T / np.sqrt(1 + r2)[..., None]
            dA = (s * s / (n * n) / (1 + r2) ** 2).ravel()
            lobe = np.stack([m.lobe((P - p_j).reshape(-1, 2), lam) for lam in lams], -1)
            total += (lobe * dA[:, None]).sum(0) @ w.T
    return total


def _pixel_areas(width, height, fov):
    tx, ty, s = post.pixel_tangents(width, height, fov)
    TX, TY = np.meshgrid(tx, ty)
    return s * s / (1 + TX ** 2 + TY ** 2) ** 2


@pytest.mark.parametrize("where", ["centre", "edge", "corner"])
def test_wide_field_energy_matches_brute_force(where):
    """At a 120° field the pinhole is far from uniform in d; the lobe energy the pass
    puts into the frame from one bright pixel equals the brute-force integral of the
    lobe over the frame (within 0.5 %; measured 0.3 % at 128x96, 0.1 % at 64x48, where
    the pixels of 3° are cut into sub-pixels), and a naive convolution in pixel space
    does not."""
    W, H, fov = 128, 96, 120.0
    j = {"centre": (48, 64), "edge": (48, 4), "corner": (6, 120)}[where]
    m = post.layer(**LAYER)
    img = np.zeros((H, W, 3), np.float32)
    img[j] = 1.0
    out = post.apply(img, fov, m, progress=False).astype(np.float64)
    area = _pixel_areas(W, H, fov)
    got = (out * area[..., None]).sum((0, 1)) - m.coherent_transmittance * area[j]
    want = area[j] * _lobe_energy_in_frame(m, W, H, fov, j, n=3)
    np.testing.assert_allclose(got, want, rtol=0.005)
    # negative control: pixels taken as uniform in d (the tangent plane as if it were p)
    tx, ty, s = post.pixel_tangents(W, H, fov)
    TX, TY = np.meshgrid(tx, ty)
    d = np.stack([TX - tx[j[1]], TY - ty[j[0]]], -1).reshape(-1, 2)
    naive = sum(m.lobe(d, lam).sum() for lam in (450.0, 550.0, 650.0)) / 3 * s * s * s * s
    if where != "centre":
        assert abs(naive / (want.mean()) - 1) > 0.1


def test_far_field_values_and_no_wrap_around():
    """Pixels far from a light at the left edge get the lobe at their offset (the point
    formula, within 3 % of the brightest channel), the right edge included: the FFT
    padding wraps no light around the grid."""
    W, H, fov = 96, 32, 60.0
    m = post.layer(radius=1.7, area_fraction=0.3, mode="particle")
    img = np.zeros((H, W, 3), np.float32)
    img[16, 0] = 1.0
    out = post.apply(img, fov, m, progress=False)
    tx, ty, s = post.pixel_tangents(W, H, fov)
    area = _pixel_areas(W, H, fov)
    w = post.channel_responses("srgb", 3, post.WAVELENGTHS[::2])

    def p(i, k):
        t = np.array([tx[k], ty[i]])
        return t / np.sqrt(1 + t @ t)
    for k in (40, 70, 93):     # means over 5 pixels of a row (the pass averages over a pixel)
        d = np.array([p(16, q) - p(16, 0) for q in range(k - 2, k + 3)])
        want = np.array([sum(wc * m.lobe(d, lam).mean() for lam, wc in zip(post.WAVELENGTHS[::2], w[c]))
                         for c in range(3)]) * area[16, 0]
        np.testing.assert_allclose(out[16, k - 2:k + 3].mean(0), want, rtol=0.03, atol=0.03 * want.max())
    # wrap-around would put the light one pixel away from the right edge: far brighter
    assert np.all(out[16, 95] < 0.01 * out[16, 1])


@pytest.mark.slow     # 2.5 s of CPU warm
def test_huge_pixels_keep_the_energy():
    """A 4x6 image of a 170° field (pixels of ~70°): a white image gets T_c plus about the
    lobe's whole energy at its centre, not the near-zero a point per pixel would give."""
    m = post.layer(**LAYER)
    out = post.apply(np.ones((4, 6, 3), np.float32), 170.0, m, progress=False)
    centre = out[1:3, 2:4].mean()
    assert m.coherent_transmittance + 0.7 * m.diffuse_transmittance() < centre
    assert np.all(out <= m.coherent_transmittance + m.diffuse_transmittance() + 1e-3)


def test_constant_image_bounds_and_coherent_part():
    """A white image: every pixel keeps T_c and gains at most the whole diffuse
    transmittance (no energy gain); a layer with F_a -> 0 leaves the image as it is."""
    img = np.ones((40, 50, 3), np.float32)
    m = post.layer(**LAYER)
    out = post.apply(img, 90.0, m, progress=False)
    assert np.all(np.isfinite(out))
    assert np.all(out >= m.coherent_transmittance - 1e-6)
    assert np.all(out <= m.coherent_transmittance + m.diffuse_transmittance() + 1e-3)
    clear = post.apply(img, 90.0, progress=False, radius=3.0, area_fraction=1e-4, mode="particle",
                       process="poisson")
    np.testing.assert_allclose(clear, 1.0, atol=1e-3)


def test_anisotropic_lobe_orientation_and_symmetry():
    """A rectangle twice as tall as wide diffracts twice as far along x as along y; the
    pass keeps the lobe's point symmetry (lobe(d) = lobe(-d))."""
    W = H = 49
    m = post.layer(shape="rectangle", radius=4.0, aspect=2.0, area_fraction=0.2, process="poisson")
    img = np.zeros((H, W, 3), np.float32)
    img[24, 24] = 1.0
    out = post.apply(img, 20.0, m, progress=False)[..., 1]
    row, col = out[24].copy(), out[:, 24].copy()
    row[24] = col[24] = 0
    yy, xx = np.mgrid[:H, :W] - 24.0
    lobe = out.copy()
    lobe[24, 24] = 0
    var_x = (lobe * xx ** 2).sum() / lobe.sum()
    var_y = (lobe * yy ** 2).sum() / lobe.sum()
    assert var_x > 2.0 * var_y
    np.testing.assert_allclose(lobe, lobe[::-1, ::-1], rtol=1e-3, atol=1e-9)


def test_colour_spaces():
    """ACEScg's AP1 white (1, 1, 1) is the ACES white point x, y = (0.32168, 0.33767);
    the channel responses are non-negative quadratures summing to 1."""
    xyz = post.AP1_TO_XYZ @ np.ones(3)
    np.testing.assert_allclose(xyz[:2] / xyz.sum(), [0.32168, 0.33767], atol=2e-5)
    for cs in post.COLORSPACES:
        w = post.channel_responses(cs)
        assert w.shape == (3, post.WAVELENGTHS.size) and np.all(w >= 0)
        np.testing.assert_allclose(w.sum(1), 1.0)
    img = np.zeros((32, 32, 3), np.float32)
    img[16, 16] = 1.0
    a = post.apply(img, 20.0, progress=False, colorspace="acescg", **LAYER)
    b = post.apply(img, 20.0, progress=False, **LAYER)
    assert np.all(np.isfinite(a)) and not np.allclose(a, b)
    with pytest.raises(corona.CoronaError, match="colorspace"):
        post.apply(img, 20.0, progress=False, colorspace="p3", **LAYER)


def test_mono_image():
    img = np.zeros((20, 30), np.float32)
    img[10, 15] = 1.0
    out = post.apply(img, 20.0, progress=False, **LAYER)
    assert out.shape == img.shape and np.isfinite(out).all()


@pytest.mark.parametrize("bad, match", [
    (dict(image=np.full((8, 8, 3), np.nan, np.float32)), "non-finite"),
    (dict(image=np.zeros((8, 8, 3), np.uint8)), "not linear HDR"),
    (dict(image=np.zeros((8, 8, 4), np.float32)), "shape"),
    (dict(fov=0.0), "fov"),
    (dict(fov=180.0), "fov"),
    (dict(shape="sphere"), "sphere"),
    (dict(substrate="glass"), "substrate"),
    (dict(radius=-1.0), "radius"),
])
def test_bad_input_one_line(bad, match):
    kw = dict(image=np.zeros((8, 8, 3), np.float32), fov=30.0, radius=3.0)
    kw.update(bad)
    image, fov = kw.pop("image"), kw.pop("fov")
    with pytest.raises(corona.CoronaError, match=match) as err:
        post.apply(image, fov, progress=False, **kw)
    assert "\n" not in str(err.value)


@pytest.mark.slow
@pytest.mark.render
def test_render_through_the_pane_equals_post_of_the_render_without_it():
    """Mitsuba (RGB variant, box filter): a small bright light seen through the corona pane
    right in front of the camera, against the same scene without the pane passed through
    corona.apps.post (with the plugin's spectral quadrature): equal within the renders' noise.

    Measured (64x64, 30° field, 256 spp through the pane, 4096 spp without): mean squared
    difference 1.06x the pane render's own variance over the image, 1.6x off the light's
    pixels, the lobe's energy off the light within 0.2 % per channel.  With the finer
    spectral quadrature of the default (2.5 nm) instead of the plugin's 8 wavelengths per
    channel: 5.3x off the light (the plugin's quadrature error, up to 14 % in red at
    |d| = 0.2 for this 2 µm layer).
    """
    import mitsuba as mi
    previous = mi.variant()
    mi.set_variant("llvm_ad_rgb")
    corona.register()
    try:
        fov, res = 30.0, 64
        layer = dict(radius=2.0, area_fraction=0.3, mode="particle", process="hard-disk")

        def scene(pane, spp, params=layer):
            d = {"type": "scene", "integrator": {"type": "path", "max_depth": 4},
                 "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x", "near_clip": 1e-4,
                            "film": {"type": "hdrfilm", "width": res, "height": res,
                                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                            "sampler": {"type": "independent", "sample_count": spp}},
                 "light": {"type": "sphere", "center": [1.2, 0.5, 20.0], "radius": 0.3,
                           "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 0.8, 0.6]}}}}
            if pane:    # 2 mm in front of the pinhole: the parallax to the light (20 m) is 1e-4
                d["pane"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 0.002]),
                             "bsdf": {"type": "corona", **params}}
            return mi.load_dict(d)
        plain = np.array(mi.render(scene(False, 4096), seed=1), dtype=np.float32)
        pane = scene(True, 256)
        a = np.array(mi.render(pane, seed=2), dtype=np.float64)
        b = np.array(mi.render(pane, seed=3), dtype=np.float64)
        out = post.apply(plain, fov, response=post.plugin_response(), progress=False, **layer)
        var = np.mean((a - b) ** 2) / 2
        off = plain.sum(-1) == 0
        var_off = np.mean(((a - b) ** 2)[off]) / 2
        assert np.mean((out - a) ** 2) < 1.3 * var
        assert np.mean(((out - a) ** 2)[off]) < 3.0 * var_off
        np.testing.assert_allclose(out[off].sum(0), a[off].sum(0), rtol=0.01)
        # negative controls: a layer 10 % off in radius, or no coherent part, is far outside the noise
        wrong = post.apply(plain, fov, response=post.plugin_response(), progress=False,
                           **{**layer, "radius": 2.2})
        assert np.mean(((wrong - a) ** 2)[off]) > 10 * var_off
        m = post.layer(**layer)
        no_coherent = out - m.coherent_transmittance * plain
        assert np.mean((no_coherent - a) ** 2) > 10 * var
    finally:
        if previous:
            mi.set_variant(previous)


# ----------------------------------------------------------------------
# the command line
# ----------------------------------------------------------------------
def _cli_process(*args):
    """The real entry point, a separate process (``test_cli_exr_and_png``)."""
    return subprocess.run([sys.executable, "-m", "corona.apps.cli", *args], capture_output=True, text=True)


def _cli(*args):
    """The same command in this process through click's runner (the code path of
    ``corona.apps.cli.main`` without a process start and import per call)."""
    from corona.apps.cli import main
    r = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return SimpleNamespace(returncode=r.exit_code, stdout=r.stdout, stderr=r.stderr)


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    import mitsuba as mi
    folder = tmp_path_factory.mktemp("post")
    img = np.zeros((24, 32, 3), np.float32)
    img[12, 16] = 50.0
    img[2:5, 2:5] = 0.3
    exr, png = folder / "in.exr", folder / "in.png"
    mi.Bitmap(img).write(str(exr))
    mi.Bitmap(np.clip(img, 0, 1)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, True).write(str(png))
    return folder, img


@pytest.mark.slow
def test_cli_exr_and_png(images):
    import mitsuba as mi
    folder, img = images
    out = folder / "out.exr"
    r = _cli_process("post", str(folder / "in.exr"), "--fov", "30", "-D", "radius=5", "-D", "area_fraction=0.3",
             "-D", "mode=particle", "--out", str(out), "--no-progress")
    assert r.returncode == 0, r.stderr
    got = np.array(mi.Bitmap(str(out)), dtype=np.float32)
    want = post.apply(img, 30.0, progress=False, radius=5.0, area_fraction=0.3, mode="particle")
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    r = _cli_process("post", str(folder / "in.exr"), "--fov", "30", "--out", str(folder / "out.png"))
    assert r.returncode == 0, r.stderr
    assert "corona post" in r.stderr               # the progress bar
    assert (folder / "out.png").stat().st_size > 0


@pytest.mark.slow
def test_cli_refuses_8_bit_input_without_srgb_input(images):
    folder, _ = images
    r = _cli("post", str(folder / "in.png"), "--fov", "30", "--out", str(folder / "o.exr"))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "not linear HDR" in r.stderr and "--srgb-input" in r.stderr
    r = _cli("post", str(folder / "in.png"), "--fov", "30", "--srgb-input", "--out", str(folder / "o.exr"),
             "--no-progress")
    assert r.returncode == 0, r.stderr


@pytest.mark.slow
@pytest.mark.parametrize("args, match", [
    (["--fov", "200"], "fov=200.0 is out of range"),
    (["--fov", "30", "-D", "radius=-1"], "radius='-1' is out of range"),
    (["--fov", "30", "-D", "radiu=1"], "unknown parameter(s) radiu"),
    (["--fov", "30", "-D", "radius"], "expected NAME=VALUE"),
    (["--fov", "30", "-D", "spp=4"], "unknown parameter(s) spp"),
    (["--fov", "30", "-D", "shape=sphere"], "shape='sphere'"),
])
def test_cli_errors_one_line(images, args, match):
    folder, _ = images
    r = _cli("post", str(folder / "in.exr"), *args, "--out", str(folder / "o.exr"), "--no-progress")
    assert r.returncode == 2
    assert match in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr


@pytest.mark.slow
def test_cli_bad_output_name(images):
    folder, _ = images
    r = _cli("post", str(folder / "in.exr"), "--fov", "30", "--out", str(folder / "o.tif"))
    assert r.returncode == 2 and "allowed .exr, .png" in r.stderr


# ----------------------------------------------------------------------
# issue 47: AOV images, unwritable folders, huge pixels, the substrate named
# ----------------------------------------------------------------------
@pytest.mark.parametrize("value, dtype", [(1e37, np.float32), (1e38, np.float32), (5e37, np.float64)])
def test_huge_finite_pixels_give_finite_output(value, dtype):
    """Pixels of 1e37-1e38 overflowed float32 in the splat and the FFT (NaN/inf, written with
    exit 0): the result is now finite and equals the pass of the image scaled to 1, times the
    scale (the pass is linear)."""
    img = np.zeros((24, 32, 3), dtype)
    img[12, 16] = value
    img[3:6, 3:6] = value / 100
    out = post.apply(img, 30.0, progress=False, **LAYER)
    unit = post.apply((img / value).astype(np.float32), 30.0, progress=False, **LAYER)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out.astype(np.float64) / value, unit, rtol=1e-5, atol=1e-7 * unit.max())


@pytest.mark.parametrize("value", [2e38, 3.4e38, 1e39, 1e300])
def test_pixels_beyond_the_float32_output_are_one_line(value):
    """Negative control of the bound: beyond 1e38 (float64 above float32's range included) one
    line, nothing computed."""
    img = np.zeros((8, 8, 3), np.float64 if value > 3.4e38 else np.float32)
    img[4, 4] = value
    with pytest.raises(corona.CoronaError, match=r"values up to .* allowed \|values\| <= 1e\+38") as err:
        post.apply(img, 30.0, progress=False, **LAYER)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("substrate", ["mirror", "glass"])
def test_the_refused_substrate_is_named(substrate):
    with pytest.raises(corona.CoronaError, match=f"substrate='{substrate}' is out of range") as err:
        post.layer(radius=3.0, substrate=substrate)
    other = "glass" if substrate == "mirror" else "mirror"
    assert f"'{other}'" not in str(err.value)


@pytest.mark.slow
@pytest.mark.render
def test_cli_multichannel_exr_uses_its_main_layer(images, tmp_path):
    """A render with AOVs (Mitsuba's aov integrator: R, G, B, A, albedo.*, nn.*) printed a
    RuntimeError traceback: its main R, G, B layer is the image, and the result equals the pass
    of that layer alone.  Without an unnamed colour layer: one line naming the channels."""
    import mitsuba as mi
    previous = mi.variant()
    mi.set_variant("scalar_rgb")
    try:
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": "aov", "aovs": "albedo:albedo,nn:sh_normal",
                                            "img": {"type": "path"}},
            "sensor": {"type": "perspective", "fov": 30, "film": {"type": "hdrfilm", "width": 20, "height": 16},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "light": {"type": "sphere", "center": [0, 0, 5], "radius": 0.5, "emitter": {"type": "area"}}})
        img = mi.render(scene)
        bmp = scene.sensors()[0].film().bitmap()
        assert bmp.pixel_format() == mi.Bitmap.PixelFormat.MultiChannel and bmp.channel_count() > 4
        path = tmp_path / "aov.exr"
        bmp.write(str(path))
        rgb = np.array(img, dtype=np.float32)[..., :3]
        assert rgb.max() > 0.5 and rgb.min() == 0.0          # the light and black around it
        names = ["albedo.R", "albedo.G", "albedo.B", "nn.X", "nn.Y", "nn.Z"]
        mi.Bitmap(np.ones((4, 4, 6), np.float32), mi.Bitmap.PixelFormat.MultiChannel, names).write(
            str(tmp_path / "aovs_only.exr"))
    finally:
        if previous:
            mi.set_variant(previous)
    r = _cli("post", str(path), "--fov", "30", "-D", "radius=5", "--out", str(tmp_path / "o.exr"), "--no-progress")
    assert r.returncode == 0, r.stderr
    got = np.array(mi.Bitmap(str(tmp_path / "o.exr")), dtype=np.float32)
    np.testing.assert_allclose(got, post.apply(rgb, 30.0, progress=False, radius=5.0), rtol=1e-5, atol=1e-7)
    r = _cli("post", str(tmp_path / "aovs_only.exr"), "--fov", "30", "--out", str(tmp_path / "p.exr"),
             "--no-progress")
    assert r.returncode == 2 and "albedo.R" in r.stderr and "no main R, G, B" in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr


@pytest.mark.slow
@pytest.mark.parametrize("out", ["/sys/corona-post.exr", "/sys/no/such/folder/o.png", "/proc/o.exr"])
def test_cli_unwritable_output_is_refused_before_the_pass(images, out):
    """An output in a folder that takes no new file (sysfs and procfs refuse them even to root,
    unlike permission bits) ran the whole pass, then a traceback at write time: now one line
    before anything is read or computed (the input here is a missing file: the output is
    checked first)."""
    folder, _ = images
    r = _cli("post", str(folder / "in.exr"), "--fov", "30", "--out", out, "--no-progress")
    assert r.returncode == 2 and "cannot be written" in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
    r = _cli("post", str(folder / "missing.exr"), "--fov", "30", "--out", out, "--no-progress")
    assert r.returncode == 2 and "cannot be written" in r.stderr, r.stderr


def test_unwritable_output_is_checked_before_the_pass(images, tmp_path, monkeypatch):
    """In process: apply is never called when the output cannot be written; a read-only existing
    file is refused too (where the permission bits bind: not for root)."""
    folder, _ = images
    monkeypatch.setattr(post, "apply", lambda *a, **k: pytest.fail("the pass ran"))
    with pytest.raises(corona.CoronaError, match="cannot be written"):
        post.apply_file(str(folder / "in.exr"), "/sys/x.exr", 30.0, progress=False)
    # negative control: a writable folder, created on the way, passes the check
    post.check_writable(str(tmp_path / "new" / "deeper" / "o.exr"))
    assert not (tmp_path / "new").exists() and not list(tmp_path.iterdir())


# ----------------------------------------------------------------------
# issue 47 item 6: the cost of anisotropic kernels
# ----------------------------------------------------------------------
def _per_node_kernel(m, response, ny, nx, step):
    """Reference: the renderer's lobe at every node of the padded grid and every quantile
    wavelength (what the pass did before the table), centre nodes left out."""
    lams = post._quantile_wavelengths(response, post.N_PER_CHANNEL_2D)
    ky, kx = np.arange(-(ny - 1), ny), np.arange(-(nx - 1), nx)
    KX, KY = np.meshgrid(kx * step, ky * step)
    d = np.stack([KX, -KY], -1)
    return np.array([sum(m.lobe_tabulated(d, float(lam)) for lam in lams[c]) * step * step / lams.shape[1]
                     for c in range(lams.shape[0])])


@pytest.mark.parametrize("params", [dict(shape="square", radius=5.0, area_fraction=0.3, mode="particle"),
                                    pytest.param(dict(shape="polygon", sides=6, radius=8.0, area_fraction=0.3,
                                                      mode="particle"),   # 3 s of CPU warm
                                                 marks=pytest.mark.slow),
                                    dict(shape="ellipse", radius=3.0, aspect=1.5, area_fraction=0.3,
                                         mode="particle")])
def test_anisotropic_kernel_from_the_table_equals_the_lobe_at_each_node(params, monkeypatch):
    """A grid fine against the lobe (200x150 at 10°): the kernel read from the table of v(u)
    equals the lobe at every node and quantile wavelength within 3e-3 of its peak, its sum within
    3e-4 (measured 1.3e-4).  Negative control: a table ten times coarser misses by more than 1 %."""
    m = post.layer(**params)
    resp = (post.WAVELENGTHS, post.channel_responses("srgb", 3))
    g = post._Grid(200, 150, 10.0)
    ly, lx = post._even_fast_length(2 * g.ny - 1), post._even_fast_length(2 * g.nx - 1)
    assert post.anisotropic_cost(m, resp, g.nx, g.ny, g.step)[1] == "table"
    want = _per_node_kernel(m, resp, g.ny, g.nx, g.step)
    c = post.CENTRE_NODES
    cy, cx = g.ny - 1, g.nx - 1
    want[:, cy - c:cy + c + 1, cx - c:cx + c + 1] = 0       # the centre nodes are tent averages: apart

    def unrolled(kernel):
        got = kernel[:, np.mod(np.arange(-(g.ny - 1), g.ny), ly)][:, :, np.mod(np.arange(-(g.nx - 1), g.nx), lx)]
        got[:, cy - c:cy + c + 1, cx - c:cx + c + 1] = 0
        return got
    got = unrolled(post._anisotropic_kernel(m, resp, ly, lx, g.ny, g.nx, g.step))
    assert np.abs(got - want).max() < 3e-3 * want.max()
    np.testing.assert_allclose(got.sum((1, 2)), want.sum((1, 2)), rtol=3e-4)
    monkeypatch.setattr(post, "TABLE_STEP_U", 10 * post.TABLE_STEP_U)
    coarse = unrolled(post._anisotropic_kernel(m, resp, ly, lx, g.ny, g.nx, g.step))
    assert np.abs(coarse - want).max() > 1e-2 * want.max()


@pytest.mark.slow     # 2 s of CPU warm
def test_anisotropic_kernel_evaluates_the_lobe_a_bounded_number_of_times(monkeypatch):
    """The 3840x2160 frame with a square took 254 s and 5 GB: the lobe in float64 at every node of
    the padded grid x 24 wavelengths (here 960x540: 46 M evaluations).  Now the lobe is read from
    one table: at most 10 M evaluations for that frame (measured 5.1 M, the centre nodes' tent
    samples included), the result finite."""
    from corona.model import render_lobe
    count = [0]
    original = render_lobe.RenderLobe.eval

    def counting(self, u):
        count[0] += np.asarray(u).size // 2
        return original(self, u)
    monkeypatch.setattr(render_lobe.RenderLobe, "eval", counting)
    m = post.layer(shape="square", radius=5.0, area_fraction=0.3, mode="particle")
    img = np.zeros((540, 960, 3), np.float32)
    img[270, 480] = 1.0
    out = post.apply(img, 40.0, m, progress=False)
    assert np.all(np.isfinite(out)) and out[270, 490].sum() > 0
    assert count[0] < 10_000_000, count[0]


@pytest.mark.slow     # 4K-frame cost checks and four particle tables: 5 s of CPU warm
def test_anisotropic_kernel_beyond_the_limit_is_one_line():
    """Pixels coarse against the lobe on a large frame (a 20 µm square, 3840x2160 at 90°: 2.5e8
    evaluations) is refused in one line naming the limit; the 10 µm square of the same frame
    (1e8, at the limit: benchmarks/results/post_anisotropic.json) is accepted by the check."""
    resp = (post.WAVELENGTHS, post.channel_responses("srgb", 3))
    g = post._Grid(3840, 2160, 90.0)
    small = post.layer(shape="square", radius=10.0, area_fraction=0.3, mode="particle")
    assert post.anisotropic_cost(small, resp, g.nx, g.ny, g.step)[0] <= post.ANISOTROPIC_EVALUATIONS_MAX
    big = post.layer(shape="square", radius=20.0, area_fraction=0.3, mode="particle")
    assert post.anisotropic_cost(big, resp, g.nx, g.ny, g.step)[0] > post.ANISOTROPIC_EVALUATIONS_MAX
    with pytest.raises(corona.CoronaError, match=r"lobe evaluations; allowed at most 1e\+08") as err:
        post.apply(np.zeros((2160, 3840, 3), np.float32), 90.0, big, progress=False)
    assert "\n" not in str(err.value)
    # an evaluation costs by the outline's edges: a 16-gon's 2.7 hexagons' on the frame where the
    # hexagon is accepted (slowest accepted: 63 s CPU, benchmarks/results/post_anisotropic.json)
    g = post._Grid(2400, 1350, 90.0)
    hexagon = post.layer(shape="polygon", sides=6, radius=20.0, area_fraction=0.3, mode="particle")
    sixteen = post.layer(shape="polygon", sides=16, radius=20.0, area_fraction=0.3, mode="particle")
    assert post.anisotropic_cost(hexagon, resp, g.nx, g.ny, g.step)[0] <= post.ANISOTROPIC_EVALUATIONS_MAX
    with pytest.raises(corona.CoronaError, match="lobe evaluations; allowed at most"):
        post.apply(np.zeros((1350, 2400, 3), np.float32), 90.0, sixteen, progress=False)


# ----------------------------------------------------------------------
# issue 47 item 13: the field of view's true bound
# ----------------------------------------------------------------------
def _diffuse_by_radius(m, lams=post.WAVELENGTHS[::4]):
    """The channel-weighted directional diffuse transmittance ``D(λ, cos θ = sqrt(1 - |p|²))``
    (``Material.diffuse_transmittance``: the lobe integrated over the propagating directions,
    exact for a radial lobe) on 801 radii ``|p|`` of the unit disk; it does not depend on the
    frame, so one table serves every field of view."""
    w = post.channel_responses("srgb", 3, lams)
    pr = np.linspace(0.0, 1.0, 801)
    lams = np.asarray(lams, dtype=float)         # every wavelength in one call (the same values)
    Dc = np.array([m.diffuse_transmittance(lams, float(np.sqrt(max(0.0, 1 - r * r)))) for r in pr]) @ w.T
    return pr, Dc


def _white_frame_reference(m, W, H, fov, diffuse, n=40):
    """A white image's pixel values for a frame that covers the unit disk but for slivers
    (fields near 180°): ``T_c`` plus the t-average over each pixel of the directional diffuse
    transmittance ``diffuse = _diffuse_by_radius(m)``."""
    pr, Dc = diffuse
    tx, ty, s = post.pixel_tangents(W, H, fov)
    sub = (np.arange(n) + 0.5) / n - 0.5
    out = np.empty((H, W, 3))
    for i in range(H):
        for j in range(W):
            TX, TY = np.meshgrid(tx[j] + sub * s, ty[i] + sub * s)
            r = np.hypot(TX, TY)
            p = r / np.sqrt(1 + r * r)
            out[i, j] = [np.interp(p, pr, Dc[:, c]).mean() for c in range(3)]
    return out + m.coherent_transmittance


@pytest.mark.parametrize("fov", [176.5, 177.0, 179.0])
def test_fields_beyond_176_degrees_are_one_line(fov):
    """179° was accepted ("exact below 180°") and lost 9 % of a 31x21 image's lobe energy."""
    with pytest.raises(corona.CoronaError, match=r"fov=.* is out of range; allowed \(0, 176\] degree") as err:
        post.apply(np.ones((21, 31, 3), np.float32), fov, progress=False, **LAYER)
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_the_widest_field_keeps_the_lobe_within_3_percent(monkeypatch):
    """At the bound (176°) a 31x21 white image's lobe part is within 3 % per pixel of the frame
    integral (measured 2.8 %; the reference takes the frame as the whole disk, within 1.3e-3 in
    p of it here).  Negative control: past the bound, at 179°, pixels are off by more than 8 %
    (measured 11 %; a 9 % energy loss) with the same code."""
    m = post.layer(**LAYER)
    W, H = 31, 21
    out = post.apply(np.ones((H, W, 3), np.float32), 176.0, m, progress=False).astype(np.float64)
    diffuse = _diffuse_by_radius(m)
    ref = _white_frame_reference(m, W, H, 176.0, diffuse)
    rel = (out - ref) / (ref - m.coherent_transmittance)
    assert np.abs(rel).max() < 0.03
    monkeypatch.setattr(post, "FOV_MAX", 179.0)
    out = post.apply(np.ones((H, W, 3), np.float32), 179.0, m, progress=False).astype(np.float64)
    ref = _white_frame_reference(m, W, H, 179.0, diffuse)
    assert np.abs((out - ref) / (ref - m.coherent_transmittance)).max() > 0.08
