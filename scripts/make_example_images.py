"""examples/night.exr: three street lights at night, no layer in front of the camera.

    python scripts/make_example_images.py          (a few seconds on 2 cores)

The input of the documented ``corona post examples/night.exr --fov 24 ...`` (a corona
put on an image that was rendered, or photographed, without one): the scene of
scenes/teaser.xml with its window pane taken out, 256 x 256 pixels, 64 spp, linear
sRGB, a horizontal field of view of 24 degrees.
"""
import os
import re
import sys
import tempfile

import numpy as np

import corona  # noqa: F401  (first: Dr.Jit's libLLVM)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))


def main() -> int:
    import mitsuba as mi
    corona.set_default_variant()
    corona.register()
    text = open(os.path.join(ROOT, "scenes", "teaser.xml"), encoding="utf-8").read()
    # the pane: the one rectangle (the window with condensation) goes, the lamps stay
    bare, n = re.subn(r"\s*<!-- the window pane.*?</shape>", "", text, count=1, flags=re.S)
    assert n == 1, "scenes/teaser.xml: the pane's rectangle was not found"
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "night.xml")
        open(path, "w", encoding="utf-8").write(bare)
        scene = mi.load_file(path, res=256, spp=64)
    image = np.array(mi.render(scene, seed=0), dtype=np.float32)
    out = os.path.join(ROOT, "examples", "night.exr")
    mi.Bitmap(image).convert(component_format=mi.Struct.Type.Float16).write(out)
    print(f"{out}: {image.shape[1]}x{image.shape[0]}, brightest pixel {image.max():.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
