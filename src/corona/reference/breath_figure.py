"""Breath figures: droplets that nucleate, grow, coalesce and evaporate on a plane.

A simulation of dropwise condensation in the spirit of Beysens & Knobler
(PRL 57, 1433, 1986), Family & Meakin (PRL 61, 428, 1988) and Fritter,
Knobler & Beysens (PRA 43, 2858, 1991).  Lengths in µm, times in s, volumes
in µm³.

The model (each choice the physics leaves open is marked *choice*):

* **Box.**  A periodic square of side ``box`` (µm).  Distances are minimum
  images, so every drop must stay smaller than ``box / 4`` in contact radius
  (:class:`~corona.CoronaError` otherwise: the box is too small for that time).
* **Drops** are spherical caps of one contact angle θ: contact radius ``a``
  and volume ``V = π a³ f(θ) / 3`` with
  ``f(θ) = (1 − cos θ)² (2 + cos θ) / sin³ θ`` (``f = 2`` for hemispheres,
  θ = 90°).  *Choice:* no contact-angle hysteresis; a drop is always at its
  equilibrium angle (pinning would raise the coverage).
* **Nucleation.**  Candidate nuclei land uniformly at the rate
  ``nucleation_rate`` J (µm⁻² s⁻¹, a Poisson number per step); one whose
  centre falls on a drop is discarded, so the rate acts per unit *free* area
  and renucleation fills the area freed by coalescence.  Nuclei start with
  contact radius ``nucleus_radius``, and their volume is added to the
  condensed water.  Nucleation acts only during condensation and only until
  ``nucleation_stop`` (s; ``None``: for ever).  *Choice:* no depletion zone
  around drops (Fritter et al. 1991 discuss one); a burst (a finite
  ``nucleation_stop``) is the situation of the classic experiments, where the
  nucleation sites are used up early.
* **Growth.**  Water condenses at a fixed volume per unit substrate area and
  time, ``flux`` (µm s⁻¹, the thickness of the water film it would make),
  shared among the drops in proportion to their contact radius:
  ``dV_i/dt = flux · box² · a_i / Σ_j a_j``.  The weight ``a_i`` is the
  diffusion-limited growth of an isolated drop (``dV/dt ∝ a``); normalising by
  the total is the overlap of the drops' diffusion fields (Beysens & Knobler
  1986: the substrate receives a uniform flux).  While the number of drops is
  fixed the mean volume grows ∝ t, hence ⟨a⟩ ∝ t^(1/3) (isolated growth); once
  coalescence holds the coverage fixed, the water per area ∝ ⟨a⟩ ∝ t
  (the coalescence regime of Family & Meakin 1988).  Steps are explicit
  (Euler) and geometric: ``dt = step · max(t, t₁/10)`` with ``t₁`` the first
  output time, landing on every output time and phase change.
* **Coalescence.**  Two drops merge when their contact discs touch
  (``|r_i − r_j| ≤ a_i + a_j``; *choice:* exact for θ ≤ 90°, for θ > 90° the
  caps would touch a little earlier).  The merged drop keeps the sum of the
  volumes (exact to rounding) and sits at the volume-weighted centre
  (*choice:* Fritter et al. 1991; the real drop relaxes towards it within
  milliseconds).  Merges are repeated until no pair overlaps, using a cell
  list in which each drop is entered in every cell its disc's bounding box
  meets.  Growth is applied before merging in every step, so after each step
  no overlap remains.
* **Evaporation.**  From ``dry_from`` (s) on, the flux is
  ``−evaporation_rate`` (µm s⁻¹), shared by the same weights: small drops
  lose their volume first and vanish when it reaches zero; the share a
  vanishing drop cannot give is taken from the others (in the same
  proportion), so water leaves at exactly the prescribed rate until none is
  left.

Defaults are for water on (silanised) glass under a breath-like flux:
θ = 90° (Beysens & Knobler 1986 used silanised glass, θ ≈ 90°), a film rate
of 0.1 µm/s, nuclei of 0.25 µm contact radius (diameter 0.5 µm) appearing at
0.05 µm⁻² s⁻¹ — orders of magnitude, not fitted to an experiment.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from corona._validation import CoronaError, check_positive, check_range

# ==========================================================================
# numba kernels
# ==========================================================================


@nb.njit(cache=True)
def _wrap(d, L):
    if d > 0.5 * L:
        d -= L
    elif d < -0.5 * L:
        d += L
    return d


@nb.njit(cache=True)
def _cell_box(x, y, a, c, m):
    """The cells (unwrapped, ``x0..x1`` × ``y0..y1``) that a disc's bounding box meets; all of an axis
    when the box spans the periodic box."""
    x0 = int(math.floor((x - a) / c))
    x1 = int(math.floor((x + a) / c))
    y0 = int(math.floor((y - a) / c))
    y1 = int(math.floor((y + a) / c))
    if x1 - x0 + 1 >= m:
        x0, x1 = 0, m - 1
    if y1 - y0 + 1 >= m:
        y0, y1 = 0, m - 1
    return x0, x1, y0, y1


@nb.njit(cache=True)
def _cells(x, y, a, n, L, m):
    """CSR cell list: drop ``i`` in every cell its disc's bounding box meets."""
    c = L / m
    count = np.zeros(m * m + 1, np.int64)
    for i in range(n):
        x0, x1, y0, y1 = _cell_box(x[i], y[i], a[i], c, m)
        for cy in range(y0, y1 + 1):
            for cx in range(x0, x1 + 1):
                count[(cy % m) * m + (cx % m) + 1] += 1
    for k in range(m * m):
        count[k + 1] += count[k]
    idx = np.empty(count[m * m], np.int64)
    fill = count[:m * m].copy()
    for i in range(n):
        x0, x1, y0, y1 = _cell_box(x[i], y[i], a[i], c, m)
        for cy in range(y0, y1 + 1):
            for cx in range(x0, x1 + 1):
                k = (cy % m) * m + (cx % m)
                idx[fill[k]] = i
                fill[k] += 1
    return count, idx


