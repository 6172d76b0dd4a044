"""Brute-force wave-optics reference: random screens, FFT, ensemble average (docs/physics.md#validation-figures).

The model claims that the diffraction lobe of a layer, ``F_a T_a(d) T_s(d)``,
is the ensemble average of the Fraunhofer diffraction of a random screen.
This module computes that average directly, with none of the model's
assumptions (no form-factor × structure-factor split, no tables):

1. **Positions** — one realisation of the point process in a periodic box
   (:func:`positions_source`): hard-disk configurations from the event-chain
   simulation (:func:`corona.reference.hard_disk.simulate_hard_disks`, the same
   ``N = 2000`` disks the shipped table was made with), random sequential
   adsorption (:func:`corona.model.processes.rsa.rsa_configuration`), jittered
   lattices (box commensurate with the lattice), Poisson (``N`` uniform
   centres) and measured point sets (:class:`corona.PointSet`, treated as
   periodic).  Every realisation is translated by a uniform random offset, so
   the ensemble is translation invariant and the mean amplitude ``⟨T̂(q)⟩``
   vanishes for every ``q ≠ 0``.
2. **Scatterers** — every scatterer gets its own draw of the random shape
   parameters (:class:`~corona.model.shapes.Mixture` component, size factor of
   :class:`~corona.model.shapes.SizeDistribution`, angle of
   :class:`~corona.model.shapes.RandomOrientation`); the resulting profile is
   rasterised into a small *stamp* around its centre and combined into the
   screen (:func:`rasterise`).
3. **FFT** — ``T̂(q) ≈ h_x h_y · FFT[t]`` (:mod:`scipy.fft`, worker threads),
   ``|T̂|²`` averaged over realisations, converted to the d-space intensity

       ``I(d) = ⟨|T̂(q)|²⟩ / (A_screen λ²)``,  ``q = 2π d / λ``

   (docs/physics.md#validation-figures), which is compared with ``lobe(d) = F_a T_a(d) T_s(d)``
   (:meth:`BruteForce.lobe`).  Both scale with λ only through ``d = q λ/2π``,
   so one ensemble serves every wavelength.

Rasterisation (the grid rule)
-----------------------------
* Pixel pitch ``h ≤ R / samples_per_radius`` (default 16 samples per
  circumradius ``R`` of the smallest base shape at scale 1); the box side is
  rounded up to an FFT-friendly number of pixels (``scipy.fft.next_fast_len``)
  and ``h`` set so that the grid tiles the periodic box exactly.
* **Analytic shapes** (circle, ellipse, rectangle/square, polygons): the
  anti-aliased coverage ``clip(1/2 - sd(x)/h, 0, 1)`` of the signed distance
  ``sd`` to the boundary (exact for circles, rectangles and polygons, first
  order for ellipses) — a box filter of width ``h`` across the edge.  Its
  transfer function is ``H(q) ≈ sinc(|q| h/2)`` (``sinc x = sin x / x``; the
  edge points that dominate ``Â(q)`` have their normal along ``q``; to
  second order every filter of variance ``h²/12`` per axis gives
  ``1 - q²h²/24``), and the ensemble spectrum is divided by ``H(q)²``
  (``pixel_transfer = "ramp-deconvolved"``).  Without it the lobe would be
  ~1–2 % low at ``u = qR ≈ 8`` with 16 samples per radius.
* **Masks** (:class:`~corona.model.shapes.Mask`) are defined by the model as the
  band-limited profile through the pixel values.  At fixed orientation and
  size they are rasterised *exactly*: the grid pitch is the mask's own pixel
  size, the stamp is the image itself, and centres are snapped to the grid
  (a displacement ≤ h/2 per axis; the box is stretched by ≤ one pixel to fit
  a whole number of pixels, which changes the density by ≤ 2 h/L, reported as
  ``area_fraction_screen``).  The DFT of those samples is then exactly the
  band-limited Â (no aliasing, no filter; ``pixel_transfer = "none"``).
  Rotated or scaled masks are resampled with cubic interpolating B-splines
  (an approximation of the band-limited profile near the band limit).
* **Soft edges** (:class:`~corona.model.shapes.SoftEdge`): the sharp stamp is
  multiplied in Fourier space by the Gaussian's transfer
  ``exp(-|q|² w²/2)`` (stamps padded by 5 w).
* Stamps are combined as ``t = min(1, Σ_j A_j)`` (``overlaps="clip"``,
  default): where scatterers do not overlap this is exactly ``Σ_j A_j`` (also
  for soft edges, whose blurred tails add up to at most 1 around
  non-overlapping cores); where binary openings overlap the screen transmits
  their union, never more than 1, and the particle screen ``1 - t`` is opaque
  on the union of the particles.  ``overlaps="add"`` keeps the model's linear
  superposition ``t = Σ_j A_j`` even where it exceeds 1 (unphysical, but the
  exact counterpart of the model for overlapping processes such as Poisson).

Coherent peak
-------------
The coherent (delta) part is separated at the DC bin only: the screens are
FFT'd after subtracting their own mean, the coherent weight is
``|⟨T̂(0)⟩|² / A_screen² = ⟨mean t⟩²`` (``F_a²`` aperture, ``(1 - F_a)²``
particle for the model), and the diffuse value of the DC bin is the
variance ``A_screen · Var(mean t)`` (0 for a fixed number of non-overlapping
scatterers).  At ``q ≠ 0`` nothing is subtracted: the ensemble mean
amplitude vanishes there by the random translation, and subtracting its
finite-sample estimate would bias the lobe low by ``1/M``.  The diffuse total
``⟨mean t²⟩ - ⟨mean t⟩²`` is exact by Parseval over the whole grid.

Aperture and particle screens of the same realisation are complements
(``t_particle = 1 - t_aperture``), so ``t - mean t`` differs only in sign and
both share one spectrum (Babinet): :func:`brute_force` computes the
statistics of both modes from one ensemble (:meth:`BruteForce.with_mode`).

References
----------
J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., ch. 4 (Fraunhofer
diffraction) and §2.4 (sampling); R. Yang, J. Kim, A. Pediredla, W. Jarosz,
"A wave-optics BSDF for correlated scatterers", CGF 44(4), 2025.
"""
from __future__ import annotations

import copy
import math
import os
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage

