"""The far field of a breath figure, exactly and in the three approximations of a polydisperse layer.

A breath figure (:mod:`corona.reference.breath_figure`) is a periodic box of side ``L`` holding
``N`` droplets, centres ``r_j``, contact radii ``a_j``.  Seen from above (Fraunhofer, the model's
flat layer), droplet ``j`` is an opaque disk of its footprint radius ``a_j`` (*choice*: the contact
radius, the footprint of a cap of contact angle θ <= 90°; a cap of θ > 90° overhangs its contact
line, footprint ``a / sin θ``), amplitude ``F_j(q) = π a_j² · 2 J1(q a_j)/(q a_j)``.  On the box's
reciprocal lattice ``q = 2π (m, n)/L`` the diffuse intensity per droplet is exactly

    ``I(q) = |Σ_j F_j(q) e^{-i q·r_j}|² / N``                                    (the reference)

(the periodic box has no other wave vectors: no window, no leakage).  The approximations, each from
ingredients measured on the same configuration:

* **decoupling** (Kotlarchyk & Chen, J. Chem. Phys. 79, 2461, 1983; corona's rule,
  :func:`corona.model.layer.decoupled_lobe`): ``⟨|F|²⟩ + |⟨F⟩|² (S(q) - 1)`` with
  ``S = |Σ_j e^{-i q·r_j}|² / N`` the structure factor of all the centres;
* **local monodisperse** (Pedersen, J. Appl. Cryst. 27, 595, 1994):
  ``Σ_j |F_j|² S_HD(2 a_j q; η) / N``: every droplet sits among droplets of its own size, a hard-disk
  fluid (corona's table, :func:`corona.model.processes.hard_disk.structure_factor_table`) at the
  layer's coverage η (clipped to the table's 0.72);
* **partial structure factors** over ``K`` size classes (Ashcroft & Langreth, Phys. Rev. 156, 685,
  1967; Pedersen, Adv. Colloid Interface Sci. 70, 171, 1997): ``|Σ_k F̄_k ρ_k|² / N`` with
  ``ρ_k = Σ_{j∈k} e^{-i q·r_j}`` and ``F̄_k`` the class's mean amplitude, plus the decoupling within
  each class, ``Σ_k N_k (⟨|F|²⟩_k - |F̄_k|²) / N``.  ``K = 1`` is the decoupling approximation;
  ``K → N`` is exact.

Every quantity is evaluated at each lattice point and averaged over rings of ``|q|`` (what the
model's radial lobe is); one numba pass, the phases advanced by recurrence along each lattice row.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import special

from corona._validation import CoronaError

#: Step of the table of ``2 J1(x)/x`` the kernel interpolates linearly (error < 1e-7).
_G_STEP = 2e-3


def _airy_table(x_max: float) -> np.ndarray:
    x = np.arange(int(math.ceil(x_max / _G_STEP)) + 3) * _G_STEP
    g = np.ones_like(x)
    g[1:] = 2.0 * special.j1(x[1:]) / x[1:]
    return g


@nb.njit(cache=True, inline="always")
def _interp(table, step, x):
    t = x / step
    i = int(t)
    if i >= table.shape[0] - 1:
        return table[table.shape[0] - 1]
    f = t - i
    return table[i] * (1.0 - f) + table[i + 1] * f


@nb.njit(cache=True)
def _row_phases(x, y, m0, dq, qy):
    """``e^{-i q·r_j}`` at ``q = (m0 dq, qy)`` and its step ``e^{-i dq x_j}`` along the row (real and
    imaginary parts): then each point of the row costs one complex product per droplet."""
    N = x.shape[0]
    wr = np.empty(N)
    wi = np.empty(N)
    sr = np.empty(N)
    si = np.empty(N)
    for j in range(N):
        ph = -(m0 * dq * x[j] + qy * y[j])
        wr[j] = math.cos(ph)
        wi[j] = math.sin(ph)
        sr[j] = math.cos(-dq * x[j])
        si[j] = math.sin(-dq * x[j])
    return wr, wi, sr, si


@nb.njit(cache=True, parallel=True)
def _rings(x, y, a, cls, K, L, q_max, dq_ring, n_ring, g, g_step, shd, shd_step):
    """Ring sums over the half lattice ``q = 2π (m, n)/L``, ``0 < |q| <= q_max``: columns
    0 exact, 1 decoupling, 2 local monodisperse, 3 partial structure factors, 4 S, 5 ⟨|F|²⟩,
    6 |⟨F⟩|², 7 the number of lattice points."""
    N = x.shape[0]
    dq = 2.0 * math.pi / L
    nmax = int(q_max / dq)
    out = np.zeros((nmax + 1, n_ring, 8))
    area = math.pi * a * a
    for n in nb.prange(nmax + 1):
        qy = n * dq
        mmax = int(math.sqrt(max(q_max * q_max - qy * qy, 0.0)) / dq)
        m0 = 1 if n == 0 else -mmax
        wr, wi, sr, si = _row_phases(x, y, m0, dq, qy)    # phases at m = m0, their steps along the row
        rho_r = np.zeros(K)
        rho_i = np.zeros(K)
        f_sum = np.zeros(K)
        f2_sum = np.zeros(K)
        cnt = np.zeros(K)
        acc = out[n]
        for m in range(m0, mmax + 1):
            qx = m * dq
            q = math.sqrt(qx * qx + qy * qy)
            ring = int(q / dq_ring)
            if q <= q_max and ring < n_ring:
                ar = 0.0
                ai = 0.0
                tr = 0.0
                ti = 0.0
                p_sum = 0.0
                fm = 0.0
                lma = 0.0
                rho_r[:] = 0.0
                rho_i[:] = 0.0
                f_sum[:] = 0.0
                f2_sum[:] = 0.0
                cnt[:] = 0.0
                for j in range(N):
                    F = area[j] * _interp(g, g_step, q * a[j])
                    ar += F * wr[j]
                    ai += F * wi[j]
                    tr += wr[j]
                    ti += wi[j]
                    F2 = F * F
                    p_sum += F2
                    fm += F
                    lma += F2 * _interp(shd, shd_step, 2.0 * q * a[j])
                    k = cls[j]
                    rho_r[k] += wr[j]
                    rho_i[k] += wi[j]
                    f_sum[k] += F
                    f2_sum[k] += F2
                    cnt[k] += 1.0
                exact = (ar * ar + ai * ai) / N
                S = (tr * tr + ti * ti) / N
                P = p_sum / N
                C = (fm / N) * (fm / N)
                br = 0.0
                bi = 0.0
                within = 0.0
                for k in range(K):
                    if cnt[k] > 0:
                        fk = f_sum[k] / cnt[k]
                        br += fk * rho_r[k]
                        bi += fk * rho_i[k]
                        within += f2_sum[k] - cnt[k] * fk * fk
                acc[ring, 0] += exact
                acc[ring, 1] += P + C * (S - 1.0)
                acc[ring, 2] += lma / N
                acc[ring, 3] += (br * br + bi * bi + within) / N
                acc[ring, 4] += S
                acc[ring, 5] += P
                acc[ring, 6] += C
                acc[ring, 7] += 1.0
            # advance the phases by one lattice step along x
            for j in range(N):
                r = wr[j] * sr[j] - wi[j] * si[j]
                wi[j] = wr[j] * si[j] + wi[j] * sr[j]
                wr[j] = r
    return out.sum(axis=0)


@nb.njit(cache=True, parallel=True)
def _exact_rings(x, y, a, L, q_max, dq_ring, n_ring, g, g_step):
    """Column 0 (exact) and 7 (lattice points) of :func:`_rings` alone, by the same operations in
    the same order (the same values, bit for bit): ``(n_ring, 2)`` ring sums."""
    N = x.shape[0]
    dq = 2.0 * math.pi / L
    nmax = int(q_max / dq)
    out = np.zeros((nmax + 1, n_ring, 2))
    area = math.pi * a * a
    for n in nb.prange(nmax + 1):
        qy = n * dq
        mmax = int(math.sqrt(max(q_max * q_max - qy * qy, 0.0)) / dq)
        m0 = 1 if n == 0 else -mmax
        wr, wi, sr, si = _row_phases(x, y, m0, dq, qy)
        acc = out[n]
        for m in range(m0, mmax + 1):
            qx = m * dq
            q = math.sqrt(qx * qx + qy * qy)
            ring = int(q / dq_ring)
            if q <= q_max and ring < n_ring:
                ar = 0.0
                ai = 0.0
                for j in range(N):
                    F = area[j] * _interp(g, g_step, q * a[j])
                    ar += F * wr[j]
                    ai += F * wi[j]
                acc[ring, 0] += (ar * ar + ai * ai) / N
                acc[ring, 1] += 1.0
            for j in range(N):
                r = wr[j] * sr[j] - wi[j] * si[j]
                wi[j] = wr[j] * si[j] + wi[j] * sr[j]
                wr[j] = r
    return out.sum(axis=0)


def ring_error(exact, values) -> dict:
    """The relative error of ring averages ``values`` against the exact ones ``exact`` (the same
    rings, e.g. of :func:`far_field_rings`), over the rings holding at least 1e-3 of the exact
    peak: ``{"rms": ..., "max": ...}``.

    >>> e = ring_error(np.array([1.0, 2.0, 1e-6]), np.array([1.1, 1.8, 5.0]))   # the last ring: too faint
    >>> round(e["rms"], 12), round(e["max"], 12)
    (0.1, 0.1)
    """
    exact, values = np.asarray(exact, dtype=np.float64), np.asarray(values, dtype=np.float64)
    sel = exact > 1e-3 * exact.max()
    rel = values[sel] / exact[sel] - 1.0
    return {"rms": float(np.sqrt(np.mean(rel ** 2))), "max": float(np.max(np.abs(rel)))}


def size_classes(radii, K: int) -> np.ndarray:
    """Class of each droplet among ``K`` classes of equal covered area (quantiles of ``a²``-weighted
    radius), 0 the smallest."""
    a = np.asarray(radii, dtype=np.float64)
    if K <= 1:
        return np.zeros(a.size, np.int64)
    order = np.argsort(a)
    w = np.cumsum(a[order] ** 2)
    w /= w[-1]
    cls = np.empty(a.size, np.int64)
    cls[order] = np.minimum((w * K - 1e-12).astype(np.int64), K - 1)
    return cls


def far_field_rings(centres, radii, box: float, *, length: float, u_max: float = 14.0,
                    du: float = 0.25, classes: int = 6, coverage: float | None = None,
                    exact_only: bool = False) -> dict:
    """Ring averages (in ``u = |q| · length``) of the exact far field of one configuration and of
    its three approximations (module docstring), per droplet [µm⁴].

    Parameters
    ----------
    centres : (N, 2) array_like
        Droplet centres [µm] in the periodic box ``[0, box)²``.
    radii : (N,) array_like
        Footprint radii [µm] (opaque disks).
    box : float
        Side of the periodic box [µm].
    length : float
        The length [µm] of ``u = |q| · length``.
    u_max, du : float
        Range and width of the rings in ``u``.
    classes : int
        Size classes of the partial structure factors.
    coverage : float, optional
        The packing fraction of the local monodisperse approximation (default: the configuration's,
        ``Σ π a² / box²``), clipped to the hard-disk table's 0.72.
    exact_only : bool
        Only the exact far field (``u``, ``exact``, ``points``, ``coverage``), by a kernel that
        skips the approximations (the same values; a few times faster).

    Returns
    -------
    dict of ndarrays over the rings that hold lattice points: ``u`` (mean over each ring),
    ``exact``, ``decoupling``, ``local_monodisperse``, ``partial``, ``S``, ``P`` (⟨|F|²⟩),
    ``C`` (|⟨F⟩|²), ``points``; and ``coverage``, ``eta`` (used by the local monodisperse).
    """
    from corona.model.processes.hard_disk import ETA_MAX, structure_factor_table
    c = np.ascontiguousarray(np.asarray(centres, dtype=np.float64).reshape(-1, 2))
    a = np.ascontiguousarray(np.asarray(radii, dtype=np.float64).ravel())
    if a.size == 0 or a.size != c.shape[0]:
        raise CoronaError(f"far_field_rings: {a.size} radii for {c.shape[0]} centres; expected one each, >= 1")
    L = float(box)
    cov = float(np.pi * np.sum(a ** 2) / L ** 2) if coverage is None else float(coverage)
    eta = min(cov, ETA_MAX)
    q_max = u_max / length
    n_ring = int(math.ceil(u_max / du))
    g = _airy_table(q_max * a.max() + 1.0)
    if exact_only:
        sums = _exact_rings(np.mod(c[:, 0], L), np.mod(c[:, 1], L), a, L, q_max, du / length, n_ring, g,
                            _G_STEP)
        cnt = sums[:, 1]
    else:
        shd_step = 0.01
        qs = np.arange(int(math.ceil(2.0 * q_max * a.max() / shd_step)) + 3) * shd_step
        shd = np.asarray(structure_factor_table(qs, eta), dtype=np.float64)
        cls = size_classes(a, classes)
        sums = _rings(np.mod(c[:, 0], L), np.mod(c[:, 1], L), a, cls, int(max(classes, 1)), L, q_max,
                      du / length, n_ring, g, _G_STEP, shd, shd_step)
        cnt = sums[:, 7]
    keep = cnt > 0
    # the ring's mean u: recomputed from the lattice (cheap, numpy)
    dq = 2 * np.pi / L
    nmax = int(q_max / dq)
    m = np.arange(-nmax, nmax + 1)
    mm, nn = np.meshgrid(m, np.arange(nmax + 1), indexing="xy")
    half = (nn > 0) | ((nn == 0) & (mm > 0))
    qq = dq * np.hypot(mm, nn)[half]
    qq = qq[qq <= q_max]
    ring = (qq / (du / length)).astype(np.int64)
    inside = ring < n_ring
    u_sum = np.bincount(ring[inside], weights=qq[inside] * length, minlength=n_ring)
    out = {"u": u_sum[keep] / cnt[keep]}
    names = ("exact",) if exact_only else ("exact", "decoupling", "local_monodisperse", "partial", "S", "P", "C")
    for k, name in enumerate(names):
        out[name] = sums[keep, k] / cnt[keep]
    out["points"] = cnt[keep]
    out["coverage"] = cov
    if not exact_only:
        out["eta"] = eta
    return out


@nb.njit(cache=True, parallel=True)
def _structure_rings(x, y, L, q_max, dq_ring, n_ring):
    """Ring sums of ``|Σ_j e^{-i q·r_j}|² / N`` and the lattice points per ring (half lattice)."""
    N = x.shape[0]
    dq = 2.0 * math.pi / L
    nmax = int(q_max / dq)
    out = np.zeros((nmax + 1, n_ring, 2))
    for n in nb.prange(nmax + 1):
        qy = n * dq
        mmax = int(math.sqrt(max(q_max * q_max - qy * qy, 0.0)) / dq)
        m0 = 1 if n == 0 else -mmax
        wr, wi, sr, si = _row_phases(x, y, m0, dq, qy)
        for m in range(m0, mmax + 1):
            q = math.sqrt((m * dq) ** 2 + qy * qy)
            ring = int(q / dq_ring)
            if q <= q_max and ring < n_ring:
                tr = 0.0
                ti = 0.0
                for j in range(N):
                    tr += wr[j]
                    ti += wi[j]
                out[n, ring, 0] += (tr * tr + ti * ti) / N
                out[n, ring, 1] += 1.0
            for j in range(N):
                r = wr[j] * sr[j] - wi[j] * si[j]
                wi[j] = wr[j] * si[j] + wi[j] * sr[j]
                wr[j] = r
    return out.sum(axis=0)


@nb.njit(cache=True, parallel=True)
def _partial_rings(x, y, cls, K, L, q_max, dq_ring, n_ring):
    """Ring sums of ``Re(ρ_i ρ_k*) / N`` (``ρ_i = Σ_{j∈i} e^{-i q·r_j}``) and the lattice points per
    ring (half lattice): (n_ring, K, K), (n_ring,)."""
    N = x.shape[0]
    dq = 2.0 * math.pi / L
    nmax = int(q_max / dq)
    out = np.zeros((nmax + 1, n_ring, K, K))
    cnt = np.zeros((nmax + 1, n_ring))
    for n in nb.prange(nmax + 1):
        qy = n * dq
        mmax = int(math.sqrt(max(q_max * q_max - qy * qy, 0.0)) / dq)
        m0 = 1 if n == 0 else -mmax
        wr, wi, sr, si = _row_phases(x, y, m0, dq, qy)
        rr = np.zeros(K)
        ri = np.zeros(K)
        for m in range(m0, mmax + 1):
            q = math.sqrt((m * dq) ** 2 + qy * qy)
            ring = int(q / dq_ring)
            if q <= q_max and ring < n_ring:
                rr[:] = 0.0
                ri[:] = 0.0
                for j in range(N):
                    rr[cls[j]] += wr[j]
                    ri[cls[j]] += wi[j]
                for i in range(K):
                    for k in range(K):
                        out[n, ring, i, k] += (rr[i] * rr[k] + ri[i] * ri[k]) / N
                cnt[n, ring] += 1.0
            for j in range(N):
                r = wr[j] * sr[j] - wi[j] * si[j]
                wi[j] = wr[j] * si[j] + wi[j] * sr[j]
                wr[j] = r
    return out.sum(axis=0), cnt.sum(axis=0)


def partial_structure_rings(centres, classes, K: int, box: float, *, length: float, u_max: float, du: float):
    """The partial structure factors ``S_ik = Re⟨ρ_i ρ_k*⟩ / N`` (normalised by all ``N`` droplets,
    so ``S_ik → x_i δ_ik`` at large q) averaged over rings ``[j du, (j + 1) du)`` of ``u = |q| length``:
    (n_ring, K, K); rings without a lattice point: NaN."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    L = float(box)
    n_ring = int(math.ceil(u_max / du))
    s, n = _partial_rings(np.mod(c[:, 0], L), np.mod(c[:, 1], L), np.asarray(classes, np.int64), int(K), L,
                          u_max / length, du / length, n_ring)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n[:, None, None] > 0, s / np.maximum(n, 1)[:, None, None], np.nan)


