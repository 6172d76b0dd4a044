"""The `corona` command line: one-line errors with exit code 2, render outputs,
and `corona lobe --json` numbers that match the physics (docs/physics.md)."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from corona.apps.cli import main

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
TEASER = os.path.join(ROOT, "scenes", "teaser.xml")


@pytest.fixture
def variant(mi_variant):
    """The default variant, active and with the plugin registered (another test may have switched)."""
    import mitsuba as mi

    import corona
    mi.set_variant(mi_variant)
    corona.register()
    return mi_variant


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def assert_one_line_error(result, *words):
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("corona: error: ")
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert "Traceback" not in result.stderr and "Usage:" not in result.stderr
    return lines[0]


# ----------------------------------------------------------------------------
# errors: missing file, unknown option, bad parameter
# ----------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.render
def test_render_missing_file(tmp_path):
    assert_one_line_error(run("render", tmp_path / "nope.xml"), "nope.xml", "does not exist")


@pytest.mark.slow
@pytest.mark.render
def test_render_missing_file_from_the_console_script(tmp_path):
    """The real entry point (a separate process), not only click's test runner."""
    p = subprocess.run([sys.executable, "-m", "corona.apps.cli", "render", str(tmp_path / "nope.xml")],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "does not exist" in p.stderr


@pytest.mark.parametrize("args", [
    ["render", TEASER, "--bogus"],
    ["lobe", "--no-such-option", "1"],
    ["no-such-command"],
])
def test_unknown_option_or_command(args):
    assert_one_line_error(run(*args))


@pytest.mark.parametrize("args,words", [
    (["render", TEASER, "--spp", "0"], ["--spp"]),
    (["render", TEASER, "--spp", "many"], ["--spp"]),
    (["render", TEASER, "-D", "radius"], ["KEY=VALUE"]),
    (["lobe", "--shape", "hexagon"], ["--shape", "hexagon"]),
    (["lobe", "--area-fraction", "1.5"], ["area_fraction", "1.5"]),
    (["lobe", "--radius", "-2"], ["radius"]),
    (["lobe", "--json", "--wavelength", "2000"], ["wavelength"]),
])
def test_bad_parameter_on_the_command_line(args, words):
    assert_one_line_error(run(*args), *words)


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("define,words", [
    ("area_fraction=1.5", ["area_fraction=1.5", "teaser.xml", "line"]),
    ("radius=-1", ["radius", "teaser.xml"]),
    ("radius=abc", ["abc"]),
    ("no_such_key=1", ["no_such_key"]),
    ("res=0", ["film"]),
])
def test_bad_scene_parameter_is_one_line(define, words, variant, tmp_path):
    """Errors raised while Mitsuba loads the corona plugin come back as one line naming the parameter."""
    assert_one_line_error(run("render", TEASER, "-D", define, "-D", "spp=1", "--out", tmp_path), *words)


@pytest.mark.slow
@pytest.mark.render
def test_bad_variant(tmp_path):
    assert_one_line_error(run("render", TEASER, "--variant", "no_such_variant", "--out", tmp_path),
                          "no_such_variant")


@pytest.mark.slow
@pytest.mark.render
def test_bad_plugin_parameter_in_a_scene_file(tmp_path, variant):
    bad = tmp_path / "bad.xml"
    bad.write_text(open(TEASER, encoding="utf-8").read().replace(
        '<string name="process" value="hard-disk"/>', '<string name="process" value="crystal"/>'))
    line = assert_one_line_error(run("render", bad, "-D", "res=8", "--out", tmp_path), "process", "crystal")
    assert "bad.xml" in line


# ----------------------------------------------------------------------------
# render
# ----------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.render
def test_render_writes_linear_exr_and_png(tmp_path, variant):
    import imageio.v3 as iio
    import mitsuba as mi
    r = run("render", TEASER, "-D", "res=16", "-D", "radius=8", "--spp", "2", "--out", tmp_path,
            "--name", "t", "--variant", variant)
    assert r.exit_code == 0, r.stderr
    assert variant in r.stderr          # says which variant
    exr, png = tmp_path / "t.exr", tmp_path / "t.png"
    assert exr.is_file() and png.is_file() and str(png) in r.stdout
    b = mi.Bitmap(str(exr))
    assert b.pixel_format() == mi.Bitmap.PixelFormat.RGB and not b.srgb_gamma()
    a = np.array(b)
    assert a.shape == (16, 16, 3) and np.all(np.isfinite(a)) and a.max() > 0
    p = iio.imread(png)
    assert p.shape == (16, 16, 3) and p.dtype == np.uint8


@pytest.mark.slow
@pytest.mark.render
def test_render_default_variant_and_scene_spp(tmp_path, variant):
    """Without --variant the fastest one is picked and named; without --spp the scene's spp is used."""
    r = run("render", TEASER, "-D", "res=8", "-D", "spp=3", "--out", tmp_path)
    assert r.exit_code == 0, r.stderr
    assert "fastest available" in r.stderr and ("llvm" in r.stderr or "cuda" in r.stderr)
    assert "3 spp" in r.stdout


@pytest.mark.slow
@pytest.mark.render
def test_render_converts_xyz_film_to_linear_srgb(tmp_path, variant):
    """Whatever the film's pixel format, the EXR holds linear sRGB."""
    import mitsuba as mi
    xyz = tmp_path / "xyz.xml"
    xyz.write_text(open(TEASER, encoding="utf-8").read().replace('value="rgb"', 'value="xyz"'))
    for path, name in [(TEASER, "rgb"), (xyz, "xyz")]:
        assert run("render", path, "-D", "res=8", "--spp", "4", "--seed", "1", "--out", tmp_path,
                   "--name", name).exit_code == 0
    a, b = (np.array(mi.Bitmap(str(tmp_path / f"{n}.exr"))) for n in ("rgb", "xyz"))
    assert np.allclose(a, b, rtol=1e-3, atol=1e-6 * a.max())


# ----------------------------------------------------------------------------
# lobe
# ----------------------------------------------------------------------------
def lobe_json(*args):
    r = run("lobe", "--json", *args)
    assert r.exit_code == 0, r.stderr
    return json.loads(r.stdout)


def airy_times_hard_disk_table(u, fa):
    """``(2 J1(u)/u)² S(2u)``, computed here independently of corona: the circle's
    normalised Airy pattern times the shipped hard-disk table's row at η = F_a
    (circles with σ = 2R: qσ = 2u), read straight from the .npz and
    interpolated by a scipy cubic spline (the table's rows are 0.05 apart in
    η, and ``fa`` must be one of them; ``u <= 20`` stays inside the table)."""
    from scipy.interpolate import CubicSpline
    from scipy.special import j1
    with np.load(os.path.join(ROOT, "src", "corona", "data", "hard_disk_structure_factor.npz")) as z:
        row = int(np.flatnonzero(np.isclose(z["eta"], fa))[0])
        S = CubicSpline(z["q_sigma"], z["S"][row])(2 * np.asarray(u))
    u = np.asarray(u, dtype=np.float64)
    airy = np.where(u > 0, 2 * j1(u) / np.where(u > 0, u, 1), 1.0) ** 2
    return airy * S


@pytest.mark.parametrize("R,lam,fa", [(5.0, 550.0, 0.3), (1.5, 450.0, 0.5)])
def test_lobe_json_at_d0_is_fa_ta_ts(R, lam, fa):
    o = lobe_json("--radius", R, "--wavelength", lam, "--area-fraction", fa)
    assert o["u"][0] == 0.0 and o["d"][0] == 0.0
    ta0 = math.pi * R**2 / (lam * 1e-3) ** 2          # circle: T_a(0) = π R² / λ²
    assert o["form_factor_Ta"][0] == pytest.approx(ta0, rel=1e-9)
    # identical circles: the coherent form factor is the form factor
    assert o["coherent_form_factor_Tc"] == o["form_factor_Ta"]
    # every point: lobe = F_a T_a(0) (2 J1(u)/u)² S_hard-disk(2u), from an independent evaluation
    u, lobe = np.array(o["u"]), np.array(o["lobe"])
    inside = u <= 20.0
    ref = fa * ta0 * airy_times_hard_disk_table(u[inside], fa)
    np.testing.assert_allclose(lobe[inside], ref, rtol=1e-4, atol=1e-6 * lobe[0])


def test_lobe_json_physics():
    R, lam, fa = 5.0, 550.0, 0.3
    o = lobe_json("--radius", R, "--wavelength", lam, "--area-fraction", fa, "--mode", "aperture")
    u, ta, ts = (np.array(o[k]) for k in ("u", "form_factor_Ta", "structure_factor_Ts"))
    # u and d agree: u = 2π R d / λ
    assert np.allclose(u, 2 * np.pi * R * np.array(o["d"]) / (lam * 1e-3))
    # the Airy pattern: T_a(u) = T_a(0) (2 J1(u)/u)², zeros at u = 3.8317, 7.0156
    from scipy.special import j1
    airy = np.where(u > 0, 2 * j1(u) / np.where(u > 0, u, 1), 1.0) ** 2
    assert np.allclose(ta / ta[0], airy, rtol=1e-6, atol=1e-9)
    for zero in (3.8317, 7.0156):
        i = np.searchsorted(u, zero)
        assert ta[i] < ta[i - 1] and ta[i] < ta[i + 1] or ta[i - 1] < ta[i - 2] and ta[i - 1] < ta[i]
    # hard disks: S(0) from Henderson's equation of state at η = 0.3 (≈ 0.258), S → 1 far out
    assert ts[0] == pytest.approx(0.258, abs=0.02)
    assert abs(ts[-1] - 1) < 0.05
    # component energies: coherent F_a², lobe F_a (1 - F_a) for non-overlapping holes
    assert o["coherent_transmittance"] == pytest.approx(fa**2)
    assert o["diffuse_transmittance"] == pytest.approx(fa * (1 - fa), rel=0.03)
    p = lobe_json("--radius", R, "--area-fraction", fa, "--mode", "particle")
    assert p["coherent_transmittance"] == pytest.approx((1 - fa) ** 2)
    assert np.allclose(p["lobe"], o["lobe"])          # Babinet: the same diffuse lobe


def test_lobe_json_anisotropic_material():
    o = lobe_json("--shape", "square", "--radius", "2", "--process", "lattice-square", "--jitter", "0.3")
    assert len(o["u"]) == len(o["lobe"]) and np.all(np.isfinite(o["lobe"]))
    # square of side 2a: T_a(0) = |A| / λ² = (2a)² / λ²
    assert o["form_factor_Ta"][0] == pytest.approx(16.0 / 0.55**2, rel=1e-9)


@pytest.mark.slow
def test_lobe_picture(tmp_path, monkeypatch):
    """The panels side by side, and library code leaves matplotlib's global state alone.  The
    picture goes into a folder that does not exist yet (the gallery's documented command run from
    a fresh folder: docs/gallery/lobe_tables.png), which is made, as corona render does."""
    import imageio.v3 as iio
    import matplotlib
    monkeypatch.delitem(sys.modules, "matplotlib.pyplot", raising=False)
    backend = dict.__getitem__(matplotlib.rcParams, "backend")
    out = tmp_path / "docs" / "gallery" / "lobe.png"
    r = run("lobe", "--radius", "5", "--area-fraction", "0.4", "--mode", "particle", "--out", out)
    assert r.exit_code == 0, r.stderr
    # library code leaves matplotlib's global state alone: no pyplot, no backend switch
    assert "matplotlib.pyplot" not in sys.modules
    assert dict.__getitem__(matplotlib.rcParams, "backend") == backend
    assert out.is_file() and str(out) in r.stdout
    img = iio.imread(out)
    assert img.ndim == 3 and img.shape[1] > 2 * img.shape[0]    # the panels side by side


@pytest.mark.slow
def test_lobe_picture_anisotropic(tmp_path):
    out = tmp_path / "sq.png"
    r = run("lobe", "--shape", "square", "--radius", "20", "--area-fraction", "0.25",
            "--process", "lattice-square", "--jitter", "4", "--out", out)
    assert r.exit_code == 0, r.stderr
    assert out.is_file()


def test_lobe_maps_match_the_physics():
    """The pictured lobe map is v(u) = (2 J1(u)/u)² S(2u) (circles on hard disks, v in units
    of P(0)/R² = π), checked against the independent evaluation on the 2-D grid."""
    import corona
    from corona.apps.pictures import lobe_maps
    fa = 0.35
    m = corona.Material(corona.Circle(radius=3.0), corona.HardDisk(area_fraction=fa))
    maps = lobe_maps(m, 20.0, n=41)
    u = maps["u"]
    ux, uy = np.meshgrid(u, u[::-1], indexing="xy")
    ua = np.hypot(ux, uy)
    inside = ua <= 20.0
    ref = np.pi * airy_times_hard_disk_table(ua[inside], fa)
    np.testing.assert_allclose(maps["lobe"][inside], ref, rtol=1e-4, atol=1e-7 * np.pi)
    # the form-factor map is the Airy pattern, the structure-factor map the hard-disk S
    np.testing.assert_allclose(maps["form_factor"][inside] * maps["structure_factor"][inside], ref,
                               rtol=1e-4, atol=1e-7 * np.pi)
    # S(0) against Henderson's compressibility 1 / (d(ηZ)/dη), Z = (1 + η²/8)/(1 - η)² (within 1 %)
    henderson = (1 - fa) ** 3 / ((1 + 3 * fa**2 / 8) * (1 - fa) + 2 * fa * (1 + fa**2 / 8))
    assert maps["structure_factor"][20, 20] == pytest.approx(henderson, rel=0.01)


def test_lobe_picture_without_matplotlib_is_one_line(tmp_path, monkeypatch):
    """matplotlib is in the `reference` extra: without it, one line says how to get it."""
    for name in [k for k in sys.modules if k == "matplotlib" or k.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)          # import matplotlib -> ImportError
    line = assert_one_line_error(run("lobe", "--radius", "5", "--out", tmp_path / "x.png"),
                                 "matplotlib", "corona-bsdf[reference]")
    assert not (tmp_path / "x.png").exists(), line


# ----------------------------------------------------------------------------
# corona lobe for spheres (issue 43 items 2 and 6): a picture, a progress bar with a total
# ----------------------------------------------------------------------------
@pytest.mark.slow
def test_lobe_picture_of_spheres_shows_the_table_build(tmp_path, monkeypatch):
    """`corona lobe --shape sphere --out` draws the Mie layer (it was refused); a radius whose table
    is not in the (empty) cache builds it first, with a progress bar on stderr that has a total;
    `--json --out` prints the numbers alone on stdout and writes the picture too."""
    import re

    import imageio.v3 as iio

    from corona.model import tabulated
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(tabulated, "PROGRESS_DELAY", 0.0)        # the bar at once, however fast the build
    out = tmp_path / "sphere.png"
    r = CliRunner().invoke(main, ["lobe", "--shape", "sphere", "--radius", "2.9", "--area-fraction", "0.2",
                                  "--process", "poisson", "--out", str(out)], catch_exceptions=False)
    assert r.exit_code == 0, r.stderr
    assert r.stdout.strip() == str(out)
    img = iio.imread(out)
    assert img.ndim == 3 and img.shape[1] > 2 * img.shape[0] and img.std() > 10   # the panels side by side
    states = r.stderr.replace("\r", "\n").splitlines()
    bars = [s for s in states if "building the Mie sphere table (2.9 µm)" in s]
    assert bars, r.stderr
    # every state of the bar shows "done/total", and the last one is complete
    assert all(re.search(r"\| *\d+/\d+ \[", s) for s in bars), [s for s in bars if not re.search(r"\d+/\d+ \[", s)]
    n, total = map(int, re.search(r"(\d+)/(\d+) \[", bars[-1]).groups())
    assert n == total > 100
    # the table is in the cache now: no bar the second time; --json --out: JSON alone on stdout
    out2 = tmp_path / "again.png"
    r = CliRunner().invoke(main, ["lobe", "--shape", "sphere", "--radius", "2.9", "--area-fraction", "0.2",
                                  "--process", "poisson", "--json", "--out", str(out2)], catch_exceptions=False)
    assert r.exit_code == 0, r.stderr
    assert "building the Mie sphere table" not in r.stderr
    assert json.loads(r.stdout)["length_scale_um"] == 2.9 and out2.stat().st_size > 1000


@pytest.mark.slow
def test_sphere_corona_is_mie_theory():
    """The corona of the sphere picture (corona.apps.pictures.sphere_corona) is Mie theory: for a
    dilute Poisson layer each pixel is F_a w dσ/dΩ / (π r² cos θ) (corona.model.mie.theory), weighted
    by the black body and taken to linear sRGB; negative control: a radius 10 % off differs."""
    import warnings

    from corona.apps.pictures import sphere_corona
    from corona.color import blackbody, spectrum_to_linear_srgb
    from corona.model.mie import theory as mie
    from corona.parameters import material_from_parameters
    r, fa, n_lam, half = 3.0, 0.05, 6, 12.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = material_from_parameters(shape="sphere", radius=r, area_fraction=fa, process="poisson", ior=1.5)
    img = sphere_corona(m, half, size=21, n_wavelengths=n_lam)
    t = np.radians(np.linspace(-half, half, 21))
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    d = np.stack([np.sin(tx) * np.cos(ty), np.sin(ty)], -1)
    cos_t = np.sqrt(1 - np.sum(d * d, -1))
    lams = np.linspace(380.0, 780.0, n_lam)
    spd = blackbody(lams, 3000.0)
    spd = spd / spd.max()

    def reference(radius):
        f = np.stack([fa * float(m.energies(1.0, lam)["weight"])
                      * mie.differential_cross_section(1.5, radius, lam * 1e-3, cos_t) / (np.pi * radius**2) / cos_t
                      for lam in lams], -1)
        return spectrum_to_linear_srgb(f * spd, lams)
    ref = reference(r)
    np.testing.assert_allclose(img, ref, rtol=0.01, atol=2e-3 * ref.max())
    assert np.abs(reference(1.1 * r) - img).max() > 0.05 * ref.max()
