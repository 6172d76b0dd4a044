"""Equilibrium hard-disk fluid: simulation, structure-factor table, process.

(Module docstring completed below.)
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

# ==========================================================================
# numba kernels (lengths in units of the disk diameter σ = 1)
# ==========================================================================
_CELL_CAP = 16


@nb.njit(cache=True)
def _seed(s):
    np.random.seed(s)


@nb.njit(cache=True)
def _cell_coord(x, c, m):
    k = int(x / c)
    if k >= m:
        k = m - 1
    elif k < 0:
        k = 0
    return k


@nb.njit(cache=True)
def _build_cells(pos, L, m):
    N = pos.shape[0]
    c = L / m
    count = np.zeros(m * m, np.int64)
    members = np.full((m * m, _CELL_CAP), -1, np.int64)
    cell_of = np.empty(N, np.int64)
    slot = np.empty(N, np.int64)
    for i in range(N):
        k = _cell_coord(pos[i, 1], c, m) * m + _cell_coord(pos[i, 0], c, m)
        if count[k] >= _CELL_CAP:
            return cell_of, slot, members, count, False
        members[k, count[k]] = i
        slot[i] = count[k]
        count[k] += 1
        cell_of[i] = k
    return cell_of, slot, members, count, True


@nb.njit(cache=True)
def _relocate(i, pos, c, m, cell_of, slot, members, count):
    k_new = _cell_coord(pos[i, 1], c, m) * m + _cell_coord(pos[i, 0], c, m)
    k_old = cell_of[i]
    if k_new == k_old:
        return True
    # remove from the old cell (swap with its last member)
    s = slot[i]
    last = members[k_old, count[k_old] - 1]
    members[k_old, s] = last
    slot[last] = s
    members[k_old, count[k_old] - 1] = -1
    count[k_old] -= 1
    if count[k_new] >= _CELL_CAP:
        return False
    members[k_new, count[k_new]] = i
    slot[i] = count[k_new]
    count[k_new] += 1
    cell_of[i] = k_new
    return True


@nb.njit(cache=True)
def _ecmc(pos, L, m, cell_of, slot, members, count, n_events, chain_length, first_direction):
    """Straight event-chain Monte Carlo (Bernard, Krauth & Wilson 2009).

    Runs chains of total displacement ``chain_length`` alternately along +x
    and +y (starting with ``first_direction``) until at least ``n_events``
    displacement events (lifts + chain ends) happened.  Returns
    ``(events, lift_sum, total_length, n_chains, ok)`` where ``lift_sum`` is
    the sum over lifts of the centre separation projected on the direction
    of motion; ``Z = βP/ρ = 1 + lift_sum / total_length`` (Michel, Kapfer &
    Krauth 2014).
    """
    N = pos.shape[0]
    c = L / m
    half = 0.5 * L
    events = 0
    lift_sum = 0.0
    total_length = 0.0
    n_chains = 0
    while events < n_events:
        d = (first_direction + n_chains) % 2
        p = 1 - d
        i = np.random.randint(N)
        remaining = chain_length
        while remaining > 0.0:
            xi = pos[i, d]
            yi = pos[i, p]
            k = cell_of[i]
            kx = k % m
            ky = k // m
            ca = kx if d == 0 else ky
            cb = ky if d == 0 else kx
            s_min = 3.0 * c - (xi - ca * c) - 1.0
            j_min = -1
            dx_min = 0.0
            for oa in range(3):
                a = (ca + oa) % m
                for ob in range(-1, 2):
                    b = (cb + ob) % m
                    cell = b * m + a if d == 0 else a * m + b
                    for t in range(count[cell]):
                        j = members[cell, t]
                        if j == i:
                            continue
                        dy = pos[j, p] - yi
                        if dy > half:
                            dy -= L
                        elif dy < -half:
                            dy += L
                        if dy >= 1.0 or dy <= -1.0:
                            continue
                        dx = pos[j, d] - xi
                        if dx > half:
                            dx -= L
                        elif dx < -half:
                            dx += L
                        if dx <= 0.0:
                            continue
                        s = dx - math.sqrt(1.0 - dy * dy)
                        if s < 0.0:
                            s = 0.0
                        if s < s_min:
                            s_min = s
                            j_min = j
                            dx_min = dx
            if remaining <= s_min:
                step = remaining
                j_min = -1
            else:
                step = s_min
            x_new = xi + step
            if x_new >= L:
                x_new -= L
            pos[i, d] = x_new
            remaining -= step
            if not _relocate(i, pos, c, m, cell_of, slot, members, count):
                return events, lift_sum, total_length, n_chains, False
            if j_min >= 0:
                lift_sum += dx_min - step      # centre separation at contact
                events += 1
                i = j_min
        events += 1
        total_length += chain_length
        n_chains += 1
    return events, lift_sum, total_length, n_chains, True


@nb.njit(cache=True)
def _select_wave_vectors(n_max, L, q_max, bin_width, n_bins, cap):
    """Half-plane box wave vectors ``2π(nx, ny)/L`` with ``0 < |k| <= q_max``,
    at most ``cap`` per ``|k|`` bin (uniform reservoir sample)."""
    seen = np.zeros(n_bins, np.int64)
    kept = np.zeros((n_bins, cap, 2), np.int64)
    two_pi_over_L = 2.0 * math.pi / L
    for ny in range(0, n_max + 1):
        nx_lo = 1 if ny == 0 else -n_max
        for nx in range(nx_lo, n_max + 1):
            q = two_pi_over_L * math.sqrt(nx * nx + ny * ny)
            if q > q_max:
                continue
            b = int(q / bin_width)
            if b >= n_bins:
                continue
            if seen[b] < cap:
                kept[b, seen[b], 0] = nx
                kept[b, seen[b], 1] = ny
            else:
                r = np.random.randint(seen[b] + 1)
                if r < cap:
                    kept[b, r, 0] = nx
                    kept[b, r, 1] = ny
            seen[b] += 1
    return kept, seen


@nb.njit(cache=True)
def _density_modes(pos, L, knx, kny, n_max):
    """``|ρ_k|² / N`` with ``ρ_k = Σ_j exp(-i k·s_j)`` for each selected k."""
    N = pos.shape[0]
    K = knx.size
    re = np.zeros(K)
    im = np.zeros(K)
    ex = np.empty(n_max + 1, np.complex128)
    ey = np.empty(n_max + 1, np.complex128)
    w = 2.0 * math.pi / L
    for j in range(N):
        phx = complex(math.cos(w * pos[j, 0]), -math.sin(w * pos[j, 0]))
        phy = complex(math.cos(w * pos[j, 1]), -math.sin(w * pos[j, 1]))
        ex[0] = 1.0
        ey[0] = 1.0
        for n in range(1, n_max + 1):
            ex[n] = ex[n - 1] * phx
            ey[n] = ey[n - 1] * phy
        for t in range(K):
            nx = knx[t]
            if nx >= 0:
                a = ex[nx]
            else:
                a = ex[-nx].conjugate()
            v = a * ey[kny[t]]
            re[t] += v.real
            im[t] += v.imag
    return (re * re + im * im) / N


@nb.njit(cache=True)
def _pair_scan(pos, L, r_max, n_bins, r_bond):
    """Pair-distance histogram up to ``r_max``, the smallest pair distance,
    and the global bond-orientational order ``|⟨ψ6⟩|`` (bonds shorter than
    ``r_bond``)."""
    N = pos.shape[0]
    half = 0.5 * L
    hist = np.zeros(n_bins, np.int64)
    dr = r_max / n_bins
    r_max2 = r_max * r_max
    r_bond2 = r_bond * r_bond
    d_min2 = 1e300
    psi_re = np.zeros(N)
    psi_im = np.zeros(N)
    nb_count = np.zeros(N)
    for i in range(N):
        xi = pos[i, 0]
        yi = pos[i, 1]
        for j in range(i + 1, N):
            dx = pos[j, 0] - xi
            if dx > half:
                dx -= L
            elif dx < -half:
                dx += L
            dy = pos[j, 1] - yi
            if dy > half:
                dy -= L
            elif dy < -half:
                dy += L
            r2 = dx * dx + dy * dy
            if r2 < d_min2:
                d_min2 = r2
            if r2 < r_max2:
                b = int(math.sqrt(r2) / dr)
                if b < n_bins:
                    hist[b] += 1
            if r2 < r_bond2:
                th = 6.0 * math.atan2(dy, dx)
                cr = math.cos(th)
                sr = math.sin(th)
                psi_re[i] += cr
                psi_im[i] += sr
                psi_re[j] += cr       # 6(θ+π) ≡ 6θ
                psi_im[j] += sr
                nb_count[i] += 1.0
                nb_count[j] += 1.0
    tr = 0.0
    ti = 0.0
    for i in range(N):
        if nb_count[i] > 0:
            tr += psi_re[i] / nb_count[i]
            ti += psi_im[i] / nb_count[i]
    return hist, math.sqrt(d_min2), math.sqrt(tr * tr + ti * ti) / N


def _triangular_start(n_disks, eta, rng):
    """Non-overlapping start: a triangular lattice filling the square box
    (a few random vacancies when N does not factor)."""
    L = math.sqrt(n_disks * math.pi / (4.0 * eta))
    ny = max(2, 2 * int(round(math.sqrt(2.0 * n_disks / math.sqrt(3.0)) / 2.0)))
    nx = int(math.ceil(n_disks / ny))
    ax, ay = L / nx, L / ny
    if min(ax, math.hypot(0.5 * ax, ay), ay * 2.0) < 1.0 + 1e-9:
        raise ValueError(f"packing fraction {eta} too high for a lattice start with N={n_disks}")
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
    x = (ix + 0.5 * (iy % 2) + 0.25) * ax
    y = (iy + 0.5) * ay
    sites = np.stack([x.ravel(), y.ravel()], axis=1) % L
    keep = rng.choice(len(sites), n_disks, replace=False)
    return np.ascontiguousarray(sites[np.sort(keep)]), L


@nb.njit(cache=True)
def _push_apart(pos, L, max_iter):
    """Remove overlaps (pair distance < 1) by repeatedly moving both disks of
    each overlapping pair apart along their centre line (a crude
    steepest-descent relaxation of a soft repulsion).  Returns the number of
    overlapping pairs left (0 on success)."""
    N = pos.shape[0]
    half = 0.5 * L
    m = int(L / 1.0)
    c = L / m
    target = 1.0 + 1e-9
    n_over = 0
    for it in range(max_iter):
        # cell list for this pass
        head = np.full(m * m, -1, np.int64)
        nxt = np.full(N, -1, np.int64)
        for i in range(N):
            k = _cell_coord(pos[i, 1], c, m) * m + _cell_coord(pos[i, 0], c, m)
            nxt[i] = head[k]
            head[k] = i
        disp = np.zeros((N, 2))
        n_over = 0
        for i in range(N):
            kx = _cell_coord(pos[i, 0], c, m)
            ky = _cell_coord(pos[i, 1], c, m)
            for ox in range(-1, 2):
                for oy in range(-1, 2):
                    j = head[((ky + oy) % m) * m + (kx + ox) % m]
                    while j >= 0:
                        if j > i:
                            dx = pos[j, 0] - pos[i, 0]
                            if dx > half:
                                dx -= L
                            elif dx < -half:
                                dx += L
                            dy = pos[j, 1] - pos[i, 1]
                            if dy > half:
                                dy -= L
                            elif dy < -half:
                                dy += L
                            r2 = dx * dx + dy * dy
                            if r2 < target * target:
                                n_over += 1
                                r = math.sqrt(r2)
                                if r < 1e-12:
                                    dx, dy, r = 1.0, 0.0, 1.0
                                f = 0.5 * (target + 1e-6 - r) / r
                                disp[i, 0] -= f * dx
                                disp[i, 1] -= f * dy
                                disp[j, 0] += f * dx
                                disp[j, 1] += f * dy
                        j = nxt[j]
        if n_over == 0:
            return 0
        for i in range(N):
            for a in range(2):
                x = pos[i, a] + disp[i, a]
                x = x % L
                if x >= L:
                    x -= L
                pos[i, a] = x
    return n_over