from corona._validation import CoronaError, check_choice, check_range
from corona.model.processes import Lattice, PointSet, Poisson, Process, SequentialAdsorption
from corona.model.processes.rsa import rsa_configuration
from corona.model.shapes import (Mask, Mixture, Polygon, RandomOrientation, RegularPolygon, Shape,
                                  SizeDistribution, SoftEdge)

#: default samples per circumradius of the smallest base shape
SAMPLES_PER_RADIUS = 16
#: default number of scatterers per realisation (the hard-disk table used 2000)
N_SCATTERERS = 2000
#: largest grid side accepted by default
MAX_GRID = 8192
#: hard-disk packing fraction from which the simulated box is hexatic (one domain)
HEXATIC_ETA = 0.69
#: stamp elements per vectorised chunk
_CHUNK_ELEMENTS = 2_000_000
_OVERLAPS = ("clip", "add")


# ==========================================================================
# numba kernels
# ==========================================================================
@nb.njit(cache=True, nogil=True)
def _splat_add(grid, stamps, which, iy0, ix0):
    """grid[wrap(iy0+a), wrap(ix0+b)] += stamps[which[k], a, b] (periodic)."""
    ny, nx = grid.shape
    sy, sx = stamps.shape[1], stamps.shape[2]
    for k in range(which.size):
        s = which[k]
        for a in range(sy):
            iy = iy0[k] + a
            if iy >= ny:
                iy -= ny
            for b in range(sx):
                v = stamps[s, a, b]
                if v != 0.0:
                    ix = ix0[k] + b
                    if ix >= nx:
                        ix -= nx
                    grid[iy, ix] += v


@nb.njit(cache=True, nogil=True)
def _polygon_sd(X, Y, vx, vy, cut, out):
    """Signed distance (negative inside) of points (X, Y) to the closed polygon
    (vx, vy); points farther than ``cut`` from the origin get ``cut``."""
    n = vx.size
    c2 = cut * cut
    for p in range(X.size):
        x = X[p]
        y = Y[p]
        if x * x + y * y > c2:
            out[p] = cut
            continue
        dmin = 1e300
        inside = False
        for i in range(n):
            j = i + 1
            if j == n:
                j = 0
            ax = vx[i]
            ay = vy[i]
            ex = vx[j] - ax
            ey = vy[j] - ay
            wx = x - ax
            wy = y - ay
            t = (wx * ex + wy * ey) / (ex * ex + ey * ey)
            if t < 0.0:
                t = 0.0
            elif t > 1.0:
                t = 1.0
            dx = wx - t * ex
            dy = wy - t * ey
            d = dx * dx + dy * dy
            if d < dmin:
                dmin = d
            if (ay > y) != (vy[j] > y):
                xc = ax + (y - ay) * ex / ey
                if x < xc:
                    inside = not inside
        d = math.sqrt(dmin)
        out[p] = -d if inside else d


# ==========================================================================
# shapes: decomposition into base shapes with per-scatterer draws
# ==========================================================================
def _rasterisable(shape) -> bool:
    """A base shape the brute force stamps: a mask (its image), or a class with a
    ``signed_distance`` (every registered family that defines one, corona.model.registry)."""
    return isinstance(shape, Mask) or type(shape).signed_distance is not Shape.signed_distance


#: Faster rasterisers of some families' ``signed_distance`` (numba: the same values): an
#: optimisation only, every other family uses its own method.
_FAST_SIGNED_DISTANCE = {}


@dataclass
class _Draws:
    """Per-scatterer random shape parameters (world = scale · Rot(angle) · base)."""
    leaves: list
    leaf: np.ndarray      # (n,) index into leaves
    angle: np.ndarray     # (n,) rad
    scale: np.ndarray     # (n,)
    blur: np.ndarray      # (n,) Gaussian edge width in the world [µm]


def _draw_sizes(sd: SizeDistribution, n: int, rng) -> np.ndarray:
    """Number-weighted size factors s (mean 1, std ``spread``) of a SizeDistribution."""
    sp = sd.spread
    if sp == 0.0 or n == 0:
        return np.ones(n)
    if sd.distribution == "lognormal":
        s2 = math.log1p(sp * sp)
        return np.exp(rng.normal(-0.5 * s2, math.sqrt(s2), n))
    k = 1.0 / (sp * sp)
    return rng.gamma(k, 1.0 / k, n)


def _leaves_of(shape: Shape, out=None) -> list:
    out = [] if out is None else out
    if isinstance(shape, Mixture):
        for sh, _ in shape.components:
            _leaves_of(sh, out)
    elif isinstance(shape, (SizeDistribution, RandomOrientation, SoftEdge)):
        _leaves_of(shape.shape, out)
    elif _rasterisable(shape):
        if not any(s is shape for s in out):
            out.append(shape)
    else:
        from corona.model import registry
        known = ", ".join(f.name for f in registry.SHAPE_FAMILIES.values()
                          if f.cls is not None and (f.cls is Mask or _rasterisable_class(f.cls)))
        raise CoronaError(f"shape={shape!r} is not supported by the brute force (no signed_distance); "
                          f"supported: {known} and SoftEdge, RandomOrientation, SizeDistribution, Mixture "
                          "of them")
    return out


def _rasterisable_class(cls) -> bool:
    return cls.signed_distance is not Shape.signed_distance


def _draw(shape: Shape, n: int, rng) -> _Draws:
    """Draw the random shape parameters of ``n`` scatterers."""
    leaves = _leaves_of(shape)
    leaf = np.zeros(n, dtype=np.int64)
    angle = np.zeros(n)
    scale = np.ones(n)
    blur2 = np.zeros(n)

    def walk(sh, idx):
        if idx.size == 0:
            return
        if isinstance(sh, Mixture):
            w = np.array([wt for _, wt in sh.components], dtype=np.float64)
            pick = rng.choice(len(w), size=idx.size, p=w / w.sum())
            for k, (sub, _) in enumerate(sh.components):
                walk(sub, idx[pick == k])
        elif isinstance(sh, SizeDistribution):
            scale[idx] *= _draw_sizes(sh, idx.size, rng)
            walk(sh.shape, idx)
        elif isinstance(sh, RandomOrientation):
            angle[idx] += rng.uniform(0.0, 2.0 * np.pi, idx.size)
            walk(sh.shape, idx)
        elif isinstance(sh, SoftEdge):
            blur2[idx] += (sh.edge_width * scale[idx]) ** 2
            walk(sh.shape, idx)
        else:
            leaf[idx] = next(i for i, s in enumerate(leaves) if s is sh)

    walk(shape, np.arange(n))
    return _Draws(leaves, leaf, angle, scale, np.sqrt(blur2))


