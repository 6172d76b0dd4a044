"""Render Mitsuba scenes that use the corona BSDF and save EXR + PNG."""
from __future__ import annotations

import os
import re
import time

import numpy as np

from corona._validation import CoronaError, one_line_error


def setup_variant(variant: str | None = None) -> str:
    """Activate ``variant`` (default: the fastest usable spectral one) and register the plugin."""
    import mitsuba as mi
    from corona import _environment
    if variant is None:
        variant = _environment.default_variant()
    if variant not in mi.variants():
        raise CoronaError(f"variant={variant!r} is not available; available: {', '.join(mi.variants())}")
    # check the backend first: Dr.Jit fails deep inside set_variant otherwise
    if variant.startswith("cuda_") and not _environment.has_cuda():
        raise CoronaError(f"variant={variant!r} needs a CUDA GPU and none is usable here; "
                          f"use {_environment.default_variant(prefer_gpu=False)!r}")
    if variant.startswith("llvm_") and not _environment.has_llvm():
        raise CoronaError(f"variant={variant!r} needs Dr.Jit's LLVM backend, which is not usable here; "
                          + _environment.FIX_HINT)
    try:
        mi.set_variant(variant)
    except (ImportError, RuntimeError) as err:
        raise CoronaError(f"variant={variant!r} could not be activated: "
                          f"{str(err).strip().splitlines()[-1]}") from None
    from corona import register            # the corona BSDF and the corona_mie phase function
    register()
    return variant


def is_interrupt(err) -> bool:
    """True when ``err`` is, or wraps, a KeyboardInterrupt (Mitsuba turns a Ctrl-C
    inside a Python plugin into a RuntimeError whose text ends in the traceback)."""
    while err is not None:
        if isinstance(err, KeyboardInterrupt):
            return True
        lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
        if lines and lines[-1].startswith("KeyboardInterrupt"):
            return True
        err = err.__cause__ or err.__context__
    return False


def load_scene(path: str, defines: dict | None = None):
    """``mi.load_file(path, **defines)`` with one-line :class:`CoronaError` messages."""
    import mitsuba as mi
    if not os.path.isfile(path):
        raise CoronaError(f"scene file {path!r} does not exist")
    try:
        scene = mi.load_file(path, **{k: str(v) for k, v in (defines or {}).items()})
    except Exception as err:  # Mitsuba raises RuntimeError for every kind of problem
        if is_interrupt(err):
            raise KeyboardInterrupt from None
        unused = re.findall(r"^\s*-\s*\$(\w+)=", str(err), flags=re.M)
        if "unused parameters" in str(err) and unused:
            raise CoronaError(f"{path} has no parameter {', '.join(unused)} "
                              f"(-D KEY=VALUE sets a <default name=\"KEY\"> / $KEY of the scene)") from None
        raise CoronaError(one_line_error(err)) from None
    sensors = scene.sensors()
    if not sensors:
        raise CoronaError(f"{path}: the scene has no sensor")
    if scene.integrator() is None:
        raise CoronaError(f"{path}: the scene has no integrator (e.g. <integrator type=\"path\"/>)")
    size = [int(v) for v in sensors[0].film().size()]
    if min(size) < 1:
        raise CoronaError(f"{path}: film size {size[0]}x{size[1]} is empty; width and height must be >= 1")
    return scene


def scene_spp(scene) -> int:
    """The sample count the scene's sensor asks for (``<sampler><integer name="sample_count">``)."""
    return int(scene.sensors()[0].sampler().sample_count())


