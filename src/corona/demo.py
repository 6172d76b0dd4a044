"""``make demo``: a lobe table, its pictures, and a rendered corona.

Writes into ``out/demo/`` (or the folder given as the first argument).
"""
from __future__ import annotations

import os
import sys

import numpy as np


def main(out_dir: str = "out/demo") -> int:
    import corona
    from .parameters import material_from_parameters
    from .pictures import lobe_figure

    os.makedirs(out_dir, exist_ok=True)
    params = dict(shape="circle", radius=5.0, area_fraction=0.4, process="hard-disk", mode="particle")
    material = material_from_parameters(**params)
    print(f"corona {corona.__version__}: condensation on a window pane")
    print(f"  {material!r}")
    print(f"  coherent transmittance {material.coherent_transmittance:.4f}, "
          f"diffuse (lobe) {material.diffuse_transmittance():.4f} "
          f"(hard disks: F_a(1-F_a) = {material.area_fraction * (1 - material.area_fraction):.4f})")
    print("\n  lobe at 550 nm along the x axis  (f = F_a T_a T_s, no cosine)")
    print(f"  {'angle [deg]':>12} {'u':>8} {'T_a':>12} {'T_s':>8} {'f':>12}")
    R, lam = material.length_scale, 0.55
    for deg in [0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0]:
        dx = np.sin(np.radians(deg))
        u = 2 * np.pi * R * dx / lam
        q = np.array([[u / R, 0.0]])
        ta = material.shape.form_factor(q)[0] / lam**2
        ts = material.process.structure_factor_at(q, material.shape)[0]
        f = material.lobe(np.array([[dx, 0.0]]), 550.0)[0]
        print(f"  {deg:12.1f} {u:8.2f} {ta:12.4g} {ts:8.3f} {f:12.4g}")
    fig = lobe_figure(material, os.path.join(out_dir, "lobe.png"))
    print(f"\n  lobe tables and far-field corona: {fig}")

    from .render import render_to_files, setup_variant
    from .scenes import street_light_scene
    variant = setup_variant()
    import mitsuba as mi
    scene = mi.load_dict(street_light_scene(resolution=256, bsdf={"type": "corona", **params}))
    res = render_to_files(scene, out_dir, "teaser", spp=64)
    print(f"  rendered with {variant} in {res['seconds']:.1f} s: {res['png']} (linear: {res['exr']})")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
