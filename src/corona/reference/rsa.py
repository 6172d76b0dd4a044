"""Random sequential adsorption (RSA) of disks: the Monte Carlo generator.

Kernels compiled with numba (the ``reference`` extra); they make the
shipped table ``corona/data/rsa_structure_factor.npz`` (see
``scripts/make_rsa_table.py``) and the RSA screens of the brute-force
reference.  The runtime reads the table with
:func:`corona.processes.rsa.rsa_structure_factor`.
"""
from __future__ import annotations

import math

import numpy as np

from .._validation import CoronaError, check_positive, check_range
from ..processes.rsa import RSA_JAMMING_LIMIT

# =====================================================================
# numba kernels (compiled lazily on first use, cached on disk)
# =====================================================================
_KERNELS = ("_wrap", "_rsa_free", "_rsa_covered", "_rsa_fill", "_rsa_sk_prefix", "_rsa_pair_hist")
_JIT_DONE = False


def _jit() -> None:
    """Compile the numba kernels of this module (once; numba caches them on disk)."""
    global _JIT_DONE
    if _JIT_DONE:
        return
    import numba
    g = globals()
    for name in _KERNELS:
        g[name] = numba.njit(cache=True, nogil=True)(g[name])
    _JIT_DONE = True


def _wrap(d, L):
    """Minimum-image convention for a separation ``d`` in a period ``L``."""
    if d > 0.5 * L:
        return d - L
    if d < -0.5 * L:
        return d + L
    return d


def _rsa_free(x, y, pos, cell, nc, h, L):
    """True when a unit-diameter disk centred at (x, y) overlaps no placed disk."""
    ci = int(x / h) % nc
    cj = int(y / h) % nc
    for di in range(-2, 3):
        for dj in range(-2, 3):
            if (di == 2 or di == -2) and (dj == 2 or dj == -2):
                continue  # corner cells are farther than h*sqrt(5) > 1
            p = cell[(ci + di) % nc, (cj + dj) % nc]
            if p >= 0:
                dx = _wrap(pos[p, 0] - x, L)
                dy = _wrap(pos[p, 1] - y, L)
                if dx * dx + dy * dy < 1.0:
                    return False
    return True


def _rsa_covered(vx, vy, v, pos, cell, nc, h, L):
    """True when the square voxel [vx, vx+v) x [vy, vy+v) lies inside the
    exclusion disk (radius 1) of a single placed centre."""
    cx = vx + 0.5 * v
    cy = vy + 0.5 * v
    ci = int(cx / h) % nc
    cj = int(cy / h) % nc
    for di in range(-2, 3):
        for dj in range(-2, 3):
            p = cell[(ci + di) % nc, (cj + dj) % nc]
            if p >= 0:
                dx = abs(_wrap(pos[p, 0] - cx, L)) + 0.5 * v
                dy = abs(_wrap(pos[p, 1] - cy, L)) + 0.5 * v
                if dx * dx + dy * dy < 1.0:
                    return True
    return False


def _rsa_fill(L, n_stop, seed):
    """Random sequential adsorption of unit-diameter disks in the periodic box
    ``[0, L)²``; returns the centres (N, 2) in insertion order.

    Stops after ``n_stop`` disks (``n_stop <= 0``: at saturation).  Phase 1
    makes plain uniform attempts up to coverage 0.40; phase 2 is the exact
    voxel method (Wang 1994; Zhang & Torquato 2013): attempts are drawn
    uniformly in a list of equal square voxels that together contain all of
    the still-available area; voxels inside one exclusion disk are dropped
    and, when fewer than a quarter of the attempts of a sweep succeed, every
    voxel is split in four.  Since the voxels cover the whole available area
    and are of equal size, this samples the same process as plain RSA; it
    ends when no voxel is left, i.e. at saturation.
    """
    np.random.seed(seed)
    nc = int(L * math.sqrt(2.0)) + 1  # cell side h < 1/sqrt(2): at most one centre per cell
    h = L / nc
    cell = -np.ones((nc, nc), np.int64)
    n_max = int(L * L / (math.pi / 4.0) * 0.5471 * 1.1) + 16
    if 0 < n_stop < n_max:
        n_max = n_stop
    pos = np.empty((n_max, 2))
    n = 0
    n_switch = int(0.40 * L * L / (math.pi / 4.0))
    fails = 0
    while n < n_max and n < n_switch and fails < 2000:
        x = np.random.random() * L
        y = np.random.random() * L
        if _rsa_free(x, y, pos, cell, nc, h, L):
            pos[n, 0] = x
            pos[n, 1] = y
            cell[int(x / h) % nc, int(y / h) % nc] = n
            n += 1
            fails = 0
        else:
            fails += 1
    if n >= n_max:
        return pos[:n]
    v = 0.5 * h
    nv1 = 2 * nc
    vox = np.empty((nv1 * nv1, 2))
    m = 0
    for i in range(nv1):
        for j in range(nv1):
            vx = i * v
            vy = j * v
            if not _rsa_covered(vx, vy, v, pos, cell, nc, h, L):
                vox[m, 0] = vx
                vox[m, 1] = vy
                m += 1
    depth = 0
    while m > 0 and n < n_max:
        acc = 0
        for _ in range(m):
            k = int(np.random.random() * m)
            x = vox[k, 0] + np.random.random() * v
            y = vox[k, 1] + np.random.random() * v
            if x >= L:
                x -= L
            if y >= L:
                y -= L
            if _rsa_free(x, y, pos, cell, nc, h, L):
                pos[n, 0] = x
                pos[n, 1] = y
                cell[int(x / h) % nc, int(y / h) % nc] = n
                n += 1
                acc += 1
                if n >= n_max:
                    break
        m2 = 0
        for k in range(m):
            if not _rsa_covered(vox[k, 0], vox[k, 1], v, pos, cell, nc, h, L):
                vox[m2, 0] = vox[k, 0]
                vox[m2, 1] = vox[k, 1]
                m2 += 1
        m = m2
        if m > 0 and acc < 0.25 * m and depth < 40:
            v2 = 0.5 * v
            out = np.empty((4 * m, 2))
            m2 = 0
            for k in range(m):
                for a in range(2):
                    for b in range(2):
                        vx = vox[k, 0] + a * v2
                        vy = vox[k, 1] + b * v2
                        if not _rsa_covered(vx, vy, v2, pos, cell, nc, h, L):
                            out[m2, 0] = vx
                            out[m2, 1] = vy
                            m2 += 1
            vox = out
            m = m2
            v = v2
            depth += 1
    return pos[:n]


