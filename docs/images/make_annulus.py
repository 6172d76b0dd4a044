"""docs/images/annulus.png: a street light through a layer of rings (shape=annulus) beside disks
of the same outer radius (docs/adding_a_scatterer.md).  Run: python docs/images/make_annulus.py"""
import os

import corona  # first: it points Dr.Jit at a libLLVM >= 16
import imageio.v3 as iio
import mitsuba as mi
import numpy as np

from corona.apps.scenes import street_light_scene
from corona.color import tonemap_srgb

mi.set_variant(corona.default_variant(prefer_gpu=False))
corona.register()
layer = {"type": "corona", "radius": 10.0, "process": "hard-disk", "area_fraction": 0.3, "mode": "particle"}
images = []
for shape in ({"shape": "annulus", "inner_ratio": 0.6}, {"shape": "circle"}):
    scene = mi.load_dict(street_light_scene(160, {**layer, **shape}, fov=12.0))
    images.append(np.asarray(mi.render(scene, spp=64, seed=1)))
rgb = np.concatenate(images, axis=1)
iio.imwrite(os.path.join(os.path.dirname(os.path.abspath(__file__)), "annulus.png"), tonemap_srgb(rgb))
