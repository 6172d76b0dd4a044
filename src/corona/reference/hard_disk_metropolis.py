"""A second, independent hard-disk sampler: plain Metropolis with local moves.

It shares nothing with the event-chain Monte Carlo of
:mod:`corona.reference.hard_disk` that makes the shipped ``S(qσ, η)`` table
(issue 18): a different move set (single-disk displacements, accepted when
they create no overlap; Metropolis et al. 1953, the original hard-disk
study), a different start (random points whose disks are grown to σ:
after every sweep the diameter becomes ``min(σ, smallest pair distance)``,
so it never sees a lattice), its own cell list and its own ``S(k)``
estimator, evaluated only on the box wave vectors of chosen ``|k|σ``
windows.  Lengths in units of the disk diameter σ.

:func:`metropolis_structure_factor` returns, per window, ``S`` averaged
over the window's box wave vectors with its standard error (blocking within
each chain, independent chains pooled), and the mean ``|k|σ`` of the
vectors, so a table can be averaged over exactly the same vectors.
"""
from __future__ import annotations

import math
import time

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _seed(s):
    np.random.seed(s)


@nb.njit(cache=True)
def _cells(pos, L, m):
    """Linked cell list: head (m*m,), next (N,)."""
    N = pos.shape[0]
    head = np.full(m * m, -1, np.int64)
    nxt = np.full(N, -1, np.int64)
    c = L / m
    for i in range(N):
        cx = min(int(pos[i, 0] / c), m - 1)
        cy = min(int(pos[i, 1] / c), m - 1)
        k = cy * m + cx
        nxt[i] = head[k]
        head[k] = i
    return head, nxt


@nb.njit(cache=True)
def _min_distance(pos, L, m):
    """Smallest pair distance (periodic), by the cell list (cells >= 1)."""
    head, nxt = _cells(pos, L, m)
    c = L / m
    best = 1e300
    N = pos.shape[0]
    for i in range(N):
        cx = min(int(pos[i, 0] / c), m - 1)
        cy = min(int(pos[i, 1] / c), m - 1)
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                k = ((cy + dy) % m) * m + (cx + dx) % m
                j = head[k]
                while j >= 0:
                    if j > i:
                        ddx = pos[j, 0] - pos[i, 0]
                        ddy = pos[j, 1] - pos[i, 1]
                        ddx -= L * round(ddx / L)
                        ddy -= L * round(ddy / L)
                        d2 = ddx * ddx + ddy * ddy
                        if d2 < best:
                            best = d2
                    j = nxt[j]
    return math.sqrt(best)


@nb.njit(cache=True)
def _sweeps(pos, L, m, sigma, delta, n_sweeps):
    """``n_sweeps`` sweeps of N single-disk trial moves (uniform in a square of
    half-width ``delta``), accepted when no disk overlaps (diameter ``sigma``).
    The cell list is rebuilt every sweep (cells >= 1 >= sigma).  Returns the
    acceptance ratio."""
    N = pos.shape[0]
    c = L / m
    s2 = sigma * sigma
    acc = 0
    for _ in range(n_sweeps):
        head, nxt = _cells(pos, L, m)
        cell_of = np.empty(N, np.int64)
        for i in range(N):
            cell_of[i] = min(int(pos[i, 1] / c), m - 1) * m + min(int(pos[i, 0] / c), m - 1)
        for _t in range(N):
            i = np.random.randint(N)
            x = pos[i, 0] + delta * (2.0 * np.random.random() - 1.0)
            y = pos[i, 1] + delta * (2.0 * np.random.random() - 1.0)
            x -= L * math.floor(x / L)
            y -= L * math.floor(y / L)
            cx = min(int(x / c), m - 1)
            cy = min(int(y / c), m - 1)
            ok = True
            for dy in range(-1, 2):
                if not ok:
                    break
                for dx in range(-1, 2):
                    k = ((cy + dy) % m) * m + (cx + dx) % m
                    j = head[k]
                    while j >= 0:
                        if j != i:
                            ddx = pos[j, 0] - x
                            ddy = pos[j, 1] - y
                            ddx -= L * round(ddx / L)
                            ddy -= L * round(ddy / L)
                            if ddx * ddx + ddy * ddy < s2:
                                ok = False
                                break
                        j = nxt[j]
                    if not ok:
                        break
            if ok:
                # move i between cells of the linked list
                k_old = cell_of[i]
                k_new = cy * m + cx
                if k_new != k_old:
                    if head[k_old] == i:
                        head[k_old] = nxt[i]
                    else:
                        j = head[k_old]
                        while nxt[j] != i:
                            j = nxt[j]
                        nxt[j] = nxt[i]
                    nxt[i] = head[k_new]
                    head[k_new] = i
                    cell_of[i] = k_new
                pos[i, 0] = x
                pos[i, 1] = y
                acc += 1
    return acc / (n_sweeps * N)


