"""corona in five steps: a material from scratch, its lobe, a render, a fit, a gradient.

    python examples/tutorial.py [OUT_FOLDER]          (about a minute on 2 CPU cores)

The script the documentation's tutorial page walks through (docs/tutorial.md);
the tests run it (tests/package/test_docs.py).  Lengths are in µm, wavelengths in nm,
angles in degrees unless a name says otherwise.
"""
import os
import sys
import time

import numpy as np

import corona                   # first: it points Dr.Jit at a usable libLLVM

OUT = sys.argv[1] if len(sys.argv) > 1 else "out/tutorial"
os.makedirs(OUT, exist_ok=True)
t_start = time.perf_counter()

# --- 1. a material from scratch -----------------------------------------------------
# Water droplets of radius 4 µm covering 35 % of a window pane, their centres a
# hard-disk fluid (droplets do not overlap).  Particle mode: opaque blockers in a
# clear layer (Babinet: the same lobe as holes in an opaque screen).
material = corona.Material(corona.Circle(radius=4.0), corona.HardDisk(area_fraction=0.35),
                           mode="particle")
print(f"1. {material!r}")
print(f"   coherent transmittance T_c = (1 - F_a)^2 = {material.coherent_transmittance:.4f}")
print(f"   diffuse transmittance (the lobe's energy) = {material.diffuse_transmittance():.4f}")

# --- 2. its lobe ------------------------------------------------------------------------
# lobe(d) = F_a T_a(d) T_s(d) per unit d²d, d = (wo + wi).xy the change of the
# direction cosines.  One droplet alone gives the Airy pattern, brightest at d = 0
# with its first dark ring at u = 2πR|d|/λ = 3.8317; the hard disks' structure factor
# (S(0) < 1: they fill the pane more evenly than chance) dims the centre and makes
# a bright ring of the corona.
d = np.linspace(0.0, 0.2, 2001)
offsets = np.stack([d, 0 * d], -1)
for lam in (450.0, 550.0, 650.0):
    lobe = material.lobe(offsets, lam)
    airy = 3.8317 * lam * 1e-3 / (2 * np.pi * 4.0)
    print(f"2. λ = {lam:.0f} nm: lobe(0) = {lobe[0]:.2f}, brightest at |d| = {d[np.argmax(lobe)]:.4f} "
          f"(lobe {lobe.max():.2f}); one droplet's first dark ring at |d| = {airy:.4f}")

# --- 3. a render ---------------------------------------------------------------------------
# A distant 3000 K lamp seen through the layer right in front of a pinhole camera
# (corona.apps.scenes.lamp_photograph_scene), in the default spectral variant.
import mitsuba as mi                                           # noqa: E402
corona.set_default_variant()                                   # cuda > llvm > scalar, spectral
corona.register()
from corona.apps.scenes import lamp_photograph_scene                # noqa: E402

FOV, RES, SPP = 20.0, 96, 64
layer = {"type": "corona", "radius": 4.0, "area_fraction": 0.35, "process": "hard-disk", "mode": "particle"}
scene = mi.load_dict(lamp_photograph_scene(RES, layer, fov=FOV, source_radius_deg=0.1))
image = np.array(mi.render(scene, spp=SPP, seed=0))
mi.Bitmap(image.astype(np.float32)).write(os.path.join(OUT, "render.exr"))
mi.util.write_bitmap(os.path.join(OUT, "render.png"), np.clip(image / np.percentile(image, 99.5), 0, 1))
print(f"3. rendered {RES}x{RES} at {SPP} spp with {mi.variant()}: {OUT}/render.exr")

# --- 4. a fit ----------------------------------------------------------------------------------
# Back from the picture to the layer: corona.fit_photograph fits the radius, the
# size spread, the area fraction and the lamp's temperature to the rings.
fit = corona.fit_photograph(os.path.join(OUT, "render.exr"), FOV, source_diameter_deg=0.2)
print(f"4. fitted radius {fit.radius:.3f} µm (rendered with 4.000), "
      f"area fraction {fit.area_fraction:.3f} (0.350)")

# --- 5. a gradient -----------------------------------------------------------------------------
# Inverse rendering: the derivative of an image loss with respect to the droplet
# radius, by Mitsuba's prb integrator (reverse mode).  Start 10 % too large: the
# gradient says to shrink the droplets.
import drjit as dr                                               # noqa: E402
spec = lamp_photograph_scene(RES, {**layer, "radius": 4.4}, fov=FOV, source_radius_deg=0.1)
spec["integrator"] = {"type": "prb", "max_depth": 3}
ad_scene = mi.load_dict(spec)
params = mi.traverse(ad_scene)
key = "pane.bsdf.radius.value"                                   # mi.traverse's name of the radius
target = mi.TensorXf(image.astype(np.float32))
dr.enable_grad(params[key])
params.update()
rendered = mi.render(ad_scene, params, spp=SPP, seed=1, seed_grad=2)
loss = dr.mean(dr.square(rendered - target), axis=None)
dr.backward(loss)
gradient = float(dr.grad(params[key]).array[0])
print(f"5. d loss / d radius at 4.4 µm = {gradient:.3e} per µm ({'shrink' if gradient > 0 else 'grow'} "
      "the droplets)")

# --- and the same layer as a pass over any image ---------------------------------------------------
# corona.apps.post puts the layer in front of the camera of an image that was rendered
# (or photographed) without it: the render of the bare lamp, passed through the
# layer, against the render through the pane above.
bare = lamp_photograph_scene(RES, layer, fov=FOV, source_radius_deg=0.1)
del bare["pane"]
plain = np.array(mi.render(mi.load_dict(bare), spp=4 * SPP, seed=3))
import corona.apps.post                                                # noqa: E402
through = corona.apps.post.apply(plain, FOV, radius=4.0, area_fraction=0.35, mode="particle", progress=False)
off = plain.sum(-1) == 0
ratio = through[off].sum() / image[off].sum()
print(f"+. corona.apps.post of the bare lamp: the corona's energy is {ratio:.3f} x the render's")
print(f"done in {time.perf_counter() - t_start:.0f} s")
