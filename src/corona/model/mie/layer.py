"""A layer of transparent spheres (Mie scatterers): the numpy reference BSDF (docs/physics.md#transparent-droplets-mie-spheres).

:class:`corona.Material` builds a :class:`SphereMaterial` when its shape is a
:class:`corona.Sphere` (or a size distribution of one).  The layer is a single
plane of spheres whose centres follow a 2D point process; every sphere
scatters by Mie theory (:mod:`corona.model.mie.theory`).

Model (per unit layer area; ``μ_i = |cos θi|``; λ the wavelength in air)
------------------------------------------------------------------------

* number density ``n = F_a / ⟨π r²⟩``;
* every direction ``wo`` on the sphere of directions is reached; its
  scattering angle Θ from the undeviated direction ``wt = -wi`` splits the
  pattern into a **forward lobe** (Θ < 90°, component 1) and a **backward
  lobe** (Θ >= 90°, component 2, the glory and the fogbow), each of which can
  fall on either side of the layer at oblique incidence;
* the smooth BSDF times the cosine is

      f |cos θo| = F_s · w · Z(Θ, λ),      Z = [P + C (S(q) - 1)]   (forward)
                                           Z = P                    (backward)

  with ``P = ⟨|S1|² + |S2|²⟩ / (2π ⟨x²⟩)`` and ``C = (|⟨S1⟩|² + |⟨S2⟩|²) / (2π ⟨x²⟩)``
  per steradian (``x = 2π r/λ``; ``C = P`` for one size), so that ``F_a P``
  is ``n dσ/dΩ`` and ``∫ P dΩ = Q_sca``; ``S(q)`` is the structure factor of
  the centres at the in-plane momentum transfer ``q = 2π |(wo + wi).xy| / λ``
  (decoupling rule, docs/physics.md#mixtures-and-size-distributions);
* on a fixed :class:`corona.Lattice` (a colloidal crystal, one size) ``S`` is the lattice's
  at the in-plane ``q = k (wo + wi)_xy`` (Bragg orders and the Debye–Waller background) and
  multiplies both lobes, ``Z = P S(q)``: transmitted and reflected orders
  (:meth:`SphereMaterial.lattice_nodes`, docs/physics.md#spheres-on-a-lattice);
* ``F_s = min(F_a / μ_i, 1)``: the spheres' shadow area per unit layer area
  along the beam (their cross-section does not shrink with the angle as a
  flat disk's does), saturated at full cover;
* the coherent beam is the mean transmitted field (optical theorem,
  van de Hulst §4.3): ``t = 1 - F_s s₀``, ``s₀ = 2⟨S(0)⟩/⟨x²⟩``, weight ``|t|²``
  (``(1 - F_a)²`` for large spheres at normal incidence, as opaque disks);
* ``w = min(1, (1 - |t|²) / (F_s (e_f + e_b)))`` caps the scattered energy
  (``e_f``, ``e_b``: the forward lobe with S and the backward lobe integrated
  at normal incidence) so that coherent + scattered never exceeds 1 (Poisson
  centres overlap, as for the flat shapes: docs/physics.md#lobe-weight-cap).

Tables (what the renderer evaluates and samples)
------------------------------------------------

Rows at size parameters ``x_j`` from ``2π r/830 nm`` to ``2π r/360 nm``: for one
size, rows ``ROW_DLNX`` apart in ``ln x``, halved where the lookup between two rows
misses Mie theory at the midpoint by more than ``ROW_TOLERANCE`` (so rows crowd
where the lobes change fastest in x: the resonances), up to ``MAX_ROWS``; for a
size distribution, rows ``σ x / 4`` apart, each the exact average of one shared
fine grid of sizes (:func:`build_mie_rows`).  In each row the forward ``P`` (and
``C``) on a uniform grid of the chord ``s = |wo - wt| = 2 sin(Θ/2)`` in ``[0, √2]``
(step ``CHORD_DX / x_max``; ``CHORD_DX_SPREAD / x_max`` for a size spread of at least
``SPREAD_COARSE_CHORD``, whose rings are smoothed)
(a sliver beyond) and the backward ``P`` on the chord ``s' = |wo - wi| = 2 cos(Θ/2)``
from the backscatter direction.  Since ``dΩ = s ds dφ`` exactly, each row is a
radial table in the chord (:class:`corona.model.tabulated.RadialTable`: density
``2π s P(s)``, exact CDF inversion) with the chord computed accurately in float32
as a vector norm.  A wavelength between two rows j, j+1 (weight t, linear in x)
reads each row at the chord scaled by ``x / x_row`` (the rings at a fixed ``x·s``
line up; :func:`_scaled_blend`), with Catmull–Rom cubics in the chord for the
value, and is sampled exactly by picking row j with probability
``(1 - t) T_j / ((1 - t) T_j + t T_j+1)`` (``T`` the rows' totals), drawing that
row's chord and scaling it: the pdf is the interpolated P over the interpolated
total, so sampling is proportional to the tabulated ``P``.
"""
from __future__ import annotations

import copy
import functools
import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from corona.model import tabulated   # the table types and the cache
from corona.model.mie import theory as mie
from corona._validation import CoronaError, check_choice, check_finite_array, check_range
from corona.model import registry
from corona.model.layer import decoupled_lobe
from corona.model.material import Material, MieMembers
from corona.model.processes import Lattice, Poisson, Process
from corona.model.shapes.modifiers import SizeDistribution
from corona.model.mie.sphere import Sphere, sphere_parts
from corona.model.substrate import BareLayer, GlassPane, Mirror, layer_substrate

#: Format of the sphere tables in the cache.
SPHERE_FORMAT = 3
#: One size: the rows start ``ROW_DLNX`` apart in ln x (x the size parameter; a lobe's sampler
#: reaches ``√2 x_j+1/x_j`` in the chord, a sliver past 90°), at most ``ROW_DX_START`` in x; an interval is halved (down to
#: ``ROW_DX_MIN`` in x) where the lookup between its rows misses Mie theory at its midpoint by more
#: than ``ROW_TOLERANCE`` (energy-weighted RMS of either lobe), up to ``MAX_ROWS`` rows.
ROW_DLNX = 0.001
ROW_DX_START = 0.1
ROW_DX_MIN = 0.005
#: A table still under ``MAX_ROWS`` after that goes on halving the intervals that stopped at
#: ``ROW_DX_MIN``, down to ``ROW_DX_FINE`` (narrow resonances of small spheres; a table that
#: reaches the cap spends no rows on them).
ROW_DX_FINE = 0.0015
ROW_TOLERANCE = 0.007
#: The midpoint test reads every ``ROW_TEST_STRIDE``-th chord node (an RMS over thousands of nodes,
#: a ring spans about 20).
ROW_TEST_STRIDE = 2
#: Chord step: ``ds <= CHORD_DX / x_max`` (about 25 nodes to the first Airy minimum).
CHORD_DX = 0.15
#: A size spread of at least ``SPREAD_COARSE_CHORD`` smooths the rings: chord step ``CHORD_DX_SPREAD / x_max``
#: (the lookup between the nodes then differs from the finer grid's by < 0.06 %, docs/mie.md).
CHORD_DX_SPREAD = 0.3
SPREAD_COARSE_CHORD = 0.1
MIN_NODES, MAX_NODES = 512, 8192
MIN_ROWS, MAX_ROWS = 8, 4096
CHORD_MAX = math.sqrt(2.0)
#: ``|cos θi|`` nodes (uniform, decreasing) of the forward lobe's energy with S(q).
INCIDENCE_MU = tuple(np.linspace(1.0, 0.0, 11))
#: The lobe weight's cap counts the lobes' energy this much larger: what the cap integrates
#: (rows, a grid of incidences, S averaged on a coarse grid) and what eval returns between rows
#: and incidences differ by up to 0.4 % (measured for dense hard disks at grazing light), and
#: the cap must not let a layer return more than it receives.
ENERGY_MARGIN = 1.006
#: Largest sphere radius [µm] the Mie tables take: the table of a 25 µm droplet (size parameter
#: up to 436) takes about a minute once (then it is cached); larger droplets' corona is the
#: Fraunhofer pattern of a disk of the same radius (shape=circle).
SPHERE_RADIUS_MAX = 25.0
#: The largest droplet a size distribution's tables hold [µm] (their build time: the size
#: grid's Mie series grow with the largest size parameter; docs/mie.md).
SPHERE_SIZES_MAX = 50.0
#: Precision of the angular products of the Mie sums (theory.AngularBasis).
ANGULAR_DTYPE = np.float32
#: Rows computed together (memory of the amplitudes: ROW_CHUNK x nodes complex values).
ROW_CHUNK = 128
#: The preview (:meth:`SphereMaterial.preview`): this many one-size rows, geometric in x over the
#: table's range, unrefined, on a chord grid of ``PREVIEW_CHORD_DX / x_max`` (at least
#: ``MIN_NODES``, at most ``PREVIEW_MAX_NODES`` nodes): a first look within about a second,
#: the size spread left out.
PREVIEW_ROWS = 48
PREVIEW_CHORD_DX = 0.3
PREVIEW_MAX_NODES = 2048
#: Sizes of a size distribution computed together: the recurrences of a batch of ``SIZE_BATCH`` (all
#: index nodes, fewer Python steps), the rest ``SIZE_CHUNK`` at a time (arrays that stay in the caches).
SIZE_BATCH = 1536
SIZE_CHUNK = 128
#: Size distributions: step of the fine grid of size parameters the rows average (at most), the
#: grid's steps per standard deviation of the sizes (at least), its most samples per index node,
#: the part of the scattered power ``s² p(s)`` beyond the largest droplet a table may hold, and the
#: largest change of the index between the index nodes of a dispersive sphere.
SIZE_DX = 0.06
#: Size distributions: rows ``σ x / 4`` apart in x (σ the spread), at least this (and at most 2).
SIZE_ROW_DX = 0.02
#: Size distributions: rows at most this fraction of x apart.  The rows are blended with the
#: chord scaled by ``x / x_j`` (rings at a fixed ``x·s`` line up), which moves what sits at a fixed
#: angle (the rainbow of the backward lobe, sharp for any spread) by the rows' relative step: at
#: 2 µm / 50 % water, rows 12 % apart were 1.9 % RMS off Mie theory between rows (docs/mie.md).
#: ``SIZE_ROW_RULE`` names the rule (relative steps) in the table key.
SIZE_ROW_DLNX = 0.02
SIZE_ROW_RULE = "relative"
SIZE_PER_SIGMA = 4.0
#: Size distributions: the sharp Mie resonances.  The size grid's local step at X is at most
#: ``max(SIZE_RES_DX · sqrt(σ X), σ X / SIZE_RES_PER_SIGMA)`` (σ the spread of ln s): a resonance
#: narrower than the step is sampled at random (aliased), and a narrow spread averages few of
#: them, so the step shrinks with the spread's width σ X in size parameter; from σ X of 6 on
#: ``SIZE_DX`` rules (the errors of many resonances average out).  On a grid 0.06 apart water's
#: 2 µm / 1 % rows were up to 6.8 % RMS (+3.6 % in total) off Mie theory in the backward lobe
#: (x = 34, 370 nm), 2 µm / 2 % 4.3 % at 360 nm; on this one 0.10 % and 0.30 % (the worst of
#: water's 1-5 % spreads at 2-7 µm 0.57 %; the errors are not monotonic in the step: a 1.4x
#: coarser linear term left 0.95 % at 5 µm / 3 %).  The grid is uniform in the coordinate u with
#: ``dX/du`` the step (:func:`_size_grid`); ``SIZE_STEP_RULE`` names the rule in the table key.
SIZE_RES_DX = 0.010
SIZE_RES_PER_SIGMA = 100.0
SIZE_STEP_RULE = "resonance"
MAX_SIZE_SAMPLES = 8000
#: ... and at most this many in all (every index node together; each node's count scaled down
#: alike above it): the index nodes that a narrow spread of large drops needs (``SIZE_DM_PHASE``)
#: share the budget of six nodes (water's at ``SIZE_DM``), so the slowest spread costs what it
#: did (25 µm / 0.1 %); spreads of 1 % and more stay below it (water 25 µm / 1 %: 43 513 sizes on
#: 14 nodes).
MAX_SIZE_TOTAL = 48000
SIZE_TAIL = 1e-6
#: Size distributions: the part of the scattered power ``s² p(s)`` left out at each end of the sizes
#: the rows average (``SIZE_TAIL`` stays the limit of the largest droplets, :func:`largest_sphere`).
#: 1e-4 instead of 1e-6 evaluates 16 % fewer sizes at 20 µm / 10 %; against a grid 4x finer with
#: tails at 1e-8 the backward rows move from 0.22 to 0.26 % off (worst row, docs/mie.md).
SIZE_TAIL_ROWS = 1e-4
SIZE_DM = 0.004
#: Size distributions of a dispersive sphere: the rows are Lagrange polynomials of this degree in
#: the index (its arc length) through the nearest index nodes (cubics on nodes 0.004 apart are as
#: close to dense nodes as lines on nodes 0.002 apart, with fewer nodes: docs/mie.md).
SIZE_INDEX_ORDER = 3
#: Size distributions of a dispersive sphere whose spread leaves the sizes' phases coherent: where
#: ``σ x_top < SIZE_DM_SMOOTH`` (σ the spread of ln s, x_top the largest size parameter) the index
#: nodes are at most ``SIZE_DM_PHASE / (2 x_top)`` apart.  The forward lobe holds the interference of
#: the diffracted and the transmitted light, a phase ``2 x (m - 1)`` whose rate in m is ``2x``; a
#: spread damps it by about ``exp(-(2 (m - 1) σ x)² / 2)`` (gone from σx ≈ 8), and a narrow one
#: leaves it, so the cubics in m need nodes closer than 0.004 at large x: water 20 µm / 1 % was
#: 1.1 % RMS off Mie theory in the forward lobe at 552 nm on nodes 0.004 apart, 0.17 % on nodes
#: 0.002 apart, and 0.04-0.11 % with a constant index (docs/mie.md).
SIZE_DM_PHASE = 1.4
SIZE_DM_SMOOTH = 8.0
#: Size distributions: the rows average Mie theory at fewer chords than the table's nodes, every node
#: while the node step is below ``SPREAD_CHORD_SMOOTH · σ · s`` (σ the spread, s the chord) and
#: geometric steps of that beyond (a spread of σ smears the pattern's fringes at the chord s over
#: ``σ s``); a cubic in the chord fills the nodes between (:func:`_spread_chord_nodes`; the
#: filled rows differ from rows on every node by less than the size grid's own error, docs/mie.md).
#: ``SPREAD_CHORD_RULE`` names the rule in the table key.
SPREAD_CHORD_SMOOTH = 0.1
SPREAD_CHORD_RULE = "geometric"
#: Why a size spread takes no fixed lattice (the one line of the refusal).
SPHERE_LATTICE_ONE_SIZE = ("the reflected Bragg orders need the coherent part |<S(Θ)>|² of the backward "
                           "amplitudes, which the tables of a size spread do not hold (a colloidal "
                           "crystal is of one size)")