@nb.njit(cache=True)
def _merge_all(x, y, V, a, n, L, m, kf):
    """Merge every touching pair (volume-weighted centre, summed volume) until
    no pair overlaps; compact the arrays.  Returns ``(n_new, merges)``."""
    alive = np.ones(n, np.bool_)
    total = 0
    while True:
        count, idx = _cells(x, y, a, n, L, m)
        merged = 0
        for k in range(m * m):
            for p in range(count[k], count[k + 1]):
                i = idx[p]
                if not alive[i]:
                    continue
                for q in range(p + 1, count[k + 1]):
                    j = idx[q]
                    if not alive[j] or j == i:
                        continue
                    dx = _wrap(x[j] - x[i], L)
                    dy = _wrap(y[j] - y[i], L)
                    s = a[i] + a[j]
                    if dx * dx + dy * dy <= s * s:
                        w = V[j] / (V[i] + V[j])
                        xi = x[i] + w * dx
                        yi = y[i] + w * dy
                        x[i] = xi - L * math.floor(xi / L)
                        y[i] = yi - L * math.floor(yi / L)
                        V[i] = V[i] + V[j]
                        a[i] = (V[i] / kf) ** (1.0 / 3.0)
                        alive[j] = False
                        merged += 1
        total += merged
        if merged == 0:
            break
        # compact so that the next pass sees only live drops
        w = 0
        for i in range(n):
            if alive[i]:
                x[w] = x[i]
                y[w] = y[i]
                V[w] = V[i]
                a[w] = a[i]
                alive[w] = True
                w += 1
        n = w
    return n, total


@nb.njit(cache=True)
def _grow(V, a, n, dvol, kf):
    """Share the volume ``dvol`` (< 0: evaporation) in proportion to ``a``.  A
    drop whose share exceeds its volume vanishes (volume 0) and the rest of its
    share goes to the others, again in proportion to ``a``, so the whole
    ``dvol`` is applied unless every drop vanishes.  Returns the volume applied."""
    applied = 0.0
    left = dvol
    live = np.ones(n, np.bool_)
    for _ in range(n + 1):
        sa = 0.0
        for i in range(n):
            if live[i]:
                sa += a[i]
        if sa <= 0.0 or left == 0.0:
            break
        gone = False
        if left < 0.0:
            for i in range(n):
                if live[i] and V[i] + left * a[i] / sa <= 0.0:
                    live[i] = False
                    left += V[i]
                    applied -= V[i]
                    V[i] = 0.0
                    a[i] = 0.0
                    gone = True
        if gone:
            continue            # the shares change: recompute them among the survivors
        for i in range(n):
            if live[i]:
                V[i] += left * a[i] / sa
        applied += left
        left = 0.0
    for i in range(n):
        if live[i]:
            a[i] = (V[i] / kf) ** (1.0 / 3.0)
    return applied


@nb.njit(cache=True)
def _drop_empty(x, y, V, a, n):
    w = 0
    for i in range(n):
        if V[i] > 0.0:
            x[w] = x[i]
            y[w] = y[i]
            V[w] = V[i]
            a[w] = a[i]
            w += 1
    return w