def render_linear(scene, spp: int, seed: int = 0, progress: bool = True, desc: str = "render") -> tuple:
    """Render ``scene`` in passes; returns (linear sRGB float32 (h, w, 3), seconds).

    Whatever the film's pixel format (RGB, RGBA, XYZ, luminance...), the image
    is converted to linear sRGB by Mitsuba's own ``Bitmap.convert``; in
    spectral variants the film has already integrated the spectra against the
    CIE 1931 matching functions.  Passes of <= 16-ish spp let a progress bar
    follow long renders.
    """
    import mitsuba as mi
    from tqdm import tqdm
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or not 1 <= spp <= 2**32 - 1:
        raise CoronaError(f"spp={spp!r} is out of range; allowed integers >= 1")
    # passes of ~16 spp (a progress bar), each at most 2^24 samples where possible (the
    # wavefront's memory), at most 256 (the seeds seed·1000 + i stay distinct uint32s)
    npix = int(np.prod([int(v) for v in scene.sensors()[0].film().size()]))
    passes = int(min(256, spp, max(1, min(spp // 16, 64), -(-spp * npix // 2**24))))
    spp_pass = [spp // passes + (1 if i < spp % passes else 0) for i in range(passes)]
    acc = None
    t0 = time.perf_counter()
    for i, s in enumerate(tqdm(spp_pass, desc=desc, unit="pass", disable=not progress, leave=False)):
        try:
            img = np.array(mi.render(scene, spp=s, seed=seed * 1000 + i), dtype=np.float64)
        except Exception as err:  # RuntimeError mostly; a bare Exception for some scene problems
            if is_interrupt(err):
                raise KeyboardInterrupt from None
            msg = one_line_error(err)
            if "non-spectral" in msg:
                msg += f" (variant {mi.variant()}; this scene needs a *_spectral variant)"
            raise CoronaError(f"{desc}: {msg}") from None
        acc = img * s if acc is None else acc + img * s
    seconds = time.perf_counter() - t0
    img = (acc / spp).astype(np.float32)
    if img.ndim == 2:
        img = img[..., None]
    pf = scene.sensors()[0].film().bitmap().pixel_format()
    rgb = np.array(mi.Bitmap(img, pixel_format=pf).convert(
        mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False), dtype=np.float32)
    if not np.all(np.isfinite(rgb)):
        raise CoronaError(f"{desc}: the render produced non-finite pixels")
    return rgb, seconds


def write_images(rgb, out_dir: str, name: str, exposure: float | None = None) -> dict:
    """Write ``name.exr`` (linear sRGB, float32) and ``name.png`` (8-bit sRGB by
    :func:`corona.apps.pictures.display_srgb`) into ``out_dir``, both with ``mi.Bitmap``."""
    import mitsuba as mi

    from corona.apps.pictures import display_srgb
    os.makedirs(out_dir, exist_ok=True)
    exr = os.path.join(out_dir, f"{name}.exr")
    png = os.path.join(out_dir, f"{name}.png")
    rgb_pf = mi.Bitmap.PixelFormat.RGB
    mi.Bitmap(np.ascontiguousarray(rgb, dtype=np.float32), pixel_format=rgb_pf).write(exr)
    # uint8 data: Mitsuba marks the bitmap sRGB-encoded, as the tone map made it
    mi.Bitmap(np.ascontiguousarray(display_srgb(rgb, exposure)), pixel_format=rgb_pf).write(png)
    return {"exr": exr, "png": png}


def render_to_files(scene, out_dir: str, name: str, spp: int, seed: int = 0,
                    progress: bool = True, exposure: float | None = None) -> dict:
    """Render ``scene`` (a loaded ``mi.Scene``) and write ``name.exr`` and ``name.png``.

    The EXR holds linear sRGB (see :func:`render_linear`); the PNG is
    8-bit sRGB (:func:`corona.apps.pictures.display_srgb`: ``exposure`` scales the linear
    values, by default the glow around the lamps maps to 1; highlights roll off to white).
    """
    import mitsuba as mi
    rgb, seconds = render_linear(scene, spp, seed=seed, progress=progress, desc=f"render {name}")
    files = write_images(rgb, out_dir, name, exposure)
    return {**files, "seconds": seconds, "spp": spp, "variant": mi.variant(), "image": rgb}