def _rsa_sk_prefix(pos, L, targets, mn):
    """``|Σ_{j<N_t} e^{-i k·r_j}|² / N_t`` at the box wave vectors
    ``k = 2π/L (m, n)`` listed in ``mn`` (K, 2), for every prefix length
    ``N_t`` in ``targets`` (sorted) — RSA never removes a disk, so the first
    ``N_t`` centres are the configuration at coverage ``N_t π/4 / L²``."""
    K = mn.shape[0]
    T = targets.shape[0]
    mmax = 0
    for k in range(K):
        mmax = max(mmax, abs(mn[k, 0]), abs(mn[k, 1]))
    out = np.zeros((T, K))
    acc = np.zeros(K, np.complex128)
    px = np.empty(mmax + 1, np.complex128)
    py = np.empty(2 * mmax + 1, np.complex128)
    t = 0
    N = pos.shape[0]
    for j in range(N):
        ex = np.exp(-2j * np.pi * pos[j, 0] / L)
        ey = np.exp(-2j * np.pi * pos[j, 1] / L)
        px[0] = 1.0
        py[mmax] = 1.0
        for a in range(1, mmax + 1):
            px[a] = px[a - 1] * ex
            py[mmax + a] = py[mmax + a - 1] * ey
            py[mmax - a] = np.conj(py[mmax + a])
        for k in range(K):
            acc[k] += px[mn[k, 0]] * py[mmax + mn[k, 1]]
        while t < T and targets[t] == j + 1:
            for k in range(K):
                out[t, k] = (acc[k].real ** 2 + acc[k].imag ** 2) / (j + 1)
            t += 1
    return out


def _rsa_pair_hist(pos, L, targets, dr, nbins):
    """Histogram of pair distances (bin ``dr``) of every prefix configuration
    (counts per target, pairs counted once)."""
    T = targets.shape[0]
    H = np.zeros((T, nbins))
    rmax2 = (dr * nbins) ** 2
    N = pos.shape[0]
    tb = 0
    for j in range(N):
        while tb < T and targets[tb] <= j:
            tb += 1
        if tb >= T:
            break
        for i in range(j):
            dx = _wrap(pos[i, 0] - pos[j, 0], L)
            dy = _wrap(pos[i, 1] - pos[j, 1], L)
            r2 = dx * dx + dy * dy
            if r2 < rmax2:
                b = int(math.sqrt(r2) / dr)
                if b < nbins:
                    H[tb, b] += 1.0
    for t in range(1, T):
        for b in range(nbins):
            H[t, b] += H[t - 1, b]
    return H


# =====================================================================
# the shipped table: accumulators of S(k) and g(r) over independent runs
# =====================================================================
TABLE_ETAS = np.round(np.arange(0.01, 0.54 + 1e-9, 0.01), 4)


def box_vectors(L, kcut):
    """Box wave vectors ``2π/L (m, n)`` of the half plane with ``|k| <= kcut`` (as ``(m, n)``)."""
    M = int(kcut * L / (2 * np.pi)) + 1
    m, n = np.meshgrid(np.arange(0, M + 1), np.arange(-M, M + 1), indexing="ij")
    sel = ((m > 0) | ((m == 0) & (n > 0))) & ((m * m + n * n) * (2 * np.pi / L) ** 2 <= kcut ** 2)
    return np.stack([m[sel], n[sel]], -1).astype(np.int64)


