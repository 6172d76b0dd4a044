"""The breath figure over time: a gallery strip of ``scenes/breath_figure.xml`` and its statistics.

    python scripts/breath_strip.py [--stats-only] [--drying-gif] [--variant V]

writes

* ``docs/gallery/breath_figure_strip.png``: the scene at breath times of 5, 10, 20, 40 and 80 s
  (160², 32 spp each, one exposure for all: that of the 10 s panel), through the gallery's
  strip ``breath_figure_strip`` (scripts/gallery.py; ``docs/gallery.md`` is rewritten with its
  commands, as ``python scripts/gallery.py --only breath_figure_strip`` does);
* ``docs/gallery/breath_figure_stats.png``: at the same times, from the shipped table that the
  layer uses (``corona.model.processes.breath_figure``): the droplets' size distribution, the
  structure factor S(q) of their centres, and the diffuse intensity of the layer per area
  against the scattering angle at 550 nm (the lobe the renders sample);
* ``docs/gallery/breath_figure_drying_stats.png``: the same panels for the fading phase, a pane
  breathed on for 20 s and then drying for 0 to 16 s (the size distribution as the number per area of droplets at least a in
  contact radius, from the process's size classes).

With ``--drying-gif`` instead: ``docs/gallery/breath_figure_drying.gif``, the same pane breathed on for
20 s and then drying (``dry_time`` 0 to 16 s in 2 s steps: the fading phase), 128², 16 spp a frame,
one exposure for all (the first frame's), as an animated GIF (Pillow), each frame labelled with its
dry time (about 10 s of CPU).

Cost: about 15 s of CPU for the five renders at 160², a second for the plot.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

TIMES = (5.0, 10.0, 20.0, 40.0, 80.0)
ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))


def stats_figure(path: str, times=TIMES, wavelength_nm: float = 550.0) -> None:
    """The size distribution, S(q) and the diffuse intensity at ``times`` [s] into ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from corona.model.processes.breath_figure import BreathFigure, load_table
    table = load_table()
    edges = table["x_edges"]
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 3.9), constrained_layout=True)
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(times)))
    lam = wavelength_nm * 1e-3
    for t, c in zip(times, colours):
        p = BreathFigure(breath_time=t)
        k = int(np.argmin(np.abs(table["times"] - p.simulation_time)))
        if not np.isclose(table["times"][k], p.simulation_time):
            raise SystemExit(f"breath_time={t:g} s is not a time of the table ({table['times']})")
        # number of droplets per area and per µm of contact radius, in the table's bins of a/R
        R = p.mean_radius
        dens = table["fraction"][k] * p.number_density / (np.diff(edges) * R)
        mid = 0.5 * (edges[1:] + edges[:-1]) * R
        ok = dens > 0
        axes[0].step(mid[ok], dens[ok], where="mid", color=c, label=f"{t:g} s (R = {R:.1f} µm)")
        _structure_and_lobe(axes, p, c, f"{t:g} s", lam)
    _finish(fig, axes, path, wavelength_nm, "droplets per µm² per µm")


def _structure_and_lobe(axes, p, colour, label: str, lam: float) -> None:
    """S(q) of ``p``'s centres into ``axes[1]``, its diffuse intensity per area into ``axes[2]``."""
    q = np.geomspace(0.02, 60.0, 600) / p.mean_radius
    axes[1].plot(q, p.structure_factor_radial(q), color=colour, label=label)
    theta = np.linspace(0.02, 15.0, 600)
    qa = 2 * np.pi * np.sin(np.radians(theta)) / lam
    axes[2].plot(theta, p.intensity(qa) * p.number_density, color=colour, label=label)