#: Gauss–Legendre nodes per axis over ``±LATTICE_PEAK_REACH`` rms widths of a Bragg peak (the
#: energy of every order, :meth:`SphereMaterial.lattice_nodes`).
LATTICE_PEAK_NODES = 12
LATTICE_PEAK_REACH = 5.0
#: Orders whose window reaches past this ``|wo_xy|`` (near grazing exit) are integrated in the
#: polar angles of ``wo`` instead (twice the nodes in θ), which removes the ``1/|cos θo|``.
LATTICE_STEEP = 0.9
#: Azimuths of the quadrature of a jittered lattice's diffuse part (1 - e^{-q²δ²}) P.
LATTICE_DIFFUSE_PHI = 64
#: Rows serving a range of radii (``radius_cover``) hold the index at ``λ = 2π r/x`` of one radius r: read
#: at radius r' a dispersive index is that of ``λ r/r'``, a phase error ``2 x |Δm|`` on the rays through
#: the droplet.  It is kept below this [rad]: about 1 % of the forward peak (water, 2 µm, measured in
#: docs/layer.md#sphere-radius-textures); a constant index has none.
RADIUS_INDEX_PHASE = 0.07


def _grid(radius: float, radius_max: float, spread: float = 0.0, cover=None):
    """(x rows, chord step ds, number of chord nodes) for spheres of mean radius ``radius`` [µm].

    ``cover``: (r_lo, r_hi) [µm], the radii the rows serve (a radius texture): the rows run from
    ``2π r_lo/830 nm`` to ``2π r_hi/360 nm`` and the chord grid resolves ``radius_max r_hi / radius``;
    None: ``radius`` alone.

    One size: rows ``ROW_DLNX`` apart in ln x (at most ``ROW_DX_START`` in x), refined by
    :func:`_refine_rows`.  A size distribution of
    relative spread σ smears the pattern over ``σ x`` in size parameter: its rows are
    ``min(2, σ x / 4, SIZE_ROW_DLNX x)`` apart at x (at least ``SIZE_ROW_DX``; what sits at a fixed
    angle, the rainbow, is not smeared).  The chord grid runs to
    ``√2 x_1 / x_0`` (a little past Θ = 90°): a row is read at the chord scaled by ``x / x_j``
    (see :func:`_scaled_blend`), up to ``√2 x_j+1 / x_j`` for the wavelengths above it."""
    lam_lo, lam_hi = tabulated.WAVELENGTH_MIN * 1e-3, tabulated.WAVELENGTH_MAX * 1e-3
    r_lo, r_hi = (radius, radius) if cover is None else cover
    x_lo, x_hi = 2 * np.pi * r_lo / lam_hi, 2 * np.pi * r_hi / lam_lo
    if spread == 0.0:
        # ROW_DLNX apart in ln x up to x_b = ROW_DX_START / ROW_DLNX, ROW_DX_START apart above
        x_b = min(max(ROW_DX_START / ROW_DLNX, x_lo), x_hi)
        n_log = max(int(math.ceil(math.log(x_b / x_lo) / ROW_DLNX)) + 1, 2)
        n_lin = int(math.ceil((x_hi - x_b) / ROW_DX_START)) + 1
        x_rows = np.geomspace(x_lo, x_b, n_log) if x_b > x_lo else np.array([x_lo])
        if x_hi > x_b:
            x_rows = np.concatenate([x_rows, np.linspace(x_b, x_hi, max(n_lin, 2))[1:]])
        if x_rows.size < MIN_ROWS:
            x_rows = np.geomspace(x_lo, x_hi, MIN_ROWS)
    else:
        # the step at x: min(σ/4, SIZE_ROW_DLNX) x, within [SIZE_ROW_DX, 2]; rows uniform in the
        # coordinate g with dg/dx = 1 / step(x) (geometric where the relative step rules)
        xf = np.geomspace(x_lo, x_hi, 4097) if x_hi > x_lo else np.array([x_lo, x_lo * (1 + 1e-9)])
        step = np.clip(min(0.25 * spread, SIZE_ROW_DLNX) * xf, SIZE_ROW_DX, 2.0)
        g = np.concatenate([[0.0], np.cumsum(0.5 * (1 / step[1:] + 1 / step[:-1]) * np.diff(xf))])
        n_rows = int(np.clip(math.ceil(g[-1]) + 1, MIN_ROWS, MAX_ROWS))
        x_rows = np.interp(np.linspace(0.0, g[-1], n_rows), g, xf)
        x_rows[[0, -1]] = x_lo, x_hi
    x_top = 2 * np.pi * radius_max * (r_hi / radius) / lam_lo
    s_max = min(2.0, CHORD_MAX * x_rows[1] / x_rows[0] * (1.0 + 1e-9))
    chord_dx = CHORD_DX_SPREAD if spread >= SPREAD_COARSE_CHORD else CHORD_DX
    n_nodes = int(np.clip(math.ceil(s_max * x_top / chord_dx) + 1, MIN_NODES, MAX_NODES))
    return x_rows, s_max / (n_nodes - 1), n_nodes


def index_phase_error(sphere: Sphere, r_lo: float, r_hi: float) -> float:
    """Largest phase error ``2 x |m(λ r/r') - m(λ)|`` [rad] over 360–830 nm and ``r' ∈ {r_lo, r_hi}`` of
    rows holding the index of ``sphere`` (radius r) read at radius r' (``x = 2π r'/λ``); 0 for a
    constant index."""
    lam = np.linspace(tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX, 95)
    r = float(sphere.radius)
    out = 0.0
    for rp in (float(r_lo), float(r_hi)):
        dm = np.abs(sphere.index(lam * r / rp) - sphere.index(lam))
        out = max(out, float(np.max(2.0 * (2 * np.pi * rp / (lam * 1e-3)) * dm)))
    return out


def share_forward_energies(layers) -> None:
    """Let sphere layers of one set of rows (the same spheres; hard cores of other F_a, as the
    plugin's F_a rows) compute their forward energies with ``S(q)`` together: the first of them to
    derive its tables computes those of the others not derived yet in the same pass over the rows
    (the chord nodes' weights are the rows'; only ⟨S⟩_φ differs), and they take theirs when they
    derive (a cached one is read as before)."""
    layers = list(layers)
    for m in layers:
        m.__dict__["_energy_peers"] = layers


def radius_span(sphere: Sphere, most: float) -> float:
    """The largest factor ``f <= most`` with rows of ``sphere`` serving ``[r/f, r f]`` within
    ``RADIUS_INDEX_PHASE`` (:func:`index_phase_error`; bisection)."""
    r = float(sphere.radius)
    if index_phase_error(sphere, r / most, r * most) <= RADIUS_INDEX_PHASE:
        return float(most)
    lo, hi = 1.0, float(most)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if index_phase_error(sphere, r / mid, r * mid) <= RADIUS_INDEX_PHASE else (lo, mid)
    return lo


def _size_quadrature(sizes, tail: float = SIZE_TAIL):
    """Density of ``y = ln s`` of a size distribution on a fine grid, trimmed to where the
    scattered power lives: (y grid, density) holding all but ``tail`` of ``s² p(s)`` at each
    end, normalised in number."""
    y = np.linspace(sizes._y_lo, sizes._y_hi, 20001)
    p = np.exp(sizes._logpdf(y))
    power = np.cumsum(p * np.exp(2 * y))
    power /= power[-1]
    lo = max(int(np.searchsorted(power, tail)) - 1, 0)
    hi = min(int(np.searchsorted(power, 1.0 - tail)) + 1, y.size - 1)
    return y[lo:hi + 1], p[lo:hi + 1]


def largest_sphere(radius: float, spread: float, distribution: str = "lognormal") -> float:
    """The largest radius [µm] a size distribution's tables hold: the top of the sizes holding all
    but ``SIZE_TAIL`` of the scattered power ``s² p(s)`` (:func:`_size_quadrature`).

    >>> round(largest_sphere(20.0, 0.1), 1) < SPHERE_SIZES_MAX < round(largest_sphere(25.0, 0.5))
    True
    """
    if spread <= 0:
        return float(radius)
    sizes = SizeDistribution(Sphere(radius), spread, distribution=distribution)
    return float(radius * math.exp(_size_quadrature(sizes)[0][-1]))


def largest_spread(radius: float, distribution: str = "lognormal") -> float:
    """The largest size spread whose droplets stay within ``SPHERE_SIZES_MAX`` at mean radius
    ``radius`` [µm] (bisection on :func:`largest_sphere`; 0 when ``radius`` itself is too big)."""
    if largest_sphere(radius, 1e-3, distribution) > SPHERE_SIZES_MAX:
        return 0.0
    lo, hi = 1e-3, 0.5
    if largest_sphere(radius, hi, distribution) <= SPHERE_SIZES_MAX:
        return hi
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if largest_sphere(radius, mid, distribution) <= SPHERE_SIZES_MAX else (lo, mid)
    return lo


def _mono_sums(m, X, basis, amplitudes=False):
    """|S|² forward and backward, S(0) and the efficiencies' sums of the spheres (m, X) (arrays
    (B,)) on the nodes of ``basis``; with ``amplitudes`` the forward S1, S2 as rows [Re; Im]."""
    a, b = mie.coefficients(m, X)
    N = a.shape[-1]
    n = np.arange(1, N + 1)
    S1f, S2f, S1b, S2b = mie._both_ways_parts(m, X, basis, (a, b))          # rows [Re; Im]
    B = X.size
    sq = lambda v: v[:B] * v[:B] + v[B:] * v[B:]
    out = {"P_f": sq(S1f) + sq(S2f), "P_b": sq(S1b) + sq(S2b),
           "s0": 0.5 * np.sum((2 * n + 1) * (a + b), axis=-1),
           "q_sca": 2 * np.sum((2 * n + 1) * (np.abs(a) ** 2 + np.abs(b) ** 2), axis=-1),
           "q_ext": 2 * np.sum((2 * n + 1) * (a + b).real, axis=-1)}
    if amplitudes:
        out["A1"], out["A2"] = S1f, S2f
    return out


#: Elements per block of :func:`_blend_rows` (its working arrays stay in the caches).
BLEND_BLOCK = 1 << 13


