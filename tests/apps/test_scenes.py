"""Every scene of scenes/ loads and renders (tiny, few spp) without NaN/Inf;
the gallery's strips point at scenes and parameters that exist."""
from __future__ import annotations

import glob
import os
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
SCENES = sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml")))
RES, SPP = 24, 2


@pytest.fixture
def variant(mi_variant):
    """The default variant, active and with the plugin registered (another test may have switched)."""
    import mitsuba as mi

    import corona
    mi.set_variant(mi_variant)
    corona.register()
    return mi_variant


def _defaults(path: str) -> dict:
    return {d.get("name"): d.get("value") for d in ET.parse(path).getroot().iter("default")}


def _render(path: str, defines: dict):
    import mitsuba as mi
    from corona.apps.render import load_scene, render_linear
    scene = load_scene(path, {**defines, "res": RES})
    rgb, _ = render_linear(scene, SPP, progress=False, desc=os.path.basename(path))
    return np.asarray(rgb), mi


def test_there_are_scenes():
    names = {os.path.basename(p) for p in SCENES}
    for required in ["teaser.xml", "lycopodium.xml", "fabric.xml", "sweep_radius.xml",
                     "sweep_area_fraction.xml", "sweep_incidence.xml", "circle_vs_square.xml",
                     "babinet.xml", "monochromatic.xml", "mixed.xml", "sampling.xml",
                     "window_at_night.xml", "wiped_window.xml", "condensation_gradient.xml",
                     "dusty_mirror.xml", "fogged_window.xml", "breath_figure.xml", "breath_spot.xml",
                     "fogged_pane_drying.xml", "wiped_window_refog.xml"]:
        assert required in names


@pytest.mark.parametrize("path", SCENES, ids=os.path.basename)
def test_scene_declares_its_parameters_and_units(path):
    d = _defaults(path)
    assert "spp" in d and "res" in d, "every scene takes -D spp=N -D res=N"
    text = open(path, encoding="utf-8").read()
    assert 'version="3.0.0"' in text
    assert "metres" in text and "micrometres" in text, "the comment states the units"
    assert 'type="corona"' in text or 'type="corona_mie"' in text    # the BSDF or the phase function


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("path", SCENES, ids=os.path.basename)
def test_scene_renders_finite(path, variant):
    rgb, _ = _render(path, {})
    assert rgb.shape == (RES, RES, 3)
    assert np.all(np.isfinite(rgb))
    assert rgb.max() > 0, "the light (or its corona) is in view"
    # channels may go negative (spectral colours are outside sRGB), luminance may not
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    assert lum.min() > -1e-4 * lum.max()


#: Strips whose panels differ only in values that move a light or the camera or change a number
#: of the layer (no branch of the plugin or the scene: the same kernels, other tables): one
#: panel of each is rendered here, the strip's last (the widest value), and the scene's
#: defaults above.  Panels that switch a shape, a mode, a substrate, the sampling or a mixture's
#: weights to zero are each rendered.
VALUES_ONLY = {"dusty_mirror": {"torch_z"}, "fogged_window": {"thickness"}, "lycopodium": {"fov"},
               "sweep_radius": {"radius"}, "sweep_area_fraction": {"area_fraction"},
               "sweep_incidence": {"elevation"},
               "monochromatic": {"area_fraction", "lambda_min", "lambda_max"}}


def _gallery_panels():
    from gallery import STRIPS
    out = []
    for strip in STRIPS:
        panels = [(i, {k: v for k, v in panel.defines.items() if k not in ("spp", "res")})
                  for i, panel in enumerate(strip.panels)]
        panels = [(i, d) for i, d in panels if d]      # the scene's defaults are covered above
        panels = [(i, d) for k, (i, d) in enumerate(panels) if d not in [e for _, e in panels[:k]]]
        same = VALUES_ONLY.get(strip.name)
        if same and all(set(d) <= same for _, d in panels):
            panels = panels[-1:]
        out += [pytest.param(strip.scene, d, id=f"{strip.name}-{i + 1}") for i, d in panels]
    return out


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("scene,defines", _gallery_panels())
def test_gallery_panel_renders_finite(scene, defines, variant):
    rgb, _ = _render(os.path.join(ROOT, "scenes", scene), defines)
    assert np.all(np.isfinite(rgb)) and rgb.max() > 0


def test_gallery_strips_refer_to_existing_scenes_and_parameters():
    from gallery import STRIPS
    names = [s.name for s in STRIPS]
    assert len(names) == len(set(names))
    for strip in STRIPS:
        if strip.scene is None:
            assert strip.lobe_args
            continue
        path = os.path.join(ROOT, "scenes", strip.scene)
        assert os.path.isfile(path)
        known = _defaults(path)
        for panel in strip.panels:
            assert set(panel.defines) <= set(known), (strip.name, set(panel.defines) - set(known))


def test_gallery_tile_and_page(tmp_path):
    import gallery
    ims = [np.zeros((10, 12, 3), np.uint8), np.full((10, 8, 3), 255, np.uint8)]
    img = gallery.tile(ims, ["a µm", "b ×"], gap=2, band=20)
    assert img.size == (12 + 2 + 8, 30)
    strip = gallery.STRIPS[0]
    (tmp_path / "g").mkdir()
    img.save(tmp_path / "g" / f"{strip.name}.png")
    md = tmp_path / "gallery.md"
    gallery.write_markdown(str(md), str(tmp_path / "g"), {strip.name: ["corona render x"]}, {}, "v")
    text = md.read_text()
    assert f"![{strip.title}](g/{strip.name}.png)" in text and "corona render x" in text
    # strips without a picture are left out
    assert gallery.STRIPS[1].title not in text


