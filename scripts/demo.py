"""``make demo``: a lobe table, its pictures, and a rendered corona.

Writes into ``out/demo/`` (or the folder given as the first argument); from
a source checkout it renders ``scenes/teaser.xml``.  With ``--update-docs``
(``make gallery`` passes it) the picture is also copied to
``docs/images/teaser.png``, the README's; a plain ``make demo`` leaves the
checkout's tracked files alone.
"""
from __future__ import annotations

import os
import shutil
import sys

import numpy as np

from corona import CoronaError


def _repo_file(*parts: str) -> str | None:
    """``parts`` inside the source checkout (scenes/, docs/), or None where missing."""
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))
    path = os.path.join(root, *parts)
    if parts[-1].endswith(".xml"):
        return path if os.path.isfile(path) else None
    if os.path.isdir(os.path.join(root, "scenes")):
        os.makedirs(path, exist_ok=True)
        return path
    return None


def main(out_dir: str = "out/demo", update_docs: bool = False, variant: str | None = None) -> int:
    import corona
    from corona.parameters import material_from_parameters
    from corona.apps.pictures import lobe_figure

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

    from corona.apps.render import load_scene, render_to_files, scene_spp, setup_variant
    variant = setup_variant(variant)
    import mitsuba as mi
    teaser = _repo_file("scenes", "teaser.xml")
    fast = not variant.startswith("scalar")
    if teaser is not None:
        # the scene's own resolution and spp (512², 256 spp) on llvm / cuda; less in scalar (Python per sample)
        scene = load_scene(teaser, {} if fast else {"res": 128, "spp": 16})
        spp = scene_spp(scene)
        what = teaser
    else:  # an installed package without the repository's scenes/
        from corona.apps.scenes import street_light_scene
        scene = mi.load_dict(street_light_scene(resolution=256 if fast else 96, bsdf={"type": "corona", **params}))
        spp, what = (64 if fast else 8), "the built-in street-light scene"
    print(f"\n  rendering {what} with {variant} ({spp} spp)...")
    res = render_to_files(scene, out_dir, "teaser", spp=spp)
    print(f"  rendered in {res['seconds']:.1f} s")
    docs = _repo_file("docs", "images") if update_docs else None
    if docs is not None and teaser is not None and fast:
        shutil.copyfile(res["png"], os.path.join(docs, "teaser.png"))
        print(f"  copied to {os.path.join(docs, 'teaser.png')} (the README's picture)")
    print(f"\n  the teaser image: {os.path.abspath(res['png'])}")
    print(f"  linear sRGB EXR:  {os.path.abspath(res['exr'])}")
    print(f"  lobe pictures:    {os.path.abspath(fig)}")
    return 0


if __name__ == "__main__":
    args = sys.argv[1:]
    flag = "--update-docs" in args
    args = [a for a in args if a != "--update-docs"]
    chosen = None
    if "--variant" in args:   # make gallery VARIANT=llvm_ad_rgb passes it on
        i = args.index("--variant")
        if i + 1 >= len(args):
            print("scripts/demo.py: --variant needs a value (e.g. llvm_ad_rgb)", file=sys.stderr)
            sys.exit(2)
        chosen = args[i + 1]
        del args[i:i + 2]
    try:
        sys.exit(main(*args, update_docs=flag, variant=chosen))
    except CoronaError as err:
        print(f"scripts/demo.py: {err}", file=sys.stderr)
        sys.exit(2)
