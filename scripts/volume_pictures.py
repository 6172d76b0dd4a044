"""The pictures of docs/volumes.md: the rings' contrast against optical depth, and the scenes.

    python scripts/volume_pictures.py series      # docs/volumes_tau_series.png (about a minute)
    corona render scenes/moon_altocumulus.xml --spp 512 -D res=128 --out docs --name volumes_moon
    corona render scenes/streetlight_fog.xml --spp 256 -D res=256 --out docs --name volumes_streetlight
    corona render scenes/streetlight_mist.xml --spp 256 -D res=256 --out docs --name volumes_mist
    python scripts/volume_pictures.py glory       # docs/volumes_glory.png: multiple scattering, truncated peak
"""
from __future__ import annotations

import math
import os
import sys

import corona  # noqa: F401  (before drjit)
import mitsuba as mi
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DOCS = os.path.join(HERE, os.pardir, "docs")


def series(taus=(0.05, 0.3, 1.0, 3.0), radius=5.0, size=128, spp=256, fov=24.0):
    """A slab of 5 µm droplets (gamma, v_eff 0.01) in front of a distant light at each optical
    depth: the panels side by side, each scaled to its own 99.5th percentile; returns the
    ring contrasts (green channel, tests/plugin/test_volume.py's measure)."""
    import imageio.v3 as iio

    from corona.mitsuba import volume
    from corona.mitsuba.phase import channel_response
    from corona.model.mie.volume import MieVolume
    mi.set_variant("llvm_ad_rgb")
    corona.register()
    kw = dict(distribution="gamma", variance=0.01)
    v = MieVolume(radius, **kw)
    T = v.table
    h = 0.01
    panels, contrasts = [], []
    rows = v.rgb_table(*channel_response())
    sys.path.insert(0, os.path.join(HERE, os.pardir, "tests"))
    from test_volume import ring_contrast
    for tau in taus:
        N = tau / (v.cross_sections(550.0)["c_ext"] * h)
        st = N * T["c_ext"]
        med = {"type": "homogeneous", "sigma_t": volume.spectrum_dict(T["wavelength"], st / st.max()),
               "scale": float(st.max()), "albedo": volume.spectrum_dict(T["wavelength"], T["c_sca"] / T["c_ext"]),
               "phase": {"type": "corona_mie", "radius": radius, **kw}}
        img = np.array(mi.render(mi.load_dict(volume.slab_scene(med, thickness=h, fov=fov, size=size,
                                                                   spp=spp, max_depth=64)), seed=1))
        contrasts.append(ring_contrast(img, fov, rows, T["theta"]))
        # a logarithmic tone map (the rings are ~100x dimmer than the aureole): the level of the
        # rings (the median over 3-10 degrees) maps to 0.35, the peak to 1
        c, prof, _ = volume.radial_profile(img.mean(-1), fov, np.radians([3.0, 10.0]))
        k = max(float(prof[0, 0]), 1e-12)
        top = float(np.percentile(img.mean(-1), 99.9))
        disp = np.log1p(np.clip(img, 0, None) / (0.05 * k)) / math.log1p(top / (0.05 * k))
        panels.append((np.clip(disp, 0, 1) * 255).astype(np.uint8))
    gap = np.full((size, 4, 3), 255, np.uint8)
    row = [p for panel in panels for p in (panel, gap)][:-1]
    iio.imwrite(os.path.join(DOCS, "volumes_tau_series.png"), np.concatenate(row, axis=1))
    for tau, c in zip(taus, contrasts):
        print(f"tau = {tau:g}: ring contrast {c:.3f}")
    return contrasts


def glory_scene(truncation=5.0, radius=10.0, variance=0.01, sigma_t=0.05, res=128, spp=512,
                max_depth=64, variant="llvm_ad_rgb"):
    """scenes/glory_cloud_deck.xml as a dict, its medium from corona.mitsuba.volume.homogeneous_medium
    (σ_t = ``sigma_t`` /m at 550 nm, albedo 1) with the forward peak truncated at
    ``truncation`` degrees (0: none): the camera 300 m above a 200 m deck of 10 µm droplets,
    the sun behind it, multiple scattering on."""
    from corona.mitsuba import volume
    from corona.model.mie.volume import MieVolume
    mi.set_variant(variant)
    corona.register()
    v = MieVolume(radius, "gamma", variance)
    N = sigma_t / (v.cross_sections(550.0)["c_ext"] * 1e-12)          # droplets per m³
    med = volume.homogeneous_medium(radius, number_density=N, distribution="gamma",
                                    variance=variance, truncation=truncation)
    T = mi.ScalarTransform4f
    return {"type": "scene",
            "integrator": {"type": "volpath", "max_depth": int(max_depth)},
            "sensor": {"type": "perspective", "fov": 16.0, "fov_axis": "x",
                       "to_world": T().look_at(origin=[0, 0, 300], target=[0, 0, 0], up=[0, 1, 0]),
                       "sampler": {"type": "independent", "sample_count": int(spp)},
                       "film": {"type": "hdrfilm", "width": int(res), "height": int(res),
                                "pixel_format": "rgb", "rfilter": {"type": "box"}}},
            "deck": {"type": "cube", "to_world": T().translate([0, 0, -100]).scale([5000, 5000, 100]),
                     "bsdf": {"type": "null"}, "interior": med},
            "sun": {"type": "directional", "direction": [0, 0, -1],
                    "irradiance": {"type": "rgb", "value": [1.0, 0.97, 0.92]}}}


def glory(truncation=5.0, res=128, spp=1536, out="volumes_glory.png"):
    """docs/volumes_glory.png: the glory above the cloud deck with multiple scattering, the
    droplets' forward peak truncated (docs/volumes.md#forward-peak-truncation); an sRGB PNG
    (exposure: the median pixel at 0.4)."""
    import imageio.v3 as iio
    img = np.array(mi.render(mi.load_dict(glory_scene(truncation, res=res, spp=spp)), seed=1))
    lum = img.mean(-1)
    disp = np.clip(img / (2.5 * np.median(lum)), 0, 1)
    srgb = np.where(disp <= 0.0031308, 12.92 * disp, 1.055 * disp ** (1 / 2.4) - 0.055)
    iio.imwrite(os.path.join(DOCS, out), (srgb * 255 + 0.5).astype(np.uint8))
    print(f"glory (truncation {truncation:g} deg): mean {lum.mean():.4f}, median {np.median(lum):.4f}, "
          f"max {lum.max():.3f}")
    return img


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "series"
    if what == "series":
        series()
    elif what == "glory":
        glory()