def structure_factor_rings(centres, box: float, *, length: float, u_max: float, du: float):
    """``S`` of the centres averaged over rings ``[i du, (i + 1) du)`` of ``u = |q| length``
    (box lattice; rings without a lattice point: NaN)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    L = float(box)
    n_ring = int(math.ceil(u_max / du))
    s = _structure_rings(np.mod(c[:, 0], L), np.mod(c[:, 1], L), L, u_max / length, du / length, n_ring)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s[:, 1] > 0, s[:, 0] / np.maximum(s[:, 1], 1), np.nan)


#: The breath-figure table (corona.model.processes.breath_figure): times [s], seeds, box [µm].
TABLE_TIMES = (5.0, 7.0, 10.0, 14.0, 20.0, 28.0, 40.0, 57.0, 80.0)
TABLE_SEEDS = (1, 2)
TABLE_BOX = 400.0
#: Size classes of the table: log bins of a / R (R = ⟨a³⟩/⟨a²⟩).
TABLE_X_EDGES = np.geomspace(0.01, 5.0, 61)
#: Size classes of the table's partial structure factors (equal covered area).
TABLE_CLASSES = 12
#: Rings of the table's S in u = q R.
TABLE_U_MAX, TABLE_DU = 12.0, 0.25


def _measure(a, centres, box, volume, i, acc, counts, xsum, S, partial, x_edges, class_edges):
    """Add one frame's ingredients (radii ``a``, centres, total water ``volume`` [µm³]) to row ``i``."""
    nx, K = x_edges.size - 1, class_edges.size - 1
    R = float(np.sum(a ** 3) / np.sum(a ** 2))
    acc["R"][i] += R
    acc["mean_radius"][i] += a.mean()
    acc["coverage"][i] += float(np.pi * np.sum(a ** 2) / box ** 2)
    acc["density"][i] += a.size / box ** 2
    acc["water"][i] += float(volume) / box ** 2
    x = a / R
    k = np.clip(np.searchsorted(x_edges, x, side="right") - 1, 0, nx - 1)
    counts[i] += np.bincount(k, minlength=nx)
    xsum[i] += np.bincount(k, weights=x, minlength=nx)
    cls = np.clip(np.searchsorted(class_edges, x, side="right") - 1, 0, K - 1)
    p = partial_structure_rings(centres, cls, K, box, length=R, u_max=TABLE_U_MAX, du=TABLE_DU)
    partial[i] += p
    S[i] += np.einsum("rik->r", p)           # Σ_ik S_ik: the S of all the centres