@nb.njit(cache=True)
def _free(cx, cy, x, y, a, n, L, m):
    """Mask of the candidate points that fall on no drop."""
    count, idx = _cells(x, y, a, n, L, m)
    c = L / m
    ok = np.ones(cx.shape[0], np.bool_)
    for t in range(cx.shape[0]):
        k = (min(int(cy[t] / c), m - 1)) * m + min(int(cx[t] / c), m - 1)
        for p in range(count[k], count[k + 1]):
            i = idx[p]
            dx = _wrap(cx[t] - x[i], L)
            dy = _wrap(cy[t] - y[i], L)
            if dx * dx + dy * dy < a[i] * a[i]:
                ok[t] = False
                break
    return ok


# ==========================================================================
# Python layer
# ==========================================================================


def cap_volume_factor(contact_angle: float) -> float:
    """``k`` in ``V = k a³`` for a spherical cap of contact angle θ (degrees):
    ``k = π (1 − cos θ)² (2 + cos θ) / (3 sin³ θ)`` (``2π/3`` at 90°)."""
    th = math.radians(check_range("contact_angle", contact_angle, 0.0, 180.0,
                                  lo_open=True, hi_open=True, unit="degrees"))
    c, s = math.cos(th), math.sin(th)
    return math.pi * (1.0 - c) ** 2 * (2.0 + c) / (3.0 * s ** 3)


def _cell_count(a: np.ndarray, n: int, L: float) -> int:
    if n == 0:
        return 1
    amean = float(np.mean(a[:n]))
    return int(max(1, min(L / max(2.5 * amean, 1e-12), 2.0 * math.sqrt(n) + 1, 2048)))


def merge_droplets(centres, radii, box: float, contact_angle: float = 90.0):
    """Merge every pair of drops that touch, until no overlap remains.

    Parameters
    ----------
    centres : (N, 2) array_like
        Drop centres (µm), in ``[0, box)``.
    radii : (N,) array_like
        Contact radii (µm), > 0.
    box : float
        Side of the periodic square (µm).
    contact_angle : float
        Contact angle θ of the caps (degrees, in (0, 180)).

    Returns
    -------
    centres : (M, 2) ndarray
    radii, volumes : (M,) ndarray
        The merged drops (volumes in µm³; each merged drop holds the sum of
        its parents' volumes at their volume-weighted centre).
    """
    L = check_positive("box", box, "µm")
    kf = cap_volume_factor(contact_angle)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    r = np.asarray(radii, dtype=np.float64).ravel()
    if r.shape[0] != c.shape[0]:
        raise CoronaError(f"radii has {r.shape[0]} entries; expected one per centre ({c.shape[0]})")
    if not (np.all(np.isfinite(r)) and np.all(r > 0)):
        raise CoronaError("radii must be finite and > 0 µm")
    if not np.all(np.isfinite(c)):
        raise CoronaError("centres must be finite (µm)")
    if r.size and r.max() >= L / 4:
        raise CoronaError(f"radii max={r.max():g} is out of range; allowed < box/4 = {L / 4:g} µm")
    x, y = np.mod(c[:, 0], L), np.mod(c[:, 1], L)
    V = kf * r ** 3
    a = r.copy()
    n, _ = _merge_all(x, y, V, a, len(r), L, _cell_count(a, len(r), L), kf)
    return np.stack([x[:n], y[:n]], -1), a[:n].copy(), V[:n].copy()


@dataclass
class BreathFigure:
    """A breath-figure run: the drops at each output time.

    Attributes
    ----------
    times : (T,) ndarray
        Output times (s).
    centres, radii, volumes : list of T ndarrays
        Drop centres (N_t, 2) (µm), contact radii (µm) and volumes (µm³).
    coverage : (T,) ndarray
        Fraction of the substrate under water, ``Σ π a² / box²`` (exact: no
        drops overlap).
    box : float
        Side of the periodic square (µm).
    contact_angle : float
        Contact angle (degrees).
    params : dict
        Every parameter of the run.
    merges : (T,) ndarray
        Coalescence events up to each output time.
    seconds : float
        Wall time of the run.
    """

    times: np.ndarray
    centres: list
    radii: list
    volumes: list
    coverage: np.ndarray
    box: float
    contact_angle: float
    params: dict = field(default_factory=dict)
    merges: np.ndarray = None
    seconds: float = 0.0

    @property
    def count(self) -> np.ndarray:
        """Number of drops at each output time."""
        return np.array([len(r) for r in self.radii])

    @property
    def mean_radius(self) -> np.ndarray:
        """Mean contact radius (µm) at each output time (NaN without drops)."""
        return np.array([r.mean() if len(r) else np.nan for r in self.radii])

    @property
    def total_volume(self) -> np.ndarray:
        """Water on the substrate (µm³) at each output time."""
        return np.array([v.sum() for v in self.volumes])