def table_geometry(L: float, kcut: float) -> dict:
    """What every run of the table shares: the coverage rows, their disk counts
    ``N_t`` in a box of side ``L`` (σ = 1), the wave vectors and their ``|k|`` bins
    (width 2π/L, centred on multiples of 2π/L)."""
    targets = np.round(TABLE_ETAS * L * L / (np.pi / 4)).astype(np.int64)
    mn = box_vectors(L, kcut)
    kabs = 2 * np.pi / L * np.hypot(mn[:, 0], mn[:, 1])
    kbin = np.floor(kabs / (2 * np.pi / L) + 0.5).astype(np.int64)
    nkb = int(kbin.max()) + 1
    return dict(etas=TABLE_ETAS, targets=targets, mn=mn, kabs=kabs, kbin=kbin, nkb=nkb,
                kcount=np.bincount(kbin, minlength=nkb).astype(np.float64),
                ksum=np.bincount(kbin, weights=kabs, minlength=nkb))


def table_runs(L: float, kcut: float, dr: float, rmax: float, seeds) -> dict:
    """Sums over the RSA runs seeded by ``seeds`` (one chunk of the table; one task).

    Each run fills the periodic box of side ``L`` to saturation
    (:func:`_rsa_fill`); for every coverage row ``t`` (and the saturated
    state, the last row) it adds the bin sums of ``S(k)`` (``sk_sum``), their
    squares over the bin counts (``sk_sq``), the pair-distance histogram
    ``H`` (bin ``dr`` to ``rmax``) and the ideal-gas pair counts ``ideal``.
    Chunks add up (in a fixed order: ``scripts/make_rsa_table.py``); a run
    depends only on its seed.
    """
    _jit()
    geo = table_geometry(L, kcut)
    kbin, nkb, kcount, targets = geo["kbin"], geo["nkb"], geo["kcount"], geo["targets"]
    nbins = int(round(rmax / dr))
    T = len(targets) + 1
    sk_sum, sk_sq = np.zeros((T, nkb)), np.zeros((T, nkb))
    H, ideal = np.zeros((T, nbins)), np.zeros((T, nbins))
    shell = np.pi * (((np.arange(nbins) + 1) * dr) ** 2 - (np.arange(nbins) * dr) ** 2) / L ** 2
    nsat = []
    import time
    c0 = time.process_time()
    for seed in seeds:
        pos = _rsa_fill(float(L), 0, int(seed))
        N = len(pos)
        nsat.append(N)
        tg = np.concatenate([targets, [N]])
        sk = _rsa_sk_prefix(pos, float(L), tg, geo["mn"])
        for t in range(T):
            s = np.bincount(kbin, weights=sk[t], minlength=nkb)
            sk_sum[t] += s
            sk_sq[t] += s * s / np.maximum(kcount, 1)
        H += _rsa_pair_hist(pos, float(L), tg, dr, nbins)
        ideal += (tg * (tg - 1) / 2.0)[:, None] * shell[None, :]
    return dict(sk_sum=sk_sum, sk_sq=sk_sq, H=H, ideal=ideal, nsat=np.array(nsat, np.float64),
                cpu_seconds=time.process_time() - c0)


def rsa_configuration(box_size: float, packing_fraction: float | None = None, *,
                      sigma: float = 1.0, seed=None) -> np.ndarray:
    """One RSA configuration of disks of diameter ``sigma`` in the periodic box
    ``[0, box_size)²``.

    Parameters
    ----------
    box_size : float
        Side of the square periodic box (same unit as ``sigma``).
    packing_fraction : float or None
        Stop at ``N = round(η box_size² / (π σ²/4))`` disks; None runs to
        saturation (``η ≈ 0.5471`` for a large box).
    sigma : float
        Disk (exclusion) diameter.
    seed : int or None
        Seed of the (numba) random generator.

    Returns
    -------
    numpy.ndarray
        Centres (N, 2) in insertion order (fewer than requested if a small
        box saturates first).
    """
    sigma = check_positive("sigma", sigma)
    box_size = check_positive("box_size", box_size)
    L = box_size / sigma
    if L < 3.0:
        raise CoronaError(f"box_size={box_size!r} is out of range; expected >= 3 sigma = {3 * sigma:g}")
    n_stop = 0
    if packing_fraction is not None:
        eta = check_range("packing_fraction", packing_fraction, 0.0, RSA_JAMMING_LIMIT)
        n_stop = int(round(eta * L * L / (np.pi / 4.0)))
        if n_stop == 0:
            return np.zeros((0, 2))
    if seed is None:
        seed = int(np.random.default_rng().integers(2**31 - 1))
    _jit()
    return _rsa_fill(float(L), int(n_stop), int(seed)) * sigma


