"""``make gallery``: render every scene of ``scenes/`` into figure strips.

Each :class:`Strip` is one figure of the reference talk (docs/gallery.md): one or
more renders of a scene with different ``-D`` parameters, tiled side by side
with a label under each.  The strips go to ``docs/gallery/``, the linear EXRs
and single PNGs to ``out/gallery/``, and ``docs/gallery.md`` is rewritten
with every picture and the exact ``corona`` command behind each panel.

    python scripts/gallery.py [--only NAME ...] [--variant V] [--workers N | --scheduler ADDRESS]
                                                                    (make gallery)

The panels are the points of one sweep (:mod:`corona.apps.sweep`): they render on
a local Dask cluster sized to the machine (``--workers 0``: in this process,
``--scheduler``: on an existing cluster), and the strips are assembled here.
"""
from __future__ import annotations

import collections
import dataclasses
import os
import shlex
import sys
import time

import numpy as np

from corona._validation import CoronaError


@dataclasses.dataclass
class Panel:
    label: str
    defines: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class Strip:
    name: str            # file stem in docs/gallery/
    title: str
    scene: str | None    # file in scenes/ (None: a `corona lobe` picture)
    text: str
    panels: list = dataclasses.field(default_factory=list)
    shared_exposure: int | None = None   # index of the panel whose auto exposure all panels use
    lobe_args: list = dataclasses.field(default_factory=list)
    extra: object = None      # f(list of linear images) -> (image, label): one more panel (not a render)
    annotate: object = None   # f(list of linear images) -> list of label suffixes (measured numbers)


def _rmse_against_last(rgbs):
    """Relative RMS error of each panel's luminance against the last panel (the reference)."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    ref = rgbs[-1] @ lum
    out = [f": rel. RMSE {np.sqrt(np.mean((im @ lum - ref) ** 2)) / np.mean(ref):.2f}" for im in rgbs[:-1]]
    return out + [""]


def _babinet_difference(rgbs):
    """particle − aperture: the halos cancel, the lamp's coherent part remains."""
    ap, pa = rgbs
    lum = np.array([0.2126, 0.7152, 0.0722])
    la, lp = ap @ lum, pa @ lum
    lamp = lp >= 0.5 * lp.max()
    ratio = float(np.mean(lp[lamp]) / max(np.mean(la[lamp]), 1e-30))
    return pa - ap, f"particle − aperture (lamp ×{ratio:.2f})"