def _finish(fig, axes, path: str, wavelength_nm: float, size_label: str) -> None:
    import matplotlib.pyplot as plt
    axes[0].set(xscale="log", yscale="log", xlabel="contact radius a [µm]",
                ylabel=size_label, title="size distribution")
    axes[1].set(xscale="log", yscale="log", xlabel="q [rad/µm]", ylabel="S(q)", title="structure factor of the centres")
    axes[1].axhline(1.0, color="0.6", lw=0.6)
    axes[2].set(yscale="log", xlabel=f"scattering angle at {wavelength_nm:g} nm [degree]",
                ylabel="n I(q) [µm²]", title="diffuse intensity per area (the lobe)")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def drying_stats_figure(path: str, breath_time: float = 20.0, dry_times=(0.0, 4.0, 8.0, 12.0, 16.0),
                        wavelength_nm: float = 550.0) -> None:
    """The fading phase's statistics: after ``breath_time`` [s] of growth, at ``dry_times`` [s] of
    drying, the droplets per area in each of the process's size classes, S(q) and the diffuse
    intensity per area (the same panels as :func:`stats_figure`)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from corona.model.processes.breath_figure import BreathFigure
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 3.9), constrained_layout=True)
    colours = plt.cm.magma(np.linspace(0.0, 0.8, len(dry_times)))
    for t, c in zip(dry_times, colours):
        p = BreathFigure(breath_time=breath_time, dry_time=t)
        radii, fraction = p.size_classes
        order = np.argsort(radii)[::-1]
        label = f"dry {t:g} s (R = {p.mean_radius:.1f} µm, F_a = {p.area_fraction(None):.2f})"
        # the process's size classes as a cumulative count: droplets per µm² at least a in radius
        axes[0].step(radii[order], np.cumsum(fraction[order]) * p.number_density, where="post", color=c,
                     label=label)
        _structure_and_lobe(axes, p, c, f"dry {t:g} s", wavelength_nm * 1e-3)
    fig.suptitle(f"a pane breathed on for {breath_time:g} s, then drying", fontsize=10)
    _finish(fig, axes, path, wavelength_nm, "droplets per µm² of radius ≥ a")


DRY_TIMES = tuple(float(t) for t in range(0, 17, 2))


def drying_gif(path: str, breath_time: float = 20.0, dry_times=DRY_TIMES, res: int = 128, spp: int = 16,
               variant: str | None = None) -> None:
    """``scenes/breath_figure.xml`` at ``dry_times`` [s] after ``breath_time`` [s] of growth, one exposure
    (the first frame's), as an animated GIF at ``path``."""
    from PIL import Image, ImageDraw

    import corona  # noqa: F401  (libLLVM before drjit)
    from corona.apps.pictures import display_exposure, display_srgb
    from corona.apps.render import load_scene, render_linear, setup_variant
    setup_variant(variant)
    scene_path = os.path.join(ROOT, "scenes", "breath_figure.xml")
    frames, exposure = [], None
    for t in dry_times:
        scene = load_scene(scene_path, {"breath_time": breath_time, "dry_time": t, "res": res, "spp": spp})
        rgb, _ = render_linear(scene, spp, progress=False, desc=f"dry {t:g} s")
        if exposure is None:
            exposure = display_exposure(rgb)
        im = Image.fromarray(display_srgb(rgb, exposure))
        ImageDraw.Draw(im).text((4, res - 14), f"dry {t:g} s", fill=(255, 255, 255))
        frames.append(im.convert("P", palette=Image.ADAPTIVE))
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=400, loop=0, optimize=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/breath_strip.py", description=__doc__.splitlines()[0])
    ap.add_argument("--stats-only", action="store_true", help="only the statistics figure (no renders)")
    ap.add_argument("--drying-gif", action="store_true", help="only the GIF of the fading phase")
    ap.add_argument("--variant", default=None)
    a = ap.parse_args(argv)
    out = os.path.join(ROOT, "docs", "gallery")
    os.makedirs(out, exist_ok=True)
    if a.drying_gif:
        gif = os.path.join(out, "breath_figure_drying.gif")
        drying_gif(gif, variant=a.variant)
        print(f"breath_strip: {os.path.relpath(gif, ROOT)}")
        return 0
    stats = os.path.join(out, "breath_figure_stats.png")
    stats_figure(stats)
    drying_stats = os.path.join(out, "breath_figure_drying_stats.png")
    drying_stats_figure(drying_stats)
    print(f"breath_strip: {os.path.relpath(stats, ROOT)}, {os.path.relpath(drying_stats, ROOT)}")
    if a.stats_only:
        return 0
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import gallery
    from corona._executor import Executor
    with Executor(0) as ex:
        res = gallery.build(only=["breath_figure_strip"], variant=a.variant, executor=ex)
    return 1 if res["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