def _transformed_leaves(shape: Shape) -> set:
    """ids of base shapes that appear under RandomOrientation or SizeDistribution."""
    found = set()

    def walk(sh, moved):
        if isinstance(sh, Mixture):
            for sub, _ in sh.components:
                walk(sub, moved)
        elif isinstance(sh, SizeDistribution):
            walk(sh.shape, moved or sh.spread > 0.0)
        elif isinstance(sh, RandomOrientation):
            walk(sh.shape, True)
        elif isinstance(sh, SoftEdge):
            walk(sh.shape, moved)
        elif moved:
            found.add(id(sh))

    walk(shape, False)
    return found


def _mask_geometry(mask: Mask):
    """Cropped image with rows flipped (row index grows with y), its centroid
    (row, col) in that crop, and the prefiltered padded spline coefficients."""
    img = mask.image
    rows = np.nonzero(img.any(axis=1))[0]
    cols = np.nonzero(img.any(axis=0))[0]
    crop = np.ascontiguousarray(img[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1][::-1])
    ii, jj = np.indices(crop.shape)
    tot = float(crop.sum())
    ci = float(np.sum(ii * crop)) / tot
    cj = float(np.sum(jj * crop)) / tot
    return crop, ci, cj


def _leaf_profile(leaf, X, Y, h_leaf):
    """Anti-aliased profile of a base shape at leaf coordinates (X, Y) [µm].

    ``h_leaf`` (broadcastable) is the pixel pitch in leaf units: coverage
    ``clip(1/2 - sd/h, 0, 1)`` of the signed distance ``sd``.
    """
    fast = _FAST_SIGNED_DISTANCE.get(type(leaf))
    sd = leaf.signed_distance(X, Y) if fast is None else fast(leaf, X, Y, h_leaf)
    return np.clip(0.5 - sd / h_leaf, 0.0, 1.0)


def _polygon_signed_distance(leaf, X, Y, h_leaf):
    """:meth:`corona.Polygon.signed_distance` by the numba loop (cut off beyond the outline)."""
    Xb, Yb = np.broadcast_arrays(X, Y)
    Xf = np.ascontiguousarray(Xb, dtype=np.float64).ravel()
    Yf = np.ascontiguousarray(Yb, dtype=np.float64).ravel()
    out = np.empty(Xf.size)
    cut = leaf.length_scale + 2.0 * float(np.max(h_leaf))
    v = leaf.vertices
    _polygon_sd(Xf, Yf, np.ascontiguousarray(v[:, 0]), np.ascontiguousarray(v[:, 1]), cut, out)
    return out.reshape(Xb.shape)


_FAST_SIGNED_DISTANCE[Polygon] = _polygon_signed_distance
_FAST_SIGNED_DISTANCE[RegularPolygon] = _polygon_signed_distance


def _fourier_blur(stamps, blur, hx, hy):
    """Multiply each stamp's spectrum by exp(-|q|² w²/2) (w = blur[k], µm)."""
    if not np.any(blur > 0):
        return stamps
    K, sy, sx = stamps.shape
    F = sp_fft.rfft2(stamps, axes=(-2, -1))
    ky = 2 * np.pi * sp_fft.fftfreq(sy, d=hy)
    kx = 2 * np.pi * sp_fft.rfftfreq(sx, d=hx)
    q2 = ky[:, None] ** 2 + kx[None, :] ** 2
    F *= np.exp(-0.5 * q2[None] * (np.asarray(blur) ** 2)[:, None, None])
    return sp_fft.irfft2(F, s=(sy, sx), axes=(-2, -1))


# ==========================================================================
# position sources
# ==========================================================================
_HD_CACHE: dict = {}


def hard_disk_configurations(packing_fraction: float, count: int, n_disks: int = N_SCATTERERS,
                             seed: int = 0, progress: bool = False):
    """``count`` equilibrium hard-disk configurations (cached per process).

    Event-chain Monte Carlo (:func:`corona.reference.hard_disk.simulate_hard_disks`):

    * η < 0.69 (fluid): one chain from a triangular lattice, equilibrated for
      3000 sweeps (η < 0.6) or 10⁴ sweeps, then one configuration every 100
      sweeps (200 above η = 0.65); the density modes at the first peak and
      at the smallest box wave vectors are decorrelated after that (measured
      lag-1 correlation ≲ 0.3);
    * η ≥ 0.69 (fluid–hexatic coexistence and hexatic, see
      :class:`corona.HardDisk`): the periodic box holds a single
      orientationally ordered domain whose director is pinned by the start
      (a lattice start keeps it along the box axes), while the table's
      ``S(|q|)`` is an orientational average (a macroscopic layer has many
      domains).  So 6 independent chains are started from compressed fluids
      (random directors), equilibrated for 2·10⁴ sweeps, and sampled every
      200 sweeps, interleaved chain by chain.

    Returns
    -------
    positions : ndarray (count, N, 2)
        Centres in units of the disk diameter σ, in the periodic box [0, L)².
    L : float
        Box side in units of σ.
    """
    from corona.reference.hard_disk import simulate_hard_disks
    eta = check_range("packing_fraction", packing_fraction, 0.0, 0.8, lo_open=True)
    count = int(check_range("count", count, 1, 1e6))
    key = (round(eta, 12), int(n_disks), int(seed))
    hit = _HD_CACHE.get(key)
    if hit is not None and hit[0].shape[0] >= count:
        return hit[0][:count], hit[1]
    hexatic = eta >= HEXATIC_ETA
    chains = 6 if hexatic else 1
    per = int(math.ceil(count / chains))
    gap = 100 if eta < 0.65 else 200
    neq = 20000 if hexatic else (3000 if eta < 0.6 else 10000)
    sim = simulate_hard_disks(eta, n_disks=int(n_disks), n_sweeps=gap * per, seed=int(seed),
                              progress=progress, n_equilibration=neq, sample_every=gap,
                              q_sigma_max=1.0, r_max=1.5, dr=0.01, n_keep=per, n_chains=chains,
                              jobs=min(chains, os.cpu_count() or 1),
                              start="compressed" if hexatic else "lattice")
    if sim.min_distance < 1.0 - 1e-9:
        raise RuntimeError(f"hard-disk simulation produced an overlap (min distance {sim.min_distance})")
    snaps = np.mod(sim.snapshots, sim.box_length)
    if chains > 1:      # interleave: chain 0 snapshot 0, chain 1 snapshot 0, ...
        snaps = snaps.reshape(chains, -1, *snaps.shape[1:]).swapaxes(0, 1).reshape(snaps.shape)
    _HD_CACHE[key] = (snaps, sim.box_length)
    return snaps[:count], sim.box_length