def _blend_rows(lobes, ja, jb, xa, xb, x, ds, stride: int = 1):
    """The lookup's value between two rows (:func:`_scaled_blend`, Catmull–Rom) at the weight of
    ``x`` between ``xa`` and ``xb``, on every ``stride``-th chord node, for several lobes at once,
    read in place: ``lobes`` arrays (R, K) of rows, ``ja``, ``jb`` (n,) the two rows of each pair in
    them, ``xa``, ``xb``, ``x`` (n,); one list of arrays (n, K / stride).

    In blocks of pairs that stay in the caches; the nodes each pair reads (the scaled chord, its
    interval and weight) are found once for all the lobes, and the end nodes repeated past a row's
    ends come from clamped indices (at the first interval ``max(k - 1, row start) = k``, at the last
    ``min(k + 2, row end) = k + 1``)."""
    K = lobes[0].shape[1]
    node = np.arange(0, K, stride, dtype=np.float64)
    n = np.shape(x)[0]
    out = [np.empty((n, node.size)) for _ in lobes]
    flats = [P.reshape(-1) for P in lobes]
    ja, jb = np.asarray(ja, dtype=np.int64), np.asarray(jb, dtype=np.int64)
    step = max(1, BLEND_BLOCK // node.size)
    for r0 in range(0, n, step):
        r = slice(r0, min(r0 + step, n))
        t = ((x[r] - xa[r]) / (xb[r] - xa[r]))[:, None]
        acc = [0.0] * len(lobes)
        for j, xr, wgt in ((ja[r], xa[r], 1.0 - t), (jb[r], xb[r], t)):
            c = (xr / x[r])[:, None]
            g = node[None, :] / c                      # the node read at the chord scaled by x / x_row
            i = np.minimum(g.astype(np.int64), K - 2)  # g >= 0: truncation is the floor
            f = np.minimum(g - i, 1.0)
            inside = g <= K - 1
            cc = c * c
            base = (j * K)[:, None]
            k = base + i
            k0 = np.maximum(k - 1, base)
            k3 = np.minimum(k + 2, base + K - 1)
            k2 = k + 1
            for m, flat in enumerate(flats):
                p0, p1, p2, p3 = flat[k0], flat[k], flat[k2], flat[k3]
                v = p1 + 0.5 * f * (p2 - p0 + f * (2 * p0 - 5 * p1 + 4 * p2 - p3 + f * (3 * (p1 - p2) + p3 - p0)))
                acc[m] = acc[m] + wgt * np.where(inside, np.maximum(v, 0.0), 0.0) / cc
        for m in range(len(lobes)):
            out[m][r] = acc[m]
    return out


def _lobe_error(est, ref, ds):
    """Energy-weighted RMS of ``est/ref - 1`` per row over the chord nodes up to √2 (weights
    ``ref · s``, as ``dΩ = s ds dφ``)."""
    s = np.arange(ref.shape[1]) * ds
    w = ref * np.where(s <= CHORD_MAX, s, 0.0)[None, :]
    ok = ref > 0
    rel = np.where(ok, est / np.where(ok, ref, 1.0) - 1.0, 0.0)
    return np.sqrt(np.sum(w * rel * rel, axis=1) / np.maximum(np.sum(w, axis=1), 1e-300))


def _refine_rows(sphere, rows: dict, basis, ds, bar=None) -> dict:
    """Halve the row intervals of a one-size table where the lookup between two rows misses Mie
    theory at the midpoint by more than ``ROW_TOLERANCE`` (energy-weighted RMS, either lobe),
    down to ``ROW_DX_MIN``: best first (the largest misses, at any depth), in batches of
    ``ROW_CHUNK``, up to ``MAX_ROWS`` rows; then, while under ``MAX_ROWS``, the halves that
    stopped at ``ROW_DX_MIN`` (of intervals that missed) the same way down to ``ROW_DX_FINE``.

    ``rows``: per-row arrays keyed like :func:`_evaluate_rows`, normalised (P per steradian).
    Returns the same keys with the new rows, in increasing ``x``."""
    n0 = rows["x"].size
    # every row kept and every midpoint still pending lives in one store, reserved for the cap and
    # a batch's midpoints (memory is touched only where written; grown by doubling beyond)
    store = {k: np.empty((max(2 * n0, MAX_ROWS + 2 * ROW_CHUNK),) + np.shape(v)[1:], np.asarray(v).dtype)
             for k, v in rows.items()}
    used = 0

    def put(new):
        nonlocal store, used
        n = new["x"].size
        if used + n > store["x"].shape[0]:
            size = max(2 * store["x"].shape[0], used + n)
            for k, v in store.items():
                grown = np.empty((size,) + v.shape[1:], v.dtype)
                grown[:used] = v[:used]
                store[k] = grown
        for k, v in new.items():
            store[k][used:used + n] = v
        used += n
        return np.arange(used - n, used)

    def candidates(pairs, halves=True):
        """Midpoints of the intervals ``pairs`` (n, 2) of store indices: the intervals that
        miss, their midpoints' store indices and their errors.  ``halves``: the intervals are
        halves of intervals that missed (those too narrow to halve are kept for the fine pass)."""
        xa, xb = store["x"][pairs[:, 0]], store["x"][pairs[:, 1]]
        keep = (xb - xa) > 2.0 * dx_min * (1 - 1e-9)
        if halves:
            blocked.append(pairs[~keep & ((xb - xa) > 2.0 * ROW_DX_FINE * (1 - 1e-9))])
        pairs, xa, xb = pairs[keep], xa[keep], xb[keep]
        if not pairs.size:
            return pairs, np.zeros(0, np.int64), np.zeros(0)
        xm = 0.5 * (xa + xb)
        # the lookup's estimate from the stored rows on a second thread while this one evaluates
        # Mie theory at the midpoints (numpy releases the GIL: the two overlap on two cores)
        blend = pool.submit(_blend_rows, [store[key] for key in ("P_f", "P_b")], pairs[:, 0], pairs[:, 1],
                            xa, xb, xm, ds, ROW_TEST_STRIDE)
        new = _evaluate_rows(sphere, xm, basis)
        ests = blend.result()
        err = np.zeros(xm.size)
        for key, est in zip(("P_f", "P_b"), ests):
            err = np.maximum(err, _lobe_error(est, new[key][:, ::ROW_TEST_STRIDE], ds * ROW_TEST_STRIDE))
        if bar is not None:
            if bar.total is not None and bar.n + xm.size >= bar.total:   # past the estimate: no bar
                bar.total = bar.n + xm.size + 1                            # without a total meanwhile
            bar.update(xm.size)
        bad = err > ROW_TOLERANCE
        return pairs[bad], put({k: v[bad] for k, v in new.items()}), err[bad]

    def estimate(n_kept, pending):
        """The bar's total: what is evaluated, plus two midpoints for each interval that missed
        (kept up to the cap; the finer pass adds more when it runs: the total grows then)."""
        if bar is not None:
            bar.total = max(bar.n + 1, bar.n + 2 * min(pending, MAX_ROWS - n_kept))
            bar.refresh()

    with ThreadPoolExecutor(max_workers=1) as pool:   # (candidates' second thread)
        kept = [put(rows)]
        n_kept = n0
        dx_min, blocked = ROW_DX_MIN, []
        pend_pairs, pend_mid, pend_err = candidates(np.stack([np.arange(n0 - 1), np.arange(1, n0)], -1), False)
        while n_kept < MAX_ROWS:
            estimate(n_kept, pend_err.size)
            if not pend_err.size:
                if dx_min == ROW_DX_FINE:
                    break
                # under the cap: the intervals stopped at ROW_DX_MIN, down to ROW_DX_FINE
                dx_min, stopped, blocked = ROW_DX_FINE, np.concatenate(blocked + [np.zeros((0, 2), np.int64)]), []
                pend_pairs, pend_mid, pend_err = candidates(stopped)
                continue
            take = np.argsort(-pend_err)[:min(ROW_CHUNK, MAX_ROWS - n_kept)]
            rest = np.setdiff1d(np.arange(pend_err.size), take)
            idx = pend_mid[take]
            kept.append(idx)
            n_kept += idx.size
            children = np.concatenate([np.stack([pend_pairs[take, 0], idx], -1),
                                       np.stack([idx, pend_pairs[take, 1]], -1)])
            c_pairs, c_mid, c_err = candidates(children)
            pend_pairs = np.concatenate([pend_pairs[rest], c_pairs])
            pend_mid = np.concatenate([pend_mid[rest], c_mid])
            pend_err = np.concatenate([pend_err[rest], c_err])
    if bar is not None:
        bar.total = bar.n
        bar.refresh()
    kept = np.concatenate(kept)
    kept = kept[np.argsort(store["x"][kept])]
    # the kept rows moved to the front of the store in increasing x, in place: a sorted copy of
    # the table would be as much fresh memory again, paid for page by page on a cold load
    # (0.1-0.2 s at 8 µm); the rows returned are the store's first rows
    _gather_rows_in_place(list(store.values()), np.concatenate(
        [kept, np.setdiff1d(np.arange(used), kept, assume_unique=True)]))
    return {k: v[:kept.size] for k, v in store.items()}


def _gather_rows_in_place(arrays, src):
    """``a[i] = a[src[i]]`` for ``i < len(src)`` in each of ``arrays`` (rows along the first axis),
    ``src`` a permutation of ``range(len(src))``: the permutation's cycles followed once, one row
    of scratch per array, no copy of the arrays."""
    src = np.asarray(src, dtype=np.int64)
    done = src == np.arange(src.size)
    tmp = [np.empty(a.shape[1:], a.dtype) for a in arrays]
    for start in np.flatnonzero(~done):
        if done[start]:
            continue
        for a, t in zip(arrays, tmp):
            t[...] = a[start]
        i = start
        while True:
            j = src[i]
            done[i] = True
            if j == start:
                for a, t in zip(arrays, tmp):
                    a[i] = t
                break
            for a in arrays:
                a[i] = a[j]
            i = j


def _evaluate_rows(sphere, x, basis) -> dict:
    """One-size rows at the size parameters ``x`` of the sphere (index at ``λ = 2π r / x``):
    P_f, P_b per steradian, S(0) and the efficiencies per ``π r²`` (:func:`_mono_sums`)."""
    lam = 2 * np.pi * sphere.radius / x * 1e3
    m = np.asarray(sphere.index(lam), dtype=np.complex128) * np.ones(x.size)
    parts = []
    for a0 in range(0, x.size, ROW_CHUNK):
        c = slice(a0, min(a0 + ROW_CHUNK, x.size))
        parts.append(_mono_sums(m[c], x[c], basis))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    x2 = x * x
    out["P_f"] = out["P_f"] / (2 * np.pi * x2[:, None])
    out["P_b"] = out["P_b"] / (2 * np.pi * x2[:, None])
    out["s0"] = np.stack([2 * out["s0"].real / x2, 2 * out["s0"].imag / x2], -1)
    out["q_sca"] = out["q_sca"] / x2
    out["q_ext"] = out["q_ext"] / x2
    out["x"] = x
    return out


def build_mie_rows(sphere: Sphere, sizes=None, radius_cover=None) -> dict:
    """The Mie tables of a sphere (optionally a size distribution of it) over wavelength rows.

    ``radius_cover``: (r_lo, r_hi) [µm], the rows reach the size parameters of those radii over
    the wavelength range (a radius texture, :class:`SphereMaterial`); row x holds the sphere's
    index at ``λ = 2π r / x`` (``r = sphere.radius``).

    One sphere: each row is Mie theory at its size parameter.  A size distribution: the rows
    share the evaluations of one fine grid of size parameters ``X`` (step ``SIZE_DX`` or finer,
    finer still where a narrow spread needs the sharp resonances resolved: :func:`_size_step`,
    :func:`_size_grid`); row j (mean size ``x_j``, index ``m_j``) is the quadrature
    ``Σ_k W_jk F(X_k)`` with ``W_jk ∝ p_y(ln(X_k/x_j)) ΔX_k/X_k`` (a convolution in ``ln x``; the
    trapezoid in X).  A dispersive index is handled by evaluating the grid at index nodes
    ``m(λ_q)`` at most ``SIZE_DM`` apart and interpolating the rows between them in the index
    (Lagrange cubics in its arc length, ``SIZE_INDEX_ORDER``; :func:`_size_plan`).
    The sizes are evaluated on a subset of the chord nodes (:func:`_spread_chord_nodes`; the
    average is smooth in the chord where the spread smears the fringes) and the rows filled in
    between (:func:`_fill_chord`).

    Returns
    -------
    dict of arrays
        ``x`` (J,) size parameters of the mean sphere, ``wavelength`` (J,) [nm],
        ``ds`` chord step, ``P_f``, ``C_f``, ``P_b`` (J, K) per steradian
        (``C_f`` empty for one size), ``s0`` (J, 2) real and imaginary part of
        ``2⟨S(0)⟩/⟨x²⟩``, ``q_sca``, ``q_ext`` (J,) efficiencies per ``⟨π r²⟩``.
    """
    from tqdm import tqdm

    r = sphere.radius
    spread = 0.0 if sizes is None else float(sizes.spread)
    if sizes is not None and spread > 0.0:
        yq, pq = _size_quadrature(sizes, SIZE_TAIL_ROWS)
        s_lo, s_hi = math.exp(yq[0]), math.exp(yq[-1])
    else:
        sizes, s_lo, s_hi = None, 1.0, 1.0
    # chord resolution for the radii that carry the light (mean + 3 std); the rare larger
    # droplets' forward peaks are narrower than the grid and get smoothed
    x_rows, ds, K = _grid(r, r * min(s_hi, 1.0 + 3.0 * spread), spread, radius_cover)
    lam = 2 * np.pi * r / x_rows * 1e3                                    # nm
    chord = np.arange(K) * ds
    mu = 1.0 - 0.5 * chord * chord                                        # cos Θ of the forward nodes
    J = x_rows.size
    x_top = float(x_rows[-1]) * s_hi
    # the angular products in single precision: |S|² to about 1e-6 (AngularBasis), twice as fast
    if sizes is None:
        basis = mie.AngularBasis(mu, int(mie.n_terms(x_top)), ANGULAR_DTYPE)
        # the total: the first rows and their midpoints, then re-estimated as the refinement goes
        with tqdm(total=2 * J, unit="row", leave=False, delay=tabulated.PROGRESS_DELAY,
                  desc=f"corona: building the Mie sphere table ({r:g} µm)") as bar:
            rows = _evaluate_rows(sphere, x_rows, basis)
            bar.update(J)
            rows = _refine_rows(sphere, rows, basis, ds, bar)
        x_rows = rows["x"]
        return {"x": x_rows, "wavelength": 2 * np.pi * r / x_rows * 1e3, "ds": np.array(ds),
                "P_f": rows["P_f"], "P_b": rows["P_b"], "C_f": np.zeros((0, K)), "s0": rows["s0"],
                "q_sca": rows["q_sca"], "q_ext": rows["q_ext"]}
    # the size average is smooth in the chord beyond the first fringes: Mie theory on a subset of
    # the nodes, a cubic in the chord between them
    nodes = _spread_chord_nodes(K, ds, spread)
    s_e = nodes * ds
    basis = mie.AngularBasis(1.0 - 0.5 * s_e * s_e, int(mie.n_terms(x_top)), ANGULAR_DTYPE)
    Ke = nodes.size
    plan = _size_plan(sphere, x_rows, lam, yq, pq, s_lo, s_hi)
    total = sum(p[3].size for p in plan)
    with tqdm(total=total, unit="size", leave=False, delay=tabulated.PROGRESS_DELAY,
              desc=f"corona: building the Mie sphere table ({r:g} µm, {spread:.0%} spread)") as bar:
        acc, s0, q_sca, q_ext, x2 = _average_sizes(plan, basis, J, Ke, bar)
    norm = 1.0 / (2 * np.pi * x2[:, None])
    P_f, P_b = acc[0] * norm, acc[1] * norm
    C_f = (acc[2] ** 2 + acc[3] ** 2 + acc[4] ** 2 + acc[5] ** 2) * norm
    P_f, C_f, P_b = _fill_chord(nodes, K, P_f, C_f, P_b)
    return {"x": x_rows, "wavelength": lam, "ds": np.array(ds),
            "P_f": P_f, "P_b": P_b, "C_f": C_f,
            "s0": np.stack([2 * s0.real / x2, 2 * s0.imag / x2], -1),
            "q_sca": q_sca / x2, "q_ext": q_ext / x2}


def build_preview_rows(sphere: Sphere, radius_cover=None) -> dict:
    """Coarse one-size Mie rows of ``sphere`` for a preview: :data:`PREVIEW_ROWS` rows geometric in
    x over the wavelength range (and the radii of ``radius_cover``), no refinement, a chord grid of
    ``PREVIEW_CHORD_DX / x_max``.  The keys and units of :func:`build_mie_rows` (one size)."""
    r = sphere.radius
    lam_lo, lam_hi = tabulated.WAVELENGTH_MIN * 1e-3, tabulated.WAVELENGTH_MAX * 1e-3
    r_lo, r_hi = (r, r) if radius_cover is None else radius_cover
    x_rows = np.geomspace(2 * np.pi * r_lo / lam_hi, 2 * np.pi * r_hi / lam_lo, PREVIEW_ROWS)
    s_max = min(2.0, CHORD_MAX * x_rows[1] / x_rows[0] * (1.0 + 1e-9))
    K = int(np.clip(math.ceil(s_max * x_rows[-1] / PREVIEW_CHORD_DX) + 1, MIN_NODES, PREVIEW_MAX_NODES))
    ds = s_max / (K - 1)
    chord = np.arange(K) * ds
    basis = mie.AngularBasis(1.0 - 0.5 * chord * chord, int(mie.n_terms(float(x_rows[-1]))), ANGULAR_DTYPE)
    rows = _evaluate_rows(sphere, x_rows, basis)
    return {"x": x_rows, "wavelength": 2 * np.pi * r / x_rows * 1e3, "ds": np.array(ds),
            "P_f": rows["P_f"], "P_b": rows["P_b"], "C_f": np.zeros((0, K)), "s0": rows["s0"],
            "q_sca": rows["q_sca"], "q_ext": rows["q_ext"]}


def _average_sizes(plan, basis, J: int, Ke: int, bar=None):
    """The sums ``Σ_q w_jq Σ_k W_jk F(X_k, m_q)`` of a size distribution's rows over the plan's
    evaluations (:func:`_size_plan`): F is ``|S|²`` forward and backward, the forward ``S1``, ``S2``
    ([Re; Im]), ``S(0)``, the efficiencies' sums and ``x²`` (:func:`theory._power_both_ways`).

    The evaluations of every index node are taken together in order of size, ``SIZE_BATCH`` at a
    time: the recurrences of the Riccati–Bessel functions and of ``D_n`` run once for a batch (fewer
    Python steps), the rest ``SIZE_CHUNK`` sizes of one node at a time, each added to the rows whose
    weights reach it.

    Returns
    -------
    acc : ndarray (6, J, Ke)
        ``P_f``, ``P_b``, ``Re S1``, ``Im S1``, ``Re S2``, ``Im S2`` (forward) sums.
    s0 : complex ndarray (J,); q_sca, q_ext, x2 : ndarrays (J,)
    """
    acc = np.zeros((6, J, Ke))
    s0 = np.zeros(J, complex)
    q_sca, q_ext, x2 = np.zeros(J), np.zeros(J), np.zeros(J)
    # each node's rows reach the sizes [first, last] of its grid (the rows ascend in x)
    reach = []
    for rows_q, _, _, _, W in plan:
        nz = W > 0.0
        first = np.argmax(nz, axis=1)
        last = W.shape[1] - 1 - np.argmax(nz[:, ::-1], axis=1)
        monotone = bool(np.all(np.diff(first) >= 0) and np.all(np.diff(last) >= 0))
        reach.append((first, last) if monotone else None)
    node = np.concatenate([np.full(p[3].size, q) for q, p in enumerate(plan)])
    index = np.concatenate([np.arange(p[3].size) for p in plan])
    X_all = np.concatenate([p[3] for p in plan])
    m_node = np.array([p[2] for p in plan], dtype=np.complex128)
    order = np.argsort(X_all, kind="stable")
    work = {}                                                       # scratch arrays, reused
    for b0 in range(0, order.size, SIZE_BATCH):
        sel = order[b0:b0 + SIZE_BATCH]
        sel = sel[np.lexsort((index[sel], node[sel]))]          # by node, then size
        X, q_b, k_b = X_all[sel], node[sel], index[sel]
        m = m_node[q_b]
        N = int(mie.n_terms(X.max()))
        with np.errstate(over="ignore", invalid="ignore"):     # terms past a size's own N may overflow
            psi, chi = mie._riccati_bessel(X, N, by_order=True)
        D = mie._log_derivative(m * X, N)
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(q_b)) + 1, [X.size]])
        for g0, g1 in zip(cuts[:-1], cuts[1:]):
            q = int(q_b[g0])
            rows_q, node_w, _, _, W = plan[q]
            for c0 in range(g0, g1, SIZE_CHUNK):
                c = slice(c0, min(c0 + SIZE_CHUNK, g1))
                ka, kb = int(k_b[c.start]), int(k_b[c.stop - 1]) + 1     # the node's sizes [ka, kb)
                if kb - ka != c.stop - c.start:
                    raise AssertionError("a batch holds a node's sizes out of order")
                n = int(mie.n_terms(X[c].max())) + 1
                R, s0_c, qs_c, qe_c = mie._power_both_ways(m[c], X[c], basis, psi[:n, c], chi[:n, c], D[:n, c],
                                                           work)
                if reach[q] is None:
                    r = slice(0, rows_q.size)
                else:
                    first, last = reach[q]
                    r = slice(int(np.searchsorted(last, ka)), int(np.searchsorted(first, kb)))
                rows = rows_q[r]
                if rows.size == 0:
                    continue
                if rows[-1] - rows[0] == rows.size - 1:
                    rows = slice(int(rows[0]), int(rows[-1]) + 1)
                G = (W[r, ka:kb] * node_w[r, None]).astype(ANGULAR_DTYPE)   # (rows, sizes)
                acc[:, rows] += np.matmul(G, R, out=mie._work(work, "GR", (6, G.shape[0], R.shape[2]), R.dtype))
                s0[rows] += G @ s0_c
                q_sca[rows] += G @ qs_c
                q_ext[rows] += G @ qe_c
                x2[rows] += G @ (X[c] ** 2)
        if bar is not None:
            bar.update(X.size)
    return acc, s0, q_sca, q_ext, x2