def breath_figure_table(times=TABLE_TIMES, seeds=TABLE_SEEDS, box: float = TABLE_BOX,
                        progress: bool = True) -> dict:
    """What the lobe of a breath figure needs at each time, averaged over seeds (hemispherical caps,
    the simulator's defaults otherwise): the area-weighted mean contact radius ``R = ⟨a³⟩/⟨a²⟩``
    [µm], the number-mean radius, the coverage, the droplets per area [µm⁻²], the water per area
    ``water`` [µm] (the film it would make), the number fractions
    and mean ``a/R`` of the size bins (``x_edges``: :data:`TABLE_X_EDGES` split at the class edges), and ``S`` of the centres over rings of
    ``u = q R`` (:data:`TABLE_DU` wide up to :data:`TABLE_U_MAX`), and the partial structure factors
    ``partial`` (n_t, rings, K, K) of :data:`TABLE_CLASSES` classes of equal covered area in
    ``a/R`` (``class_edges``, the same at every time)."""
    from tqdm import tqdm
    from corona.reference.breath_figure import simulate_breath_figure
    times = np.asarray(times, dtype=np.float64)
    nt, nx = times.size, TABLE_X_EDGES.size - 1
    n_ring = int(math.ceil(TABLE_U_MAX / TABLE_DU))
    acc = {k: np.zeros(nt) for k in ("R", "mean_radius", "coverage", "density", "water")}
    S = np.zeros((nt, n_ring))
    t0 = __import__("time").perf_counter()
    runs = [simulate_breath_figure(times, box=box, seed=int(seed)) for seed in seeds]
    # the partial structure factors' classes: TABLE_CLASSES of equal covered area in a / R,
    # pooled over every time and seed (the same classes at every time, so rows interpolate)
    xs = np.concatenate([bf.radii[i] / (np.sum(bf.radii[i] ** 3) / np.sum(bf.radii[i] ** 2))
                         for bf in runs for i in range(nt)])
    order = np.argsort(xs)
    w = np.cumsum(xs[order] ** 2) / np.sum(xs ** 2)
    inner = [xs[order][np.searchsorted(w, k / TABLE_CLASSES)] for k in range(1, TABLE_CLASSES)]
    class_edges = np.concatenate([[0.0], inner, [np.inf]])
    # the size bins split at the class edges too: each bin lies in one class
    x_edges = np.unique(np.concatenate([TABLE_X_EDGES, inner]))
    nx = x_edges.size - 1
    counts = np.zeros((nt, nx))
    xsum = np.zeros((nt, nx))
    partial = np.zeros((nt, n_ring, TABLE_CLASSES, TABLE_CLASSES))
    with tqdm(total=len(seeds) * nt, desc="corona: breath-figure table", unit="frame",
              disable=not progress, leave=False) as bar:
        for bf in runs:
            for i in range(nt):
                _measure(bf.radii[i], bf.centres[i], box, bf.total_volume[i], i, acc, counts, xsum, S, partial,
                         x_edges, class_edges)
                bar.update(1)
    ns = len(seeds)
    out = {k: v / ns for k, v in acc.items()}
    out["times"] = times
    out["fraction"] = counts / counts.sum(axis=1, keepdims=True)
    out["x"] = np.where(counts > 0, xsum / np.maximum(counts, 1), np.sqrt(x_edges[:-1] * x_edges[1:]))
    out["x_edges"] = x_edges
    out["S"] = S / ns
    out["partial"] = partial / ns
    out["class_edges"] = class_edges
    out["u"] = (np.arange(n_ring) + 0.5) * TABLE_DU
    out["seconds"] = __import__("time").perf_counter() - t0
    return out


