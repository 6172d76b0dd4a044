"""Metropolis Monte Carlo of the hard-sphere fluid: S(q) to check Percus–Yevick.

``n`` spheres of diameter 1 in a periodic cube at volume fraction ``φ``,
started on a simple cubic lattice (which holds up to φ = π/6), moved by
single-particle Metropolis trials (a move is rejected when it overlaps),
the step adapted during equilibration to an acceptance near 0.4.  The
structure factor ``S(q) = |Σ_j exp(i q·r_j)|² / n`` is averaged over the
wave vectors ``q = 2π m / L`` (m integer) in shells of ``|q|`` and over
configurations taken once a sweep after equilibration.  Compiled with numba.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["structure_factor_mc", "simulate"]


@numba.njit(cache=True)
def _sweeps(pos, L, step, n_sweeps, seed, adapt):
    np.random.seed(seed)
    n = pos.shape[0]
    accepted = 0
    for _ in range(n_sweeps):
        acc_sweep = 0
        for _k in range(n):
            i = np.random.randint(n)
            nx = pos[i, 0] + step * (2 * np.random.random() - 1)
            ny = pos[i, 1] + step * (2 * np.random.random() - 1)
            nz = pos[i, 2] + step * (2 * np.random.random() - 1)
            nx -= L * math.floor(nx / L)
            ny -= L * math.floor(ny / L)
            nz -= L * math.floor(nz / L)
            ok = True
            for j in range(n):
                if j == i:
                    continue
                dx = nx - pos[j, 0]
                dy = ny - pos[j, 1]
                dz = nz - pos[j, 2]
                dx -= L * round(dx / L)
                dy -= L * round(dy / L)
                dz -= L * round(dz / L)
                if dx * dx + dy * dy + dz * dz < 1.0:
                    ok = False
                    break
            if ok:
                pos[i, 0], pos[i, 1], pos[i, 2] = nx, ny, nz
                acc_sweep += 1
        accepted += acc_sweep
        if adapt:
            rate = acc_sweep / n
            step *= 1.05 if rate > 0.4 else 0.95
            step = min(step, 0.5 * L)
    return step, accepted


def simulate(volume_fraction: float, n: int = 400, sweeps: int = 300, equilibrate: int = 200,
             seed: int = 0, every: int = 5):
    """Configurations (list of (n, 3) arrays, diameter 1, one each ``every`` sweeps) and the box side L."""
    L = (n * math.pi / 6 / volume_fraction) ** (1 / 3)
    m = int(math.ceil(n ** (1 / 3)))
    if L / m < 1.0:
        raise ValueError(f"volume_fraction={volume_fraction} too high for a cubic start with n={n}")
    g = (np.arange(m) + 0.5) * (L / m)
    pos = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T[:n].copy()
    step, _ = _sweeps(pos, L, 0.1, equilibrate, seed, True)
    confs = []
    for k in range(sweeps // every):
        _sweeps(pos, L, step, every, seed + 1 + k, False)
        confs.append(pos.copy())
    return confs, L


def structure_factor_mc(volume_fraction: float, n: int = 400, sweeps: int = 300, seed: int = 0,
                        q_max: float = 16.0, dq: float = 0.25):
    """(shell centres q [1/diameter], S(q)) from :func:`simulate`."""
    confs, L = simulate(volume_fraction, n, sweeps, seed=seed)
    mmax = int(q_max * L / (2 * math.pi)) + 1
    r = np.arange(-mmax, mmax + 1)
    mv = np.array(np.meshgrid(r, r, r, indexing="ij")).reshape(3, -1).T
    qa = 2 * math.pi / L * np.linalg.norm(mv, axis=1)
    keep = (qa > 0) & (qa < q_max)
    mv, qa = mv[keep], qa[keep]
    # at most 96 wave vectors per shell (a fixed random subset): the shells are isotropic
    edges = np.arange(0.0, q_max + dq, dq)
    idx = np.digitize(qa, edges) - 1
    rng = np.random.default_rng(seed)
    pick = np.concatenate([rng.permutation(np.flatnonzero(idx == k))[:96] for k in range(edges.size - 1)])
    mv, qa = mv[pick] + mmax, qa[pick]                   # the index of each m in r
    S = np.zeros(qa.size)
    for pos in confs:
        # exp(i q·r) = Π over the axes of exp(i 2π m_a r_a / L): three small tables of phases
        # (n, 2 mmax + 1) and two products a wave vector instead of a complex exponential
        E = np.exp(1j * (2 * math.pi / L) * pos[:, :, None] * r[None, None, :])
        ph = E[:, 0, mv[:, 0]] * E[:, 1, mv[:, 1]] * E[:, 2, mv[:, 2]]
        S += np.abs(ph.sum(axis=0)) ** 2 / n
    S /= len(confs)
    idx = np.digitize(qa, edges) - 1
    cen, val = [], []
    for k in range(edges.size - 1):
        sel = idx == k
        if np.any(sel):
            cen.append(0.5 * (edges[k] + edges[k + 1]))
            val.append(S[sel].mean())
    return np.array(cen), np.array(val)