STRIPS = [
    Strip("teaser", "Teaser: street lights through a fogged window", "teaser.xml",
          "Three lamps (3000 K, 2400 K, 5000 K) seen at night through a window pane with condensation: "
          "water droplets of radius 5 µm on 40 % of the glass, hard-disk positions, particle mode. "
          "Every lamp wears the same rings: their size depends on the droplets, not on the lamp. "
          "`make demo` renders it at 512², 256 spp for the README.",
          [Panel("condensation, R = 5 µm, F_a = 0.4", {"res": 256, "spp": 64})]),
    Strip("window_at_night", "A window at night: the layer on glass", "window_at_night.xml",
          "A room lamp behind the camera, mirrored in a fogged window pane (corona BSDF with "
          "substrate=glass, index 1.52), and three street lights behind the pane; droplets of radius 6 µm "
          "on 35 % of the glass, hard disks, particle mode. Left: droplets on the room side, so the lamp's "
          "light crosses them on its way to the glass and back: its mirror image (C R + C² (R' − R) = 2.5 % of "
          "the lamp: the room-side face returns the light through the droplets once, the far face's light "
          "crosses them twice) wears the same corona as the street lights. Middle: droplets outside, so the glass "
          "mirrors the lamp before any droplet: a sharp image of R' = 8 %. Right: the droplets without "
          "the glass (substrate=none): no reflection. Same exposure.",
          [Panel("droplets on the room side", {}),
           Panel("droplets outside", {"substrate_side": "front"}),
           Panel("no glass", {"substrate": "none"})],
          shared_exposure=0),
    Strip("dusty_mirror", "A dusty mirror and a torch: Quetelet rings", "dusty_mirror.xml",
          "A torch (4000 K, radius 4 mm) 3 cm beside the camera, a dusty mirror 1 m away (substrate=mirror: "
          "glass of index 1.52, 4 mm thick, silvered behind; grains of radius 10 µm on 5 % of the glass, hard "
          "disks, particle mode). The torch's mirror image (C R + C² (R' − R) = 0.79 of the torch) wears the dust's corona, "
          "and across it run Stokes' fringes: each grain scatters the light on its way to the silvering and on "
          "its way out, the two paths differing by 2 n t (cos r_s - cos r_o). Their zero order (θo = θs) "
          "passes through the torch's image. Left: the torch at the camera's distance from the mirror, the "
          "fringes are straight bands midway between the torch's image and the camera's own; middle: the "
          "torch at half that distance (seen directly on the right); right: at twice it, the bands curve "
          "into Quetelet rings. They wash out after a few orders in the torch's white light. Same exposure.",
          [Panel("torch beside the camera", {}),
           Panel("torch at half the distance", {"torch_z": 0.5}),
           Panel("torch at twice the distance", {"torch_z": -1})],
          shared_exposure=0),
    Strip("fogged_window", "A fogged window at night: Quetelet rings of a thick pane", "fogged_window.xml",
          "A small room lamp (2700 K, radius 5 mm) behind the camera, mirrored in a fogged window pane 0.6 m "
          "away (substrate=glass, index 1.52, with its thickness: substrate_thickness; droplets of radius 6 µm "
          "on 35 % of the glass, hard disks, particle mode, on the room side). The lamp's mirror image wears "
          "the droplets' corona, and across it run faint coloured Quetelet rings: each droplet scatters the "
          "light on its way to the back face and again after the back face's reflection, the two paths "
          "differing by 2 n t (cos r_s - cos r_o). The bare back face reflects 4 %: the rings modulate the "
          "reflected corona by about ±40 %. Left: a 2 mm pane; middle: 4 mm; right: 6 mm, the rings closer "
          "(bright order m where sin²θo = sin²θs + m n λ / t). The lamp's light crosses the droplets once where "
          "the near face reflects it (the sharp image) and twice where the far face does. Same exposure.",
          [Panel("2 mm pane", {"thickness": 2000}),
           Panel("4 mm pane", {}),
           Panel("6 mm pane", {"thickness": 6000})],
          shared_exposure=1),
    Strip("breath_figure_strip", "A breath on a cold pane: the breath figure's corona over time",
          "breath_figure.xml",
          "A street light (2100 K) 25 m behind a pane breathed on from the camera's side "
          "(process=breath-figure: droplets nucleate, grow, touch and merge, and new ones nucleate in the "
          "gaps; docs/physics.md#breath-figures-processbreath-figure). From left to right 5, 10, 20, 40 and "
          "80 s after the breath: the droplets grow (area-weighted mean contact radius 1.8 to 17 µm) and the "
          "ring around the lamp, the peak of the light that droplets keeping dry zones around them scatter, "
          "shrinks as 1/R. Same exposure (the 10 s panel's). Above the strip: the size distribution, the structure "
          "factor of the droplets' centres and the layer's diffuse intensity at 550 nm at the same times, "
          "from the table the layer uses (`python scripts/breath_strip.py` makes both).\n\n"
          "![Breath figure statistics](gallery/breath_figure_stats.png)",
          [Panel(f"{t:g} s", {"breath_time": t, "res": 160, "spp": 32}) for t in (5.0, 10.0, 20.0, 40.0, 80.0)],
          shared_exposure=1),
    Strip("breath_figure_drying", "The breath evaporates: the breath figure's corona fading",
          "breath_figure.xml",
          "The pane of the strip above, breathed on for 20 s, then drying (dry_time since the vapour "
          "stopped; water leaves at 0.1 µm/s, the small droplets vanish first; "
          "docs/physics.md#breath-figures-processbreath-figure): 0, 4, 8, 12 and 16 s after the breath "
          "(90 % of the water is gone at 18 s). The droplets shrink (R from 4.9 to 3.7 µm) and cover less of "
          "the glass (0.62 to 0.17), but stay where they are: the ring, set by their spacing, stays (it moves "
          "in a little as the small droplets vanish, as in the exact far field), the small droplets' wide "
          "glow goes first, and the ring brightens a little, then fades. Same exposure (the first panel's). "
          "Below, as an animation in 2 s steps (`python scripts/breath_strip.py --drying-gif`), and the "
          "size distribution, structure factor and diffuse intensity at the same dry times (`python "
          "scripts/breath_strip.py --stats-only`): the small droplets go first, so the centres left are "
          "more ordered (S(q) at small q falls from 0.9 to 0.2).\n\n"
          "![The breath figure drying, animated](gallery/breath_figure_drying.gif)\n\n"
          "![Breath figure statistics while drying](gallery/breath_figure_drying_stats.png)",
          [Panel(f"dry {t:g} s", {"breath_time": 20.0, "dry_time": t, "res": 160, "spp": 32})
           for t in (0.0, 4.0, 8.0, 12.0, 16.0)],
          shared_exposure=0),
    Strip("fogged_pane_drying", "A fogged pane clearing from its edges: dry time from a bitmap",
          "fogged_pane_drying.xml",
          "A street light (2100 K) behind a pane fogged for 20 s and drying from its frame inwards: the time "
          "since the vapour stopped is a texture (scenes/textures/fogged_pane_dry.exr), 0 s in the middle "
          "rising to 16 s at the frame. The halo's outer parts are seen through the drying glass, where the "
          "droplets are smaller and sparser: the corona fades outwards.",
          [Panel("dry 0–16 s (bitmap)", {"res": 192, "spp": 32})]),
    Strip("wiped_window_refog", "A wiped window fogging up again: breath time from a bitmap",
          "wiped_window_refog.xml",
          "The street lights of the wiped window behind a breath figure whose age is a texture "
          "(scenes/textures/wiped_refog_age.exr): 40 s old over the pane (R = 8.9 µm), 5 s old in the "
          "streak wiped across it (R = 1.8 µm), which is fogging up again. The lamps behind the old fog wear "
          "a small, tight ring; the two in the streak a broad, faint glow five times wider.",
          [Panel("5 s streak, 40 s fog", {"res": 192, "spp": 32})]),
    Strip("teaser_spheres", "Teaser with transparent droplets (Mie spheres)", "teaser.xml",
          "The teaser's condensation (radius 5 µm, 40 % cover, hard disks) modelled two ways: left, opaque "
          "disks (Fraunhofer diffraction); right, transparent water spheres (Mie theory, water's "
          "dispersion, shape=sphere). The spheres' first dark ring sits about 8 % closer to the lamp and "
          "the first bright ring is brighter relative to the aureole; the light they refract away "
          "from the lamp adds a faint wide halo. Same exposure.",
          [Panel("opaque disks", {"res": 256, "spp": 64}),
           Panel("water spheres (Mie)", {"res": 256, "spp": 64, "shape": "sphere"})], shared_exposure=0),
    Strip("lunar_corona", "Lunar corona through a thin cloud", "lunar_corona.xml",
          "The full moon (4100 K, 0.52° across) through a thin cloud of water droplets of radius 5 µm "
          "on 10 % of the layer, Poisson positions, under a dark night sky. Left: the droplets as Mie "
          "spheres (shape=sphere); right: the same cloud as opaque disks. Same exposure.",
          [Panel("water droplets (Mie)", {}), Panel("opaque disks", {"shape": "circle"})],
          shared_exposure=0),
    Strip("glory_fogbow", "Glory and fogbow in light reflected from fog", "glory_fogbow.xml",
          "The sun behind the camera lights a fog bank of water droplets (radius 8 µm, 40 % cover, "
          "Poisson); the camera sees their backward lobe. Left (100° field of view): the white fogbow "
          "about 40° from the antisolar point, with a supernumerary inside, and the glory at the centre. "
          "Right (12°): the glory's coloured rings around the camera's shadow.",
          [Panel("fogbow, 100° field", {}), Panel("glory, 12° field", {"fov": 12})]),
    Strip("wiped_window", "A wiped window: area fraction from a bitmap", "wiped_window.xml",
          "Five identical street lights (2700 K) behind a fogged pane whose area fraction is a texture "
          "(scenes/textures/wiped_fog.png): droplets of radius 6 µm, hard disks, F_a = 0.22 in the middle "
          "rising to 0.55 at the frame, and a streak wiped clean (F_a = 0.015) from the lower left to the "
          "upper right. Each lamp's corona follows the glass it is seen through: the two lamps in the "
          "streak are sharp with a faint aureole and wear their rings only where these reach the fog "
          "beside it; the lamps near the corners drown in their corona.",
          [Panel("F_a from a bitmap, R = 6 µm", {})]),
    Strip("condensation_gradient", "Condensation gradient: droplet radius from a bitmap",
          "condensation_gradient.xml",
          "Four identical 3000 K street lights behind a pane whose droplets grow from 3 µm at the left "
          "edge to 12 µm at the right (radius texture scenes/textures/condensation_radius.exr; F_a = 0.35, "
          "hard disks). The radius scales the whole layer, so the lobe stays exact: the rings shrink as "
          "1/R across the pane, first dark ring at about 4.7°, 3.1°, 2.3° and 1.8°.",
          [Panel("R = 3 → 12 µm, left to right", {})]),
    Strip("lobe_tables", "Single-aperture table and structure-factor table", None,
          "`corona lobe` for the teaser's droplets: the form-factor table T_a, the hard-disk "
          "structure-factor table T_s, their product (the lobe), and the far-field corona as seen "
          "around a 3000 K point light.", [],
          lobe_args=["--radius", "5", "--area-fraction", "0.4", "--process", "hard-disk", "--mode", "particle"]),
    Strip("lobe_tables_fabric", "Tables of the fabric: square pores on a jittered square lattice", None,
          "`corona lobe` for the fabric scene's material: the square pore's cross-shaped form factor, "
          "the lattice's Bragg peaks (weakened by the jitter), their product and the corona.", [],
          lobe_args=["--shape", "square", "--radius", "20", "--area-fraction", "0.25",
                     "--process", "lattice-square", "--jitter", "4", "--mode", "aperture"]),
    Strip("lycopodium", "Lycopodium powder on a slide, 10× and 40×", "lycopodium.xml",
          "Spores of 30 µm diameter (5 % size spread) on 35 % of a glass slide, random sequential "
          "adsorption, particle mode, in front of a point-like 3200 K lamp. Magnification narrows the "
          "field of view of the same set-up: 16° across at 10×, 4° at 40×.",
          [Panel("10×: 16° field of view", {"fov": 16}), Panel("40×: 4° field of view", {"fov": 4})]),
    Strip("fabric", "A fabric held against a light", "fabric.xml",
          "A voile curtain: square pores 40 µm wide on a square lattice of pitch 80 µm (25 % open), "
          "each pore displaced by 4 µm rms. The lattice turns the corona into spots; orders ±2 vanish "
          "because the pore is half the pitch. Right: a perfect weave turned by 20°.",
          [Panel("jitter 4 µm", {}), Panel("jitter 0, weave turned 20°", {"jitter": 0, "angle": 20})]),
    Strip("sweep_radius", "Sweep: aperture radius", "sweep_radius.xml",
          "Circular holes in a foil, F_a = 0.3, hard disks: the corona scales as 1/R "
          "(each panel exposed on its own).",
          [Panel(f"R = {r} µm", {"radius": r}) for r in (2.5, 5, 10)]),
    Strip("sweep_area_fraction", "Sweep: area fraction", "sweep_area_fraction.xml",
          "Holes of radius 5 µm, hard disks: denser holes are more ordered, S(q) < 1 dims the aureole "
          "relative to the rings (each panel exposed on its own).",
          [Panel(f"F_a = {f}", {"area_fraction": f}) for f in (0.1, 0.3, 0.5)]),
    Strip("sweep_incidence", "Sweep: incident angle (elevation 90°, 60°, 30°)", "sweep_incidence.xml",
          "The layer turns about the vertical axis; the light arrives at 90° (normal), 60° and 30° above "
          "its plane. The lobe lives in d = (wo + wi).xy, so the corona stretches along the tilt.",
          [Panel(f"elevation {e}°", {"elevation": e}) for e in (90, 60, 30)]),
    Strip("circle_vs_square", "Circle vs square apertures", "circle_vs_square.xml",
          "Holes of the same area (circle R = 5 µm, square of side 8.86 µm), F_a = 0.3, hard disks: "
          "Airy rings against a sinc² cross.",
          [Panel("circle", {"shape": "circle", "radius": 5.0}),
           Panel("square", {"shape": "square", "radius": 4.43})]),
    Strip("babinet", "Particle vs aperture at f = 0.3, r = 0.5 µm (Babinet)", "babinet.xml",
          "The same halo around the lamp (the lobe is identical), but the lamp itself is brighter "
          "through the particles: coherent (1 − F_a)² = 0.49 against F_a² = 0.09, 5.4×. Same exposure "
          "(set by the halo, so the lamp saturates); the right panel is the difference of the two "
          "linear images, where the halos cancel and only the lamp remains, with the lamp's measured "
          "brightness ratio in its label.",
          [Panel("aperture (holes)", {"mode": "aperture"}), Panel("particle (discs)", {"mode": "particle"})],
          shared_exposure=0, extra=_babinet_difference),
    Strip("monochromatic", "F_a = 0.3 at 400 nm vs F_a = 0.5 at 600 nm", "monochromatic.xml",
          "Holes of radius 5 µm, hard disks, lit by narrow-band (10 nm) lamps: the rings are sharp, "
          "1.5× wider at 600 nm, and the denser layer's aureole is weaker (each panel exposed on its own).",
          [Panel("F_a = 0.3, 400 nm", {"area_fraction": 0.3, "lambda_min": 395, "lambda_max": 405,
                                        "spp": 256}),
           Panel("F_a = 0.5, 600 nm", {"area_fraction": 0.5, "lambda_min": 595, "lambda_max": 605,
                                        "spp": 256})]),
    Strip("mixed", "Mixed aperture types", "mixed.xml",
          "Circular and square holes of equal area on one set of hard-disk positions, F_a = 0.3 in "
          "all (the corona BSDF's shape=mixture, decoupling approximation): number fractions of "
          "square holes 0, ½ and 1.",
          [Panel(f"{label}", {"circles": c, "squares": q}) for label, c, q in
           (("circles", 1, 0), ("half circles, half squares", 0.5, 0.5), ("squares", 0, 1))]),
    Strip("sampling", "MIS(cosine, light) vs MIS(T_a × T_s, light)", "sampling.xml",
          "Droplets of radius 20 µm (a narrow lobe) in front of a large lamp (4.8° radius), both "
          "strategies combined with light sampling by multiple importance sampling, at 16 spp each; "
          "right: a 512 spp reference. Same exposure. The labels give each 16 spp image's relative "
          "RMS error (luminance) against the reference.",
          [Panel("cosine, 16 spp", {"sampling": "cosine", "spp": 16}),
           Panel("T_a × T_s, 16 spp", {"sampling": "lobe", "spp": 16}),
           Panel("reference: T_a × T_s, 512 spp", {"sampling": "lobe", "spp": 512})],
          shared_exposure=2, annotate=_rmse_against_last),
]


