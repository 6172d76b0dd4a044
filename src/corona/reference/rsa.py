"""Random sequential adsorption (RSA) of disks: the Monte Carlo generator.

The generator itself (:func:`corona.model.processes.rsa.rsa_configuration`,
re-exported here) belongs to the runtime, which samples realisations of the
process with it; this module adds the numba kernels (the ``reference``
extra) that turn runs of it into the shipped table
``corona/data/rsa_structure_factor.npz`` (see ``scripts/make_rsa_table.py``)
and the RSA screens of the brute-force reference.  The runtime reads the
table with :func:`corona.model.processes.rsa.rsa_structure_factor`.
"""
from __future__ import annotations

import math

import numpy as np

from corona.model.processes import rsa as _runtime
# the generator lives with the process (the runtime samples it too); re-exported here
from corona.model.processes.rsa import RSA_JAMMING_LIMIT, minimum_image, rsa_configuration, rsa_fill  # noqa: F401

# =====================================================================
# numba kernels of the table (compiled lazily on first use, cached on disk)
# =====================================================================
_KERNELS = ("_rsa_sk_prefix", "_rsa_pair_hist")
#: the generator's kernels that this module's kernels call (rebound to their compiled versions)
_GENERATOR = ("minimum_image", "rsa_fill")
_JIT_DONE = False


def _jit() -> None:
    """Compile the generator's kernels and this module's (once; numba caches them on disk)."""
    global _JIT_DONE
    if _JIT_DONE:
        return
    _runtime.compile_kernels()
    import numba
    g = globals()
    for name in _GENERATOR:                 # the compiled generator, seen by the kernels below
        g[name] = getattr(_runtime, name)
    for name in _KERNELS:
        g[name] = numba.njit(cache=True, nogil=True)(g[name])
    _JIT_DONE = True



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
            dx = minimum_image(pos[i, 0] - pos[j, 0], L)
            dy = minimum_image(pos[i, 1] - pos[j, 1], L)
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
    (:func:`rsa_fill`); for every coverage row ``t`` (and the saturated
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
        pos = rsa_fill(float(L), 0, int(seed))
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
