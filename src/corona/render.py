"""Render Mitsuba scenes that use the corona BSDF and save EXR + PNG."""
from __future__ import annotations

import os
import time

import numpy as np

from ._validation import CoronaError


def setup_variant(variant: str | None = None) -> str:
    """Activate ``variant`` (default: the fastest usable spectral one) and register the plugin."""
    import mitsuba as mi
    from . import _environment
    if variant is None:
        variant = _environment.default_variant()
    if variant not in mi.variants():
        raise CoronaError(f"variant={variant!r} is not available; available: {', '.join(mi.variants())}")
    mi.set_variant(variant)
    from .mitsuba_bsdf import register
    register()
    return variant


def render_to_files(scene, out_dir: str, name: str, spp: int, seed: int = 0,
                    progress: bool = True, exposure: float | None = None) -> dict:
    """Render ``scene`` (a loaded ``mi.Scene``) and write ``name.exr`` and ``name.png``.

    The EXR holds the film's linear RGB (spectral variants are converted to
    linear sRGB by Mitsuba's film); the PNG is tonemapped sRGB.  Rendering is
    split into passes so a progress bar can follow long renders.
    """
    import mitsuba as mi
    from tqdm import tqdm

    from .color import tonemap_srgb
    os.makedirs(out_dir, exist_ok=True)
    passes = max(1, min(spp // 16, 64))
    spp_pass = [spp // passes + (1 if i < spp % passes else 0) for i in range(passes)]
    acc = None
    t0 = time.perf_counter()
    for i, s in enumerate(tqdm(spp_pass, desc=f"render {name}", unit="pass", disable=not progress)):
        img = np.array(mi.render(scene, spp=s, seed=seed * 1000 + i), dtype=np.float64)
        acc = img * s if acc is None else acc + img * s
    seconds = time.perf_counter() - t0
    img = (acc / spp).astype(np.float32)
    if not np.all(np.isfinite(img)):
        raise CoronaError(f"render of {name} produced non-finite pixels")
    exr = os.path.join(out_dir, f"{name}.exr")
    png = os.path.join(out_dir, f"{name}.png")
    mi.Bitmap(img[..., :3], pixel_format=mi.Bitmap.PixelFormat.RGB).write(exr)
    import imageio.v3 as iio
    iio.imwrite(png, tonemap_srgb(img[..., :3], exposure))
    return {"exr": exr, "png": png, "seconds": seconds, "spp": spp, "variant": mi.variant()}