def repo_root() -> str:
    return os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def render_command(strip: Strip, index: int, exposure: float | None) -> str:
    panel = strip.panels[index]
    args = ["corona", "render", f"scenes/{strip.scene}"]
    for k, v in panel.defines.items():
        args += ["-D", f"{k}={_fmt(v)}"]
    args += ["--out", "out/gallery", "--name", _panel_name(strip, index)]
    if exposure is not None:
        args += ["--exposure", f"{exposure:.4g}"]
    return shlex.join(args)


def _panel_name(strip: Strip, index: int) -> str:
    return strip.name if len(strip.panels) == 1 else f"{strip.name}-{index + 1}"


def _auto_exposure(rgb) -> float:
    """The panel's automatic exposure (corona render's: the glow around the lamps to 1), to the
    4 digits its command line shows."""
    from corona.apps.pictures import display_exposure
    return float(f"{display_exposure(rgb):.4g}")


def _font(size: int):
    """DejaVu Sans (shipped with matplotlib: has µ, ×, °), else Pillow's default."""
    from PIL import ImageFont
    try:
        from matplotlib import font_manager
        return ImageFont.truetype(font_manager.findfont("DejaVu Sans"), size)
    except Exception:
        try:
            return ImageFont.load_default(size=size)
        except TypeError:  # Pillow < 10.1
            return ImageFont.load_default()