def _d4(p: np.ndarray, L: float, k: int) -> np.ndarray:
    """Image of centres ``p`` in the periodic square box [0, L)² under element k (0..7) of D4."""
    x, y = p[:, 0], p[:, 1]
    if k & 1:
        x = L - x
    if k & 2:
        y = L - y
    if k & 4:
        x, y = y, x
    return np.column_stack([x, y])


@dataclass
class PositionSource:
    """Realisations of a point process in a periodic box ``[0, Lx) × [0, Ly)`` [µm]."""
    box: tuple
    draw: object                  # callable (r, rng) -> (N, 2) µm
    description: str
    realisations_max: int | None = None   # None: unlimited
    exact_count: bool = True


def lattice_box(process: Lattice, n_scatterers: int = N_SCATTERERS) -> tuple:
    """The periodic box ``(Lx, Ly)`` [µm] the brute force uses for a lattice:
    ``m`` periods along x and ``m'`` rectangular cells (two sites each for the
    hexagonal lattice) along y, with about ``n_scatterers`` sites."""
    a = process.spacing
    if process.kind == "square":
        m = max(4, int(round(math.sqrt(n_scatterers))))
        return (m * a, m * a)
    m = max(4, int(round(math.sqrt(n_scatterers * math.sqrt(3.0) / 2.0))))
    m2 = max(2, int(round(m / math.sqrt(3.0))))
    return (m * a, m2 * math.sqrt(3.0) * a)


def positions_source(process: Process, shape: Shape, *, n_scatterers: int = N_SCATTERERS,
                     realisations: int = 1, seed: int = 0, progress: bool = False) -> PositionSource:
    """A source of centres [µm] for ``process`` with ``shape`` (see the module notes).

    The box holds about ``n_scatterers`` centres at the process's density
    ``n = F_a / ⟨|A|⟩``; hard disks and RSA keep their exclusion diameter σ.
    """
    from corona.model.processes import HardDisk
    process.validate(shape)
    fa = float(process.area_fraction(shape))
    area = float(shape.area)
    if isinstance(process, HardDisk):
        sigma = process.diameter(shape)
        eta = process.packing_fraction(shape)
        snaps, L = hard_disk_configurations(eta, realisations, n_scatterers, seed, progress)
        box = (L * sigma, L * sigma)

        def draw(r, rng):
            return _d4(snaps[r % len(snaps)], L, int(rng.integers(8))) * sigma
        return PositionSource(box, draw,
                              f"hard disks η={eta:.4g}, N={snaps.shape[1]}, event-chain MC "
                              f"({len(snaps)} configurations"
                              + (", 6 chains from compressed fluids" if eta >= HEXATIC_ETA else "")
                              + ", each in a random one of the 8 symmetric images of the box)",
                              realisations_max=len(snaps))
    if isinstance(process, SequentialAdsorption):
        sigma = process.sigma(shape)
        eta = min(process.packing_fraction(shape), 0.547069)
        Lb = math.sqrt(n_scatterers * area / fa)

        def rsa(r, rng):
            return rsa_configuration(Lb, eta, sigma=sigma, seed=int(rng.integers(2**31 - 1)))
        return PositionSource((Lb, Lb), rsa, f"RSA η={eta:.4g}, N≈{n_scatterers}")
    if isinstance(process, Poisson):
        Lb = math.sqrt(n_scatterers * area / fa)
        N = int(round(fa * Lb * Lb / area))
        return PositionSource((Lb, Lb), lambda r, rng: rng.uniform(0.0, Lb, (N, 2)),
                              f"Poisson (binomial), N={N} uniform centres")
    if isinstance(process, Lattice):
        return _lattice_source(process, n_scatterers)
    if isinstance(process, PointSet):
        (x0, x1), (y0, y1) = process.box
        pts = np.asarray(process.points) - np.array([x0, y0])
        return PositionSource((x1 - x0, y1 - y0), lambda r, rng: pts.copy(),
                              f"measured point set, N={len(pts)} (one realisation, treated as "
                              "periodic)", realisations_max=1)
    from corona.model.processes import BreathFigure
    if isinstance(process, BreathFigure):
        from corona.reference.breath_figure import simulate_breath_figure
        Lb = float(process.table_box)

        def breath(r, rng):
            return simulate_breath_figure([process.simulation_time], box=Lb,
                                          seed=int(rng.integers(2**31 - 1))).centres[0]
        return PositionSource((Lb, Lb), breath,
                              f"breath figure at {process.simulation_time:g} s of the hemispherical run "
                              "(centres only: the rasteriser draws each droplet's size from the mixture, "
                              "uncorrelated with its place; the droplets' own far field is "
                              "corona.reference.breath_figure_optics.far_field_rings)", exact_count=False)
    raise CoronaError(f"process={process!r} is not supported by the brute force; supported: "
                      "HardDisk, SequentialAdsorption, Lattice, Poisson, PointSet, BreathFigure")


def _lattice_source(process: Lattice, n_scatterers: int) -> PositionSource:
    Lx, Ly = lattice_box(process, n_scatterers)
    a = process.spacing
    if process.kind == "square":
        m = int(round(Lx / a))
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="xy")
        sites = np.stack([i.ravel() * a, j.ravel() * a], -1)
        period = 0.5 * np.pi
    else:
        m = int(round(Lx / a))
        m2 = int(round(Ly / (math.sqrt(3.0) * a)))
        i, j = np.meshgrid(np.arange(m), np.arange(2 * m2), indexing="xy")
        sites = np.stack([(i + 0.5 * (j % 2)).ravel() * a, j.ravel() * (0.5 * math.sqrt(3.0) * a)], -1)
        period = np.pi / 3.0
    delta = process.jitter
    fixed = process.orientation == "fixed"
    if fixed:
        k = math.radians(process.angle) / period
        if abs(k - round(k)) > 1e-9:
            raise CoronaError(f"Lattice angle={process.angle!r}° is not supported by the brute force: "
                              "a fixed lattice must be aligned with the periodic box (angle a multiple "
                              f"of {math.degrees(period):g}°)")

    def draw(r, rng):
        p = sites.copy()
        if not fixed:   # powder: one randomly rotated lattice per realisation (seams at the box edge)
            phi = rng.uniform(0.0, 2.0 * np.pi)
            c, s = math.cos(phi), math.sin(phi)
            p = p @ np.array([[c, s], [-s, c]])
        if delta > 0:
            p = p + rng.normal(0.0, delta, p.shape)
        return p

    desc = (f"{process.kind} lattice, {len(sites)} sites, jitter {delta:g} µm"
            + ("" if fixed else ", randomly rotated per realisation (not periodic: seams)"))
    return PositionSource((Lx, Ly), draw, desc)