@nb.njit(cache=True)
def _structure_factor(pos, kx, ky):
    """``|Σ_j exp(-i k·s_j)|² / N`` for each wave vector (kx[t], ky[t])."""
    N = pos.shape[0]
    out = np.empty(kx.size)
    for t in range(kx.size):
        re = 0.0
        im = 0.0
        for j in range(N):
            ph = kx[t] * pos[j, 0] + ky[t] * pos[j, 1]
            re += math.cos(ph)
            im += math.sin(ph)
        out[t] = (re * re + im * im) / N
    return out


def _window_vectors(L, windows, max_vectors=None, seed=0):
    """Half-plane box wave vectors with |k|σ in each window [lo, hi) (at most
    ``max_vectors`` per window, a fixed random subset)."""
    k_max = max(hi for _, hi in windows)
    n_max = int(k_max * L / (2 * math.pi)) + 1
    nx, ny = np.meshgrid(np.arange(-n_max, n_max + 1), np.arange(0, n_max + 1), indexing="xy")
    keep = (ny > 0) | (nx > 0)
    kx = 2 * math.pi / L * nx[keep]
    ky = 2 * math.pi / L * ny[keep]
    k = np.hypot(kx, ky)
    sel = [np.flatnonzero((k >= lo) & (k < hi)) for lo, hi in windows]
    if max_vectors:
        rng = np.random.default_rng(seed)
        sel = [np.sort(rng.choice(i, max_vectors, replace=False)) if i.size > max_vectors else i
               for i in sel]
    return kx, ky, k, sel