def tile(images: list, labels: list, gap: int = 4, band: int = 26):
    """Side-by-side 8-bit images with a label under each (a PIL image)."""
    from PIL import Image, ImageDraw
    h = max(im.shape[0] for im in images)
    w = sum(im.shape[1] for im in images) + gap * (len(images) - 1)
    canvas = Image.new("RGB", (w, h + band), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    font = _font(15)
    x = 0
    for im, label in zip(images, labels):
        canvas.paste(Image.fromarray(im), (x, 0))
        tw = draw.textlength(label, font=font)
        draw.text((x + (im.shape[1] - tw) / 2, h + 4), label, fill=(0, 0, 0), font=font)
        x += im.shape[1] + gap
    return canvas


def build(only=None, variant: str | None = None, out_dir: str | None = None,
          md_path: str | None = None, progress: bool = True, log=print, executor=None) -> dict:
    """Render the strips (all, or the names in ``only``) and rewrite the gallery page.

    Every panel of every strip is one point of a sweep: they all go to
    ``executor`` (a :class:`corona._executor.Executor`: a local Dask cluster, an
    existing one, or this process) at once; then each strip is exposed,
    annotated and tiled here.  Returns ``{"seconds": total, "strips": {name:
    seconds}, "failed": {name: message}}`` (a strip's seconds: the render time
    of its panels plus its tiling).
    """
    from corona.apps.pictures import display_srgb
    from corona.apps.render import setup_variant, write_images
    from corona._executor import Executor
    from corona.apps.sweep import RenderJob, render_jobs
    root = repo_root()
    scenes_dir = os.path.join(root, "scenes")
    if not os.path.isdir(scenes_dir):
        raise CoronaError(f"no scenes/ folder next to the package ({scenes_dir}); "
                          "the gallery needs a source checkout")
    out_dir = out_dir or os.path.join(root, "docs", "gallery")
    md_path = md_path or os.path.join(root, "docs", "gallery.md")
    raw_dir = os.path.join(root, "out", "gallery")
    os.makedirs(out_dir, exist_ok=True)
    names = [s.name for s in STRIPS]
    if only:
        bad = sorted(set(only) - set(names))
        if bad:
            raise CoronaError(f"unknown gallery strip(s) {', '.join(bad)}; known: {', '.join(names)}")
    v = setup_variant(variant)
    log(f"corona gallery: variant {v}, strips into {out_dir}")
    t_all = time.perf_counter()
    timing, failed, commands = {}, {}, {}
    strips = [s for s in STRIPS if not only or s.name in only]
    # every panel of every scene strip: one render job (the scene's own spp, seed 0)
    jobs, where = [], []
    for strip in strips:
        for i, panel in enumerate(strip.panels if strip.scene else []):
            jobs.append(RenderJob(os.path.join(scenes_dir, strip.scene), panel.defines,
                                  f"{strip.name} {i + 1}/{len(strip.panels)}", variant=v))
            where.append((strip.name, i))
    own = executor is None
    executor = executor or Executor()
    try:
        outcomes = render_jobs(jobs, executor, desc="gallery panels", progress=progress)
        log(f"corona gallery: {len(jobs)} panels rendered, {executor.describe()}")
    finally:
        if own:
            executor.close()
    panels = collections.defaultdict(dict)
    for (name, i), o in zip(where, outcomes):
        panels[name][i] = o
    for strip in strips:
        t0 = time.perf_counter()
        png = os.path.join(out_dir, f"{strip.name}.png")
        try:
            if strip.scene is None:
                from corona.apps.cli import main as cli_main
                args = ["lobe", *strip.lobe_args, "--out", png]
                try:
                    cli_main.main(args=args, prog_name="corona", standalone_mode=False)
                except Exception as err:
                    raise CoronaError(str(err)) from None
                commands[strip.name] = [shlex.join(["corona", *args[:-1], os.path.relpath(png, root)])]
            else:
                res = [panels[strip.name][i] for i in range(len(strip.panels))]
                bad = [o for o in res if not o.ok]
                if bad:
                    raise CoronaError(f"panel {bad[0].label}: {bad[0].error}")
                rgbs = [o.value["rgb"] for o in res]
                t0 -= sum(o.value["seconds"] for o in res)
                exposures = [None] * len(rgbs)
                if strip.shared_exposure is not None:
                    exposures = [_auto_exposure(rgbs[strip.shared_exposure])] * len(rgbs)
                images, labels = [], [p.label for p in strip.panels]
                if strip.annotate is not None:
                    labels = [a + b for a, b in zip(labels, strip.annotate(rgbs))]
                for i, rgb in enumerate(rgbs):
                    write_images(rgb, raw_dir, _panel_name(strip, i), exposures[i])
                    images.append(display_srgb(rgb, exposures[i]))
                if strip.extra is not None:
                    rgb, label = strip.extra(rgbs)
                    images.append(display_srgb(rgb, exposures[0]))
                    labels.append(label)
                tile(images, labels).save(png, optimize=True)
                commands[strip.name] = [render_command(strip, i, exposures[i]) for i in range(len(rgbs))]
        except CoronaError as err:
            failed[strip.name] = str(err)
            log(f"  {strip.name}: FAILED: {err}")
            continue
        timing[strip.name] = time.perf_counter() - t0
        log(f"  {strip.name}: {timing[strip.name]:.1f} s -> {os.path.relpath(png, root)}")
    total = time.perf_counter() - t_all
    # commands of strips not rendered this time (--only) come from the previous run
    import json
    record = os.path.join(out_dir, "commands.json")
    try:
        with open(record, encoding="utf-8") as f:
            commands = {**json.load(f), **commands}
    except (OSError, ValueError):
        pass
    commands = {k: v for k, v in commands.items() if k in names and k not in failed}
    with open(record, "w", encoding="utf-8") as f:
        json.dump(commands, f, indent=1, ensure_ascii=False)
    write_markdown(md_path, out_dir, commands, failed, v)
    log(f"corona gallery: {total:.1f} s in all; page {os.path.relpath(md_path, root)}")
    return {"seconds": total, "strips": timing, "failed": failed}


def write_markdown(md_path: str, out_dir: str, commands: dict, failed: dict, variant: str) -> None:
    """Rewrite the gallery page: every strip whose picture exists, with its commands."""
    rel = os.path.relpath(out_dir, os.path.dirname(md_path))
    lines = ["# Gallery", "",
             "Every scene of `scenes/` as a figure of the reference talk (docs/gallery.md), "
             "rendered at modest resolution and sample count by `make gallery` "
             f"(variant `{variant}`). Each panel comes from the command under it; the EXRs land in "
             "`out/gallery/`. Scene units are metres, the corona BSDF's lengths micrometres; each "
             "scene's comment states its dimensions.", ""]
    for strip in STRIPS:
        png = os.path.join(out_dir, f"{strip.name}.png")
        if not os.path.isfile(png) and strip.name not in failed:
            continue
        lines += [f"## {strip.title}", "", strip.text, ""]
        if strip.name in failed:
            lines += [f"*Not rendered: {failed[strip.name]}*", ""]
            continue
        lines += [f"![{strip.title}]({rel}/{strip.name}.png)", ""]
        cmds = commands.get(strip.name) or _default_commands(strip)
        lines += ["```sh", *cmds, "```", ""]
    os.makedirs(os.path.dirname(md_path) or ".", exist_ok=True)
    with open(md_path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines))


def _default_commands(strip: Strip) -> list:
    if strip.scene is None:
        return [shlex.join(["corona", "lobe", *strip.lobe_args, "--out", f"docs/gallery/{strip.name}.png"])]
    return [render_command(strip, i, None) for i in range(len(strip.panels))]


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="python scripts/gallery.py", description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, help="strip names")
    ap.add_argument("--variant", default=None)
    ap.add_argument("--workers", type=int, default=None,
                    help="local Dask cluster size (default: sized to the machine); 0: in this process")
    ap.add_argument("--scheduler", default=None, help="an existing Dask scheduler (tcp://host:8786)")
    a = ap.parse_args(argv)
    from corona._executor import Executor
    try:
        with Executor(a.workers, a.scheduler, log=print) as ex:
            res = build(only=a.only, variant=a.variant, executor=ex)
    except CoronaError as err:
        print(f"gallery: error: {err}", file=sys.stderr)
        return 2
    return 1 if res["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