#: The fading phase of the table: evaporation runs started at these growth times [s] (the first,
#: a middle and the last of :data:`TABLE_TIMES`) ...
EVAPORATION_STARTS = (5.0, 20.0, 80.0)
#: ... measured when these fractions of the water have evaporated (0: the growth rows themselves).
EVAPORATION_FRACTIONS = (0.1, 0.25, 0.5, 0.75, 0.9)
#: Evaporation rate of the table's runs [µm/s]; the rows depend on the evaporated fraction only
#: (the water leaves at a fixed rate, shared as in growth), so any rate gives the same rows.
TABLE_EVAPORATION_RATE = 0.1


def evaporation_rows(x_edges, class_edges, starts=EVAPORATION_STARTS, fractions=EVAPORATION_FRACTIONS,
                     seeds=TABLE_SEEDS, box: float = TABLE_BOX, progress: bool = True) -> dict:
    """The fading phase: the same ingredients as :func:`breath_figure_table` (in its size bins
    ``x_edges`` and classes ``class_edges``) for runs that grow until ``start`` [s] and then evaporate
    at :data:`TABLE_EVAPORATION_RATE` (no nucleation), measured when the fraction ``fractions`` of the
    water present at ``start`` has left (``τ = f · water(start) / E``, exact: the simulator removes
    water at exactly the rate ``E`` while drops remain).  Arrays over (start, fraction, ...)."""
    from tqdm import tqdm
    from corona.reference.breath_figure import simulate_breath_figure
    starts, fractions = np.asarray(starts, np.float64), np.asarray(fractions, np.float64)
    ns, nf = starts.size, fractions.size
    nx, K = x_edges.size - 1, class_edges.size - 1
    n_ring = int(math.ceil(TABLE_U_MAX / TABLE_DU))
    rows = ns * nf
    acc = {k: np.zeros(rows) for k in ("R", "mean_radius", "coverage", "density", "water")}
    start = {k: np.zeros(rows) for k in ("R", "coverage", "density", "water")}
    counts, xsum = np.zeros((rows, nx)), np.zeros((rows, nx))
    S, partial = np.zeros((rows, n_ring)), np.zeros((rows, n_ring, K, K))
    E = TABLE_EVAPORATION_RATE
    with tqdm(total=len(seeds) * rows, desc="corona: breath-figure fading rows", unit="frame",
              disable=not progress, leave=False) as bar:
        for s, t0 in enumerate(starts):
            for seed in seeds:
                grown = simulate_breath_figure([t0], box=box, seed=int(seed))
                h0 = float(grown.total_volume[0]) / box ** 2
                taus = fractions * h0 / E
                bf = simulate_breath_figure(np.concatenate([[t0], t0 + taus]), box=box, seed=int(seed),
                                            dry_from=t0, evaporation_rate=E)
                a0 = bf.radii[0]
                for f in range(nf):
                    i = s * nf + f
                    start["R"][i] += float(np.sum(a0 ** 3) / np.sum(a0 ** 2))
                    start["coverage"][i] += bf.coverage[0]
                    start["density"][i] += a0.size / box ** 2
                    start["water"][i] += float(bf.total_volume[0]) / box ** 2
                    _measure(bf.radii[f + 1], bf.centres[f + 1], box, bf.total_volume[f + 1], i, acc, counts,
                             xsum, S, partial, x_edges, class_edges)
                    bar.update(1)
    n = len(seeds)
    out = {"dry_" + k: (v / n).reshape(ns, nf) for k, v in acc.items()}
    # the ratios to the start of each run (the model scales the growth rows at any time by them)
    for k in ("R", "coverage", "density", "water"):
        out["dry_" + k + "_ratio"] = (acc[k] / start[k]).reshape(ns, nf)
    out["dry_starts"] = starts
    out["dry_fractions"] = fractions
    out["dry_fraction"] = (counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)).reshape(ns, nf, nx)
    out["dry_x"] = np.where(counts > 0, xsum / np.maximum(counts, 1),
                            np.sqrt(x_edges[:-1] * x_edges[1:])).reshape(ns, nf, nx)
    out["dry_S"] = (S / n).reshape(ns, nf, n_ring)
    out["dry_partial"] = (partial / n).reshape(ns, nf, n_ring, K, K)
    return out