def _spread_chord_nodes(K: int, ds: float, spread: float) -> np.ndarray:
    """Chord positions, in steps ``ds`` (``s = p ds``, ``0 <= p <= K - 1``), at which a size
    distribution's rows are evaluated: every node up to ``p_0 = ceil(1 / (SPREAD_CHORD_SMOOTH σ))``
    (σ the spread), then a geometric sequence of ratio at most ``1 + SPREAD_CHORD_SMOOTH σ`` (steps
    of at most ``SPREAD_CHORD_SMOOTH σ s``, between the nodes of the table's grid) ending at the last
    node ``K - 1``.

    A spread σ of the sizes smears a fringe of phase ``x φ(s)`` (φ ∝ s near the forward and the
    backward direction) over ``σ x φ``: what survives at the chord s has a period of ``~2π σ s``
    or more (amplitude ``e^{-1/2}``; ``π σ s``: ``e^{-2}``), some 60 (30) steps of ``0.1 σ s``.
    (Until 2026-12-03 the steps were whole nodes, ``floor(SPREAD_CHORD_SMOOTH σ s / ds)``, as
    little as half the allowed step: 465 positions instead of 411 at 20 µm / 10 %.)

    >>> p = _spread_chord_nodes(2169, 0.3 / 453, 0.1)      # 20 µm, 10 %: x up to 453
    >>> int(p.size), bool(np.all(np.diff(p)[:100] == 1)), float(p[-1]), bool(np.all(np.diff(p)[100:] <= 0.01 * p[100:-1] + 1e-9))
    (411, True, 2168.0, True)
    """
    f = SPREAD_CHORD_SMOOTH * spread
    p0 = min(K - 1, int(math.ceil(1.0 / f))) if f > 0 else K - 1         # f = 0: every node
    dense = np.arange(p0 + 1, dtype=np.float64)
    if p0 >= K - 1:
        return dense
    n = int(math.ceil(math.log((K - 1) / p0) / math.log1p(f)))
    ratio = ((K - 1) / p0) ** (1.0 / n)
    geo = p0 * ratio ** np.arange(1, n + 1)
    geo[-1] = K - 1.0
    return np.concatenate([dense, geo])


def _fill_chord(nodes, K: int, P_f, C_f, P_b):
    """The rows on every chord node from their values at the chord positions ``nodes`` (in steps ds,
    :func:`_spread_chord_nodes`):
    ``ln P`` of both lobes by a cubic spline in the chord (positive, and even in relative
    error over the lobes' decades), the coherent part as the fraction ``C/P`` in [0, 1] (so that
    ``C <= P``)."""
    if nodes.size == K:
        return P_f, C_f, P_b
    from scipy.interpolate import CubicSpline
    grid = np.arange(K, dtype=np.float64)
    tiny = np.finfo(np.float64).tiny

    def fill(v):
        return CubicSpline(nodes.astype(np.float64), v, axis=1)(grid)

    P_f_all = np.exp(fill(np.log(np.maximum(P_f, tiny))))
    P_b_all = np.exp(fill(np.log(np.maximum(P_b, tiny))))
    frac = np.clip(fill(np.clip(C_f / np.maximum(P_f, tiny), 0.0, 1.0)), 0.0, 1.0)
    return P_f_all, frac * P_f_all, P_b_all


def _size_plan(sphere, x_rows, lam, yq, pq, s_lo, s_hi):
    """The evaluations of a size distribution's table: per index node q, (rows, their weights of
    that node, index, the fine size parameters X, the quadrature weights W (rows, X))."""
    J = x_rows.size
    sig_y = float(np.sqrt(np.sum(pq * yq**2) / np.sum(pq) - (np.sum(pq * yq) / np.sum(pq)) ** 2))
    # index nodes in λ, uniform in the arc length of m, at most SIZE_DM apart (one node for a
    # constant index; closer where a narrow spread keeps the phase 2 x (m - 1) coherent:
    # SIZE_DM_PHASE); row j's weights of the nodes: the Lagrange polynomial of degree
    # min(SIZE_INDEX_ORDER, nodes - 1) through the nodes nearest its arc coordinate g_j
    x_top = float(np.max(x_rows)) * s_hi
    dm = SIZE_DM if sig_y * x_top >= SIZE_DM_SMOOTH else min(SIZE_DM, SIZE_DM_PHASE / (2.0 * x_top))
    lam_f = np.linspace(lam.min(), lam.max(), 4 * J + 1)
    m_f = np.asarray(sphere.index(lam_f), dtype=np.complex128) * np.ones(lam_f.size)
    arc = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(m_f)))])
    n_q = int(math.ceil(arc[-1] / dm)) + 1 if arc[-1] > 0 else 1
    if n_q == 1:
        lam_q = np.array([float(np.mean(lam))])
        node_w = np.ones((J, 1))
    else:
        lam_q = np.interp(np.linspace(0.0, arc[-1], n_q), arc, lam_f)
        g = np.interp(lam, lam_f, arc) * ((n_q - 1) / arc[-1])
        order = min(SIZE_INDEX_ORDER, n_q - 1)
        first = np.clip(np.floor(g).astype(np.int64) - (order - 1) // 2, 0, n_q - 1 - order)
        node_w = np.zeros((J, n_q))
        for a in range(order + 1):
            w = np.ones(J)
            for b in range(order + 1):
                if b != a:
                    w *= (g - (first + b)) / (a - b)
            node_w[np.arange(J), first + a] = w
    m_q = np.asarray(sphere.index(lam_q), dtype=np.complex128) * np.ones(lam_q.size)
    # each node's sizes: its rows' range, at most MAX_SIZE_SAMPLES; all nodes' at most
    # MAX_SIZE_TOTAL (each node's count scaled down alike where they would pass it)
    nodes = []
    for q in range(lam_q.size):
        rows_q = np.nonzero(node_w[:, q] != 0.0)[0]
        if rows_q.size == 0:
            continue
        x_a, x_b = float(x_rows[rows_q].min()) * s_lo, float(x_rows[rows_q].max()) * s_hi
        nodes.append((q, rows_q, x_a, x_b, min(_size_count(x_a, x_b, sig_y), MAX_SIZE_SAMPLES)))
    total = sum(c[4] for c in nodes)
    scale = min(1.0, MAX_SIZE_TOTAL / total) if total else 1.0
    plan = []
    for q, rows_q, x_a, x_b, count in nodes:
        wq = node_w[:, q]
        X, dX = _size_grid(x_a, x_b, sig_y, max(2, int(count * scale)))
        yy = np.log(X[None, :] / x_rows[rows_q, None])
        # the trapezoid on the grid's nodes: p_y dy = p_y dX / X
        W = np.interp(yy, yq, pq, left=0.0, right=0.0) * (dX / X)[None, :]
        W /= W.sum(axis=1, keepdims=True)
        plan.append((rows_q, wq[rows_q], m_q[q], X, W))
    return plan


def _size_step(X, sig_y: float):
    """The size grid's local step at the size parameters X of a spread ``sig_y`` (std of ln s):
    ``min(SIZE_DX, σ X / SIZE_PER_SIGMA, max(SIZE_RES_DX sqrt(σ X), σ X / SIZE_RES_PER_SIGMA))``."""
    w = sig_y * np.asarray(X, dtype=np.float64)
    return np.minimum(np.minimum(SIZE_DX, w / SIZE_PER_SIGMA),
                      np.maximum(SIZE_RES_DX * np.sqrt(w), w / SIZE_RES_PER_SIGMA))


def _size_u(x_a: float, x_b: float, sig_y: float):
    """Nodes ``xf`` on ``[x_a, x_b]`` and the coordinate ``u = ∫ dX / step`` there (:func:`_size_step`)."""
    xf = np.linspace(x_a, x_b, 2049) if x_b > x_a else np.array([x_a, x_a * (1 + 1e-9)])
    inv = 1.0 / _size_step(xf, sig_y)
    return xf, np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(xf))])


def _size_count(x_a: float, x_b: float, sig_y: float) -> int:
    """The number of sizes :func:`_size_grid` puts on ``[x_a, x_b]`` at its step, uncapped."""
    return int(math.ceil(_size_u(x_a, x_b, sig_y)[1][-1])) + 1


def _size_grid(x_a: float, x_b: float, sig_y: float, cap: int = MAX_SIZE_SAMPLES):
    """The fine size parameters ``X`` on ``[x_a, x_b]`` at the local step :func:`_size_step`
    (uniform in the coordinate ``u = ∫ dX / step``; at most ``cap``, then uniformly
    coarser in u) and their trapezoid weights ``dX`` (half steps at the ends).

    >>> X, dX = _size_grid(30.0, 40.0, 0.02)           # a 2 % spread at x = 30-40: steps 0.008-0.009
    >>> bool(np.allclose(np.diff(X), _size_step(0.5 * (X[1:] + X[:-1]), 0.02), rtol=0.02)), bool(np.isclose(dX.sum(), 10.0))
    (True, True)
    """
    xf, u = _size_u(x_a, x_b, sig_y)
    n = min(int(math.ceil(u[-1])) + 1, int(cap))
    X = np.interp(np.linspace(0.0, u[-1], max(n, 2)), u, xf)
    X[[0, -1]] = xf[0], xf[-1]
    dX = np.empty_like(X)
    dX[1:-1] = 0.5 * (X[2:] - X[:-2])
    dX[0], dX[-1] = 0.5 * (X[1] - X[0]), 0.5 * (X[-1] - X[-2])
    return X, dX


def _lerp_rows(values, j, t, i, f):
    """Linear in the row (j, t) and in the node (i, f) of ``values[row, node]``."""
    v0 = values[j, i] * (1 - f) + values[j, i + 1] * f
    v1 = values[j + 1, i] * (1 - f) + values[j + 1, i + 1] * f
    return v0 * (1 - t) + v1 * t


def _catmull_rom(values, row, g):
    """Cubic (Catmull–Rom) interpolation of ``values[row, ·]`` at the fractional node ``g``;
    the end nodes are repeated, 0 beyond the last node, never negative."""
    K = values.shape[1]
    i = np.clip(np.floor(g).astype(np.int64), 0, K - 2)
    f = np.clip(g - i, 0.0, 1.0)
    p0 = values[row, np.maximum(i - 1, 0)]
    p1 = values[row, i]
    p2 = values[row, i + 1]
    p3 = values[row, np.minimum(i + 2, K - 1)]
    v = p1 + 0.5 * f * (p2 - p0 + f * (2 * p0 - 5 * p1 + 4 * p2 - p3 + f * (3 * (p1 - p2) + p3 - p0)))
    return np.where(g <= K - 1, np.maximum(v, 0.0), 0.0)


