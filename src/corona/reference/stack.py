"""Brute force for a layer on a glass pane: a Monte Carlo random walk through the stack.

:class:`corona.Material` with a substrate (``docs/physics.md#the-layer-on-glass-substrateglass``) keeps the
paths that cross the layer at most twice with at most one scattering event,
and drops the rest.  This walk follows every path, to any order, with the
layer's and the pane's own statistics only:

* the layer (either side): reflects diffusely with probability ``ρ``
  (:attr:`~corona.Material.reflectance`, Lambertian), passes coherently with
  ``C`` (:attr:`~corona.Material.coherent_transmittance`), scatters into the
  lobe with the lobe's plane integral (:meth:`~corona.Material.sample`: the
  table; evanescent draws ``|wo.xy| > 1`` are lost), and absorbs the rest;
* the pane: reflects specularly with ``R'(θ)``
  (:meth:`corona.GlassPane.reflectance`) and transmits otherwise; light that has just
  crossed the layer towards the pane is reflected by the front face (``R``, the Fresnel
  reflectance of the face the layer lies on) back through the same place of the layer, which
  it does not meet again (a screen on a face is crossed once: ``t(x)² = t(x)``), and by the
  round trips (``R' - R``) back to the layer, which it meets again.

It sorts the escaping energy by path (how many scatterings, how many
reflections off the pane), so that each component of the model can be
compared with the paths it stands for, and the energy the model drops is
measured.  Numpy only (no extra needed).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corona._validation import CoronaError

#: The model's components and the paths they stand for.
CLASSES = ("coherent", "specular", "lobe_transmission", "lobe_reflection", "diffuse", "dropped")


@dataclass
class _Photons:
    """The walk's photons: travel direction (n, 3), the next element each meets (0 layer, 1 pane,
    2 escaped above (layer side), 3 escaped below, 4 absorbed), and counts of the events on its path:
    scatterings into the lobe, diffuse reflections off the layer, reflections off the pane that meet
    the layer again (or glass first), front-face reflections back through the place of the layer
    just crossed, layer events; ``crossed``: the last layer event let it through towards the pane."""
    dirs: np.ndarray
    nxt: np.ndarray
    lobes: np.ndarray
    diffuse: np.ndarray
    pane_r: np.ndarray
    pane_f: np.ndarray
    crossed: np.ndarray
    layer_hits: np.ndarray

    @classmethod
    def start(cls, n: int, ci: float, first: bool) -> "_Photons":
        s = np.sqrt(max(0.0, 1.0 - ci * ci))
        return cls(dirs=np.tile([-s, 0.0, -abs(ci) if first else abs(ci)], (n, 1)),
                   nxt=np.full(n, 0 if first else 1), lobes=np.zeros(n, int), diffuse=np.zeros(n, int),
                   pane_r=np.zeros(n, int), pane_f=np.zeros(n, int), crossed=np.zeros(n, bool),
                   layer_hits=np.zeros(n, int))


def _at_pane(ph: _Photons, at_p: np.ndarray, pane, rng) -> None:
    """The photons ``at_p`` meet the pane: reflected specularly with R'(θ) or transmitted."""
    d = ph.dirs[at_p]
    x = rng.random(at_p.size)
    refl = x < pane.reflectance(np.abs(d[:, 2]))
    front = ph.crossed[at_p] & (x < pane.face_reflectance(np.abs(d[:, 2])))
    d[refl, 2] *= -1.0
    ph.dirs[at_p] = d
    ph.pane_r[at_p] += refl & ~front
    ph.pane_f[at_p] += front
    up = d[:, 2] > 0
    # up: back to the layer (out above if the front face returned it through the layer)
    ph.nxt[at_p] = np.where(front, 2, np.where(up, 0, 3))


def _at_layer(ph: _Photons, at_l: np.ndarray, material, energies: tuple, wavelength: float, rng) -> None:
    """The photons ``at_l`` meet the layer with ``energies`` = (diffuse reflectance, lobe, coherent):
    reflected diffusely, scattered into the lobe, passed or absorbed."""
    rho, d_plane, c = energies
    d = ph.dirs[at_l]
    ph.layer_hits[at_l] += 1
    x = rng.random(at_l.size)
    is_diffuse = x < rho
    is_lobe = (x >= rho) & (x < rho + d_plane)
    is_absorbed = x >= rho + d_plane + c
    # diffuse reflection: cosine-weighted, back towards where it came from
    k = np.flatnonzero(is_diffuse)
    if k.size:
        r2 = rng.random(k.size)
        phi = 2 * np.pi * rng.random(k.size)
        z = np.sqrt(1.0 - r2)
        sign = -np.sign(d[k, 2])
        d[k] = np.stack([np.sqrt(r2) * np.cos(phi), np.sqrt(r2) * np.sin(phi), sign * z], -1)
        ph.diffuse[at_l[k]] += 1
    # the lobe: d_lobe = (wo + wi).xy with wi = -travel direction
    k = np.flatnonzero(is_lobe)
    if k.size:
        dl = material.sample(rng.random((k.size, 2)), wavelength)
        oxy = dl + d[k, :2]
        r2 = np.sum(oxy * oxy, -1)
        ok = r2 < 1.0
        oz = np.sign(d[k, 2]) * np.sqrt(np.maximum(0.0, 1.0 - r2))
        d[k] = np.concatenate([oxy, oz[:, None]], -1)
        ph.lobes[at_l[k]] += 1
        is_absorbed[k[~ok]] = True
    ph.dirs[at_l] = d
    up = d[:, 2] > 0
    ph.crossed[at_l] = ~is_diffuse & ~up
    ph.nxt[at_l] = np.where(is_absorbed, 4, np.where(up, 2, 1))   # down: on to the pane


