"""Write the textures of scenes/textures/ (small, deterministic): ``python scripts/make_scene_textures.py``.

* ``wiped_fog.png`` (96×96, 8-bit grey, read with ``raw=true``): the area
  fraction F_a = value / 255 of the condensation on the pane of
  ``scenes/wiped_window.xml``, as the camera sees it (row 0 at the top):
  0.22 in the middle of the pane rising to 0.55 at the frame (the glass is
  coldest there), a wiped streak from the lower left to the upper right with
  F_a = 0.015 left in it and soft edges, and ±0.015 of noise.
* ``condensation_radius.exr`` (64×4, one float channel): the droplet radius
  [µm] of ``scenes/condensation_gradient.xml``, growing from 3 µm at the
  left of the pane to 12 µm at the right (the droplets grow where the glass
  is coldest), linear in x.
* ``breath_spot_age.exr`` (64×64, one float channel): the breath figure's age ``breath_time`` [s]
  of ``scenes/breath_spot.xml``: a breath spot drying from its edge, 40 s (the droplets grown
  largest) in its middle falling to 5 s at its rim (r = 0.9 of the half-width) and beyond,
  smooth and uniform in log t.
* ``fogged_pane_dry.exr`` (64×64, one float channel): the time since the vapour stopped ``dry_time``
  [s] of ``scenes/fogged_pane_drying.xml`` (a pane fogged for 20 s, clearing from its edges, where
  the air reaches it first): 0 s in the middle rising to 16 s at the frame (of 18 s the table
  covers after 20 s of growth), smooth in the distance to the frame.
* ``wiped_refog_age.exr`` (96×96, one float channel): ``breath_time`` [s] of
  ``scenes/wiped_window_refog.xml``: fog 40 s old over the pane and 5 s old in the streak of
  ``wiped_fog.png`` (wiped, fogging up again), soft edges uniform in log t.
"""
from __future__ import annotations

import os

import numpy as np

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "scenes", "textures")


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def wiped_fog(n: int = 96, seed: int = 12) -> np.ndarray:
    """F_a on an n×n grid, row 0 at the top of the pane as seen from the camera."""
    y, x = (np.mgrid[:n, :n] + 0.5) / n                 # x to the right, y down
    frame = np.maximum(np.abs(x - 0.5), np.abs(y - 0.5)) * 2   # 0 in the middle, 1 at the frame
    fa = 0.22 + 0.33 * smoothstep(0.35, 1.0, frame)
    centre = 0.8 - 0.55 * x + 0.12 * np.sin(np.pi * x)   # the wipe's path
    dist = np.abs(y - centre)
    wiped = 1.0 - smoothstep(0.08, 0.12, dist)
    fa = fa * (1 - wiped) + 0.015 * wiped
    fa += np.random.default_rng(seed).normal(0.0, 0.015, fa.shape)
    return np.clip(fa, 0.005, 0.6)


def condensation_radius(width: int = 64, height: int = 4) -> np.ndarray:
    x = (np.arange(width) + 0.5) / width
    return np.tile(3.0 + 9.0 * x, (height, 1))


def breath_spot_age(n: int = 64) -> np.ndarray:
    """breath_time [s] on an n×n grid: 40 s in the middle, 5 s from r = 0.9 of the half-width on."""
    y, x = (np.mgrid[:n, :n] + 0.5) / n
    r = np.hypot(x - 0.5, y - 0.5) * 2
    return np.exp(np.log(5.0) + np.log(8.0) * (1.0 - smoothstep(0.15, 0.9, r)))


def fogged_pane_dry(n: int = 64) -> np.ndarray:
    """dry_time [s] on an n×n grid: 0 s in the middle, 16 s at the frame (the pane clears from its edges)."""
    y, x = (np.mgrid[:n, :n] + 0.5) / n
    frame = np.maximum(np.abs(x - 0.5), np.abs(y - 0.5)) * 2   # 0 in the middle, 1 at the frame
    return 16.0 * smoothstep(0.2, 1.0, frame)


def wiped_refog_age(n: int = 96) -> np.ndarray:
    """breath_time [s] on an n×n grid (row 0 at the top): 40 s, 5 s in the wiped streak of :func:`wiped_fog`."""
    y, x = (np.mgrid[:n, :n] + 0.5) / n
    centre = 0.8 - 0.55 * x + 0.12 * np.sin(np.pi * x)   # the wipe's path (as wiped_fog)
    wiped = 1.0 - smoothstep(0.08, 0.12, np.abs(y - centre))
    return np.exp(np.log(40.0) + (np.log(5.0) - np.log(40.0)) * wiped)


def main() -> None:
    import imageio.v3 as iio
    import mitsuba as mi
    import corona  # noqa: F401  (libLLVM before drjit)
    from corona.apps.render import setup_variant
    setup_variant("scalar_rgb")
    os.makedirs(HERE, exist_ok=True)
    iio.imwrite(os.path.join(HERE, "wiped_fog.png"), np.round(wiped_fog() * 255).astype(np.uint8))
    mi.Bitmap(condensation_radius().astype(np.float32)[..., None]).write(
        os.path.join(HERE, "condensation_radius.exr"))
    mi.Bitmap(breath_spot_age().astype(np.float32)[..., None]).write(os.path.join(HERE, "breath_spot_age.exr"))
    mi.Bitmap(fogged_pane_dry().astype(np.float32)[..., None]).write(os.path.join(HERE, "fogged_pane_dry.exr"))
    mi.Bitmap(wiped_refog_age().astype(np.float32)[..., None]).write(os.path.join(HERE, "wiped_refog_age.exr"))
    print(f"wrote {os.path.normpath(HERE)}/wiped_fog.png, condensation_radius.exr, breath_spot_age.exr, "
          "fogged_pane_dry.exr, wiped_refog_age.exr")


if __name__ == "__main__":
    main()