# ==========================================================================
# the grid and the rasteriser
# ==========================================================================
@dataclass
class Grid:
    """A periodic sampling grid: ``nx × ny`` pixels of ``hx × hy`` µm (box ``nx hx × ny hy``)."""
    nx: int
    ny: int
    hx: float
    hy: float

    @property
    def box(self) -> tuple:
        return (self.nx * self.hx, self.ny * self.hy)

    @property
    def h(self) -> float:
        return math.sqrt(self.hx * self.hy)


def choose_grid(shape: Shape, box, samples_per_radius: float = SAMPLES_PER_RADIUS,
                max_grid: int = MAX_GRID):
    """The grid rule (module notes).  Returns ``(grid, stretch, exact_masks)``:
    ``stretch = (sx, sy)`` ≥ 1 by which the box and the centres must be
    stretched (1 unless exact mask rasterisation needs a whole number of
    mask pixels), and whether masks are rasterised exactly."""
    spr = check_range("samples_per_radius", samples_per_radius, 2.0, 1e4)
    leaves = _leaves_of(shape)
    moved = _transformed_leaves(shape)
    analytic = [lf for lf in leaves if not isinstance(lf, Mask)]
    masks = [lf for lf in leaves if isinstance(lf, Mask)]
    h_a = min((lf.length_scale / spr for lf in analytic), default=math.inf)
    Lx, Ly = float(box[0]), float(box[1])
    exact = bool(masks) and not any(id(m) in moved for m in masks) and \
        len({m.pixel_size for m in masks}) == 1 and masks[0].pixel_size <= h_a * (1 + 1e-9)
    if exact:
        p = masks[0].pixel_size
        nx, ny = int(math.ceil(Lx / p - 1e-9)), int(math.ceil(Ly / p - 1e-9))
        grid = Grid(nx, ny, p, p)
        stretch = (nx * p / Lx, ny * p / Ly)
    else:
        h = min([h_a] + [min(m.pixel_size, m.length_scale / spr) for m in masks])
        nx = sp_fft.next_fast_len(int(math.ceil(Lx / h - 1e-9)), real=True)
        ny = sp_fft.next_fast_len(int(math.ceil(Ly / h - 1e-9)), real=True)
        grid = Grid(nx, ny, Lx / nx, Ly / ny)
        stretch = (1.0, 1.0)
    if max(grid.nx, grid.ny) > max_grid:
        raise CoronaError(f"grid={grid.nx}x{grid.ny} is out of range; allowed sides <= {max_grid} "
                          f"(box {Lx:.4g} x {Ly:.4g} µm at {grid.h:.4g} µm per pixel): use fewer "
                          "scatterers (n_scatterers) or fewer samples_per_radius")
    return grid, stretch, exact