def _energy_by_path(ph: _Photons, first: bool) -> dict:
    """The escaped photons sorted into :data:`CLASSES` and the totals (:func:`random_walk`'s result)."""
    n = ph.nxt.size
    lobes, diffuse, pane_r, pane_f, layer_hits = ph.lobes, ph.diffuse, ph.pane_r, ph.pane_f, ph.layer_hits
    unfinished = float(np.mean((ph.nxt == 0) | (ph.nxt == 1)))
    # the side of wi: above for layer-first light, below for glass-first light
    out_refl = ph.nxt == (2 if first else 3)
    out_trans = ph.nxt == (3 if first else 2)
    one_layer = layer_hits == 1
    no_pane = (pane_r == 0) & (pane_f == 0)
    # one reflection off the pane: by the front face through the layer once, or a round trip
    # between two crossings of the layer (light meeting the layer first); glass first: the pane
    one_refl = (((pane_f == 1) & (pane_r == 0) & one_layer) | ((pane_f == 0) & (pane_r == 1) & (layer_hits == 2))
                if first else (pane_f == 0) & (pane_r == 1) & (layer_hits == 0))
    classes = {
        "coherent": out_trans & (lobes == 0) & (diffuse == 0) & no_pane & one_layer,
        "specular": out_refl & (lobes == 0) & (diffuse == 0) & one_refl,
        "lobe_transmission": out_trans & (lobes == 1) & (diffuse == 0) & no_pane & one_layer,
        "lobe_reflection": out_refl & (lobes == 1) & (diffuse == 0) & one_refl & first,
        "diffuse": out_refl & (lobes == 0) & (diffuse == 1) & no_pane & one_layer,
    }
    out = {k: float(np.mean(v)) for k, v in classes.items()}
    kept = np.zeros(n, bool)
    for v in classes.values():
        kept |= v
    out["dropped"] = float(np.mean((out_refl | out_trans) & ~kept))
    out["lobe_reflection_front"] = float(np.mean(classes["lobe_reflection"] & (pane_f == 1)))
    out["reflected"] = float(np.mean(out_refl))
    out["transmitted"] = float(np.mean(out_trans))
    out["unfinished"] = unfinished
    p = max(out[k] for k in CLASSES)
    out["sigma"] = float(np.sqrt(max(p * (1 - p), 1.0 / n) / n))
    return out


def random_walk(material, cos_theta_i: float, wavelength: float = 550.0, n: int = 200_000,
                seed: int = 0, max_events: int = 64) -> dict:
    """Energy leaving the layer-on-glass stack, sorted by path, for light from ``wi``.

    Parameters
    ----------
    material : corona.Material
        With a :class:`corona.GlassPane` substrate.
    cos_theta_i : float, signed
        Cosine of ``wi`` in the layer's frame (+: from the +z side); ``wi``
        has azimuth 0.
    wavelength : float
        [nm].
    n : int
        Photons.
    max_events : int
        Interactions followed per photon (what is still inside then counts
        as absorbed; its share is returned as ``unfinished``).

    Returns
    -------
    dict: the energy (fraction of the photons) per class of :data:`CLASSES`
    (``dropped``: escaping paths the model leaves out), ``lobe_reflection_front`` (the part
    of ``lobe_reflection`` the front face returned: scattered, then reflected at the
    scattered angle, ``∫ f R(θo)``), ``reflected`` and
    ``transmitted`` (all escaping paths, on the side of ``wi`` or not),
    ``unfinished``, and ``sigma`` (the binomial standard error of a class
    holding a fraction p is ``sqrt(p (1 - p) / n)``; this is the largest).
    """
    pane = material.substrate
    if pane is None:
        raise CoronaError("random_walk needs a material with a substrate (corona.GlassPane)")
    rng = np.random.default_rng(seed)
    rho = material.reflectance
    c = material.coherent_transmittance
    # the lobe's energy over the tables it is sampled from (|d| <= 2.1 at 360 nm); the rest of
    # the plane integral, the form factor's tail, is evanescent and never propagates
    d_plane = float(material.tabulated_transmittance)
    if rho + c + d_plane > 1.0 + 1e-9:
        raise CoronaError(f"layer energies sum to {rho + c + d_plane:g} > 1")
    # Work in a frame where the layer lies above the pane: "up" (+z') is the
    # layer's outside.  Light meeting the layer first comes from above.
    ci = float(cos_theta_i)
    first = bool(pane.layer_first(ci))
    ph = _Photons.start(n, ci, first)
    for _ in range(max_events):
        at_l = np.flatnonzero(ph.nxt == 0)
        at_p = np.flatnonzero(ph.nxt == 1)
        if at_l.size == 0 and at_p.size == 0:
            break
        if at_p.size:
            _at_pane(ph, at_p, pane, rng)
        if at_l.size:
            _at_layer(ph, at_l, material, (rho, d_plane, c), wavelength, rng)
    return _energy_by_path(ph, first)