def _scaled_blend(values, ds, x_rows, j, t, x, s, cubic=True):
    """Rows j, j+1 (weight t) of a chord table, each read at its own scaled chord.

    ``(1 - t) c_j⁻² v_j(s / c_j) + t c_j+1⁻² v_j+1(s / c_j+1)`` with ``c = x_row / x``: the
    diffraction rings (and the glory's) sit at a fixed ``x·s``, so both rows are read at the
    same ``x·s`` and their rings line up; the factor ``c⁻²`` keeps ``P / x²`` (the diffraction
    peak grows as ``x²``) and makes the blend, with rows linear in the chord (``cubic=False``),
    the density of the sampler that draws a row's chord and scales it by ``c``
    (``dΩ = s ds dφ``).  ``cubic=True`` (the lobe's value) reads the rows with Catmull–Rom
    cubics, which put the rings' minima and maxima between the nodes.  Zero beyond each row's
    last node.
    """
    K = values.shape[1]
    out = 0.0
    for jj, wgt in ((j, 1.0 - t), (j + 1, t)):
        c = x_rows[jj] / x
        g = np.asarray(s, dtype=np.float64) / (c * ds)
        if cubic:
            v = _catmull_rom(values, jj, g)
        else:
            i = np.clip(np.floor(g).astype(np.int64), 0, K - 2)
            f = np.clip(g - i, 0.0, 1.0)
            v = np.where(g <= K - 1, values[jj, i] * (1 - f) + values[jj, i + 1] * f, 0.0)
        out = out + wgt * v / (c * c)
    return out