def simulate_breath_figure(times, *, box: float = 100.0, contact_angle: float = 90.0,
                           flux: float = 0.1, nucleation_rate: float = 0.05,
                           nucleus_radius: float = 0.25, nucleation_stop: float | None = None,
                           dry_from: float | None = None, evaporation_rate: float = 0.1,
                           step: float = 0.02, seed: int = 0,
                           progress: bool = False) -> BreathFigure:
    """Simulate a breath figure: nucleation, growth, coalescence, evaporation.

    The model and its choices are described in the module docstring
    (:mod:`corona.reference.breath_figure`).

    Parameters
    ----------
    times : array_like
        Output times (s), increasing, > 0.  The run starts from a dry
        substrate at t = 0.
    box : float
        Side of the periodic square (µm, > 0).
    contact_angle : float
        Contact angle θ of the caps (degrees, in (0, 180)); 90: hemispheres.
    flux : float
        Condensation rate (µm s⁻¹: water volume per substrate area and time,
        > 0).
    nucleation_rate : float
        Nuclei per free area and time (µm⁻² s⁻¹, >= 0).
    nucleus_radius : float
        Contact radius of a new nucleus (µm, > 0).
    nucleation_stop : float or None
        No nucleation after this time (s); ``None``: nucleation for as long as
        water condenses.
    dry_from : float or None
        From this time on (s) the water evaporates at ``evaporation_rate`` and
        nothing nucleates; ``None``: condensation throughout.
    evaporation_rate : float
        Evaporation rate after ``dry_from`` (µm s⁻¹, > 0).
    step : float
        Relative time step, ``dt = step · max(t, t₁/10)`` (in (0, 0.5]).
    seed : int
        Seed of the run (same seed, same result).
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    BreathFigure

    References
    ----------
    D. Beysens and C. M. Knobler, Growth of breath figures, Phys. Rev. Lett.
    57, 1433 (1986).
    F. Family and P. Meakin, Scaling of the droplet-size distribution in
    vapor-deposited thin films, Phys. Rev. Lett. 61, 428 (1988).
    D. Fritter, C. M. Knobler and D. A. Beysens, Experiments and simulation of
    the growth of droplets on a surface (breath figures), Phys. Rev. A 43,
    2858 (1991).
    """
    run = _checked_run(times, box, contact_angle, flux, nucleation_rate, nucleus_radius,
                       nucleation_stop, dry_from, evaporation_rate, step, seed)
    L, t_out = run["L"], run["t_out"]
    rng = np.random.default_rng(int(seed))
    drops = _Drops()
    t = 0.0
    tmin = t_out[0] / 10.0
    merges = 0
    out_c, out_r, out_v, out_m, cov = [], [], [], [], []
    breaks = sorted({float(b) for b in (run["t_stop"], run["t_dry"]) if math.isfinite(b)})
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(t_out), desc="corona: breath figure", unit="frame", leave=False)
    t0 = time.perf_counter()
    try:
        for t_next in t_out:
            while t < t_next:
                t_end = min(t + run["step"] * max(t, tmin), t_next)
                for b in breaks:
                    if t < b < t_end:
                        t_end = b
                merges += _advance(drops, run, rng, t, t_end, box)
                t = t_end
            x, y, V, a, n = drops.x, drops.y, drops.V, drops.a, drops.n
            out_c.append(np.stack([x[:n], y[:n]], -1).copy())
            out_r.append(a[:n].copy())
            out_v.append(V[:n].copy())
            out_m.append(merges)
            cov.append(float(np.pi * np.sum(a[:n] ** 2) / (L * L)))
            if bar is not None:
                bar.update(1)
                bar.set_postfix(drops=n)
    finally:
        if bar is not None:
            bar.close()
    params = dict(box=L, contact_angle=float(contact_angle), flux=run["F"], nucleation_rate=run["J"],
                  nucleus_radius=run["a0"], nucleation_stop=nucleation_stop, dry_from=dry_from,
                  evaporation_rate=run["E"], step=run["step"], seed=int(seed))
    return BreathFigure(times=t_out, centres=out_c, radii=out_r, volumes=out_v,
                        coverage=np.array(cov), box=L, contact_angle=float(contact_angle),
                        params=params, merges=np.array(out_m), seconds=time.perf_counter() - t0)