def _chain(eta, n_disks, n_sweeps, n_equilibration, sample_every, seed, windows, max_vectors):
    t_cpu = time.process_time()
    rng = np.random.default_rng(seed)
    _seed(int(rng.integers(2**31 - 1)))
    L = math.sqrt(n_disks * math.pi / (4.0 * eta))
    m = max(3, int(L))                      # cells >= σ
    pos = rng.random((n_disks, 2)) * L
    # grow the disks from random points to σ
    sigma = min(1.0, _min_distance(pos, L, m) * (1 - 1e-12))
    delta = 0.5
    grow = 0
    while sigma < 1.0:
        a = _sweeps(pos, L, m, sigma, delta, 1)
        delta = min(max(delta * (1.0 + (a - 0.4)), 1e-3), 0.5 * L)
        sigma = min(1.0, _min_distance(pos, L, m) * (1 - 1e-12))
        grow += 1
        if grow > 200_000:
            raise RuntimeError(f"disks did not grow to σ at η = {eta}")
    # equilibrate at σ, tuning the step to ~40 % acceptance
    done = 0
    while done < n_equilibration:
        a = _sweeps(pos, L, m, 1.0, delta, 50)
        delta = min(max(delta * (1.0 + (a - 0.4)), 1e-3), 0.5 * L)
        done += 50
    kx, ky, k, sel = _window_vectors(L, windows, max_vectors)
    use = np.concatenate(sel)
    n_snap = max(1, n_sweeps // sample_every)
    S = np.empty((n_snap, len(windows)))
    acc = 0.0
    for s in range(n_snap):
        acc += _sweeps(pos, L, m, 1.0, delta, sample_every)
        sk = np.zeros(k.size)
        sk[use] = _structure_factor(pos, kx[use], ky[use])
        S[s] = [sk[i].mean() for i in sel]
    d_min = _min_distance(pos, L, m)
    return dict(S=S, k_mean=np.array([k[i].mean() for i in sel]), n_vectors=np.array([i.size for i in sel]),
                k=[k[i] for i in sel], acceptance=acc / n_snap, delta=delta, d_min=d_min,
                grow_sweeps=grow, cpu=time.process_time() - t_cpu)


def metropolis_structure_factor(eta, windows, n_disks=2000, n_sweeps=40000, n_equilibration=10000,
                                sample_every=20, n_chains=4, n_blocks=10, max_vectors=400, seed=0):
    """``S`` averaged over the box wave vectors of each ``|k|σ`` window.

    Parameters
    ----------
    eta : float
        Packing fraction ``N π σ² / (4 L²)``.
    windows : sequence of (lo, hi)
        ``|k|σ`` windows.
    n_disks, n_sweeps, n_equilibration, sample_every, n_chains : int
        Disks, production sweeps per chain (N trial moves each), sweeps
        discarded after the growth, sweeps between snapshots, independent
        chains.
    n_blocks : int
        Blocks per chain for the standard error.
    max_vectors : int
        Wave vectors per window (a fixed random subset where there are more).

    Returns
    -------
    dict
        ``S`` (windows,), ``S_err``, ``k_vectors`` (list of the |k|σ of each
        window's vectors), ``acceptance``, ``min_distance`` (>= 1: no overlap),
        ``cpu_seconds`` and the settings.
    """
    seeds = np.random.SeedSequence(seed).spawn(n_chains)
    runs = [_chain(float(eta), int(n_disks), int(n_sweeps), int(n_equilibration), int(sample_every),
                   s, list(windows), max_vectors) for s in seeds]
    blocks = []
    for r in runs:
        x = r["S"]
        b = x.shape[0] // n_blocks
        blocks.append(x[: b * n_blocks].reshape(n_blocks, b, -1).mean(axis=1))
    blocks = np.concatenate(blocks)
    S = np.concatenate([r["S"] for r in runs]).mean(axis=0)
    err = blocks.std(axis=0, ddof=1) / math.sqrt(blocks.shape[0])
    return dict(eta=float(eta), windows=np.asarray(windows, float), S=S, S_err=err,
                k_vectors=runs[0]["k"], k_mean=runs[0]["k_mean"], n_vectors=runs[0]["n_vectors"],
                acceptance=float(np.mean([r["acceptance"] for r in runs])),
                min_distance=float(min(r["d_min"] for r in runs)),
                grow_sweeps=int(max(r["grow_sweeps"] for r in runs)),
                cpu_seconds=float(sum(r["cpu"] for r in runs)),
                settings=dict(n_disks=n_disks, n_sweeps=n_sweeps, n_equilibration=n_equilibration,
                              sample_every=sample_every, n_chains=n_chains, n_blocks=n_blocks,
                              max_vectors=max_vectors, seed=seed))


def compare_with_table(run: dict) -> list[dict]:
    """The shipped table against one stored Metropolis run (a record of
    ``tests/data/hard_disk_metropolis.json``): per window, the table averaged
    over the run's own wave vectors, the table's error bar there (the largest
    stored ``S_err`` of the row in the window, interpolated in η), the
    difference and its z-score against the combined error."""
    from corona.model.processes.hard_disk import load_table, structure_factor_table
    t = load_table()
    eta = float(run["eta"])
    out = []
    for (lo, hi), S_m, e_m, k in zip(run["windows"], run["S"], run["S_err"], run["k_vectors"]):
        S_t = float(np.mean(structure_factor_table(np.asarray(k), eta)))
        sel = (t["q_sigma"] >= lo) & (t["q_sigma"] <= hi)
        if "S_err" in t:
            e_rows = np.array([np.interp(eta, t["eta"], t["S_err"][:, j]) for j in np.flatnonzero(sel)])
            e_t = float(e_rows.max())
        else:
            e_t = float("nan")
        comb = math.hypot(e_m, e_t) if math.isfinite(e_t) else float(e_m)
        out.append(dict(eta=eta, window=[float(lo), float(hi)], table=S_t, table_err=e_t, metropolis=float(S_m),
                        metropolis_err=float(e_m), diff=S_t - float(S_m), z=(S_t - float(S_m)) / comb))
    return out