class SphereMaterial(MieMembers, Material):
    """A layer of Mie spheres: coherent beam, forward and backward lobes (see the module docstring).

    A :class:`corona.Material` (``corona.Material(corona.Sphere(r), ...)`` returns one) with
    the same methods, signatures and result keys; the flat layer's table members raise one
    line each (:class:`corona.model.material.MieMembers`).

    Parameters
    ----------
    shape : corona.Sphere or corona.SizeDistribution of a Sphere
    process : corona.Process, default Poisson()
        An isotropic process of the centres (poisson, hard-disk, rsa, a powder lattice, a
        point set), or a fixed :class:`corona.Lattice` (one sphere size): a colloidal
        crystal, whose lobes are the Mie lobes times the lattice's Bragg peaks and
        Debye–Waller background, in transmission and in reflection
        (docs/physics.md#spheres-on-a-lattice).
    mode : "particle"
        Spheres are particles in clear air; ``"aperture"`` is refused.
    albedo : 0
        Spheres reflect by Mie theory (the backward lobe), not diffusely.
    use_cache : bool
        Keep the tables in the on-disk cache.
    substrate : corona.GlassPane, optional
        The droplets sit on a thin pane (incoherent: no thickness), with the
        flat layer's weights (:meth:`eval`; docs/physics.md#the-layer-on-glass-substrateglass).
    radius_cover : (float, float), optional
        Radii [µm] ``(r_lo, r_hi)`` around the sphere's the rows serve (a radius texture or an
        optimiser's steps in the plugin): rows from ``2π r_lo/830 nm`` to ``2π r_hi/360 nm``, the
        chord grid fine enough for ``r_hi``; :meth:`at_radius` reads them at another radius.  Row x
        holds the index at ``λ = 2π r/x`` of the sphere's own radius r, so at radius ``r'`` a
        dispersive index is read at ``λ r/r'`` instead of λ: a cover whose phase error
        (:func:`index_phase_error`) passes ``RADIUS_INDEX_PHASE`` is refused
        (docs/layer.md#sphere-radius-textures).  None: the sphere's radius alone.

    Examples
    --------
    Water droplets of 5 µm radius at ``F_a = 0.05``, centres uncorrelated.
    At normal incidence the coherent beam is ``|1 - F_a s₀|² ≈ (1 - F_a Q_ext/2)²``
    (Q_ext = 2.19 here), the lobes carry ``F_a Q_sca``, 96 % of it forward, and the cap
    ``w`` trims their sum by the ``O(F_a²)`` that overlapping Poisson droplets would add:

    >>> import corona
    >>> m = corona.Material(corona.Sphere(5.0), corona.Poisson(0.05))
    >>> m
    SphereMaterial(Sphere(radius=5, ior='water'), Poisson(area_fraction=0.05))
    >>> e = m.directional_albedo(1.0, 550.0)
    >>> round(e["coherent"], 3), round(e["forward"], 3), round(e["backward"], 4)
    (0.898, 0.097, 0.0047)
    """

    mode = "particle"
    albedo = 0.0
    isotropic = True

    def __init__(self, shape, process: Process | None = None, mode: str = "particle",
                 albedo: float = 0.0, use_cache: bool = True, substrate=None, radius_cover=None):
        parts = sphere_parts(shape)
        if parts is None:
            raise CoronaError(f"shape={shape!r} is not a sphere (corona.Sphere)")
        self.sphere, self.sizes = parts
        if process is None:
            process = Poisson()
        if not isinstance(process, Process):
            raise CoronaError(f"process={process!r} is not a corona point process (e.g. corona.Poisson())")
        #: the fixed lattice of the centres (None: an isotropic process)
        self.lattice = process if isinstance(process, Lattice) and not process.isotropic else None
        if not process.isotropic and self.lattice is None:
            raise CoronaError(f"process={process!r} is out of range for shape='sphere'; allowed an isotropic "
                              "process or a fixed lattice (the Mie lobes of an anisotropic point set's S(q) "
                              "are not built)")
        if self.lattice is not None and self.sizes is not None and self.sizes.spread > 0:
            raise CoronaError(f"size_spread={self.sizes.spread:g} is out of range for shape='sphere' on a "
                              f"lattice; allowed 0 ({SPHERE_LATTICE_ONE_SIZE})")
        self.isotropic = self.lattice is None
        self._lattice_cache = {}
        if check_choice("mode", mode, ("aperture", "particle")) != "particle":
            raise CoronaError("mode='aperture' is out of range for shape='sphere'; allowed: particle "
                              "(droplets in clear air)")
        if check_range("albedo", albedo, 0.0, 1.0) != 0.0:
            raise CoronaError(f"albedo={albedo!r} is out of range for shape='sphere'; allowed 0 (a sphere "
                              "reflects by Mie theory: the backward lobe)")
        if substrate is not None and (not isinstance(substrate, GlassPane) or isinstance(substrate, Mirror)
                                      or substrate.coherent):
            raise CoronaError(f"substrate={substrate!r} is out of range for shape='sphere'; allowed none or "
                              "an incoherent glass pane (corona.GlassPane without a thickness: the double "
                              "pass's fringes are built for the flat layer)")
        self.substrate = substrate
        #: the substrate's part (corona.model.substrate.layer_substrate), chosen once
        self.substrate_part = layer_substrate(substrate, self)
        self.shape = shape
        self.process = process
        self.use_cache = bool(use_cache)
        self.area_fraction = process.layer_area_fraction(shape)
        r = float(self.sphere.radius)
        if radius_cover is not None:
            lo, hi = (float(v) for v in radius_cover)
            if not (0.0 < lo <= r * (1 + 1e-9) and r <= hi * (1 + 1e-9) and math.isfinite(hi)):
                raise CoronaError(f"radius_cover={radius_cover!r} is out of range for shape='sphere' with "
                                  f"radius={r:g}; allowed (r_lo, r_hi) with 0 < r_lo <= {r:g} <= r_hi")
            radius_cover = (min(lo, r), max(hi, r))
            phase = index_phase_error(self.sphere, *radius_cover)
            if phase > RADIUS_INDEX_PHASE:
                f = radius_span(self.sphere, max(r / radius_cover[0], radius_cover[1] / r))
                raise CoronaError(
                    f"radius={radius_cover[0]:.4g} … {radius_cover[1]:.4g} is out of range for shape='sphere' "
                    f"with a dispersive ior (water): one table of rows holds the index of one radius, "
                    f"{phase:.2f} rad off at the ends (allowed {RADIUS_INDEX_PHASE:g}); allowed radii within "
                    f"a factor {f:.4g} of {r:.4g} µm, or a constant ior for any range")
        self.radius_cover = radius_cover
        top_r = r if radius_cover is None else radius_cover[1]
        if top_r > SPHERE_RADIUS_MAX:
            raise CoronaError(f"radius={top_r:g} is out of range for shape='sphere'; allowed "
                              f"(0, {SPHERE_RADIUS_MAX:g}] µm (larger droplets: use shape='circle', "
                              "whose Fraunhofer corona theirs approaches)")
        if self.sizes is not None and self.sizes.spread > 0:
            top = largest_sphere(top_r, self.sizes.spread, self.sizes.distribution)
            if top > SPHERE_SIZES_MAX:
                allowed = largest_spread(top_r, self.sizes.distribution)
                raise CoronaError(
                    f"size_spread={self.sizes.spread:g} is out of range for shape='sphere' with radius="
                    f"{top_r:g} µm: its largest droplets ({top:.3g} µm; {SIZE_TAIL:g} of the "
                    f"scattered power beyond) pass {SPHERE_SIZES_MAX:g} µm, the Mie tables' range; allowed "
                    f"size_spread <= {allowed:.3g} ({self.sizes.distribution}) at this radius")

    def __repr__(self):
        pane = "" if self.substrate is None else f", substrate={self.substrate!r}"
        tag = ", preview" if self.is_preview else ""
        return f"SphereMaterial({self.shape!r}, {self.process!r}{pane}{tag})"

    @property
    def length_scale(self) -> float:
        return float(self.sphere.radius)

    # ------------------------------------------------------------------
    # tables
    # ------------------------------------------------------------------
    def table_params(self) -> dict:
        key = {"sphere_format": SPHERE_FORMAT, "shape": tabulated.identity(self.shape),
               "rows_x": [ROW_DLNX, ROW_DX_START, ROW_DX_MIN, ROW_DX_FINE, ROW_TOLERANCE, ROW_TEST_STRIDE],
               "chord_dx": [CHORD_DX, CHORD_DX_SPREAD, SPREAD_COARSE_CHORD], "nodes": [MIN_NODES, MAX_NODES], "rows": [MIN_ROWS, MAX_ROWS],
               "sizes": [SIZE_DX, SIZE_PER_SIGMA, MAX_SIZE_SAMPLES, MAX_SIZE_TOTAL, SIZE_TAIL, SIZE_DM, SIZE_ROW_DX, SIZE_ROW_DLNX, SIZE_ROW_RULE,
                         SPREAD_CHORD_SMOOTH,
                         SIZE_INDEX_ORDER, SIZE_TAIL_ROWS, SPREAD_CHORD_RULE,
                         SIZE_RES_DX, SIZE_RES_PER_SIGMA, SIZE_STEP_RULE, SIZE_DM_PHASE, SIZE_DM_SMOOTH],
               "angular_dtype": np.dtype(ANGULAR_DTYPE).name, "wavelengths": [tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX]}
        if self.radius_cover is not None:
            key["radius_cover"] = list(self.radius_cover)
        if self.is_preview:
            key["preview"] = [PREVIEW_ROWS, PREVIEW_CHORD_DX, PREVIEW_MAX_NODES]
        return key

    #: True for the coarse copy of :meth:`preview`.
    is_preview = False

    @functools.cached_property
    def rows(self) -> dict:
        """The Mie rows (:func:`build_mie_rows`, cached on disk), float64; a preview's:
        :func:`build_preview_rows` (not cached)."""
        if self.is_preview:
            return build_preview_rows(self.sphere, self.radius_cover)
        arrays = tabulated.cached(self.table_params(),
                               lambda: build_mie_rows(self.sphere, self.sizes, self.radius_cover),
                               use_cache=self.use_cache, background=True)
        return {k: np.asarray(v) for k, v in arrays.items()}

    def rows_cached(self) -> bool:
        """Whether the exact Mie rows are ready at once (built in this process or in the
        on-disk cache): when False, :attr:`rows` builds them (seconds to a minute, a progress
        bar on stderr) and :meth:`preview` gives a coarse look meanwhile."""
        if "rows" in self.__dict__ and not self.is_preview:
            return True
        if not self.use_cache:
            return False
        try:
            path = os.path.join(tabulated.cache_dir(), tabulated.cache_key(
                {k: v for k, v in self.table_params().items() if k != "preview"}) + ".npz")
        except CoronaError:
            return False
        return os.path.isfile(path)

    def preview(self) -> "SphereMaterial":
        """A coarse copy of this layer for a first look while the exact rows build: one-size Mie
        rows of the mean sphere (the size spread left out), :data:`PREVIEW_ROWS` of them, not
        refined, on a coarser chord grid (:func:`build_preview_rows`): about a second where the
        exact table of a new radius takes 10-60 s.  Its energies, lobes and renders are those
        of the coarse rows; ``repr`` says ``preview``.  The designer shows it while
        :attr:`rows` builds on another thread (``corona.model.mie.layer``; docs/mie.md)."""
        other = copy.copy(self)
        other.__dict__ = {k: v for k, v in self.__dict__.items()
                          if k not in ("rows", "_derived", "_energy_peers", "_forward_energy_handed")}
        other._lattice_cache = {}
        other.is_preview = True
        return other

    def at_radius(self, radius: float) -> "SphereMaterial":
        """The layer with spheres of ``radius`` [µm] (within :attr:`radius_cover`) read from these rows,
        as a radius texture's texel is: ``x = 2π radius/λ`` on the same rows, the same ``S(q r)`` table
        in ``u = q r`` and the same forward energies in x (what the plugin evaluates there).

        The Mie lobe of the new radius itself (:meth:`eval` with ``exact=True``) is Mie theory at
        that radius and the index at λ."""
        r = float(radius)
        lo, hi = self.radius_cover if self.radius_cover is not None else (self.sphere.radius,) * 2
        if not (lo * (1 - 1e-9) <= r <= hi * (1 + 1e-9)):
            raise CoronaError(f"radius={r!r} is out of range for these sphere rows; allowed "
                              f"[{lo:g}, {hi:g}] µm (radius_cover)")
        _ = self.rows, self.structure_table, self._derived        # shared, computed once
        other = copy.copy(self)
        other.sphere = Sphere(r, ior=self.sphere.ior)
        return other

    @functools.cached_property
    def structure_table(self):
        """``S`` on a radial grid of ``u = q r`` (RADIAL_DU), or None for Poisson (S = 1) and for a
        fixed lattice (its ``S`` is evaluated at the in-plane ``q`` itself: :meth:`_lobes`)."""
        if isinstance(self.process, Poisson) or self.lattice is not None:
            return None
        # in u = q r, radius-free for a hard core of the spheres' diameter; long enough for the cover's top
        top = self.length_scale if self.radius_cover is None else self.radius_cover[1]
        u_max = tabulated.u_max_for(top)
        n = min(int(np.ceil(u_max / tabulated.RADIAL_DU)) + 1, tabulated.RADIAL_MAX_SAMPLES)
        du = u_max / (n - 1)
        u = np.arange(n) * du
        S = self.process.structure_factor_radial(u / self.length_scale, self.shape)
        return du, np.maximum(np.asarray(S, dtype=np.float64), 0.0)

    def structure_factor(self, u) -> np.ndarray:
        """Tabulated ``S`` at ``u = q r`` (linear; 1 beyond the table and for Poisson)."""
        st = self.structure_table
        u = np.asarray(u, dtype=np.float64)
        if st is None:
            return np.ones_like(u)
        du, S = st
        return np.interp(u, np.arange(S.size) * du, S, right=1.0)

    @functools.cached_property
    def _derived(self) -> dict:
        """Totals per row: T_f, T_b (∫ P dΩ of the tabulated rows) and e_f (the forward lobe with S
        at normal incidence)."""
        r = self.rows
        ds = float(r["ds"])
        s = np.arange(r["P_f"].shape[1]) * ds
        C = r["C_f"] if r["C_f"].size else r["P_f"]
        T_f = tabulated.radial_totals(ds, r["P_f"])          # RadialTable(ds, row).total per row
        T_b = tabulated.radial_totals(ds, r["P_b"])
        if self.structure_table is None:
            e_mu = np.repeat(T_f[:, None], len(INCIDENCE_MU), axis=1)
        else:   # seconds for a hard core: kept in the table cache, per process
            key = {**self.table_params(), "forward_energy": 1, "process": tabulated.identity(self.process),
                   "incidence_mu": len(INCIDENCE_MU)}
            e_mu = np.asarray(tabulated.cached(key, lambda: {"e_f_mu": self._forward_energy_of_peers(s, C, T_f)},
                                            use_cache=self.use_cache)["e_f_mu"])
        return {"T_f": T_f, "T_b": T_b, "e_f": e_mu[:, 0], "e_f_mu": e_mu, "e_b": T_b, "s": s}

    @property
    def row_totals(self) -> dict:
        """Per row of x (numpy, read-only by convention): ``T_f``, ``T_b`` (``∫ P dΩ`` of the
        forward and backward rows), ``e_f_mu`` (the forward lobe's energy with ``S`` per row and
        ``μ_i`` of ``INCIDENCE_MU``), ``e_f`` (its normal-incidence column), ``e_b`` and the chords
        ``s``: what the plugin tabulates beside the rows (:mod:`corona.mitsuba.sphere`)."""
        return self._derived

    def _forward_energy_of_peers(self, s, C, T_f) -> np.ndarray:
        """:meth:`_forward_energy`, computed in one pass with the peers :func:`share_forward_energies`
        named that share this layer's rows and have not derived theirs yet (handed to them for when
        they do); or the one a peer handed to this layer."""
        handed = self.__dict__.pop("_forward_energy_handed", None)
        if handed is not None:
            return handed
        peers = [m for m in self.__dict__.get("_energy_peers", ()) if m is not self
                 and m.__dict__.get("rows") is self.rows and "_derived" not in m.__dict__]
        out = self._forward_energy(s, C, T_f, peers)
        for m, e in zip(peers, out[1:]):
            m.__dict__["_forward_energy_handed"] = e
        return out[0]

    def _forward_energy(self, s, C, T_f, peers=()) -> list[np.ndarray]:
        """``e_f(x_j, μ_i)`` (J, len(INCIDENCE_MU)): the forward lobe with ``S(q)`` integrated over
        the sphere of directions for light from ``μ_i = |cos θi|`` (``T_f`` for Poisson), of this
        layer and of ``peers`` (layers of the same rows with other hard-core processes), a list.

        Since ``⟨C⟩ <= ⟨P⟩`` and ``S >= 0``, ``P + C (S - 1) >= 0`` and the lobe's energy is
        ``T_f + ∫ C (⟨S⟩_φ - 1) dΩ``, where ``⟨S⟩_φ(s, u)``, the mean over the azimuth about
        ``wt = -wi`` of ``S(u h)`` with ``h = |(wo - wt)_xy| / |wo - wt|`` (a function of the
        chord s, the azimuth and μ_i only), is tabulated once on a coarse grid of s and a grid of
        ``u = x s`` and read at each row's ``x_j s``.  At oblique incidence q is smaller for a
        given Θ and the lobe meets another part of S: for dense hard disks its energy grows
        (14 % at F_a = 0.7 and 60°); the lobe weight's cap uses this energy (:meth:`energies`)."""
        mus = np.asarray(INCIDENCE_MU)
        J = T_f.size
        layers = [self, *peers]
        if self.structure_table is None:
            return [np.repeat(T_f[:, None], mus.size, axis=1)]
        r = self.rows
        xs = r["x"]
        keep = s <= CHORD_MAX + 1e-12
        sk = s[keep]
        w = 2 * np.pi * sk * (s[1] - s[0])        # trapezoid weights of dΩ = s ds dφ
        w[0] = 0.0
        w[-1] *= 0.5
        Ck = C[:, keep]
        n_c, n_phi = (16, 16) if self.is_preview else (48, 64)    # a preview: a coarser S grid
        s_c = np.linspace(1e-4, CHORD_MAX, n_c)
        # u nodes: 0.125 apart up to 40, then geometric (S - 1 fades; its φ-mean fades faster)
        u_top = max(41.0, 1.5 * CHORD_MAX * float(xs[-1]))
        n_geo = 160
        ratio = math.log(u_top / 40.0) / (n_geo - 1)
        u_c = np.concatenate([np.arange(320) * 0.125, 40.0 * np.exp(np.arange(n_geo) * ratio)])
        # the azimuths of the half circle φ in (0, π): wi lies in the xz plane, so h(-φ) = h(φ) and the
        # mean over the half is the mean over the whole circle's n_phi
        phi = (np.arange(n_phi // 2) + 0.5) * (2 * np.pi / n_phi)
        cos_c, sin_c = 1 - 0.5 * s_c * s_c, s_c * np.sqrt(1 - 0.25 * s_c * s_c)
        # ⟨S⟩_φ - 1 on the coarse (s_c, u_c) grid, one table per layer and incidence
        n_u = u_c.size
        Kc = np.empty((n_c * n_u, len(layers), mus.size))
        for k, mu in enumerate(mus):
            wi = np.array([math.sqrt(max(0.0, 1 - mu * mu)), 0.0, max(mu, 1e-9)])
            wi /= np.linalg.norm(wi)
            wt = -wi
            e1, e2 = _frame(wt)
            wo = (cos_c[:, None, None] * wt + sin_c[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2))
            h = np.linalg.norm((wo - wt)[..., :2], axis=-1) / s_c[:, None]          # (n_c, n_phi)
            for n, layer in enumerate(layers):
                Kc[:, n, k] = (np.mean(layer.structure_factor(u_c[None, :, None] * h[:, None, :]), axis=-1)
                               - 1.0).ravel()
        Kc = Kc.reshape(n_c * n_u, -1)
        # ∑_s C w (⟨S⟩_φ - 1) at each row's (s, u = x s), bilinear on the grid (linear in s between
        # the coarse cells, in u on u_c), is linear in the grid's values: per row, the weights its
        # chord nodes put on the grid's nodes (np.bincount over a block of rows), times the tables
        # of all layers and incidences at once; the same sums as interpolating at every node, reordered
        cell = np.clip(np.searchsorted(s_c, sk) - 1, 0, n_c - 2)
        frac = np.clip((sk - s_c[cell]) / (s_c[cell + 1] - s_c[cell]), 0.0, 1.0)
        out = np.empty((J, len(layers) * mus.size))
        block = max(1, (1 << 22) // (n_c * n_u))             # rows a block: 4 M grid weights
        for j0 in range(0, J, block):
            j1 = min(J, j0 + block)
            U = xs[j0:j1, None] * sk[None, :]                   # the rows' u = x s
            g = np.where(U < 40.0, U / 0.125, 320 + np.log(np.maximum(U, 40.0) / 40.0) / ratio)
            i = np.clip(np.floor(g).astype(np.int64), 0, n_u - 2)
            fr = np.clip((U - u_c[i]) / (u_c[i + 1] - u_c[i]), 0.0, 1.0)
            a = Ck[j0:j1] * w
            a_lo, a_hi = a * (1 - frac), a * frac                 # the two s cells' shares
            node = (cell * n_u)[None, :] + i + (np.arange(j1 - j0) * (n_c * n_u))[:, None]
            weights = np.bincount(np.concatenate([node.ravel(), (node + 1).ravel(),
                                                  (node + n_u).ravel(), (node + n_u + 1).ravel()]),
                                  np.concatenate([(a_lo * (1 - fr)).ravel(), (a_lo * fr).ravel(),
                                                  (a_hi * (1 - fr)).ravel(), (a_hi * fr).ravel()]),
                                  minlength=(j1 - j0) * n_c * n_u)
            out[j0:j1] = T_f[j0:j1, None] + weights.reshape(j1 - j0, n_c * n_u) @ Kc
        return [np.maximum(e, 0.0) for e in np.split(out, len(layers), axis=1)]

    def _forward(self, j, t, cos_theta_i):
        """``e_f`` at the row (j, t) and ``|cos θi|``: linear in both."""
        e = self._derived["e_f_mu"]
        nodes = np.asarray(INCIDENCE_MU)
        mu = np.clip(np.abs(np.asarray(cos_theta_i, dtype=np.float64)), 0.0, 1.0)
        g = (1.0 - mu) / (nodes[0] - nodes[1])
        b = np.clip(np.floor(g).astype(np.int64), 0, nodes.size - 2)
        f = np.clip(g - b, 0.0, 1.0)
        at = lambda jj: e[jj, b] * (1 - f) + e[jj, b + 1] * f
        return at(j) * (1 - t) + at(j + 1) * t

    def _row(self, wavelength):
        """Row index j and weight t of the wavelength(s) [nm] between rows (linear in x)."""
        lam = np.clip(np.asarray(wavelength, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        xr = self.rows["x"]
        x = 2 * np.pi * self.length_scale / (lam * 1e-3)
        j = np.clip(np.searchsorted(xr, x, side="right") - 1, 0, xr.size - 2)
        return j, (x - xr[j]) / (xr[j + 1] - xr[j])

    def _x(self, wavelength):
        """Size parameter ``2π r / λ`` of the mean sphere at ``wavelength`` [nm] (clipped to the range)."""
        lam = np.clip(np.asarray(wavelength, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        return 2 * np.pi * self.length_scale / (lam * 1e-3)

    def _blend(self, key, j, t, x, s, cubic=True):
        r = self.rows
        return _scaled_blend(r[key], float(r["ds"]), r["x"], j, t, x, s, cubic)

    def _node(self, s):
        ds = float(self.rows["ds"])
        K = self.rows["P_f"].shape[1]
        g = np.asarray(s, dtype=np.float64) / ds
        i = np.clip(np.floor(g).astype(np.int64), 0, K - 2)
        return i, np.clip(g - i, 0.0, 1.0), g <= K - 1

    # ------------------------------------------------------------------
    # energies
    # ------------------------------------------------------------------
    def _slant(self, cos_theta_i):
        mu = np.abs(np.asarray(cos_theta_i, dtype=np.float64))
        return np.minimum(self.area_fraction / np.maximum(mu, 1e-12), 1.0)

    def energies(self, cos_theta_i, wavelength) -> dict:
        """``coherent`` ``|t|²``, the lobe weight ``w``, and the energies of the forward and backward
        lobes ``F_s w e_f``, ``F_s w e_b`` (at normal-incidence S) for light from ``cos_theta_i``."""
        j, t = self._row(wavelength)
        d = self._derived
        r = self.rows
        lerp = lambda a: a[j] * (1 - t) + a[j + 1] * t
        fs = self._slant(cos_theta_i)
        s0 = lerp(r["s0"][:, 0]) + 1j * lerp(r["s0"][:, 1])
        coherent = np.minimum(np.abs(1.0 - fs * s0) ** 2, 1.0)
        e_f, e_b = self._forward(j, t, cos_theta_i), lerp(d["e_b"])
        scattered = fs * (e_f + e_b) * ENERGY_MARGIN
        w = np.minimum(1.0, np.maximum(1.0 - coherent, 0.0) / np.maximum(scattered, 1e-300))
        return {"coherent": coherent, "weight": w, "forward": fs * w * e_f, "backward": fs * w * e_b,
                "slant": fs}

    # ------------------------------------------------------------------
    # a fixed lattice (docs/physics.md#spheres-on-a-lattice)
    # ------------------------------------------------------------------
    def _mie_at(self, wi, wo, lam):
        """(P_f, P_b, forward mask) of the tables at directions ``wo`` (M, 3) for one ``wi`` (3,)."""
        s_f = np.linalg.norm(wo + wi, axis=-1)
        s_b = np.linalg.norm(wo - wi, axis=-1)
        j, t = self._row(lam)
        x = self._x(lam)
        return self._blend("P_f", j, t, x, s_f), self._blend("P_b", j, t, x, s_b), s_f <= s_b

    def lattice_nodes(self, wi, wavelength: float) -> dict:
        """A quadrature of the lattice layer's lobes over the sphere of directions, for one ``wi``.

        On a fixed lattice (one size, ``C = P``) the lobe is
        ``Z = P (1 - e^{-q²δ²}) + P Σ_G W_G g_G(q)`` (forward lobe's ``P_f`` or backward
        lobe's ``P_b`` by the chord, :meth:`_lobes`), ``W_G = (2π)² n e^{-G²δ²}`` and ``g_G`` the
        unit Gaussian of the broadened peak (:class:`corona.Lattice`).  Since
        ``d²q = k² |cos θo| dΩ`` (``q = k (wo + wi)_xy``), order ``G`` carries
        ``∫ P W_G g_G(q) d²q / (k² |cos θo|)``, summed over the directions on both sides of the
        layer that it reaches (``|q/k - wi_xy| < 1``): ``LATTICE_PEAK_NODES``² Gauss–Legendre
        nodes over ``±LATTICE_PEAK_REACH`` rms widths per peak and side.  The diffuse part
        ``P (1 - e^{-q²δ²})`` of a jittered lattice is integrated on the tables' chord grid
        about ``∓wi`` (``dΩ = s ds dφ``, ``LATTICE_DIFFUSE_PHI`` azimuths).  In the narrow-peak
        limit ``F_s`` times an order's energy is the kinematic grating efficiency
        ``η_G = λ² |f(Θ_G)|² e^{-G²δ²} / (A² μ_i |cos θ_G|)`` (``|f|² = (|S1|² + |S2|²) / 2k²``
        the sphere's differential cross-section at the order's scattering angle, ``A`` the cell
        area; e.g. Ashcroft & Mermin ch. 6, Guinier ch. 7).

        Returns
        -------
        dict: ``wo`` (M, 3) the nodes' directions, ``energy`` (M,) their ``Z dΩ`` (the layer's
        lobes before ``F_s w``), ``forward`` (M,) the lobe they belong to, ``bragg`` (M,) True for
        the orders' nodes (False: the diffuse part's).
        """
        wi = np.asarray(wi, dtype=np.float64)
        lam = float(np.clip(wavelength, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX))
        key = (tuple(np.round(wi, 12)), lam)
        if key in self._lattice_cache:
            return self._lattice_cache[key]
        k = 2 * np.pi / (lam * 1e-3)
        lat = self.lattice
        w = lat.peak_width
        reach = LATTICE_PEAK_REACH * w
        G, W = lat.bragg_peaks(2.0 * k + reach)
        pc = G / k - wi[:2]
        keep = np.hypot(pc[:, 0], pc[:, 1]) < 1.0 + reach / k
        G, W = G[keep], W[keep]
        xg, wg = np.polynomial.legendre.leggauss(LATTICE_PEAK_NODES)
        # orders well inside the unit disk of wo_xy: a tensor grid in q, weights d²q / (k² |cos θo|)
        rho0 = np.hypot(pc[keep, 0], pc[keep, 1])
        r_w = reach / k
        flat = rho0 + r_w < LATTICE_STEEP
        d = reach * xg
        g1 = reach * wg * np.exp(-0.5 * (d / w) ** 2) / (math.sqrt(2 * np.pi) * w)
        Gf, Wf = G[flat], W[flat]
        q = np.stack(np.broadcast_arrays(Gf[:, None, None, 0] + d[None, :, None],
                                         Gf[:, None, None, 1] + d[None, None, :]), -1).reshape(-1, 2)
        wq = (Wf[:, None, None] * g1[None, :, None] * g1[None, None, :]).reshape(-1)
        p = q / k - wi[:2]
        r2 = p[:, 0] ** 2 + p[:, 1] ** 2
        ok = (r2 < 1.0) & (wq > 0)
        p, r2 = p[ok], r2[ok]
        cz = np.sqrt(1.0 - r2)
        wq = wq[ok] / (k * k * cz)
        # orders near grazing exit: wo_xy = sin θ (cos φ, sin φ), d²q / (k² |cos θo|) = sin θ dθ dφ
        # (no 1/|cos θo| singularity), a Gauss–Legendre grid in θ and φ over the peak's window
        if np.any(~flat):
            Gs, Ws, ps = G[~flat], W[~flat], pc[keep][~flat]
            r0 = np.hypot(ps[:, 0], ps[:, 1])
            ph0 = np.arctan2(ps[:, 1], ps[:, 0])
            th_lo = np.arcsin(np.clip(r0 - r_w, 0.0, 1.0))
            th_hi = np.arcsin(np.clip(r0 + r_w, 0.0, 1.0))
            dph = np.arcsin(np.clip(r_w / np.maximum(r0, 1e-12), 0.0, 1.0))
            xt, wt = np.polynomial.legendre.leggauss(2 * LATTICE_PEAK_NODES)
            th = 0.5 * (th_lo + th_hi)[:, None] + 0.5 * (th_hi - th_lo)[:, None] * xt[None, :]
            wth = 0.5 * (th_hi - th_lo)[:, None] * wt[None, :]
            ph = ph0[:, None] + dph[:, None] * xg[None, :]
            wph = dph[:, None] * wg[None, :]
            st = np.sin(th)[:, :, None]
            pp = np.stack(np.broadcast_arrays(st * np.cos(ph)[:, None, :], st * np.sin(ph)[:, None, :]), -1)
            dq = k * (pp + wi[:2]) - Gs[:, None, None, :]
            gauss = np.exp(-0.5 * np.sum(dq * dq, axis=-1) / (w * w)) / (2 * np.pi * w * w)
            ws = (Ws[:, None, None] * gauss * st * wth[:, :, None] * wph[:, None, :]).reshape(-1)
            pp = pp.reshape(-1, 2)
            r2s = np.sum(pp * pp, axis=-1)
            ok = (r2s < 1.0) & (ws > 0)
            p = np.concatenate([p, pp[ok]])
            cz = np.concatenate([cz, np.sqrt(1.0 - r2s[ok])])
            wq = np.concatenate([wq, ws[ok]])
        parts_wo, parts_e, parts_f = [], [], []
        for side in (1.0, -1.0):
            wo = np.concatenate([p, side * cz[:, None]], axis=-1)
            P_f, P_b, fwd = self._mie_at(wi, wo, lam)
            parts_wo.append(wo)
            parts_e.append(np.where(fwd, P_f, P_b) * wq)
            parts_f.append(fwd)
        if lat.jitter > 0.0:
            K = self.rows["P_f"].shape[1]
            s = np.linspace(0.0, CHORD_MAX, K)
            ws = np.full(s.size, s[1] - s[0])
            ws[0] = ws[-1] = 0.5 * ws[0]
            phi = (np.arange(LATTICE_DIFFUSE_PHI) + 0.5) * (2 * np.pi / LATTICE_DIFFUSE_PHI)
            cos_t, sin_t = 1 - 0.5 * s * s, s * np.sqrt(1 - 0.25 * s * s)
            for axis in (-wi, wi):
                e1, e2 = _frame(axis)
                wo = (cos_t[:, None, None] * axis + sin_t[:, None, None]
                      * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2)).reshape(-1, 3)
                dw = np.repeat(ws * s * (2 * np.pi / LATTICE_DIFFUSE_PHI), phi.size)
                P_f, P_b, fwd = self._mie_at(wi, wo, lam)
                mine = fwd if axis[2] == -wi[2] else ~fwd     # each lobe on its own grid
                q2 = k * k * np.sum((wo + wi)[:, :2] ** 2, axis=-1)
                diffuse = np.where(fwd, P_f, P_b) * -np.expm1(-q2 * lat.jitter ** 2)
                parts_wo.append(wo)
                parts_e.append(np.where(mine, diffuse * dw, 0.0))
                parts_f.append(fwd)
        n_bragg = 2 * p.shape[0]
        out = {"wo": np.concatenate(parts_wo), "energy": np.concatenate(parts_e),
               "forward": np.concatenate(parts_f)}
        out["bragg"] = np.arange(out["energy"].size) < n_bragg
        if len(self._lattice_cache) > 256:
            self._lattice_cache.clear()
        self._lattice_cache[key] = out
        return out

    def lattice_energy(self, wi, wavelength: float) -> float:
        """``e = ∫ Z dΩ`` of both lobes on the lattice for one ``wi`` (3,) (:meth:`lattice_nodes`)."""
        return float(np.sum(self.lattice_nodes(wi, wavelength)["energy"]))

    def _lattice_weight(self, wi, wavelength, shape):
        """The cap ``w = min(1, (1 - |t|²) / (ENERGY_MARGIN F_s e))`` of the lattice layer at each
        (``wi``, λ) (broadcast to ``shape``); ``e`` by :meth:`lattice_energy`."""
        wi = np.broadcast_to(np.asarray(wi, dtype=np.float64), shape + (3,)).reshape(-1, 3)
        lam = np.broadcast_to(np.asarray(wavelength, dtype=np.float64), shape).reshape(-1)
        keys = np.concatenate([wi, lam[:, None]], axis=-1)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        out = np.empty(uniq.shape[0])
        for n, row in enumerate(uniq):
            e = self.energies(row[2], row[3])
            scattered = e["slant"] * self.lattice_energy(row[:3], row[3]) * ENERGY_MARGIN
            out[n] = min(1.0, max(1.0 - float(e["coherent"]), 0.0) / max(float(scattered), 1e-300))
        return out[inv.reshape(-1)].reshape(shape)

    # ------------------------------------------------------------------
    # the pane (docs/physics.md#the-layer-on-glass-substrateglass), as corona.Material's
    # ------------------------------------------------------------------
    def coherent_weight(self, cos_theta_i, wavelength=550.0) -> float | np.ndarray:
        """The layer's own coherent weight ``C = |1 - F_s s₀(λ)|²`` for light from ``cos_theta_i`` at
        ``wavelength`` [nm] (the mean field depends on both), without the pane."""
        return self.energies(cos_theta_i, wavelength)["coherent"]

    def coherent_transmission(self, cos_theta_i, wavelength=550.0) -> np.ndarray:
        """Weight of the delta transmission along ``-wi``: ``C T'(θi)``, ``C`` the :meth:`coherent_weight`
        (a spectrum: the mean field depends on λ), ``T'`` the pane's (1 without one)."""
        return self.energies(cos_theta_i, wavelength)["coherent"] * self.substrate_part.fresnel(cos_theta_i)[1]

    def specular_reflection(self, cos_theta_i, wavelength=550.0) -> np.ndarray:
        """Weight of the delta reflection (the mirror direction of ``wi``): 0 without a pane;
        ``C R + C² (R' - R)`` when light meets the layer first (the front face's ``R`` crosses the
        layer once: :meth:`corona.GlassPane.specular_through_layer`), ``R'(θi)`` when it meets the
        glass first."""
        return self.substrate_part.specular_reflection(self, cos_theta_i, wavelength)

    @property
    def coherent_transmittance(self) -> float:
        """The layer's coherent weight ``C`` at normal incidence and 550 nm (it depends on both)."""
        return float(self.energies(1.0, 550.0)["coherent"])

    # ------------------------------------------------------------------
    # the BSDF
    # ------------------------------------------------------------------
    def _lobes(self, wi, wo, wavelength, exact=False):
        """(forward Z, backward Z, forward mask) at the directions, per steradian."""
        wi = check_finite_array("wi", wi)
        wo = check_finite_array("wo", wo)
        if wi.shape[-1:] != (3,) or wo.shape[-1:] != (3,):
            raise CoronaError(f"wi and wo must have shape (..., 3), got {wi.shape} and {wo.shape}")
        wi, wo = np.broadcast_arrays(wi, wo)
        lam = np.broadcast_to(np.asarray(wavelength, dtype=np.float64), wi.shape[:-1])
        s_f = np.linalg.norm(wo + wi, axis=-1)           # |wo - wt|, wt = -wi
        s_b = np.linalg.norm(wo - wi, axis=-1)
        forward = s_f <= s_b
        dxy = np.linalg.norm((wo + wi)[..., :2], axis=-1)
        u = 2 * np.pi * self.length_scale * dxy / (np.clip(lam, tabulated.WAVELENGTH_MIN,
                                                           tabulated.WAVELENGTH_MAX) * 1e-3)
        if self.lattice is None:
            S = self.structure_factor(u)
        else:   # the fixed lattice's S at the in-plane momentum transfer q = 2π (wo + wi)_xy / λ
            lam_um = np.clip(lam, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX) * 1e-3
            S = self.lattice.structure_factor_at(2 * np.pi * (wo + wi)[..., :2] / lam_um[..., None])
        if exact:
            P_f, C_f, P_b = self._exact(s_f, s_b, lam)
        else:
            j, t = self._row(lam)
            x = self._x(lam)
            P_f = self._blend("P_f", j, t, x, s_f)
            C_f = self._blend("C_f", j, t, x, s_f) if self.rows["C_f"].size else P_f
            P_b = self._blend("P_b", j, t, x, s_b)
        Z_f = decoupled_lobe(P_f, C_f, S)        # per steradian: R = 1
        if self.lattice is not None:
            # the reflected orders: one size, C = P (a lattice takes no size spread)
            return Z_f, decoupled_lobe(P_b, P_b, S), forward
        return Z_f, P_b, forward

    def _exact(self, s_f, s_b, lam):
        """Mie P, C (forward) and P (backward) computed directly at each direction (float64)."""
        r = self.sphere.radius
        s_nodes, s_w = (np.ones(1), np.ones(1)) if self.sizes is None else \
            self.sizes._nodes(2.0 * 2 * np.pi / (tabulated.WAVELENGTH_MIN * 1e-3))
        out = [np.zeros(s_f.shape) for _ in range(3)]
        A1, A2 = np.zeros(s_f.shape, complex), np.zeros(s_f.shape, complex)
        flat = lam.ravel()
        for lv in np.unique(flat):
            sel = lam == lv
            x0 = 2 * np.pi * r / (lv * 1e-3)
            m = complex(self.sphere.index(lv))
            x2 = x0 * x0 * float(np.sum(s_w * s_nodes**2))
            mu_f = 1 - 0.5 * s_f[sel] ** 2
            mu_b = -(1 - 0.5 * s_b[sel] ** 2)
            for s, w in zip(s_nodes, s_w):
                S1, S2 = mie.amplitudes(m, x0 * s, np.concatenate([mu_f, mu_b]))
                k = mu_f.size
                out[0][sel] += w * (np.abs(S1[:k]) ** 2 + np.abs(S2[:k]) ** 2) / (2 * np.pi * x2)
                out[2][sel] += w * (np.abs(S1[k:]) ** 2 + np.abs(S2[k:]) ** 2) / (2 * np.pi * x2)
                A1[sel] += w * S1[:k] / math.sqrt(2 * np.pi * x2)
                A2[sel] += w * S2[:k] / math.sqrt(2 * np.pi * x2)
        out[1] = np.abs(A1) ** 2 + np.abs(A2) ** 2
        out[0] = np.where(s_f <= CHORD_MAX, out[0], 0.0)
        out[1] = np.where(s_f <= CHORD_MAX, out[1], 0.0)
        out[2] = np.where(s_b <= CHORD_MAX, out[2], 0.0)
        return out

    def _layer_eval(self, wi, wo, wavelength, exact=False):
        """The layer alone: ``F_s w Z`` (forward or backward lobe) and the coherent weight ``C``."""
        Z_f, Z_b, forward = self._lobes(wi, wo, wavelength, exact)
        wi = np.asarray(wi, dtype=np.float64)
        e = self.energies(np.broadcast_to(wi[..., 2], Z_f.shape), wavelength)
        weight = e["weight"] if self.lattice is None else self._lattice_weight(wi, wavelength, Z_f.shape)
        return e["slant"] * weight * np.where(forward, Z_f, Z_b), e["coherent"]

    def eval(self, wi, wo, wavelength, exact: bool = False) -> np.ndarray:
        """The smooth BSDF times the cosine, ``f |cos θo|``: ``F_s w Z`` (forward or backward lobe).

        ``wi``, ``wo`` (..., 3) unit vectors (Mitsuba's convention), ``wavelength`` [nm].
        ``exact=True`` evaluates Mie theory at each direction instead of the tables
        (the weight ``w`` still comes from the tables' energies).

        On a pane (``C`` the coherent weight at ``θi``, ``R'``, ``T'`` the pane's, ``wo'`` the
        mirror image of ``wo`` in the layer's plane), as :meth:`corona.Material.eval`:

        =====================  ==================================  ======================
        lobes' part            light meets the layer first         meets the glass first
        =====================  ==================================  ======================
        on the far side        ``f T'(θo)``                        ``T'(θi) f``
        on the side of ``wi``  ``f + F f(wo')``                    ``T'(θi) f T'(θo)``
        =====================  ==================================  ======================

        with ``F = min(R(θi), R(θo)) + C [P(θi) + P(θo)]``, ``R`` the front face's Fresnel
        reflectance and ``P = R' - R`` the round trips (:meth:`corona.GlassPane.reflected_lobe_factor`).
        """
        val, coherent = self._layer_eval(wi, wo, wavelength, exact)
        return self.substrate_part.lobes_on_pane(val, lambda wo_m: self._layer_eval(wi, wo_m, wavelength, exact)[0],
                                                 wi, wo, coherent)

    def lobe(self, d, wavelength) -> np.ndarray:
        """The transmitted lobe at normal incidence per unit ``d²d`` (docs/physics.md's ``lobe(d)``).

        ``wi = +z``, ``wo = (d, -√(1 - |d|²))``: ``lobe = f = eval / |cos θo|`` (0 for ``|d| >= 1``).
        """
        d = check_finite_array("d", d)
        if d.ndim == 0 or d.shape[-1] != 2:
            raise CoronaError(f"d must have shape (..., 2), got {d.shape}")
        r2 = np.sum(d * d, axis=-1)
        cz = np.sqrt(np.maximum(1.0 - r2, 0.0))
        wo = np.concatenate([d, -cz[..., None]], axis=-1)
        val = self._layer_eval(np.array([0.0, 0.0, 1.0]), wo, wavelength)[0]      # the layer alone
        return np.where(r2 < 1.0, val / np.maximum(cz, 1e-300), 0.0)

    # ------------------------------------------------------------------
    # sampling (the plugin's scheme in float64)
    # ------------------------------------------------------------------
    @functools.lru_cache(maxsize=64)
    def _radial(self, which: str, j: int) -> tabulated.RadialTable:
        return tabulated.RadialTable(float(self.rows["ds"]), self.rows["P_f" if which == "f" else "P_b"][j])

    def pdf_lobe(self, which: str, wi, wo, wavelength) -> np.ndarray:
        """Solid-angle density of :meth:`sample_lobe` (``which`` "f" or "b") at one wavelength [nm]:
        the rows' interpolated P over their interpolated total."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        s = np.linalg.norm(wo + wi if which == "f" else wo - wi, axis=-1)
        j, t = self._row(wavelength)
        key = "P_f" if which == "f" else "P_b"
        T = self._derived["T_f" if which == "f" else "T_b"]
        val = self._blend(key, j, t, self._x(wavelength), s, cubic=False)
        return val / (T[j] * (1 - t) + T[j + 1] * t)

    def sample_lobe(self, which: str, wi, xi, wavelength: float) -> np.ndarray:
        """Directions ``wo`` (n, 3) of the forward ("f") or backward ("b") lobe for one ``wi`` (3,).

        ``xi`` (n, 3) uniform: xi[:, 0] picks the row, xi[:, 1:] the chord and azimuth.
        """
        wi = np.asarray(wi, dtype=np.float64)
        xi = np.asarray(xi, dtype=np.float64)
        j, t = self._row(float(wavelength))
        j, t = int(j), float(t)
        T = self._derived["T_f" if which == "f" else "T_b"]
        p_next = t * T[j + 1] / ((1 - t) * T[j] + t * T[j + 1])
        rows = np.where(xi[:, 0] < p_next, j + 1, j)
        s = np.empty(len(xi))
        for row in np.unique(rows):
            sel = rows == row
            s[sel] = self._radial(which, int(row)).sample_radius(xi[sel, 1])
        s = np.minimum(s * self.rows["x"][rows] / float(self._x(wavelength)), 2.0)   # the row's chord, scaled
        phi = 2 * np.pi * xi[:, 2]
        axis = -wi if which == "f" else wi
        cos_t = 1 - 0.5 * s * s
        sin_t = s * np.sqrt(np.maximum(1 - 0.25 * s * s, 0.0))
        e1, e2 = _frame(axis)
        return (cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))

    # ------------------------------------------------------------------
    # energy checks
    # ------------------------------------------------------------------
    def directional_albedo(self, cos_theta_i: float, wavelength: float = 550.0, phi_i: float = 0.0,
                           n_phi: int | None = None, pane: bool = True) -> dict:
        """Energy of each component for light from ``cos_theta_i`` (the white furnace).

        The tabulated lobes are integrated over the sphere of directions on
        their own chord grids (``dΩ = s ds dφ``, trapezoid in s at twice the
        table's resolution, midpoint in φ, ``n_phi`` azimuths); on a pane the
        lobes' far-side part also enters the lobe in reflection (:meth:`eval`).

        Parameters
        ----------
        cos_theta_i : float in [-1, 1], not 0
            Signed cosine of ``wi``.
        wavelength : float
            Wavelength [nm].
        phi_i : float
            Azimuth of ``wi`` (the layer is isotropic: the result does not depend on it).
        n_phi : int, optional
            Azimuths of the quadrature (default 256).
        pane : bool
            False: the layer alone (without its substrate).

        Returns
        -------
        dict: :class:`corona.Material`'s keys ``coherent``, ``specular``, ``lobe_transmission``,
        ``lobe_reflection``, ``diffuse`` (0: no opaque part) and ``total`` (<= 1), plus the
        layer's own lobes ``forward`` and ``backward`` (without the pane's factors).
        """
        ci = check_range("cos_theta_i", cos_theta_i, -1.0, 1.0)
        if ci == 0.0:
            raise CoronaError("cos_theta_i=0 is out of range; allowed [-1, 0) or (0, 1]")
        n_phi = 256 if n_phi is None else n_phi
        wi = np.array([math.sqrt(max(0.0, 1 - ci * ci)), 0.0, ci])
        K = self.rows["P_f"].shape[1]
        s = np.linspace(0.0, CHORD_MAX, 2 * K - 1)
        ws = np.full(s.size, s[1] - s[0])
        ws[0] = ws[-1] = 0.5 * ws[0]
        phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
        part = self.substrate_part if pane else BareLayer()
        coherent = float(self.energies(ci, wavelength)["coherent"])
        t_i = float(part.fresnel(ci)[1])
        out = {"coherent": coherent * t_i,
               "specular": float(part.specular_reflection(self, ci, wavelength)),
               "lobe_transmission": 0.0, "lobe_reflection": 0.0, "diffuse": 0.0,
               "forward": 0.0, "backward": 0.0}
        if self.lattice is not None:
            # the orders and the diffuse part on their own quadrature (a Bragg peak is far
            # narrower than the chord grid's azimuths): lattice_nodes, scaled by F_s w
            st = math.sqrt(max(0.0, 1 - ci * ci))
            wi = np.array([st * math.cos(phi_i), st * math.sin(phi_i), ci])
            nodes = self.lattice_nodes(wi, wavelength)
            wo = nodes["wo"]
            e = nodes["energy"] * float(self._slant(ci)) * float(self._lattice_weight(wi, wavelength, ()))
            out["forward"] = float(np.sum(e[nodes["forward"]]))
            out["backward"] = float(np.sum(e[~nodes["forward"]]))
            lobes = [(wo, e)]
        else:
            lobes = []
        for which, axis in (("forward", -wi), ("backward", wi)) if self.lattice is None else ():
            e1, e2 = _frame(axis)
            cos_t = 1 - 0.5 * s * s
            sin_t = s * np.sqrt(1 - 0.25 * s * s)
            wo = (cos_t[:, None, None] * axis + sin_t[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2))
            val = self._layer_eval(wi, wo, wavelength)[0]
            dw = (ws * s)[:, None] * (2 * np.pi / n_phi)
            # the chord s = √2 is shared by both lobes: eval assigns it to one, the other's
            # trapezoid end weight there is 0.5 of a thin ring, negligible
            e = val * dw
            out[which] = float(np.sum(e))
            lobes.append((wo, e))
        for wo, e in lobes:
            same = np.sign(wo[..., 2]) == np.sign(ci)
            # each direction's energy as eval splits it (the mirrored part: wo' on the far side)
            through, own, mirrored = part.lobe_factors(np.full(wo.shape[:-1], ci), wo[..., 2], coherent)
            out["lobe_reflection"] += float(np.sum(np.where(same, e * own, e * mirrored)))
            out["lobe_transmission"] += float(np.sum(np.where(same, 0.0, e * through)))
        out["total"] = sum(out[k] for k in ("coherent", "specular", "lobe_transmission", "lobe_reflection",
                                             "diffuse"))
        return out

    def diffuse_transmittance(self, wavelength=550.0, cos_theta_i=None, phi_i=0.0) -> float | np.ndarray:
        """The lobes' energy leaving through the far side (``lobe_transmission`` of
        :meth:`directional_albedo`) for light from ``cos_theta_i`` (None: normal incidence).
        ``phi_i`` is accepted for the shared signature (the layer is isotropic)."""
        ci = 1.0 if cos_theta_i is None else float(cos_theta_i)
        # at normal incidence the lobes are symmetric about the axis: a few azimuths suffice
        return self.directional_albedo(ci, wavelength, n_phi=4 if abs(ci) == 1.0 else 256)["lobe_transmission"]

    @property
    def reflectance(self) -> float:
        """The layer's lobes' energy back to the incident side at normal incidence and 550 nm (the
        backward lobe: glory, fogbow; the layer alone); the spheres absorb what ``ior_imag`` takes."""
        return self.directional_albedo(1.0, 550.0, n_phi=4, pane=False)["lobe_reflection"]

    @property
    def lobe_weight(self) -> float:
        """The lobe's prefactor ``F_a`` (the energy cap ``w`` is part of :meth:`lobe`)."""
        return float(self.area_fraction)

    def lobe_dimensionless_radial(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(|u|)`` with ``lobe(d, λ) = F_a (R/λ)² v(2π R |d| / λ)`` at ``wavelength`` [nm]
        (the shared protocol of :class:`corona.Material`; a sphere's pattern is not a function of
        ``u`` alone, so ``v`` belongs to one wavelength).  0 where ``|d| >= 1``."""
        if self.lattice is not None:
            raise CoronaError(f"{self!r}: a fixed lattice's lobe is anisotropic; use lobe_dimensionless(u) "
                              "with u of shape (..., 2)")
        u = np.abs(check_finite_array("u", u))
        lam = float(wavelength) * 1e-3
        rho = u * lam / (2 * np.pi * self.length_scale)
        d = np.stack([np.minimum(rho, 1.0), 0 * rho], -1)
        val = self.lobe(d, float(wavelength))
        return np.where(rho < 1.0, val / (self.area_fraction * (self.length_scale / lam) ** 2), 0.0)

    def lobe_dimensionless(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(u)`` at ``u`` (..., 2): the radial one at ``|u|`` for an isotropic layer; on a fixed
        lattice the lobe at ``d = u λ / (2π R)`` itself (0 where ``|d| >= 1``)."""
        u = check_finite_array("u", u)
        if self.lattice is None:
            return self.lobe_dimensionless_radial(np.hypot(u[..., 0], u[..., 1]), wavelength)
        if u.ndim == 0 or u.shape[-1] != 2:
            raise CoronaError(f"u must have shape (..., 2), got {u.shape}")
        lam = float(wavelength) * 1e-3
        d = u * lam / (2 * np.pi * self.length_scale)
        inside = np.sum(d * d, axis=-1) < 1.0
        val = self.lobe(np.where(inside[..., None], d, 0.0), float(wavelength))
        return np.where(inside, val / (self.area_fraction * (self.length_scale / lam) ** 2), 0.0)

    def lobe_tabulated(self, d, wavelength) -> np.ndarray:
        """The lobe as the renderer evaluates it: :meth:`lobe` reads the same tables."""
        return self.lobe(d, wavelength)


def _frame(n):
    """Two unit vectors completing ``n`` (3,) to an orthonormal frame (Duff et al. 2017)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return (np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]]),
            np.array([b, sign + n[1] * n[1] * a, -n[1]]))


def _sphere_from(p: dict) -> Sphere:
    """The factory of ``shape=sphere`` (:mod:`corona.model.registry`)."""
    if p.get("ior") is None and p.get("ior_imag"):
        raise CoronaError(f"ior_imag={p['ior_imag']!r} needs ior=<real part> (the default, water, "
                          "does not absorb)")
    if p["radius"] > SPHERE_RADIUS_MAX:   # the Mie tables' range (their build time)
        raise CoronaError(f"radius={p['radius']!r} is out of range for shape='sphere'; allowed "
                          f"(0, {SPHERE_RADIUS_MAX:g}] µm (larger droplets: use shape='circle', "
                          "whose Fraunhofer corona theirs approaches)")
    ior = None if p.get("ior") is None else complex(p["ior"], p.get("ior_imag") or 0.0)
    return Sphere(p["radius"], ior=ior)


def _sphere_material(shape, process, p: dict, given: dict, substrate) -> SphereMaterial:
    # droplets in air: particles; the mode given must say so.  Every process: a fixed lattice
    # (the plugin's own path, corona.mitsuba.sphere_lattice), a point file's S(q) is radial
    return SphereMaterial(shape, process, mode=given.get("mode") or "particle", substrate=substrate)


# --- the family (corona.model.registry): shape=sphere --------------------------------------------
# edge_width, orientation, angle, aspect and albedo mean nothing for a Mie sphere (a sharp surface,
# the same from every side, reflecting by Mie theory): it does not read them, so a given value gets
# the one unused-parameter warning and is ignored
registry.add_shape(registry.ShapeFamily("sphere", _sphere_from, ("radius", "ior", "ior_imag"), cls=Sphere,
                                        bsdf="corona.mitsuba.sphere:sphere_bsdf_class",
                                        material=_sphere_material))