def _checked_run(times, box, contact_angle, flux, nucleation_rate, nucleus_radius, nucleation_stop,
                 dry_from, evaporation_rate, step, seed) -> dict:
    """The checked arguments of :func:`simulate_breath_figure` (one :class:`CoronaError` naming the
    parameter, its value and the allowed range otherwise)."""
    L = check_positive("box", box, "µm")
    kf = cap_volume_factor(contact_angle)
    F = check_positive("flux", flux, "µm/s")
    J = check_range("nucleation_rate", nucleation_rate, 0.0, math.inf, hi_open=True, unit="1/(µm² s)")
    a0 = check_positive("nucleus_radius", nucleus_radius, "µm")
    if a0 >= L / 4:
        raise CoronaError(f"nucleus_radius={nucleus_radius!r} is out of range; allowed < box/4 = {L / 4:g} µm")
    E = check_positive("evaporation_rate", evaporation_rate, "µm/s")
    step = check_range("step", step, 0.0, 0.5, lo_open=True)
    t_stop = math.inf if nucleation_stop is None else check_range(
        "nucleation_stop", nucleation_stop, 0.0, math.inf, hi_open=True, unit="s")
    t_dry = math.inf if dry_from is None else check_range(
        "dry_from", dry_from, 0.0, math.inf, hi_open=True, unit="s")
    try:
        t_out = np.asarray(times, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise CoronaError(f"times={times!r} is not a list of numbers (s)") from None
    if t_out.size == 0 or not np.all(np.isfinite(t_out)) or t_out[0] <= 0 or np.any(np.diff(t_out) <= 0):
        raise CoronaError(f"times={times!r} is out of range; expected increasing finite times > 0 s")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise CoronaError(f"seed={seed!r} is out of range; expected an integer >= 0")
    return dict(L=L, kf=kf, F=F, J=J, a0=a0, E=E, step=step, t_stop=t_stop, t_dry=t_dry, t_out=t_out)


class _Drops:
    """The drops of a run: centres ``x``, ``y`` [µm], volumes ``V`` [µm³] and contact radii ``a``
    [µm] in arrays whose capacity doubles when full; the first ``n`` entries are the drops."""

    def __init__(self, cap: int = 1024):
        self.x, self.y, self.V, self.a = (np.empty(cap) for _ in range(4))
        self.n = 0

    def add(self, cx, cy, a0: float, kf: float) -> None:
        """Nuclei of contact radius ``a0`` [µm] at (``cx``, ``cy``)."""
        n, k = self.n, len(cx)
        if n + k > len(self.x):
            cap = max(2 * len(self.x), n + k)
            self.x, self.y, self.V, self.a = (np.concatenate([arr[:n], np.empty(cap - n)])
                                              for arr in (self.x, self.y, self.V, self.a))
        self.x[n:n + k], self.y[n:n + k] = cx, cy
        self.a[n:n + k] = a0
        self.V[n:n + k] = kf * a0 ** 3
        self.n = n + k


def _advance(drops: _Drops, run: dict, rng, t: float, t_end: float, box) -> int:
    """One time step from ``t`` to ``t_end`` [s]: growth (or evaporation) of the drops present,
    nucleation on the free area, then merging until no two drops overlap; the number of merges."""
    L, kf, dt = run["L"], run["kf"], t_end - t
    drying = t >= run["t_dry"]
    if drops.n:
        _grow(drops.V, drops.a, drops.n, (-run["E"] if drying else run["F"]) * L * L * dt, kf)
        if drying:
            drops.n = _drop_empty(drops.x, drops.y, drops.V, drops.a, drops.n)
    if not drying and t < run["t_stop"] and run["J"] > 0:
        k = rng.poisson(run["J"] * L * L * dt)
        if k:
            cx = rng.random(k) * L
            cy = rng.random(k) * L
            if drops.n:
                ok = _free(cx, cy, drops.x, drops.y, drops.a, drops.n, L, _cell_count(drops.a, drops.n, L))
                cx, cy = cx[ok], cy[ok]
            drops.add(cx, cy, run["a0"], kf)
    n, a = drops.n, drops.a
    if not n:
        return 0
    if a[:n].max() >= L / 4:
        raise CoronaError(f"box={box!r} is out of range at t={t_end:g} s: a drop of radius "
                          f"{a[:n].max():g} µm needs box > {4 * a[:n].max():g} µm")
    drops.n, merges = _merge_all(drops.x, drops.y, drops.V, a, n, L, _cell_count(a, n, L), kf)
    return merges
