"""The street-light scenes against single-scattering Mie theory: rings where the mist is near the
eye (scenes/streetlight_mist.xml), only an aureole where the fog fills the way to the lamp
(scenes/streetlight_fog.xml), as docs/volumes.md says of their pictures."""
import os

import mitsuba as mi
import numpy as np
import pytest

from corona.mitsuba.phase import channel_response
from corona.model.mie.volume import MieVolume
from test_volume import ring_contrast, variant  # noqa: F401  (the fixture)

SCENES = os.path.join(os.path.dirname(__file__), os.pardir, os.pardir, "scenes")


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("variant", ["llvm_ad_rgb"], indirect=True)
def test_mist_near_the_eye_shows_the_rings_and_deep_fog_does_not(variant):
    # the droplets of both scenes at the mist's narrow spread; the rings' angles come from the
    # green row of the single-scattering phase function (Mie theory, not the renderer)
    v = MieVolume(5.0, distribution="gamma", variance=0.005)
    rows, theta = v.rgb_table(*channel_response()), v.table["theta"]
    contrast = {}
    for name, fov in (("streetlight_mist", 24.0), ("streetlight_fog", 30.0)):
        scene = mi.load_file(os.path.join(SCENES, name + ".xml"), res=128, spp=256, variance=0.005)
        img = np.array(mi.render(scene, seed=1))
        assert np.all(np.isfinite(img))
        contrast[name] = ring_contrast(img, fov, rows, theta)
    # measured 0.13 and -0.16: the mist's maxima are brighter than its minima, the fog's are not
    assert contrast["streetlight_mist"] > 0.08, contrast
    assert contrast["streetlight_fog"] < 0.02, contrast