@pytest.mark.slow
@pytest.mark.render
def test_incidence_scene_tilts_the_layer(variant):
    """elevation=30 stretches the corona along the tilt (x), not along y."""
    path = os.path.join(ROOT, "scenes", "sweep_incidence.xml")

    def spreads(elevation):
        rgb, _ = _render(path, {"elevation": elevation})
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
        lum = np.minimum(lum, np.percentile(lum, 90))       # the lamp's few pixels do not dominate
        y, x = np.mgrid[:RES, :RES] - (RES - 1) / 2
        return [float(np.sqrt(np.sum(lum * c * c) / np.sum(lum))) for c in (x, y)]

    (sx90, sy90), (sx30, sy30) = spreads(90), spreads(30)
    assert abs(sx90 - sy90) < 0.15 * sy90
    assert sx30 > 1.25 * sy30


# --- every variant: RGB variants cannot render Mitsuba's `blackbody` -------------------
RGB_VARIANTS = [("llvm_ad_rgb", 16, 2), ("scalar_rgb", 8, 1)]   # scalar: Python per sample, keep it tiny


#: Scenes whose layer takes, in a scalar variant, the plugin path of another scene rendered there
#: (scalar_rgb runs the plugin's Python-scalar branches; the emitters' RGB form is the scene's and
#: is checked for every scene in llvm_ad_rgb): aperture-mode hard-disk circles as babinet.xml,
#: particle-mode radial circles (hard-disk, rsa) as teaser.xml, Poisson spheres as lunar_corona.xml,
#: a corona_mie medium as streetlight_fog.xml.
SCALAR_SAME_PATH = {"sweep_radius.xml", "sweep_area_fraction.xml", "sweep_incidence.xml", "monochromatic.xml",
                    "circle_vs_square.xml", "sampling.xml", "lycopodium.xml", "glory_fogbow.xml",
                    "streetlight_mist.xml"}
RGB_CASES = [pytest.param(path, *v, id=f"{os.path.basename(path)}-{v[0]}") for path in SCENES
             for v in RGB_VARIANTS if not (v[0].startswith("scalar") and os.path.basename(path) in SCALAR_SAME_PATH)]


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("path,name,res,spp", RGB_CASES)
def test_scene_renders_in_rgb_variants(path, name, res, spp, mi_variant):
    """Emitters are given in a form RGB variants understand; pixels finite and >= 0."""
    import mitsuba as mi
    from corona.apps.render import load_scene, render_linear, setup_variant
    try:
        setup_variant(name)
        scene = load_scene(path, {"res": res, "spp": spp})
        rgb, _ = render_linear(scene, spp, progress=False, desc=os.path.basename(path))
    finally:
        mi.set_variant(mi_variant)
    assert rgb.shape == (res, res, 3)
    assert np.all(np.isfinite(rgb))
    assert rgb.min() >= 0.0
    assert rgb.max() > 0, "the light (or its corona) is in view"


@pytest.mark.slow
@pytest.mark.render
def test_street_light_scene_renders_in_rgb(mi_variant):
    import mitsuba as mi
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    try:
        setup_variant("llvm_ad_rgb")
        img = np.array(mi.render(mi.load_dict(street_light_scene(resolution=16)), spp=2))
    finally:
        mi.set_variant(mi_variant)
    assert np.all(np.isfinite(img)) and img.min() >= 0 and img.max() > 0


BLACKBODY = re.compile(r'blackbody (\d+) K(?: x (\d+(?:\.\d+)?))?[^>]*-->\s*<spectrum name="radiance"\s+value="([^"]+)"')


def test_scene_lamps_are_plancks_law(mi_variant):
    """Every black body of scenes/ (a wavelength:value list) is Planck's law, i.e. what
    Mitsuba's spectral-only `blackbody` gives (times the stated scale)."""
    import drjit as dr
    import mitsuba as mi
    from corona.apps.scenes import blackbody_radiance
    lam = np.arange(360.0, 831.0, 10.0)
    si = dr.zeros(mi.SurfaceInteraction3f, lam.size)
    si.wavelengths = mi.Spectrum(*[mi.Float(lam)] * 4)
    found = 0
    for path in SCENES:
        text = open(path, encoding="utf-8").read()
        assert 'type="blackbody"' not in text, f"{path}: Mitsuba's blackbody is spectral-only"
        for t, scale, values in BLACKBODY.findall(text):
            pairs = np.array([[float(x) for x in item.split(":")] for item in values.split(",")])
            np.testing.assert_array_equal(pairs[:, 0], lam)
            mitsuba_bb = np.array(mi.load_dict({"type": "blackbody", "temperature": float(t)}).eval(si))[0]
            np.testing.assert_allclose(pairs[:, 1], float(scale or 1) * mitsuba_bb, rtol=6e-4)
            np.testing.assert_allclose(blackbody_radiance(float(t), lam), mitsuba_bb, rtol=1e-5)
            found += 1
    assert found >= 15
