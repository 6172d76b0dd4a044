"""The Mie rows of a layer of transparent spheres: what the renderer evaluates and samples.

Built and read by :class:`corona.model.mie.material.SphereMaterial` (the numpy layer) and
:mod:`corona.mitsuba.sphere` (the plugin); the model they tabulate is in
:mod:`corona.model.mie.material` (docs/physics.md#transparent-droplets-mie-spheres).

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
line up; :func:`scaled_blend`), with Catmull–Rom cubics in the chord for the
value, and is sampled exactly by picking row j with probability
``(1 - t) T_j / ((1 - t) T_j + t T_j+1)`` (``T`` the rows' totals), drawing that
row's chord and scaling it: the pdf is the interpolated P over the interpolated
total, so sampling is proportional to the tabulated ``P``.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from corona.model import tabulated   # the table types and the cache
from corona.model.mie import theory as mie
from corona.model.shapes.modifiers import SizeDistribution
from corona.model.mie.sphere import Sphere

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
    (see :func:`scaled_blend`), up to ``√2 x_j+1 / x_j`` for the wavelengths above it."""
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
    """The lookup's value between two rows (:func:`scaled_blend`, Catmull–Rom) at the weight of
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


def rows_key(shape, radius_cover=None, preview: bool = False) -> dict:
    """The table-cache key of the rows of ``shape`` (a :class:`corona.Sphere` or a size distribution
    of one): the settings of every build here, the ``radius_cover`` and, for a preview
    (:func:`build_preview_rows`), its settings (:meth:`corona.model.mie.material.SphereMaterial.table_params`)."""
    key = {"sphere_format": SPHERE_FORMAT, "shape": tabulated.identity(shape),
           "rows_x": [ROW_DLNX, ROW_DX_START, ROW_DX_MIN, ROW_DX_FINE, ROW_TOLERANCE, ROW_TEST_STRIDE],
           "chord_dx": [CHORD_DX, CHORD_DX_SPREAD, SPREAD_COARSE_CHORD], "nodes": [MIN_NODES, MAX_NODES],
           "rows": [MIN_ROWS, MAX_ROWS],
           "sizes": [SIZE_DX, SIZE_PER_SIGMA, MAX_SIZE_SAMPLES, MAX_SIZE_TOTAL, SIZE_TAIL, SIZE_DM, SIZE_ROW_DX,
                     SIZE_ROW_DLNX, SIZE_ROW_RULE, SPREAD_CHORD_SMOOTH, SIZE_INDEX_ORDER, SIZE_TAIL_ROWS,
                     SPREAD_CHORD_RULE, SIZE_RES_DX, SIZE_RES_PER_SIGMA, SIZE_STEP_RULE, SIZE_DM_PHASE,
                     SIZE_DM_SMOOTH],
           "angular_dtype": np.dtype(ANGULAR_DTYPE).name,
           "wavelengths": [tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX]}
    if radius_cover is not None:
        key["radius_cover"] = list(radius_cover)
    if preview:
        key["preview"] = [PREVIEW_ROWS, PREVIEW_CHORD_DX, PREVIEW_MAX_NODES]
    return key


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


def catmull_rom(values, row, g):
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


def scaled_blend(values, ds, x_rows, j, t, x, s, cubic=True):
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
            v = catmull_rom(values, jj, g)
        else:
            i = np.clip(np.floor(g).astype(np.int64), 0, K - 2)
            f = np.clip(g - i, 0.0, 1.0)
            v = np.where(g <= K - 1, values[jj, i] * (1 - f) + values[jj, i + 1] * f, 0.0)
        out = out + wgt * v / (c * c)
    return out


def frame(n):
    """Two unit vectors completing ``n`` (3,) to an orthonormal frame (Duff et al. 2017)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return (np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]]),
            np.array([b, sign + n[1] * n[1] * a, -n[1]]))