def _memory_needed(grid: Grid, crop_elems: int) -> int:
    n = grid.nx * grid.ny
    return int(8 * n * 1.0 + 16 * grid.ny * (grid.nx // 2 + 1) * 1.5 + 8 * 4 * crop_elems
               + 8 * 3 * _CHUNK_ELEMENTS)


def _available_memory() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 8 * 2**30


def rasterise(shape: Shape, centres, grid: Grid, *, rng=None, draws: _Draws | None = None,
              overlaps: str = "clip", exact_masks: bool = False, out=None) -> np.ndarray:
    """Aperture transmission ``t`` (ny, nx) of scatterers at ``centres`` [µm].

    Parameters
    ----------
    shape : corona.Shape
        The scatterer (random shapes get one draw per scatterer).
    centres : array (N, 2)
        Centres [µm]; wrapped into the periodic box ``grid.box``.
    grid : Grid
        Sampling grid (pixel ``(iy, ix)`` has its centre at ``(ix hx, iy hy)``).
    rng : numpy Generator, optional
        For the random shape parameters.
    draws : optional
        Pre-drawn shape parameters (else drawn here).
    overlaps : {"clip", "add"}
        ``t = min(1, Σ A_j)`` or ``t = Σ A_j`` (module notes).
    exact_masks : bool
        Masks at their own pixel pitch (``grid.hx == pixel_size``) with
        centres snapped to the grid; else spline-resampled.
    out : ndarray, optional
        Work array (ny, nx) float64 to reuse.

    Returns
    -------
    ndarray (ny, nx) float64
        The aperture screen; the particle screen is ``1 - t``.
    """
    check_choice("overlaps", overlaps, _OVERLAPS)
    rng = np.random.default_rng() if rng is None else rng
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    Lx, Ly = grid.box
    c = np.column_stack([np.mod(c[:, 0], Lx), np.mod(c[:, 1], Ly)])
    n = len(c)
    if draws is None:
        draws = _draw(shape, n, rng)
    if out is None:
        out = np.empty((grid.ny, grid.nx))
    out.fill(0.0)
    splat = _splat_add
    hx, hy, h = grid.hx, grid.hy, grid.h
    for li, leaf in enumerate(draws.leaves):
        idx = np.nonzero(draws.leaf == li)[0]
        if idx.size == 0:
            continue
        if isinstance(leaf, Mask) and exact_masks:
            _stamp_mask_exact(out, splat, leaf, c[idx], draws.blur[idx], grid)
            continue
        if isinstance(leaf, Mask):
            crop, ci, cj = _mask_geometry(leaf)
            coef = ndimage.spline_filter(np.pad(crop, 4), order=3, mode="constant")
        # extents, sorted so that each chunk's stamp fits its scatterers
        ext = leaf.length_scale * draws.scale[idx] + 5.0 * draws.blur[idx] + 2.0 * h
        order = np.argsort(ext, kind="stable")
        idx, ext = idx[order], ext[order]
        start = 0
        while start < idx.size:
            est = int(math.ceil(ext[start] / min(hx, hy))) + 1
            per = max(1, _CHUNK_ELEMENTS // (2 * est + 1) ** 2)
            stop = min(idx.size, start + per)
            hx_half = int(math.ceil(ext[stop - 1] / hx)) + 1     # largest of the chunk (sorted)
            hy_half = int(math.ceil(ext[stop - 1] / hy)) + 1
            sx_, sy_ = 2 * hx_half + 1, 2 * hy_half + 1
            sel = idx[start:stop]
            start = stop
            cx, cy = c[sel, 0] / hx, c[sel, 1] / hy
            icx, icy = np.rint(cx).astype(np.int64), np.rint(cy).astype(np.int64)
            X = ((icx - cx) * hx)[:, None, None] + ((np.arange(sx_) - hx_half) * hx)[None, None, :]
            Y = ((icy - cy) * hy)[:, None, None] + ((np.arange(sy_) - hy_half) * hy)[None, :, None]
            ang = draws.angle[sel][:, None, None]
            sc = draws.scale[sel][:, None, None]
            if np.any(draws.angle[sel] != 0.0):
                ca, sa = np.cos(ang), np.sin(ang)
                Xl, Yl = (ca * X + sa * Y) / sc, (-sa * X + ca * Y) / sc
            else:
                Xl, Yl = X / sc, Y / sc
            if isinstance(leaf, Mask):
                p = leaf.pixel_size
                Xl, Yl = np.broadcast_arrays(Xl, Yl)
                coords = np.stack([ci + 4 + Yl.ravel() / p, cj + 4 + Xl.ravel() / p])
                stamps = ndimage.map_coordinates(coef, coords, order=3, mode="constant", cval=0.0,
                                                 prefilter=False).reshape(Xl.shape)
            else:
                stamps = _leaf_profile(leaf, Xl, Yl, h / sc)
            stamps = np.ascontiguousarray(
                _fourier_blur(np.broadcast_to(stamps, (len(sel), sy_, sx_)).astype(np.float64),
                              draws.blur[sel], hx, hy))
            splat(out, stamps, np.arange(len(sel), dtype=np.int64),
                  np.mod(icy - hy_half, grid.ny), np.mod(icx - hx_half, grid.nx))
    if overlaps == "clip":
        np.minimum(out, 1.0, out=out)
    return out


def _stamp_mask_exact(out, splat, mask: Mask, c, blur, grid: Grid):
    """Masks at their own pixel pitch: the image is the stamp, centres snapped."""
    crop, ci, cj = _mask_geometry(mask)
    i0, j0 = int(round(ci)), int(round(cj))
    for b in np.unique(blur):
        sel = np.nonzero(blur == b)[0]
        stamp = crop
        pad = int(math.ceil(5.0 * b / grid.h)) if b > 0 else 0
        if pad:
            stamp = _fourier_blur(np.pad(crop, pad)[None], np.array([b]), grid.hx, grid.hy)[0]
        stamp = np.ascontiguousarray(stamp[None], dtype=np.float64)
        icx = np.rint(c[sel, 0] / grid.hx).astype(np.int64)
        icy = np.rint(c[sel, 1] / grid.hy).astype(np.int64)
        splat(out, stamp, np.zeros(len(sel), dtype=np.int64),
              np.mod(icy - i0 - pad, grid.ny), np.mod(icx - j0 - pad, grid.nx))


# ==========================================================================
# the ensemble
# ==========================================================================
@dataclass
class BruteForce:
    """Ensemble-averaged Fraunhofer diffraction of random screens (docs/physics.md#validation-figures).

    Attributes
    ----------
    mode : {"aperture", "particle"}
        The screen this result describes (:meth:`with_mode` gives the other).
    material : str
        ``repr`` of the material.
    area_fraction : float
        The model's nominal ``F_a``.
    area_fraction_screen : float
        ``N ⟨|A|⟩ / A_screen`` of the rasterised ensemble (differs from the
        nominal value only by the mask-grid stretch).
    length_scale : float
        ``R`` [µm] of ``u = qR`` (the material's length scale).
    grid : Grid
        The sampling grid; ``samples_per_radius = R / h``.
    realisations : int
        Number of screens averaged (``M``).
    qx, qy : ndarray
        Wave vectors [rad/µm] of the cropped, centred spectrum (DC at the
        centre).
    power : ndarray (len(qy), len(qx))
        ``P(q) = ⟨|T̂(q)|²⟩ / A_screen`` [µm²] with the coherent part removed
        (module notes); ``I(d) = P / λ²``.
    power_halves : ndarray (2, ...)
        The same from the even and odd realisations (a split-half estimate of
        the statistical error).
    transmittance : dict
        ``⟨mean t⟩`` per mode.
    coherent : dict
        Coherent weight ``⟨mean t⟩²`` per mode.
    diffuse_total : dict
        ``⟨mean t²⟩ - ⟨mean t⟩²`` per mode: the whole diffuse energy by
        Parseval (all ``q`` up to the grid's Nyquist limit).
    overlap_loss : float
        Fraction of the summed stamp mass ``Σ∫A_j`` removed by the clip
        ``t ≤ 1`` (0 without overlaps).
    pixel_transfer : str
        ``"ramp-deconvolved"`` (spectrum divided by ``sinc²(|q|h/2)``) or ``"none"``.
    positions : str
        Description of the position source.
    seconds : dict
        Wall time per stage.
    """
    mode: str
    material: str
    area_fraction: float
    area_fraction_screen: float
    length_scale: float
    grid: Grid
    realisations: int
    n_scatterers: float
    qx: np.ndarray
    qy: np.ndarray
    power: np.ndarray
    power_halves: np.ndarray
    transmittance: dict
    coherent: dict
    diffuse_total: dict
    overlap_loss: float
    pixel_transfer: str
    overlaps: str
    positions: str
    seconds: dict = field(default_factory=dict)

    @property
    def samples_per_radius(self) -> float:
        return self.length_scale / self.grid.h

    @property
    def coherent_weight(self) -> float:
        """Coherent (delta) weight of this mode: ``⟨mean t⟩²``."""
        return self.coherent[self.mode]

    @property
    def diffuse_weight(self) -> float:
        """Whole diffuse energy of this mode (Parseval), ``⟨mean t²⟩ - ⟨mean t⟩²``."""
        return self.diffuse_total[self.mode]

    def with_mode(self, mode: str) -> "BruteForce":
        """The same ensemble seen as the other screen (``1 - t``, same diffuse spectrum)."""
        check_choice("mode", mode, ("aperture", "particle"))
        out = copy.copy(self)
        out.mode = mode
        return out

    def q(self) -> np.ndarray:
        """Wave vectors (ny, nx, 2) [rad/µm] of :attr:`power`."""
        QX, QY = np.meshgrid(self.qx, self.qy, indexing="xy")
        return np.stack([QX, QY], -1)

    def u(self) -> np.ndarray:
        """Dimensionless ``u = q R`` (ny, nx, 2)."""
        return self.q() * self.length_scale

    def d(self, wavelength) -> np.ndarray:
        """Projected offsets ``d = q λ / 2π`` (ny, nx, 2) at ``wavelength`` [nm]."""
        lam = _lam_um(wavelength)
        return self.q() * (lam / (2.0 * np.pi))

    def d_cell(self, wavelength) -> float:
        """Area of one grid cell in the d plane: ``(λ/(nx hx)) (λ/(ny hy))``."""
        lam = _lam_um(wavelength)
        Lx, Ly = self.grid.box
        return lam * lam / (Lx * Ly)

    def lobe(self, wavelength) -> np.ndarray:
        """d-space intensity ``I(d) = ⟨|T̂(q)|²⟩ / (A_screen λ²)`` (ny, nx) at
        :meth:`d` (λ in nm), comparable with ``Material.lobe(d, λ)``."""
        lam = _lam_um(wavelength)
        return self.power / lam**2

    def is_dc(self) -> np.ndarray:
        """Boolean mask of the DC (q = 0) bin."""
        m = np.zeros(self.power.shape, dtype=bool)
        m[len(self.qy) // 2, len(self.qx) // 2] = True
        return m


def _lam_um(wavelength) -> float:
    lam = check_range("wavelength", wavelength, 0.0, math.inf, lo_open=True, hi_open=True, unit="nm")
    return lam * 1e-3


def _check_brute_force_args(material, realisations, n_scatterers, overlaps, max_grid, workers, q_max) -> tuple:
    """The checked arguments of :func:`brute_force`: (realisations, n_scatterers, max_grid, workers,
    q_max)."""
    from corona.model.material import Layer
    from corona.model.mie.material import SphereMaterial
    if not isinstance(material, Layer):
        raise CoronaError(f"material={material!r} is not a corona.Material")
    if isinstance(material, SphereMaterial):
        from corona.model import registry
        flat = ", ".join(f.name for f in registry.SHAPE_FAMILIES.values() if f.material is None)
        raise CoronaError(f"material={material!r} is out of range for the brute force: it sums the far "
                          f"fields of planar screens (Fraunhofer); allowed a flat layer ({flat})")
    M = int(check_range("realisations", realisations, 1, 1e7))
    n_sc = int(check_range("n_scatterers", n_scatterers, 1, 1e8))
    check_choice("overlaps", overlaps, _OVERLAPS)
    max_grid = int(check_range("max_grid", max_grid, 16, 65536))
    workers = (os.cpu_count() or 1) if workers is None else int(check_range("workers", workers, 1, 1024))
    if q_max is not None:
        q_max = check_range("q_max", q_max, 0.0, math.inf, lo_open=True, unit="rad/µm")
    return M, n_sc, max_grid, workers, q_max


def _spectrum_crop(grid: Grid, q_max: float | None) -> tuple[int, int]:
    """The kept spectrum's half sizes (Kx, Ky) in bins (all of the grid, or ``|q_x|, |q_y| ≤ q_max``);
    a :class:`CoronaError` if accumulating it would not fit in the available memory."""
    Lx, Ly = grid.box
    Kx, Ky = grid.nx // 2 - 1, grid.ny // 2 - 1
    if q_max is not None:
        Kx, Ky = min(Kx, int(math.ceil(q_max / (2 * np.pi / Lx)))), min(Ky, int(math.ceil(q_max / (2 * np.pi / Ly))))
    need = _memory_needed(grid, (2 * Ky + 1) * (Kx + 1))
    avail = _available_memory()
    if need > 0.6 * avail:
        raise CoronaError(f"grid={grid.nx}x{grid.ny} needs about {need / 2**30:.1f} GiB; only "
                          f"{avail / 2**30:.1f} GiB is available: use a smaller n_scatterers, "
                          "samples_per_radius or q_max")
    return Kx, Ky


@dataclass
class _ScreenSums:
    """Sums over the screens of a brute force: ``|T̂|²`` in the kept bins for even and odd screens
    (``acc``, ``count``), the screens' mean ``t``, mean ``t²`` and squared mean ``t``, the scatterers'
    stamped and rasterised areas, their number, and the seconds spent rasterising and in FFTs."""
    acc: np.ndarray
    count: np.ndarray = field(default_factory=lambda: np.zeros(2))
    t: float = 0.0
    t2: float = 0.0
    mean2: float = 0.0
    mass_stamps: float = 0.0
    mass_screen: float = 0.0
    n_total: int = 0
    seconds_rasterise: float = 0.0
    seconds_fft: float = 0.0


def _sum_screens(shape, source: PositionSource, M: int, grid: Grid, stretch, exact: bool, crop: tuple,
                 overlaps: str, workers: int, rng, desc: str, progress: bool) -> _ScreenSums:
    """Rasterise ``M`` screens of ``source``'s positions (stretched, randomly translated) and sum their
    power spectra in the ``crop`` = (Kx, Ky) bins and their moments (:class:`_ScreenSums`)."""
    from tqdm.auto import tqdm
    Kx, Ky = crop
    Lx, Ly = grid.box
    rows = np.r_[grid.ny - Ky:grid.ny, 0:Ky + 1]
    s = _ScreenSums(acc=np.zeros((2, 2 * Ky + 1, Kx + 1)))
    work = np.empty((grid.ny, grid.nx))
    for r in tqdm(range(M), desc=desc, unit="screen", disable=not progress, leave=False):
        ta = time.perf_counter()
        pts = np.asarray(source.draw(r, rng), dtype=np.float64)
        pts = pts * np.array(stretch) + rng.uniform(0.0, 1.0, 2) * np.array(grid.box)
        draws = _draw(shape, len(pts), rng)
        t = rasterise(shape, pts, grid, draws=draws, overlaps=overlaps, exact_masks=exact, out=work)
        s.n_total += len(pts)
        s.mass_stamps += float(np.sum(draws.scale**2 * np.array([lf.area for lf in draws.leaves])[draws.leaf]))
        m1 = float(t.mean())
        s.mass_screen += m1 * Lx * Ly
        s.t += m1
        s.t2 += float(np.mean(t * t))
        s.mean2 += m1 * m1
        t -= m1
        tb = time.perf_counter()
        F = sp_fft.rfft2(t, workers=workers)
        sub = F[rows, :Kx + 1]
        s.acc[r % 2] += sub.real**2 + sub.imag**2
        s.count[r % 2] += 1
        del F, sub
        s.seconds_rasterise += tb - ta
        s.seconds_fft += time.perf_counter() - tb
    return s


def _power_spectrum(s: _ScreenSums, M: int, grid: Grid, crop: tuple, ramp: bool) -> tuple:
    """(qx, qy, power, power of the even and of the odd screens) of the sums ``s``: both halves of the
    q plane, the DC bin the variance of the screens' mean over the screen's area, divided by the
    pixels' anti-aliasing transfer where ``ramp``."""
    Kx, Ky = crop
    Lx, Ly = grid.box
    norm = grid.hx * grid.hy / (grid.nx * grid.ny)         # |h² F|² / A_screen
    halves = np.stack([s.acc[k] / max(s.count[k], 1) for k in range(2)]) * norm
    right = (s.acc[0] + s.acc[1]) / M * norm
    full = np.concatenate([right[::-1, Kx:0:-1], right], axis=1)
    halves = np.stack([np.concatenate([hh[::-1, Kx:0:-1], hh], axis=1) for hh in halves])
    if s.count[1] == 0:
        halves[1] = halves[0]
    qx = np.arange(-Kx, Kx + 1) * (2 * np.pi / Lx)
    qy = np.arange(-Ky, Ky + 1) * (2 * np.pi / Ly)
    mean_t = s.t / M
    var_mean = max(s.mean2 / M - mean_t**2, 0.0)
    full[Ky, Kx] = Lx * Ly * var_mean
    halves[:, Ky, Kx] = Lx * Ly * var_mean
    if ramp:
        QX, QY = np.meshgrid(qx, qy, indexing="xy")
        Hq = np.sinc(np.hypot(QX, QY) * grid.h / (2 * np.pi)) ** 2
        full /= Hq
        halves /= Hq[None]
    return qx, qy, full, halves


def brute_force(material, *, realisations: int = 16, n_scatterers: int = N_SCATTERERS,
                samples_per_radius: float = SAMPLES_PER_RADIUS, q_max: float | None = None,
                seed: int = 0, overlaps: str = "clip", deconvolve: bool = True,
                max_grid: int = MAX_GRID, workers: int | None = None, progress: bool = True,
                source: PositionSource | None = None) -> BruteForce:
    """Average ``|T̂(q)|²`` over random screens of ``material`` (docs/physics.md#validation-figures).

    Parameters
    ----------
    material : corona.Material
        Shape, process and mode of the layer.
    realisations : int
        Number of screens ``M`` (≥ 1; a measured point set has one).
    n_scatterers : int
        Scatterers per screen (sets the box; default 2000, as the hard-disk
        table).  Hard-disk configurations are simulated on the fly.
    samples_per_radius : float
        Grid rule: pixel pitch ``h ≤ R / samples_per_radius``.
    q_max : float, optional
        Keep the spectrum for ``|q_x|, |q_y| ≤ q_max`` [rad/µm] only (default:
        the whole grid).
    seed : int
        Seed of every random choice (positions, shape draws, translations).
    overlaps : {"clip", "add"}
        How overlapping scatterers combine (module notes).
    deconvolve : bool
        Divide by the anti-aliasing transfer ``sinc²(|q| h/2)`` (analytic shapes).
    max_grid : int
        Largest accepted grid side (default 8192; 8192² needs ~1.5 GB).
    workers : int, optional
        FFT threads (default: all cores).
    progress : bool
        tqdm progress bars (positions and realisations).
    source : PositionSource, optional
        Pre-built positions (default :func:`positions_source`).

    Returns
    -------
    BruteForce
    """
    M, n_sc, max_grid, workers, q_max = _check_brute_force_args(material, realisations, n_scatterers, overlaps,
                                                                max_grid, workers, q_max)
    shape, process = material.shape, material.process
    t0 = time.perf_counter()
    if source is None:
        source = positions_source(process, shape, n_scatterers=n_sc, realisations=M, seed=seed,
                                  progress=progress)
    if source.realisations_max is not None:
        M = min(M, source.realisations_max)
    t_pos = time.perf_counter() - t0
    grid, stretch, exact = choose_grid(shape, source.box, samples_per_radius, max_grid)
    ramp = deconvolve and not any(isinstance(lf, Mask) for lf in _leaves_of(shape))
    crop = _spectrum_crop(grid, q_max)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    desc = f"brute force {type(shape).__name__} F_a={material.area_fraction:.3g}"
    sums = _sum_screens(shape, source, M, grid, stretch, exact, crop, overlaps, workers, rng, desc, progress)
    qx, qy, full, halves = _power_spectrum(sums, M, grid, crop, ramp)
    A_screen = grid.box[0] * grid.box[1]
    mean_t, mean_t2 = sums.t / M, sums.t2 / M
    trans = {"aperture": mean_t, "particle": 1.0 - mean_t}
    coherent = {k: v * v for k, v in trans.items()}
    diffuse = {"aperture": mean_t2 - mean_t**2,
               "particle": (1.0 - 2.0 * mean_t + mean_t2) - (1.0 - mean_t) ** 2}
    n_mean = sums.n_total / M
    fa_screen = n_mean * float(shape.area) / A_screen
    loss = 0.0 if sums.mass_stamps <= 0 else max(0.0, 1.0 - sums.mass_screen / sums.mass_stamps)
    return BruteForce(
        mode=material.mode, material=repr(material), area_fraction=material.area_fraction,
        area_fraction_screen=fa_screen, length_scale=material.length_scale, grid=grid,
        realisations=M, n_scatterers=n_mean, qx=qx, qy=qy, power=full, power_halves=halves,
        transmittance=trans, coherent=coherent, diffuse_total=diffuse, overlap_loss=loss,
        pixel_transfer="ramp-deconvolved" if ramp else "none", overlaps=overlaps,
        positions=source.description,
        seconds={"positions": t_pos, "rasterise": sums.seconds_rasterise, "fft": sums.seconds_fft,
                 "total": time.perf_counter() - t0})
